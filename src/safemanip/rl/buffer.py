"""A replay buffer of reach-avoid transitions, saved as .npz (never pickled)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

FIELDS = ("obs", "act", "next_obs", "l", "g", "next_l", "next_g", "terminated")


class Batch(NamedTuple):
    obs: torch.Tensor
    act: torch.Tensor
    next_obs: torch.Tensor
    l: torch.Tensor  # margins of s
    g: torch.Tensor
    next_l: torch.Tensor  # margins of s'
    next_g: torch.Tensor
    terminated: torch.Tensor  # bool: success or failure; time-limit truncations are False


class ReplayBuffer:
    def __init__(self, capacity: int, obs_dim: int, act_dim: int):
        self.capacity, self.size, self.pos = capacity, 0, 0
        self.data = {
            "obs": np.zeros((capacity, obs_dim), np.float32), "act": np.zeros((capacity, act_dim), np.float32),
            "next_obs": np.zeros((capacity, obs_dim), np.float32),
            **{k: np.zeros(capacity, np.float32) for k in ("l", "g", "next_l", "next_g")},
            "terminated": np.zeros(capacity, bool),
        }

    def add_many(self, chunk: dict[str, np.ndarray]) -> None:
        n = len(chunk["obs"])
        idx = (self.pos + np.arange(n)) % self.capacity
        for k in FIELDS:
            self.data[k][idx] = chunk[k]
        self.pos = int((self.pos + n) % self.capacity)
        self.size = int(min(self.size + n, self.capacity))

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        idx = rng.integers(0, self.size, size=batch_size)
        return Batch(*(torch.from_numpy(self.data[k][idx]) for k in FIELDS))

    def save(self, path: Path) -> None:
        tmp = Path(str(path) + ".tmp.npz")
        np.savez(tmp, pos=self.pos, size=self.size, **{k: v[:self.size] for k, v in self.data.items()})
        os.replace(tmp, path)

    def load(self, path: Path) -> None:
        """Fill the buffer from a saved .npz, every array checked first (its presence, shape, dtype and finite
        values); ReplayFileError says what is wrong with a truncated or damaged file. Nothing is unpickled."""
        import zipfile

        try:
            with np.load(path, allow_pickle=False) as f:
                missing = [k for k in ("pos", "size", *FIELDS) if k not in f.files]
                if missing:
                    raise ReplayFileError(f"{path} lacks {missing}")
                pos, size = f["pos"], f["size"]
                if pos.shape or size.shape or pos.dtype.kind not in "iu" or size.dtype.kind not in "iu":
                    raise ReplayFileError(f"{path}: pos and size must be integers")
                pos, size = int(pos), int(size)
                if not 0 <= size <= self.capacity or not 0 <= pos < max(self.capacity, 1):
                    raise ReplayFileError(f"{path} holds {size} transitions at position {pos}, which does not fit a "
                                          f"buffer of {self.capacity} (buffer_size)")
                arrays = {k: f[k] for k in FIELDS}
        except ReplayFileError:
            raise
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            raise ReplayFileError(f"{path} cannot be read ({err.__class__.__name__}: {str(err)[:200]}); it is "
                                  f"truncated or damaged") from err
        for k, a in arrays.items():
            want = (size, *self.data[k].shape[1:])
            if a.shape != want or a.dtype != self.data[k].dtype or (a.dtype.kind == "f" and not np.isfinite(a).all()):
                raise ReplayFileError(f"{path}: {k} has shape {a.shape} and dtype {a.dtype}, expected {want} "
                                      f"{self.data[k].dtype} with finite values")
        self.pos, self.size = pos, size
        for k in FIELDS:
            self.data[k][:size] = arrays[k]


class ReplayFileError(ValueError):
    """A replay.npz that cannot be loaded; the message says what is wrong."""
