"""What every sub-command shares: the error convention (one ``safemanip <command>: error: ...`` line on
stderr and exit code 2, never a traceback), argparse types that refuse non-finite and out-of-range
numbers before any work starts, and the compute/semantic backend flag vocabulary:

  --backend      compute: where episodes run (local | ray)
  --vlm-backend  semantics: who answers object/constraint queries (semantic | openai)
"""

from __future__ import annotations

import argparse
import math


class CliError(ValueError):
    """An input problem to report in one line (exit code 2)."""


def int_in(lo: int, hi: int):
    """argparse type: an integer in [lo, hi]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be in {lo}..{hi:,}, got {value:,}")
        return value
    parse.__name__ = "integer"
    return parse


def float_in(lo: float, hi: float, lo_open: bool = False):
    """argparse type: a finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if value < lo or value > hi or (lo_open and value == lo):
            raise argparse.ArgumentTypeError(f"must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value:g}")
        return value
    parse.__name__ = "number"
    return parse


SEED = int_in(0, 2**31 - 1)
"""Every command's --seed: a non-negative integer numpy and MuJoCo accept."""


def add_compute_backend(p: argparse.ArgumentParser) -> None:
    from safemanip.evaluation.parallel import BACKENDS

    p.add_argument("--workers", type=int_in(1, 256), default=2,
                   help="parallel workers (local processes or Ray CPUs; default 2)")
    p.add_argument("--backend", default="local", choices=BACKENDS,
                   help="compute: local: spawn processes on this machine; ray: Ray tasks (default: local)")
    p.add_argument("--address", help="Ray cluster address for --backend ray (default: start a local Ray instance)")


def add_vlm_options(p) -> None:
    """The semantic-backend options of eval and sweep (``VLM_FIELDS`` of the evaluation harness)."""
    from safemanip.semantics.base import VLM_BACKENDS

    vlm = p.add_argument_group("semantic backend (for --selector dynamic-vlm / --constraints vlm)")
    vlm.add_argument("--vlm-backend", choices=VLM_BACKENDS,
                     help="semantic: offline embedding model (default); openai: any OpenAI-compatible server")
    vlm.add_argument("--vlm-model", help="model name for --vlm-backend openai (default gpt-4o)")
    vlm.add_argument("--vlm-base-url", help="server URL for --vlm-backend openai (default: OpenAI)")
    vlm.add_argument("--vlm-cache", metavar="DIR", help="answer cache folder for --vlm-backend openai")
    vlm.add_argument("--vlm-cache-only", action="store_true", help="never call the server; a cache miss falls back")
    add_vlm_budget(vlm)


def add_vlm_budget(p) -> None:
    """--vlm-timeout and the time budgets of the openai backend (eval and sweep)."""
    p.add_argument("--vlm-timeout", type=float_in(0, 600, lo_open=True), metavar="S",
                   help="openai backend: per-request timeout in seconds (default 30)")
    p.add_argument("--vlm-episode-budget", type=float_in(0, 86_400, lo_open=True), metavar="S",
                   help="openai backend: seconds of VLM queries per episode; after that the episode's "
                        "selectors use their fallback (default: none)")
    p.add_argument("--vlm-run-budget", type=float_in(0, 30 * 86_400, lo_open=True), metavar="S",
                   help="openai backend: seconds of VLM queries per worker process over the run; after that "
                        "every query falls back (default: none)")
    p.add_argument("--vlm-max-failures", type=int_in(1, 10_000), metavar="N",
                   help="openai backend: consecutive failed queries after which the circuit breaker opens and "
                        "the fallback answers for the rest of the run (default 5)")
