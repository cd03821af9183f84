"""The actor's forward pass in NumPy, importable without torch (rollout and evaluation workers).

Two kinds, mirroring ``rl/networks.py``: ``NumpyActor`` (the flat MLP; weights as a list, layer by
layer) and ``NumpySetActor`` (the object-set actor; weights as a dict by parameter name).
``make_numpy_actor`` picks the class from the form of the weights.
"""

from __future__ import annotations

import numpy as np

ROBOT_DIM, SLOT_DIM = 18, 9  # env/observation.py's layout (kept in step by a test; no env import here)
REL_DIM = 3  # the set encoder's extra input: the object's position relative to the held box


class NumpyActor:
    """The actor's forward pass in NumPy: no torch import in rollout workers, and faster at batch 1-8."""

    network = "mlp"

    def __init__(self, arrays: list[np.ndarray]):
        self.set(arrays)

    def set(self, arrays: list[np.ndarray]) -> None:
        self.weights = [(arrays[i].T.copy(), arrays[i + 1]) for i in range(0, len(arrays), 2)]

    @property
    def obs_dim(self) -> int | None:
        """Input width the actor requires (None: any)."""
        return self.weights[0][0].shape[0]

    def arrays(self) -> list[np.ndarray]:
        """The weights in the form ``__init__`` takes (for a worker spec or a policy file)."""
        return [a for w, b in self.weights for a in (w.T.copy(), b)]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float32)
        for i, (w, b) in enumerate(self.weights):
            x = x @ w + b
            if i < len(self.weights) - 1:
                np.maximum(x, 0.0, out=x)
        return np.tanh(x)


def _stacked(arrays: dict[str, np.ndarray], prefix: str) -> list[tuple[np.ndarray, np.ndarray]]:
    n = sum(1 for k in arrays if k.startswith(prefix + "weights."))
    return [(arrays[f"{prefix}weights.{i}"][0], arrays[f"{prefix}biases.{i}"][0]) for i in range(n)]


class NumpySetActor:
    """The object-set actor (``networks.SetActor``) in NumPy: any number of slots, absent slots (all-zero
    one-hot) masked out of the pooling. The slot width (9, or 10 with ``object_size``) is read off the
    encoder's input width."""

    network = "set"
    obs_dim = None

    def __init__(self, arrays: dict[str, np.ndarray]):
        self.set(arrays)

    def set(self, arrays: dict[str, np.ndarray]) -> None:
        self._arrays = {k: np.asarray(v, dtype=np.float32) for k, v in arrays.items()}
        self.encoder = _stacked(self._arrays, "net.encoder.")
        self.head = _stacked(self._arrays, "net.head.")
        self.embed = self.encoder[-1][0].shape[1]
        self.slot_width = self.encoder[0][0].shape[0] - REL_DIM

    def arrays(self) -> dict[str, np.ndarray]:
        return dict(self._arrays)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float32)
        single = x.ndim == 1
        x = np.atleast_2d(x)
        batch = x.shape[0]
        robot = x[:, :ROBOT_DIM]
        slots = x[:, ROBOT_DIM:].reshape(batch, -1, self.slot_width)
        mask = slots[..., 6:9].sum(-1) > 0.5
        pooled = np.zeros((batch, 2 * self.embed), np.float32)
        if slots.shape[1]:
            e = np.concatenate([slots, slots[..., 0:3] - robot[:, None, 6:9]], axis=-1)
            for w, b in self.encoder:
                e = np.maximum(e @ w + b, 0.0)
            e = np.where(mask[..., None], e, 0.0)
            count = np.maximum(mask.sum(1, keepdims=True), 1).astype(np.float32)
            pooled = np.concatenate([e.sum(1) / count, e.max(1)], axis=-1).astype(np.float32)
        h = np.concatenate([robot, pooled], axis=-1)
        for i, (w, b) in enumerate(self.head):
            h = h @ w + b
            if i < len(self.head) - 1:
                np.maximum(h, 0.0, out=h)
        out = np.tanh(h)
        return out[0] if single else out


def make_numpy_actor(arrays: list[np.ndarray] | dict[str, np.ndarray]):
    """``NumpyActor`` for a list of layer arrays (flat MLP), ``NumpySetActor`` for a dict (set network)."""
    return NumpySetActor(arrays) if isinstance(arrays, dict) else NumpyActor(arrays)
