"""The observation builder: the paper's full state, with each object's constraint type attached.

Layout (float32), for N clutter objects:
  [ee_pos(3), ee_vel(3), bottom_pos(3), bottom_vel(3), top_pos(3), top_vel(3),
   N x (obj_pos(3), obj_vel(3), constraint one-hot(3))]
Positions are in the world frame (table-centre origin), velocities in m/s. The constraint type is a
one-hot over (no_contact, soft_contact, any_contact) rather than the paper's integer: an MLP then
need not learn that the three codes are unordered categories.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from gymnasium import spaces

from safemanip.scene.catalog import CONSTRAINT_TYPES

ROBOT_DIM = 18
SLOT_DIM = 9
CONSTRAINT_INDEX = {c: i for i, c in enumerate(CONSTRAINT_TYPES)}


class SceneState(NamedTuple):
    ee_pos: np.ndarray
    ee_vel: np.ndarray
    bottom_pos: np.ndarray
    bottom_vel: np.ndarray
    top_pos: np.ndarray
    top_vel: np.ndarray
    obj_pos: np.ndarray  # (N, 3)
    obj_vel: np.ndarray  # (N, 3)


def observation_dim(n_slots: int) -> int:
    return ROBOT_DIM + SLOT_DIM * n_slots


def observation_space(n_slots: int) -> spaces.Box:
    dim = observation_dim(n_slots)
    low = np.full(dim, -10.0, dtype=np.float32)
    high = np.full(dim, 10.0, dtype=np.float32)
    for s in range(n_slots):  # one-hot entries are in [0, 1]
        start = ROBOT_DIM + s * SLOT_DIM + 6
        low[start:start + 3], high[start:start + 3] = 0.0, 1.0
    return spaces.Box(low, high, dtype=np.float32)


def encode_constraints(constraints) -> np.ndarray:
    """(N, 3) one-hot rows for a sequence of constraint type names."""
    out = np.zeros((len(constraints), 3), dtype=np.float32)
    for i, c in enumerate(constraints):
        out[i, CONSTRAINT_INDEX[c]] = 1.0
    return out


def build_observation(state: SceneState, object_ids, constraints_onehot: np.ndarray) -> np.ndarray:
    """Observation with the objects ``object_ids`` in that slot order, each tagged with its one-hot row.

    The full-state env passes all ids in index order; a task-relevant policy passes the k selected ids.
    """
    ids = np.asarray(object_ids, dtype=int)
    obs = np.empty(ROBOT_DIM + SLOT_DIM * len(ids), dtype=np.float32)
    for k, part in enumerate((state.ee_pos, state.ee_vel, state.bottom_pos, state.bottom_vel, state.top_pos, state.top_vel)):
        obs[3 * k:3 * k + 3] = part
    slots = obs[ROBOT_DIM:].reshape(len(ids), SLOT_DIM)
    slots[:, 0:3] = state.obj_pos[ids]
    slots[:, 3:6] = state.obj_vel[ids]
    slots[:, 6:9] = constraints_onehot
    return obs.clip(-10.0, 10.0, out=obs)
