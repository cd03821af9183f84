"""Checkpoints and policy files: safetensors for tensors, JSON for everything else, written atomically.

A checkpoint is a folder ``checkpoint/`` holding ``state.safetensors`` (networks, targets, optimiser
moments), ``replay.npz`` (the replay buffer's index: its counters and the chunk files that hold its transitions)
and ``meta.json`` (config and counters). The transitions themselves are in ``replay/chunk-*.safetensors`` beside
it, appended to: each checkpoint writes only those added since the one before (``rl/buffer.py``). A chunk is
written under a temporary name and renamed, then the checkpoint is written as ``checkpoint.new/`` and swapped in
with renames, so a run killed at any moment leaves the old or the new checkpoint whole, with every chunk it lists;
``recover_checkpoint`` resumes from the newest complete one, and chunks no checkpoint lists are never read.
``CheckpointWriter`` does the writing on a thread of its own, off the learner's path. Nothing is ever unpickled,
and every .safetensors file is checked (``check_safetensors``) before it is loaded.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import threading
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file as load_numpy
from safetensors.numpy import save_file as save_numpy

from safemanip.scene.embodiment import EMBODIMENTS
from safemanip.util.files import JSONInputError, atomic_path, atomic_write_text, parse_json, read_json_file
from safemanip.util.values import brief, is_int

POLICY_FORMAT = "safemanip-policy/2"
"""The policy file format: its training config (``train_config``) holds the env's settings under ``env``."""
RETIRED_POLICY_FORMATS = {
    "safemanip-policy/1": "written before 2026-12-08, with the env's settings flat in its training config",
}
"""Formats no longer read, and what they were: refused with what to do, never converted (issue 43)."""


CHECKPOINT_NAMES = ("checkpoint.new", "checkpoint", "checkpoint.old")


REPLAY_DIR = "replay"
"""The run folder's folder of replay chunks (``rl/buffer.py``), shared by its checkpoints."""


def write_checkpoint(run_dir: Path, tensors: dict, replay, meta: dict) -> Path:
    """Write a checkpoint of ``replay`` (a ``ReplayBuffer``) now, in this thread (``CheckpointWriter``: on another)."""
    return _write_checkpoint(Path(run_dir), tensors, replay.take_unsaved(), replay.index(), meta)


def _write_checkpoint(run_dir: Path, tensors: dict, chunk, index: dict, meta: dict) -> Path:
    """The new chunk (``take_unsaved``) first; then ``checkpoint.new/`` (meta.json last: its presence marks the
    folder complete), swapped in: checkpoint -> checkpoint.old, checkpoint.new -> checkpoint
    (``recover_checkpoint`` finishes an interrupted swap, whichever rename it stopped between); then the chunks the
    new checkpoint no longer lists go. Every complete checkpoint on disk therefore finds each chunk it lists."""
    from safetensors.torch import save_file

    from safemanip.rl.buffer import remove_unlisted_chunks, write_chunk

    chunks = run_dir / REPLAY_DIR
    if chunk is not None:
        write_chunk(chunks, *chunk)
    new, cur, old = (run_dir / n for n in ("checkpoint.new", "checkpoint", "checkpoint.old"))
    shutil.rmtree(new, ignore_errors=True)
    new.mkdir(parents=True)
    save_file(tensors, new / "state.safetensors")
    np.savez(new / "replay.npz", **index)
    atomic_write_text(new / "meta.json", json.dumps(meta, indent=1))
    _fsync_dir(new)
    shutil.rmtree(old, ignore_errors=True)
    if cur.exists():
        os.replace(cur, old)
    os.replace(new, cur)
    shutil.rmtree(old, ignore_errors=True)
    remove_unlisted_chunks(chunks, list(zip(index["chunk_first"].tolist(), index["chunk_count"].tolist())))
    return cur


