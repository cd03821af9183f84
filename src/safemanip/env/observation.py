"""The observation builder: the paper's full state, with each object's constraint type attached.

Layout (float32), for N clutter objects:
  [ee_pos(3), ee_vel(3), bottom_pos(3), bottom_vel(3), top_pos(3), top_vel(3),
   N x (obj_pos(3), obj_vel(3), constraint one-hot(3)[, footprint radius(1)])]
Positions are in the world frame (table-centre origin), velocities in m/s. The constraint type is a
one-hot over (no_contact, soft_contact, any_contact) rather than the paper's integer: an MLP then
need not learn that the three codes are unordered categories.

The footprint radius (m; ``object_size=True``, off by default, recorded in a policy's metadata) is
the object's size as a perception system's bounding box would give it: the catalog's objects range
from 3 to 10 cm, and without it a policy cannot tell how far from an object's centre the held box
must pass. The paper's object state has no size; its objects are not described as differing much.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from gymnasium import spaces

from safemanip.scene.catalog import CONSTRAINT_TYPES

ROBOT_DIM = 18
SLOT_DIM = 9
"""A slot without the size entry (the paper's layout, and every policy trained before ``object_size``)."""
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
    obj_radius: np.ndarray | None = None  # (N,) footprint radii [m]; needed for ``object_size`` observations


def slot_dim(object_size: bool = False) -> int:
    return SLOT_DIM + 1 if object_size else SLOT_DIM


def observation_dim(n_slots: int, object_size: bool = False) -> int:
    return ROBOT_DIM + slot_dim(object_size) * n_slots


def observation_space(n_slots: int, object_size: bool = False) -> spaces.Box:
    dim, width = observation_dim(n_slots, object_size), slot_dim(object_size)
    low = np.full(dim, -10.0, dtype=np.float32)
    high = np.full(dim, 10.0, dtype=np.float32)
    for s in range(n_slots):  # one-hot entries are in [0, 1], a radius in [0, 1] m
        start = ROBOT_DIM + s * width + 6
        low[start:start + width - 6], high[start:start + width - 6] = 0.0, 1.0
    return spaces.Box(low, high, dtype=np.float32)


def encode_constraints(constraints) -> np.ndarray:
    """(N, 3) one-hot rows for a sequence of constraint type names."""
    out = np.zeros((len(constraints), 3), dtype=np.float32)
    for i, c in enumerate(constraints):
        out[i, CONSTRAINT_INDEX[c]] = 1.0
    return out


def build_observation(state: SceneState, object_ids, constraints_onehot: np.ndarray,
                      object_size: bool = False) -> np.ndarray:
    """Observation with the objects ``object_ids`` in that slot order, each tagged with its one-hot row
    (and, with ``object_size``, its footprint radius from ``state.obj_radius``).

    The full-state env passes all ids in index order; a task-relevant policy passes the k selected ids.
    """
    ids = np.asarray(object_ids, dtype=int)
    if object_size and state.obj_radius is None:
        raise ValueError("object_size observations need SceneState.obj_radius (the env's scene_state() fills it)")
    obs = np.empty(observation_dim(len(ids), object_size), dtype=np.float32)
    for k, part in enumerate((state.ee_pos, state.ee_vel, state.bottom_pos, state.bottom_vel, state.top_pos, state.top_vel)):
        obs[3 * k:3 * k + 3] = part
    slots = obs[ROBOT_DIM:].reshape(len(ids), slot_dim(object_size))
    slots[:, 0:3] = state.obj_pos[ids]
    slots[:, 3:6] = state.obj_vel[ids]
    slots[:, 6:9] = constraints_onehot
    if object_size:
        slots[:, 9] = state.obj_radius[ids]
    return obs.clip(-10.0, 10.0, out=obs)
