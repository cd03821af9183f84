"""The actor's forward pass in NumPy, importable without torch (rollout and evaluation workers)."""

from __future__ import annotations

import numpy as np


class NumpyActor:
    """The actor's forward pass in NumPy: no torch import in rollout workers, and faster at batch 1-8."""

    def __init__(self, arrays: list[np.ndarray]):
        self.set(arrays)

    def set(self, arrays: list[np.ndarray]) -> None:
        self.weights = [(arrays[i].T.copy(), arrays[i + 1]) for i in range(0, len(arrays), 2)]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float32)
        for i, (w, b) in enumerate(self.weights):
            x = x @ w + b
            if i < len(self.weights) - 1:
                np.maximum(x, 0.0, out=x)
        return np.tanh(x)
