"""A replay buffer of reach-avoid transitions, saved incrementally as chunk files (never pickled).

The buffer is a ring: transition number ``i`` of the run (counted from 0 over the whole run, resumes included)
lives in slot ``i % capacity`` until it is overwritten. A checkpoint writes only the transitions added since the
previous one, as one chunk file (``take_unsaved``, ``write_chunk``), plus a small index (``index``): the ring's
counters and the chunks that hold what is in it now. ``load`` rebuilds the very same buffer from the index and its
chunks: the same transitions in the same slots and the same insertion position, so sampling after a resume is
sampling from the buffer as it was. Chunks no checkpoint lists (left by a kill, or fully overwritten in the ring)
are never read, and ``remove_unlisted_chunks`` deletes them.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

FIELDS = ("obs", "act", "next_obs", "l", "g", "next_l", "next_g", "terminated")
CHUNK_FORMAT = "safemanip-replay-chunk/1"
_CHUNK_NAME = re.compile(r"chunk-(\d{12})\.safetensors")


class Batch(NamedTuple):
    obs: torch.Tensor
    act: torch.Tensor
    next_obs: torch.Tensor
    l: torch.Tensor  # margins of s
    g: torch.Tensor
    next_l: torch.Tensor  # margins of s'
    next_g: torch.Tensor
    terminated: torch.Tensor  # bool: success or failure; time-limit truncations are False


def chunk_name(first: int) -> str:
    """The file of the chunk whose first transition is the run's transition number ``first``."""
    return f"chunk-{first:012d}.safetensors"