class CheckpointWriter:
    """Checkpoints written on a thread of its own, one at a time. ``submit`` takes, in the caller's thread, what
    the checkpoint holds (the tensors as given, which ``Learner.state_tensors`` has copied, and the transitions
    added since the last checkpoint) and returns; the files are written beside training. ``wait`` waits for the
    write in flight and raises what it failed with (a failed write also fails the next ``submit``)."""

    def __init__(self) -> None:
        self.thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def submit(self, run_dir: Path, tensors: dict, replay, meta: dict) -> None:
        self.wait()
        args = (Path(run_dir), tensors, replay.take_unsaved(), replay.index(), meta)
        self.thread = threading.Thread(target=self._write, args=args, name="checkpoint-writer", daemon=True)
        self.thread.start()

    def _write(self, *args) -> None:
        try:
            _write_checkpoint(*args)
        except BaseException as err:  # noqa: BLE001 - handed to the training loop's thread by ``wait``
            self.error = err

    def wait(self) -> None:
        if self.thread is not None:
            self.thread.join()
            self.thread = None
        if self.error is not None:
            error, self.error = self.error, None
            raise error


def _complete_meta(path: Path) -> dict | None:
    """The meta of a complete checkpoint folder (all three files, meta readable), else None."""
    if not all((path / f).is_file() for f in ("meta.json", "state.safetensors", "replay.npz")):
        return None
    try:
        return read_checkpoint_meta(path)
    except (OSError, ValueError):
        return None


class CheckpointError(ValueError):
    """A checkpoint that cannot be resumed from; the message says what is damaged and how to recover."""


def read_checkpoint_meta(path: Path) -> dict:
    """A checkpoint folder's meta.json, read with the bounded JSON reader and its fields' types checked (counters
    are non-negative integers, the elapsed time a finite number, the config an object); CheckpointError if not."""
    where = Path(path) / "meta.json"
    try:
        meta = read_json_file(where, f"{where}")
    except OSError as err:
        raise CheckpointError(f"cannot read {where}: {err.strerror or err}") from err
    except JSONInputError as err:
        raise CheckpointError(str(err)) from err
    if not isinstance(meta, dict):
        raise CheckpointError(f"{where} is not a checkpoint's meta.json: not a JSON object")
    wrong = [key for key in ("updates", "env_steps") if not is_int(meta.get(key)) or meta[key] < 0]
    if not _is_number(meta.get("elapsed_s")) or meta["elapsed_s"] < 0:
        wrong.append("elapsed_s")
    if "restarts" in meta and (not is_int(meta["restarts"]) or meta["restarts"] < 0):
        wrong.append("restarts")
    if "best" in meta and not (isinstance(meta["best"], dict) and _is_number(meta["best"].get("success", 0.0))):
        wrong.append("best")
    if "config" in meta and not isinstance(meta["config"], dict):
        wrong.append("config")
    if "evals" in meta and (not is_int(meta["evals"]) or meta["evals"] < 0):
        wrong.append("evals")
    if wrong:
        raise CheckpointError(f"{where} is damaged: {', '.join(wrong)} missing or of the wrong type")
    return meta


