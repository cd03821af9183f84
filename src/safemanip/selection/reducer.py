"""The reducer: the full scene state -> the observation s_rel a k-object policy was trained on.

Layout (same as the env's, ``env/observation.py``): robot part (18) then k slots of
(obj_pos(3), obj_vel(3), constraint one-hot(3)), plus the footprint radius(1) for a policy trained
with ``object_size``.

Slot order: the selected objects **sorted by horizontal distance from their centre to the
manipulated (bottom) box's centre, nearest first** (ties by object id), recomputed every step from
the current state. A selector's own order carries no meaning the policy could rely on (training
scenes list objects in placement order, which is unrelated to distance), so a fixed geometric rule
keeps the input canonical: the same set of selected objects always gives the same observation.

Constraint one-hot: the constraint selector's type for each selected object, encoded exactly as the
env encodes it, unless the policy was trained ``conservative``: such a policy only ever saw
``no_contact`` slots, so every slot gets ``no_contact`` whatever the constraint selector says (paper
Table I setting, where pi^conser avoids every selected object).

Fewer objects than slots: if fewer than k ids are available (a scene with N < k objects, run with
padding allowed), the empty slots are filled with **dummy objects standing still at the back right of
the table** (x = 0.70, 0.45, 0.20, -0.05 m; y = +0.37 m, then y = +0.22 m), at least 0.35 m from the
straight path the box takes to the goal and clear of the stack, i.e. where training scenes had
their far-away clutter. A dummy's constraint is ``any_contact`` (nothing to avoid) for an
``all`` policy and ``no_contact`` for a ``conservative`` one (the only type it knows); its footprint
radius is 5 cm, a mid-sized catalog object. Dummies are
never judged: the judge only sees the real scene. With ``empty_slots`` (object-set policies, whose
selector may hand over any number of objects up to k) the missing slots are all zeros instead: an
all-zero one-hot marks a slot absent, and the set network leaves it out of its pooling.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from safemanip.env.observation import SceneState, build_observation, encode_constraints, observation_dim
from safemanip.scene.catalog import CONSTRAINT_TYPES
from safemanip.util.nearest import nearest_ids

POLICY_CONSTRAINT_SETS = ("conservative", "all")
# Back right of the table, 0.15-0.25 m apart, on the table top (object body origins sit at z = 0.0005);
# 8 places = MAX_OBJECTS, the most slots a policy can have.
DUMMY_POSITIONS = np.array([[x, y, 0.0005] for y in (0.37, 0.22) for x in (0.70, 0.45, 0.20, -0.05)])
DUMMY_RADIUS = 0.05


def order_by_distance(state: SceneState, ids: Sequence[int]) -> list[int]:
    """``ids`` sorted by horizontal distance from object centre to the manipulated-box centre, nearest first."""
    ids = sorted(int(i) for i in ids)  # distance first, id breaks ties
    return nearest_ids(state.bottom_pos, state.obj_pos, len(ids), candidates=ids)


class Reducer:
    """Builds s_rel for a policy with ``k`` slots trained on constraint set ``policy_constraints``."""

    def __init__(self, k: int, policy_constraints: str, pad: bool = False, empty_slots: bool = False,
                 object_size: bool = False):
        if policy_constraints not in POLICY_CONSTRAINT_SETS:
            raise ValueError(f"policy_constraints must be one of {POLICY_CONSTRAINT_SETS}, got {policy_constraints!r}")
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k}")
        self.k = int(k)
        self.policy_constraints = policy_constraints
        self.pad = pad
        self.empty_slots = empty_slots
        """Fill missing slots with zeros (all-zero one-hot: *absent* to an object-set policy, which masks them)
        instead of dummy objects; for set networks under a selector that picks a varying number of objects."""
        self.object_size = object_size
        """Slots carry the footprint radius too (the policy was trained with ``object_size``)."""
        self.obs_dim = observation_dim(self.k, object_size)
        self._dummy_type = "no_contact" if policy_constraints == "conservative" else "any_contact"

    def slots(self, state: SceneState, ids: Sequence[int], constraints: Sequence[str]) -> tuple[list[int], list[str]]:
        """(slot ids, slot constraint types) for the real objects, nearest first; no padding."""
        if len(set(ids)) != len(ids):
            raise ValueError(f"selected ids must be distinct, got {list(ids)}")
        if len(ids) > self.k:
            raise ValueError(f"{len(ids)} objects selected for a policy with k={self.k} slots")
        ordered = order_by_distance(state, ids)
        if self.policy_constraints == "conservative":
            types = ["no_contact"] * len(ordered)
        else:
            types = [constraints[i] for i in ordered]
            bad = [c for c in types if c not in CONSTRAINT_TYPES]
            if bad:
                raise ValueError(f"unknown constraint type(s) {bad}; expected {CONSTRAINT_TYPES}")
        return ordered, types

    def __call__(self, state: SceneState, ids: Sequence[int], constraints: Sequence[str]) -> np.ndarray:
        """s_rel for the objects ``ids``; ``constraints`` holds one type per object of the *full* scene."""
        ordered, types = self.slots(state, ids, constraints)
        missing = self.k - len(ordered)
        if missing and self.empty_slots:
            obs = np.zeros(self.obs_dim, dtype=np.float32)
            obs[:observation_dim(len(ordered), self.object_size)] = build_observation(
                state, ordered, encode_constraints(types), self.object_size)
            return obs
        if missing and not self.pad:
            raise ValueError(f"only {len(ordered)} objects for a policy with k={self.k} slots; allow padding "
                             f"(--pad) to fill the rest with far-away dummy objects")
        if missing:
            # append dummies as extra rows of the state so build_observation handles them like objects
            n = len(state.obj_pos)
            radius = None if state.obj_radius is None else np.concatenate([state.obj_radius,
                                                                           np.full(missing, DUMMY_RADIUS)])
            state = state._replace(obj_pos=np.concatenate([state.obj_pos, DUMMY_POSITIONS[:missing]]),
                                   obj_vel=np.concatenate([state.obj_vel, np.zeros((missing, 3))]), obj_radius=radius)
            ordered = ordered + list(range(n, n + missing))
            types = types + [self._dummy_type] * missing
        return build_observation(state, ordered, encode_constraints(types), self.object_size)
