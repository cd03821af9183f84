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
        with np.load(path, allow_pickle=False) as f:
            self.pos, self.size = int(f["pos"]), int(f["size"])
            for k in FIELDS:
                self.data[k][:self.size] = f[k]