def find_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint folder of a run (most updates), among checkpoint, checkpoint.new and
    checkpoint.old: a crash between the renames of ``write_checkpoint`` may leave the newest in any."""
    best, best_key = None, None
    for name in CHECKPOINT_NAMES:
        meta = _complete_meta(Path(run_dir) / name)
        if meta is not None:
            key = (meta["updates"], meta.get("env_steps", 0))
            if best_key is None or key > best_key:
                best, best_key = Path(run_dir) / name, key
    return best


def recover_checkpoint(run_dir: Path) -> Path | None:
    """Make ``checkpoint/`` the newest complete checkpoint (finishing an interrupted swap) and remove the
    others; returns its path, or None if the run has no complete checkpoint."""
    run_dir = Path(run_dir)
    newest = find_checkpoint(run_dir)
    if newest is None:
        return None
    cur = run_dir / "checkpoint"
    if newest != cur:
        spare = run_dir / "checkpoint.stale"
        shutil.rmtree(spare, ignore_errors=True)
        if cur.exists():
            os.replace(cur, spare)
        os.replace(newest, cur)
        shutil.rmtree(spare, ignore_errors=True)
    for name in ("checkpoint.new", "checkpoint.old"):
        shutil.rmtree(run_dir / name, ignore_errors=True)
    return cur


def read_checkpoint(path: Path):
    """(state tensors, replay path, meta) of a checkpoint folder, each file checked first (CheckpointError or
    PolicyFileError saying what is wrong)."""
    from safetensors.torch import load_file

    path = Path(path)
    meta = read_checkpoint_meta(path)
    state = path / "state.safetensors"
    check_safetensors(state)
    try:
        tensors = load_file(state)
    except Exception as err:  # what the check above lets through and the Rust loader still refuses
        raise PolicyFileError(f"{state}: the safetensors loader refused it ({_brief(err)})") from err
    return tensors, path / "replay.npz", meta


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
    with atomic_path(path) as tmp:
        save_numpy(tensors, tmp, metadata={"format": POLICY_FORMAT, "network": network,
                                           "meta": json.dumps({**meta, "network": network})})
    return path


class PolicyFileError(ValueError):
    pass


def resolve_policy(name_or_path: str | Path) -> Path:
    """A path as given if it exists, else a policy by name (``rarl-k2-conservative-s0``) or by ``policies/FILE``
    (the form the shipped sweeps use, so they run from any working folder), found through the policy folders'
    manifests (``rl/policy_index.py``: the benchmark's results/policies, then the package's demo policy).

    Only those two forms fall back: a path into any other folder that does not exist stays missing (and is
    reported so), rather than silently standing for a known policy that happens to share its file name."""
    from safemanip.rl.policy_index import find_policy

    path = Path(name_or_path)
    if path.exists():
        return path
    if path.parent not in (Path("."), Path("policies")):
        return path
    return find_policy(path.name) or path


MAX_HEADER_BYTES = 10_000_000
MAX_HEADER_DEPTH = 8
"""A safetensors header nests 3 levels (header, entry, shape); the policy metadata inside is a string."""
MAX_FILE_BYTES = 2_000_000_000
_DTYPE_BYTES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2, "I8": 1, "U8": 1, "BOOL": 1}


def check_safetensors(path: str | Path) -> dict:
    """Check a .safetensors file's structure without trusting it: size, an 8-byte header length that fits
    the file, a JSON header whose tensor offsets tile the data exactly. Returns the parsed header;
    raises PolicyFileError saying what is wrong."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(8)
            if len(head) < 8:
                raise PolicyFileError(f"{path} is not a safetensors file: {size} bytes, too short for a header")
            (n,) = struct.unpack("<Q", head)
            if n < 2 or n > MAX_HEADER_BYTES or 8 + n > size:
                raise PolicyFileError(f"{path} is not a valid safetensors file: header length {n} does not fit "
                                      f"the file ({size} bytes); is it truncated or another format?")
            if size > MAX_FILE_BYTES:
                raise PolicyFileError(f"{path} is {size} bytes, larger than any policy or checkpoint of this package")
            raw = f.read(n)
    except OSError as err:
        raise PolicyFileError(f"cannot read {path}: {err.strerror or err}") from err
    try:
        header = parse_json(raw, f"{path}: its header", max_bytes=MAX_HEADER_BYTES, max_depth=MAX_HEADER_DEPTH)
    except JSONInputError as err:
        raise PolicyFileError(f"{path} is not a valid safetensors file: its header is not JSON ({err.reason})") from err
    if not isinstance(header, dict):
        raise PolicyFileError(f"{path} is not a valid safetensors file: its header is not a JSON object")
    spans = []
    for name, info in header.items():
        if name == "__metadata__":
            if not isinstance(info, dict) or not all(isinstance(v, str) for v in info.values()):
                raise PolicyFileError(f"{path}: its metadata must map names to strings")
            continue
        if not _tensor_entry_ok(info):
            raise PolicyFileError(f"{path}: tensor {name[:80]!r} has an invalid entry in the header: {str(info)[:200]}")
        spans.append(tuple(info["data_offsets"]))
    end = 0
    for a, b in sorted(spans):
        if a != end:
            raise PolicyFileError(f"{path}: tensor data overlaps or leaves gaps; the file is damaged")
        end = b
    if 8 + n + end != size:
        raise PolicyFileError(f"{path}: the header describes {end} bytes of tensor data but the file holds "
                              f"{size - 8 - n}; the file is truncated or damaged")
    return header


