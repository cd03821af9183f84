"""Checkpoints and policy files: safetensors for tensors, JSON for everything else, written atomically.

A checkpoint is a folder ``checkpoint/`` holding ``state.safetensors`` (networks, targets, optimiser
moments), ``replay.npz`` and ``meta.json`` (config and counters). It is written as
``checkpoint.new/`` and swapped in with renames, so a run killed at any moment leaves either the old
or the new checkpoint whole. Nothing is ever unpickled.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file as load_numpy
from safetensors.numpy import save_file as save_numpy

POLICY_FORMAT = "safemanip-policy/1"


def write_checkpoint(run_dir: Path, tensors: dict, replay, meta: dict) -> Path:
    from safetensors.torch import save_file

    run_dir = Path(run_dir)
    new, cur, old = run_dir / "checkpoint.new", run_dir / "checkpoint", run_dir / "checkpoint.old"
    shutil.rmtree(new, ignore_errors=True)
    new.mkdir(parents=True)
    save_file(tensors, new / "state.safetensors")
    replay.save(new / "replay.npz")
    (new / "meta.json").write_text(json.dumps(meta, indent=1))
    _fsync_dir(new)
    shutil.rmtree(old, ignore_errors=True)
    if cur.exists():
        os.replace(cur, old)
    os.replace(new, cur)
    shutil.rmtree(old, ignore_errors=True)
    return cur


def find_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint folder of a run, if any (a crash between renames leaves .old)."""
    for name in ("checkpoint", "checkpoint.old"):
        path = Path(run_dir) / name
        if (path / "meta.json").exists() and (path / "state.safetensors").exists():
            return path
    return None


def read_checkpoint(path: Path):
    from safetensors.torch import load_file

    meta = json.loads((Path(path) / "meta.json").read_text())
    return load_file(Path(path) / "state.safetensors"), Path(path) / "replay.npz", meta


def _fsync_dir(path: Path) -> None:
    for f in path.iterdir():
        with open(f, "rb") as fh:
            os.fsync(fh.fileno())


# ------------------------------------------------------------------------------------------ policies
def save_policy(path: Path, actor_arrays: list[np.ndarray] | dict[str, np.ndarray], meta: dict) -> Path:
    """One self-describing file: actor weights plus JSON metadata in the safetensors header. The header's
    ``network`` ('mlp' or 'set') says which actor class the weights belong to."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(actor_arrays, dict):  # set network: parameters by name
        network, tensors = "set", {f"set.{k}": np.ascontiguousarray(a) for k, a in actor_arrays.items()}
    else:
        network = "mlp"
        tensors = {f"layer{i // 2}.{'weight' if i % 2 == 0 else 'bias'}": a for i, a in enumerate(actor_arrays)}
    tmp = path.with_suffix(".tmp")
    save_numpy(tensors, str(tmp), metadata={"format": POLICY_FORMAT, "network": network,
                                            "meta": json.dumps({**meta, "network": network})})
    os.replace(tmp, path)
    return path


class PolicyFileError(ValueError):
    pass


SHIPPED_POLICIES = Path(__file__).resolve().parent.parent / "policies"


def resolve_policy(name_or_path: str | Path) -> Path:
    """A path as given if it exists, else a shipped policy by name (``rarl-k2-conservative``) or file name."""
    path = Path(name_or_path)
    if path.exists():
        return path
    for candidate in (SHIPPED_POLICIES / path.name, SHIPPED_POLICIES / f"{path.name}.safetensors"):
        if candidate.exists():
            return candidate
    return path


def load_policy(path: str | Path):
    """(NumpyActor, meta) from a policy file, a shipped policy's name, or a run folder (its policy)."""
    from safetensors import safe_open

    from safemanip.rl.numpy_actor import NumpyActor, NumpySetActor

    path = resolve_policy(path)
    if path.is_dir():
        candidates = [path / "policy.safetensors", path / "best.safetensors"]
        found = next((c for c in candidates if c.exists()), None)
        if found is None:
            raise PolicyFileError(f"{path} holds no policy.safetensors or best.safetensors; pass a policy file")
        path = found
    if not path.exists():
        shipped = sorted(p.stem for p in SHIPPED_POLICIES.glob("*.safetensors"))
        raise PolicyFileError(f"no policy file at {path}; pass a .safetensors file or a shipped policy name: {shipped}")
    with safe_open(str(path), framework="numpy") as f:
        header = f.metadata() or {}
    if header.get("format") != POLICY_FORMAT:
        raise PolicyFileError(f"{path} is not a safemanip policy (format {header.get('format')!r}, "
                              f"expected {POLICY_FORMAT!r})")
    tensors = load_numpy(str(path))
    if header.get("network", "mlp") == "set":  # files before the set network have no "network": flat MLP
        return NumpySetActor({k[len("set."):]: v for k, v in tensors.items()}), json.loads(header["meta"])
    n_layers = len(tensors) // 2
    arrays = []
    for i in range(n_layers):
        arrays += [tensors[f"layer{i}.weight"], tensors[f"layer{i}.bias"]]
    return NumpyActor(arrays), json.loads(header["meta"])
