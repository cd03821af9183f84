"""The toy reach-avoid system: a planar double integrator with one obstacle and one target.

Dynamics, margins and the Gymnasium env only (NumPy, no learner imports): the env registry
(``safemanip.rl.envs``) builds it by name, ``toy-double-integrator``. The exact grid solution and
the metrics that score a learned value against it are in ``safemanip.toy.oracle``.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class ToySpec:
    dt: float = 0.1
    a_max: float = 2.0
    v_max: float = 2.0
    obstacle: tuple[float, float] = (0.0, 0.0)
    obstacle_radius: float = 0.3
    target: tuple[float, float] = (0.6, 0.0)
    target_radius: float = 0.2


SPEC = ToySpec()


# ------------------------------------------------------------------ dynamics and margins (batched, pure)
def step_states(states: np.ndarray, actions: np.ndarray, spec: ToySpec = SPEC) -> np.ndarray:
    """Next states for a batch (..., 4) of states and (..., 2) of actions (clipped to [-1, 1])."""
    s = np.asarray(states, dtype=np.float64)
    a = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
    v = np.clip(s[..., 2:] + spec.a_max * spec.dt * a, -spec.v_max, spec.v_max)
    return np.concatenate([s[..., :2] + spec.dt * v, v], axis=-1)


def margins(states: np.ndarray, spec: ToySpec = SPEC) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(l, g, g_obstacle, g_box) of a batch (..., 4) (or (..., 2) positions)."""
    p = np.asarray(states, dtype=np.float64)[..., :2]
    l = spec.target_radius - np.linalg.norm(p - np.asarray(spec.target), axis=-1)
    g_obs = np.linalg.norm(p - np.asarray(spec.obstacle), axis=-1) - spec.obstacle_radius
    g_box = 1.0 - np.abs(p).max(axis=-1)
    return l, np.minimum(g_obs, g_box), g_obs, g_box


def sample_states(rng: np.random.Generator, n: int, spec: ToySpec = SPEC) -> np.ndarray:
    """n states uniform over the box x velocity box, restricted to running states (g >= 0, l <= 0)."""
    out = np.empty((0, 4))
    while len(out) < n:
        cand = np.concatenate([rng.uniform(-1, 1, size=(2 * n, 2)),
                               rng.uniform(-spec.v_max, spec.v_max, size=(2 * n, 2))], axis=1)
        l, g, _, _ = margins(cand, spec)
        out = np.concatenate([out, cand[(g >= 0) & (l <= 0)]])
    return out[:n]


# ------------------------------------------------------------------ the env
class ToyReachAvoidEnv(gym.Env):
    """Gymnasium env with the slide-out env's info contract (l, g, event, t; object/names/constraints
    are empty so the shared evaluation code runs unchanged). ``reset(options={"state": s})`` starts at s."""

    metadata = {"render_modes": []}

    def __init__(self, max_episode_steps: int = 100, spec: dict | None = None):
        self.toy = ToySpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in (spec or {}).items()})
        self.max_episode_steps = int(max_episode_steps)
        hi = np.array([1.5, 1.5, self.toy.v_max, self.toy.v_max], dtype=np.float32)
        self.observation_space = gym.spaces.Box(-hi, hi, dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._state = np.zeros(4)
        self._t = 0

    def _info(self, event: str) -> dict:
        l, g, _, _ = margins(self._state, self.toy)
        return {"l": float(l), "g": float(g), "event": event, "t": self._t, "object": None, "object_id": None,
                "names": [], "constraints": [], "is_success": event == "success"}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if options and options.get("state") is not None:
            self._state = np.asarray(options["state"], dtype=np.float64).reshape(4).copy()
        else:
            self._state = sample_states(self.np_random, 1, self.toy)[0]
        self._t = 0
        return self._state.astype(np.float32), self._info("running")

    def step(self, action):
        self._state = step_states(self._state, np.asarray(action).reshape(2), self.toy)
        self._t += 1
        l, g, g_obs, g_box = margins(self._state, self.toy)
        terminated = truncated = False
        if g < 0:
            event, terminated = ("failure:hard" if g_obs <= g_box else "failure:oob"), True
        elif l > 0:
            event, terminated = "success", True
        elif self._t >= self.max_episode_steps:
            event, truncated = "timeout", True
        else:
            event = "running"
        return self._state.astype(np.float32), float(min(l, g)), terminated, truncated, self._info(event)