def _tensor_entry_ok(info) -> bool:
    """A header entry as the Rust loader reads it: exactly dtype, shape and data_offsets; a known dtype; integer
    (not float, not boolean) dimensions and offsets that fit 64 bits; offsets spanning the tensor's bytes."""
    if not isinstance(info, dict) or set(info) != {"dtype", "shape", "data_offsets"}:
        return False
    dtype, shape, offsets = info["dtype"], info["shape"], info["data_offsets"]
    if dtype not in _DTYPE_BYTES or not isinstance(shape, list) or not isinstance(offsets, list) or len(offsets) != 2:
        return False
    if not all(is_int(v) and 0 <= v < 2**63 for v in (*shape, *offsets)):
        return False
    a, b = offsets
    return a <= b and b - a == math.prod(shape) * _DTYPE_BYTES[dtype]


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _brief(err: BaseException, limit: int = 200) -> str:
    text = str(err)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def load_policy(path: str | Path):
    """(NumpyActor, meta) from a policy file, a shipped policy's name, or a run folder (its policy).

    The file is checked before use: a safetensors structure (``check_safetensors``), the policy format
    tag, JSON metadata, the layer keys, shapes that chain (and match ``obs_dim``/``act_dim``/``hidden`` of
    the metadata when given) and finite weights; any problem is a PolicyFileError saying what is wrong."""
    from safemanip.rl.numpy_actor import NumpyActor, NumpySetActor

    path = resolve_policy(path)
    if path.is_dir():
        candidates = [path / "policy.safetensors", path / "best.safetensors"]
        found = next((c for c in candidates if c.exists()), None)
        if found is None:
            raise PolicyFileError(f"{path} holds no policy.safetensors or best.safetensors; pass a policy file")
        path = found
    if not path.exists():
        from safemanip.rl.policy_index import BENCHMARK_POLICIES, ENV_VAR, known_policies

        raise PolicyFileError(f"no policy file at {path}; pass a .safetensors file or a policy name: "
                              f"{known_policies()} (the benchmark's policies are found in {BENCHMARK_POLICIES} of "
                              f"the repository, or in the folder {ENV_VAR} names)")
    header = check_safetensors(path).get("__metadata__") or {}
    if header.get("format") in RETIRED_POLICY_FORMATS:
        raise PolicyFileError(f"{path} is a policy of the retired format {header['format']!r} "
                              f"({RETIRED_POLICY_FORMATS[header['format']]}; retired in issue 43); this version reads "
                              f"{POLICY_FORMAT!r} only. Re-train it with safemanip train (a benchmark policy: re-train "
                              f"its run and re-promote it with safemanip bench promote)")
    if header.get("format") != POLICY_FORMAT:
        raise PolicyFileError(f"{path} is not a safemanip policy (format {header.get('format')!r}, "
                              f"expected {POLICY_FORMAT!r})")
    try:
        meta = parse_json(header.get("meta", ""), "the policy's metadata")
    except JSONInputError as err:
        raise PolicyFileError(f"{path}: the policy's metadata is not valid JSON ({err.reason})") from err
    if not isinstance(meta, dict):
        raise PolicyFileError(f"{path}: the policy's metadata must be a JSON object")
    problems = policy_meta_problems(meta)
    if problems:
        raise PolicyFileError(f"{path}: its metadata is not that of a policy this package wrote: {'; '.join(problems)}; "
                              f"re-export it with safemanip train")
    try:
        tensors = load_numpy(str(path))
    except Exception as err:  # what check_safetensors lets through and the Rust loader still refuses
        raise PolicyFileError(f"{path}: the safetensors loader refused it ({_brief(err)})") from err
    network = header.get("network", "mlp")  # files from before the set network have none: a flat MLP
    if network == "set":
        return NumpySetActor(_checked_set_arrays(path, tensors, meta)), meta
    if network != "mlp":
        raise PolicyFileError(f"{path}: unknown network {network!r} in the header (expected 'mlp' or 'set')")
    n_layers = len(tensors) // 2
    expected = {f"layer{i}.{w}" for i in range(n_layers) for w in ("weight", "bias")}
    if n_layers < 1 or set(tensors) != expected:
        raise PolicyFileError(f"{path}: expected tensors layer0.weight, layer0.bias, ... layer{{n}}.bias, got "
                              f"{sorted(tensors)[:8]}")
    arrays = []
    prev = None
    for i in range(n_layers):
        w, b = tensors[f"layer{i}.weight"], tensors[f"layer{i}.bias"]
        if w.ndim != 2 or b.shape != (w.shape[0],) or (prev is not None and w.shape[1] != prev):
            raise PolicyFileError(f"{path}: layer {i} has shapes weight {w.shape} / bias {b.shape} that do not chain")
        if w.dtype.kind != "f" or not (np.isfinite(w).all() and np.isfinite(b).all()):
            raise PolicyFileError(f"{path}: layer {i} holds non-finite (NaN or infinite) or non-float weights; "
                                  "the policy cannot be used")
        prev = w.shape[0]
        arrays += [w, b]
    dims = {"obs_dim": tensors["layer0.weight"].shape[1], "act_dim": prev,
            "hidden": [tensors[f"layer{i}.weight"].shape[0] for i in range(n_layers - 1)]}
    wrong = [f"{key} {meta[key]} (the weights say {value})" for key, value in dims.items()
             if key in meta and meta[key] != value]
    if wrong:
        raise PolicyFileError(f"{path}: the metadata does not match the weights: {', '.join(wrong)}")
    return NumpyActor(arrays), meta