class ReplayBuffer:
    def __init__(self, capacity: int, obs_dim: int, act_dim: int):
        self.capacity, self.size, self.pos = capacity, 0, 0
        self.data = {
            "obs": np.zeros((capacity, obs_dim), np.float32), "act": np.zeros((capacity, act_dim), np.float32),
            "next_obs": np.zeros((capacity, obs_dim), np.float32),
            **{k: np.zeros(capacity, np.float32) for k in ("l", "g", "next_l", "next_g")},
            "terminated": np.zeros(capacity, bool),
        }
        self.added = 0
        """Transitions added over the run (resumes included): ``pos == added % capacity``."""
        self.saved = 0
        """Transitions up to which chunk files were taken (``take_unsaved``)."""
        self.chunks: list[tuple[int, int]] = []
        """(first transition, count) of the chunk files that hold what the buffer holds, oldest first."""

    def add_many(self, chunk: dict[str, np.ndarray]) -> None:
        n = len(chunk["obs"])
        idx = (self.pos + np.arange(n)) % self.capacity
        for k in FIELDS:
            self.data[k][idx] = chunk[k]
        self.pos = int((self.pos + n) % self.capacity)
        self.size = int(min(self.size + n, self.capacity))
        self.added += n

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        idx = rng.integers(0, self.size, size=batch_size)
        return Batch(*(torch.from_numpy(self.data[k][idx]) for k in FIELDS))

    # ------------------------------------------------------------------ incremental saving (checkpoints)
    def take_unsaved(self) -> tuple[int, dict[str, np.ndarray]] | None:
        """(number of the first transition, copies of the arrays) of what was added since the last call, for one new
        chunk file; None if nothing was. At most the buffer's contents: what was overwritten before it was saved is
        not needed. The chunk is entered in ``chunks`` at once (its file is written by the caller, maybe on another
        thread, before any index that lists it), and chunks now wholly overwritten leave the list."""
        first = max(self.saved, self.added - self.size)
        if first >= self.added:
            return None
        idx = np.arange(first, self.added) % self.capacity
        arrays = {k: self.data[k][idx] for k in FIELDS}  # a copy: the ring goes on filling while it is written
        self.chunks.append((first, self.added - first))
        self.saved = self.added
        oldest = self.added - self.size  # the oldest transition still in the ring
        self.chunks = [(f, n) for f, n in self.chunks if f + n > oldest]
        return first, arrays

    def index(self) -> dict[str, np.ndarray]:
        """The checkpoint's ``replay.npz``: the ring's counters and the chunks that hold its transitions (only call it
        right after ``take_unsaved``, so that the chunks cover the whole buffer)."""
        return {"capacity": np.int64(self.capacity), "added": np.int64(self.added), "pos": np.int64(self.pos),
                "size": np.int64(self.size), "chunk_first": np.array([f for f, _ in self.chunks], np.int64),
                "chunk_count": np.array([n for _, n in self.chunks], np.int64)}

    # ------------------------------------------------------------------ the whole buffer in one file
    def save(self, path: Path) -> None:
        """The whole buffer in one .npz: the checkpoints' format before issue 42 (``load`` still reads it)."""
        tmp = Path(str(path) + ".tmp.npz")
        np.savez(tmp, pos=self.pos, size=self.size, **{k: v[:self.size] for k, v in self.data.items()})
        os.replace(tmp, path)

    def load(self, path: Path, chunk_dir: Path | None = None) -> None:
        """Fill the buffer from a checkpoint's replay.npz: an index of chunk files in ``chunk_dir`` (checkpoints since
        issue 42) or the whole buffer (``save``, checkpoints before it). Every array is checked first (its presence,
        shape, dtype and finite values); ReplayFileError says what is wrong with a truncated or damaged file.
        Nothing is unpickled."""
        arrays = _read_npz(path, ("pos", "size"))
        if "chunk_first" in arrays:
            self._load_chunks(path, arrays, chunk_dir)
            return
        missing = [k for k in FIELDS if k not in arrays]
        if missing:
            raise ReplayFileError(f"{path} lacks {missing}")
        pos, size = _counter(path, arrays, "pos"), _counter(path, arrays, "size")
        if size > self.capacity or pos >= max(self.capacity, 1) or (size < self.capacity and pos != size):
            raise ReplayFileError(f"{path} holds {size} transitions at position {pos}, which does not fit a "
                                  f"buffer of {self.capacity} (buffer_size)")
        _check_arrays(path, arrays, size, self.data)
        self.pos, self.size = pos, size
        for k in FIELDS:
            self.data[k][:size] = arrays[k]
        # a ring that has wrapped holds the newest `capacity` transitions: any count with this position will do
        self.added = size if size < self.capacity else self.capacity + pos
        self.saved, self.chunks = self.added - size, []  # the first checkpoint writes it all as one chunk

    def _load_chunks(self, path: Path, counters: dict, chunk_dir: Path | None) -> None:
        names = ("capacity", "added", "pos", "size")
        capacity, added, pos, size = (_counter(path, counters, n) for n in names)
        if capacity != self.capacity:
            raise ReplayFileError(f"{path} is the index of a buffer of {capacity} transitions, not {self.capacity} "
                                  f"(buffer_size)")
        if size != min(added, capacity) or pos != added % max(capacity, 1):
            raise ReplayFileError(f"{path}: its counters do not agree (added {added}, size {size}, position {pos})")
        firsts, counts = counters["chunk_first"], counters.get("chunk_count", np.zeros((), np.int64))
        if firsts.ndim != 1 or firsts.shape != counts.shape or not {firsts.dtype.kind, counts.dtype.kind} <= set("iu"):
            raise ReplayFileError(f"{path}: chunk_first and chunk_count must be integer lists of one length")
        chunks = [(int(f), int(n)) for f, n in zip(firsts, counts)]
        # the chunks must follow one another and cover the ring's contents, the oldest up to the newest transition
        ends = [f + n for f, n in chunks]
        if chunks and (chunks[0][0] > added - size or ends[-1] != added or ends[0] <= added - size
                       or any(n < 1 for _, n in chunks) or any(e != f for e, (f, _) in zip(ends, chunks[1:]))):
            raise ReplayFileError(f"{path}: its chunks {chunks[:4]}... do not cover transitions {added - size} to "
                                  f"{added} one after another")
        if not chunks and size:
            raise ReplayFileError(f"{path} lists no chunk for its {size} transitions")
        if chunk_dir is None:
            raise ReplayFileError(f"{path} lists chunk files but no folder to read them from was given")
        for first, count in chunks:
            arrays = read_chunk(Path(chunk_dir) / chunk_name(first), first, count, self.data)
            skip = max(0, added - size - first)  # the start of the oldest chunk may be overwritten already
            idx = np.arange(first + skip, first + count) % capacity
            for k in FIELDS:
                self.data[k][idx] = arrays[k][skip:]
        self.added, self.pos, self.size = added, pos, size
        self.saved, self.chunks = added, chunks


