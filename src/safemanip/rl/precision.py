"""Which device the learner runs on and whether its forward passes use bf16 autocast.

``precision="auto"`` picks bf16 only where it is native and measured faster: a CUDA GPU that supports
bf16, or a CPU with AVX512-BF16 or AMX (read from /proc/cpuinfo) on which a quick start-up timing of
a batch-200 256x256 layer stack shows bf16 ahead of fp32. Without native support PyTorch still *runs*
bf16 on a CPU, by emulation, an order of magnitude slower (measured: 13 ms vs 1.1 ms per forward pass on an
AVX2-only EPYC); ``auto`` falls back to fp32 there and ``bf16`` runs it anyway, with a warning.
Master weights, optimiser state, losses and Bellman targets stay fp32 in either case.
"""

from __future__ import annotations

import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

DEVICES = ("auto", "cpu", "cuda")
PRECISIONS = ("auto", "bf16", "fp32")


@dataclass(frozen=True)
class Precision:
    device: str
    """'cpu' or 'cuda' (or 'cuda:N')."""
    dtype: str
    """'bf16' (autocast for forward passes) or 'fp32'."""
    reason: str
    """Why: what was asked for and what the check found."""

    @property
    def autocast_dtype(self) -> torch.dtype | None:
        return torch.bfloat16 if self.dtype == "bf16" else None

    def as_dict(self) -> dict:
        return asdict(self)


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} asked for, but PyTorch sees no CUDA GPU (use --device auto or cpu)")
    return torch.device(device)


def cpu_bf16_flags() -> set[str]:
    """The CPU's native bf16 features, from /proc/cpuinfo (empty elsewhere or when it is unreadable)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split()) & {"avx512_bf16", "amx_bf16"}
    return set()


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux): every speed a run or benchmark reports belongs to it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.split(":")[0].strip() in ("model name", "Model"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _time_forward(device: torch.device, dtype: torch.dtype | None, repeats: int = 5) -> float:
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(200, 256, generator=gen).to(device)
    ws = [torch.randn(256, 256, generator=gen).to(device) / 16 for _ in range(3)]

    def run():
        with torch.no_grad(), torch.autocast(device.type, dtype=dtype or torch.float32, enabled=dtype is not None):
            h = x
            for w in ws:
                h = torch.relu(h @ w)
        if device.type == "cuda":
            torch.cuda.synchronize()
        return h

    run()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t0)
    return best


def resolve_precision(precision: str, device: torch.device) -> Precision:
    """The precision to train in on ``device``, with the reason (logged and written to the run summary)."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    dev = str(device)
    if precision == "fp32":
        return Precision(dev, "fp32", "fp32 asked for")
    if device.type == "cuda":
        native = torch.cuda.is_bf16_supported()
        what = f"CUDA {torch.cuda.get_device_name(device)}: bf16 {'supported' if native else 'not supported'}"
    else:
        flags = cpu_bf16_flags()
        native = bool(flags)
        what = f"CPU {'with ' + '/'.join(sorted(flags)) if flags else 'without AVX512-BF16/AMX'}"
    if precision == "bf16":
        note = "" if native else " (not native: emulated, expect it to be much slower than fp32)"
        return Precision(dev, "bf16", f"bf16 asked for; {what}{note}")
    if not native:
        return Precision(dev, "fp32", f"auto: {what}, so fp32")
    t32, t16 = _time_forward(device, None), _time_forward(device, torch.bfloat16)
    if t16 < t32 / 1.1:
        return Precision(dev, "bf16", f"auto: {what}; bf16 forward {t32 / t16:.1f}x faster than fp32 at start-up")
    return Precision(dev, "fp32", f"auto: {what}, but bf16 was not faster at start-up ({t32 / t16:.2f}x), so fp32")