def _checked_set_arrays(path: Path, tensors: dict[str, np.ndarray], meta: dict) -> dict[str, np.ndarray]:
    """The object-set actor's arrays (``set.net.{encoder,head}.{weights,biases}.{i}``, one head: (1, in, out) and
    (1, 1, out)), checked as ``load_policy`` checks a flat MLP: the keys, shapes that chain from a slot's
    features to the action, finite float weights, and ``act_dim``/``hidden`` of the metadata."""
    from safemanip.rl.numpy_actor import REL_DIM, ROBOT_DIM, SLOT_DIM

    counts = {part: sum(1 for k in tensors if k.startswith(f"set.net.{part}.weights.")) for part in ("encoder", "head")}
    expected = {f"set.net.{part}.{kind}.{i}" for part, n in counts.items() for i in range(n)
                for kind in ("weights", "biases")}
    if min(counts.values()) < 1 or set(tensors) != expected:
        raise PolicyFileError(f"{path}: expected the set actor's tensors set.net.encoder.weights.0, ... "
                              f"set.net.head.biases.{{n}}, got {sorted(tensors)[:8]}")
    # a slot's features: (pos, vel, one-hot[, footprint radius]) and the position relative to the held box
    prev = SLOT_DIM + (1 if policy_object_size(meta) else 0) + REL_DIM
    for part in ("encoder", "head"):
        for i in range(counts[part]):
            w, b = tensors[f"set.net.{part}.weights.{i}"], tensors[f"set.net.{part}.biases.{i}"]
            if w.ndim != 3 or w.shape[:2] != (1, prev) or b.shape != (1, 1, w.shape[2]):
                raise PolicyFileError(f"{path}: set actor {part} layer {i} has shapes weight {w.shape} / bias "
                                      f"{b.shape} that do not chain")
            if w.dtype.kind != "f" or not (np.isfinite(w).all() and np.isfinite(b).all()):
                raise PolicyFileError(f"{path}: set actor {part} layer {i} holds non-finite (NaN or infinite) or "
                                      "non-float weights; the policy cannot be used")
            prev = w.shape[2]
        if part == "encoder":
            prev = ROBOT_DIM + 2 * prev  # the head reads the robot state and the mean+max pooling
    n_head = counts["head"]
    dims = {"act_dim": prev, "hidden": [tensors[f"set.net.head.weights.{i}"].shape[2] for i in range(n_head - 1)]}
    wrong = [f"{key} {meta[key]} (the weights say {value})" for key, value in dims.items()
             if key in meta and meta[key] != value]
    if wrong:
        raise PolicyFileError(f"{path}: the metadata does not match the weights: {', '.join(wrong)}")
    return {k[len("set."):]: v for k, v in tensors.items()}