def write_chunk(chunk_dir: Path, first: int, arrays: dict[str, np.ndarray]) -> Path:
    """One chunk file (safetensors), written under a temporary name, flushed to disk and renamed: a chunk that
    exists under its name is whole."""
    from safetensors.numpy import save_file

    from safemanip.util.files import atomic_path

    chunk_dir = Path(chunk_dir)
    chunk_dir.mkdir(parents=True, exist_ok=True)
    path = chunk_dir / chunk_name(first)
    with atomic_path(path) as tmp:
        save_file({k: np.ascontiguousarray(arrays[k]) for k in FIELDS}, tmp,
                  metadata={"format": CHUNK_FORMAT, "first": str(first)})
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
    return path


def read_chunk(path: Path, first: int, count: int, like: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A chunk file's arrays, its structure (``check_safetensors``), header and arrays checked against the index
    that lists it (``first``, ``count``) and the buffer's fields (``like``); ReplayFileError if anything is off."""
    from safetensors.numpy import load_file

    from safemanip.rl.checkpoint import PolicyFileError, check_safetensors

    if not path.is_file():
        raise ReplayFileError(f"{path} is missing (the checkpoint lists it)")
    try:
        header = check_safetensors(path)
    except PolicyFileError as err:
        raise ReplayFileError(f"{err}; the replay chunk is truncated or damaged") from err
    meta = header.get("__metadata__") or {}
    if meta.get("format") != CHUNK_FORMAT or meta.get("first") != str(first):
        raise ReplayFileError(f"{path} is not the replay chunk the checkpoint lists (format {meta.get('format')!r}, "
                              f"first transition {meta.get('first')!r}, expected {first})")
    try:
        arrays = load_file(str(path))
    except Exception as err:  # what the check above lets through and the Rust loader still refuses
        raise ReplayFileError(f"{path} cannot be read ({str(err)[:200]}); it is truncated or damaged") from err
    if set(arrays) != set(FIELDS):
        raise ReplayFileError(f"{path} holds {sorted(arrays)[:10]}, expected {list(FIELDS)}")
    _check_arrays(path, arrays, count, like)
    return arrays


def remove_unlisted_chunks(chunk_dir: Path, chunks: list[tuple[int, int]]) -> None:
    """Delete the chunk files of ``chunk_dir`` that ``chunks`` does not list (fully overwritten in the ring, or
    written for a checkpoint that a kill stopped) and temporary files a kill left; nothing else is touched."""
    keep = {chunk_name(first) for first, _ in chunks}
    if not Path(chunk_dir).is_dir():
        return
    for path in Path(chunk_dir).iterdir():
        stale = _CHUNK_NAME.fullmatch(path.name) and path.name not in keep
        if stale or (path.name.startswith(".chunk-") and path.name.endswith(".tmp")):
            path.unlink(missing_ok=True)


def _read_npz(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Every array of an .npz (allow_pickle=False), or ReplayFileError naming what is missing or damaged."""
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as f:
            missing = [k for k in required if k not in f.files]
            if missing:
                raise ReplayFileError(f"{path} lacks {missing}")
            return {k: f[k] for k in f.files}
    except ReplayFileError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
        raise ReplayFileError(f"{path} cannot be read ({err.__class__.__name__}: {str(err)[:200]}); it is "
                              f"truncated or damaged") from err


def _counter(path: Path, arrays: dict, name: str) -> int:
    value = arrays.get(name)
    if value is None or value.shape or value.dtype.kind not in "iu" or int(value) < 0:
        raise ReplayFileError(f"{path}: {name} must be a non-negative integer")
    return int(value)


def _check_arrays(path: Path, arrays: dict[str, np.ndarray], n: int, like: dict[str, np.ndarray]) -> None:
    for k in FIELDS:
        a = arrays[k]
        want = (n, *like[k].shape[1:])
        if a.shape != want or a.dtype != like[k].dtype or (a.dtype.kind == "f" and not np.isfinite(a).all()):
            raise ReplayFileError(f"{path}: {k} has shape {a.shape} and dtype {a.dtype}, expected {want} "
                                  f"{like[k].dtype} with finite values")


class ReplayFileError(ValueError):
    """A replay.npz or replay chunk that cannot be loaded; the message says what is wrong."""