def embodiment_problem(meta: dict, wanted: str | None, name: str) -> str | None:
    """Why the policy ``name`` (with metadata ``meta``) cannot drive embodiment ``wanted`` (None: its own), or None.

    A policy's input and its learned dynamics belong to the robot it was trained on; and a policy whose
    metadata names no embodiment predates the Panda arm: it was trained on the first version's task (a
    floating hand, success on passing the goal), which no longer exists.
    """
    env_kwargs = meta.get("env_kwargs") if isinstance(meta.get("env_kwargs"), dict) else {}
    trained = env_kwargs.get("embodiment")
    if trained is None:
        return (f"{name} predates the Panda arm: it was trained on the first version's task (a floating hand, "
                f"success on passing the goal, safety checked at 20 Hz), which this version no longer has; train a "
                f"new policy with `safemanip train --embodiment panda ...` (or `--embodiment hand` for the ablation)")
    if trained not in EMBODIMENTS:
        return f"{name}: its metadata names an unknown embodiment {trained!r}; use one of {list(EMBODIMENTS)}"
    if wanted is not None and wanted != trained:
        return (f"{name} was trained on the {trained!r} embodiment and cannot drive the {wanted!r}: its inputs and "
                f"learned dynamics belong to that robot. Use --embodiment {trained}, or train a policy for the "
                f"{wanted!r} (safemanip train --embodiment {wanted} ...)")
    return None


def policy_embodiment(meta: dict) -> str:
    """The embodiment a (checked) policy was trained on."""
    return meta["env_kwargs"]["embodiment"]


def policy_action_curve(meta: dict) -> float:
    """The action curve a (checked) policy was trained with; policies from before the curve existed: 1 (linear)."""
    return float(meta["env_kwargs"].get("action_curve", 1.0))


def policy_object_size(meta: dict) -> bool:
    """Whether a policy's slots carry the footprint radius; policies from before the option (or without
    env_kwargs, as the set actor's weight check may see them): no."""
    env_kwargs = meta.get("env_kwargs")
    return isinstance(env_kwargs, dict) and bool(env_kwargs.get("object_size", False))


def policy_meta_problems(meta: dict) -> list[str]:
    """What is wrong with the types and ranges of a policy's metadata (keys that are absent are not checked here:
    the commands say which ones they need). Booleans must be JSON booleans, counts integers, numbers finite."""
    from safemanip.env.config import EnvConfig, EnvConfigError
    from safemanip.rl.config import ConfigError, TrainConfig
    from safemanip.scene.config import MAX_OBJECTS

    def is_str(v):
        return isinstance(v, str)

    def is_count(lo, hi=None):
        return lambda v: is_int(v) and lo <= v and (hi is None or v <= hi)

    def is_in(lo, hi):
        return lambda v: _is_number(v) and lo <= v <= hi

    def is_widths(v):
        return isinstance(v, list) and all(is_int(h) and h >= 1 for h in v)

    top = {"algorithm": (is_str, "a name"), "k": (is_count(0, MAX_OBJECTS), f"a slot count 0..{MAX_OBJECTS}"),
           "constraints": (is_str, "a name"), "obs_dim": (is_count(1), "a positive integer"),
           "act_dim": (is_count(1), "a positive integer"), "hidden": (is_widths, "a list of layer widths"),
           "network": (lambda v: v in ("mlp", "set"), "'mlp' or 'set'"), "env_kwargs": (
               lambda v: isinstance(v, dict), "an object"), "env_steps": (is_count(0), "a count"),
           "updates": (is_count(0), "a count"), "wall_s": (is_in(0, math.inf), "a number of seconds"),
           "eval": (lambda v: v is None or isinstance(v, dict), "an object or null"),
           "train_config": (lambda v: isinstance(v, dict), "an object"),
           "train_command": (lambda v: v is None or is_str(v), "a string or null")}
    problems = [f"{key}={brief(meta[key], 60)} is not {want}" for key, (ok, want) in top.items()
                if key in meta and not ok(meta[key])]
    env_kwargs = meta.get("env_kwargs")
    if isinstance(env_kwargs, dict) and env_kwargs.get("env", "slide-out") == "slide-out":
        try:  # the env's own checker, as for every other way in
            EnvConfig.from_kwargs(env_kwargs, "env_kwargs")
        except EnvConfigError as err:
            problems.append(f"env_kwargs: {err}")
    train = meta.get("train_config")
    if isinstance(train, dict):
        try:
            TrainConfig.from_dict(train)
        except ConfigError as err:
            problems.append("train_config: " + str(err).replace("invalid training config:\n  - ", "")
                            .replace("\n  - ", "; ").strip())
    return problems
