"""Object and constraint selectors behind the protocols of ``selection/base.py``, and their registry.

What "nearest" means here
-------------------------
Every metric selector ranks objects by the **horizontal (x-y) distance between the object's centre
(its body origin) and the centre of the manipulated (bottom) cereal box**, nearest first, ties broken
by object id. The box, not the end-effector, is what hits things in this task: the hand holds the box
at its near edge, so the box's centre is the better proxy for "about to be touched". Heights are
ignored because every object stands on the same table top. (The semantic selectors in
``safemanip.semantics.selectors`` order their candidates for the backend by distance to the
end-effector instead; their fallback is the same box-centred dynamic kNN as here.)

Object selectors (``OBJECT_SELECTORS``)
  ``static-knn``   the k nearest at t = 0, fixed for the episode (never re-picks);
  ``dynamic-knn``  the k nearest, recomputed every ``interval`` control steps (default 4, the paper's);
  ``dynamic-radius`` every object within ``radius`` of the box (nearest first, at most k), on the
                   dynamic-knn schedule: a varying number of objects, for a set-network policy;
  ``privileged``   the k nearest objects whose ground-truth class is fragile (re-picked on the same
                   schedule as dynamic-knn), then the nearest others if there are fewer than k fragile
                   ones. Reads ``SceneView.privileged_classes``; an oracle, not a deployable method;
  ``privileged-criticality`` the same oracle by true criticality: fragile objects and soft ones within reach,
                   then other soft ones, then durable ones (``criticality_first``); the reference for semantic
                   selection;
  ``full``         every object in id order: the layout a k == N full-state policy was trained on;
  ``semantic``     ``semantics.selectors.DynamicVLMSelector``: a VLM (OpenAI-compatible backend), or offline the
                   classes decided from the names, ranked by ``criticality_first``;
  ``dynamic-vlm``  the same selector; offline, the earlier risk ranking (kept by name, see docs/semantics.md).

Constraint selectors (``CONSTRAINT_SELECTORS``), each assigning one type per object at t = 0:
  ``conservative`` no_contact for every object (the paper's F^conser);
  ``ground-truth`` the judge's own constraint per object (from ``privileged_classes``);
  ``vlm``          ``semantics.selectors.VLMConstraintSelector`` (ConstraintVLM).

The registry that maps these names (and the semantic selectors') to factories lives above both, in
``evaluation/registry.py``: this module imports nothing from the semantics layer.
"""

from __future__ import annotations

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_OF_CLASS
from safemanip.selection.base import SceneView, nearest_ids

DEFAULT_INTERVAL = 4  # paper Sec. V: Dynamic-kNN and Dynamic-VLM are queried every four time steps
DEFAULT_RADIUS = 0.35  # dynamic-radius: about the box's half length plus one object footprint plus a step's travel
DEFAULT_SOFT_REACH = 10.0
"""criticality_first: a soft object whose centre is within this horizontal distance of the held box's centre [m] ranks
with the fragile ones (0: every fragile object before any soft one). 10 m, farther than any table, puts every soft
object in the fragile objects' tier: chosen on development block 40 over 0, 0.2, 0.3, 0.4 and 10 m by a rule fixed
before the runs (results/semantics/soft_reach_dev.py, results/semantics/soft-reach-dev40.md)."""


def _due(last_t: int | None, t: int, interval: int) -> bool:
    # a t smaller than the last pick means a new episode began without reset(): pick again
    return last_t is None or t - last_t >= interval or t < last_t


class StaticKNN:
    """The k objects nearest to the manipulated box at t = 0; never re-picks during the episode."""

    name = "static-knn"

    def __init__(self) -> None:
        self._ids: list[int] | None = None
        self.picks = 0

    def reset(self, view: SceneView, k: int) -> None:
        self._ids = nearest_ids(view.box_position, view.positions, k)
        self.picks = 1

    def select(self, view: SceneView, k: int) -> list[int]:
        if self._ids is None:  # used without reset(): the first view it sees is its t = 0
            self.reset(view, k)
        return list(self._ids)


class DynamicKNN:
    """The k objects nearest to the manipulated box, recomputed every ``interval`` control steps.

    Picks at t = 0, interval, 2 * interval, ...; in between it keeps the last pick, as the paper's
    Dynamic-kNN does (it shares the query schedule of Dynamic-VLM so the two compare like for like).
    """

    name = "dynamic-knn"

    def __init__(self, interval: int = DEFAULT_INTERVAL) -> None:
        if interval < 1:
            raise ValueError(f"the re-selection interval must be >= 1 control step, got {interval}")
        self.interval = int(interval)
        self._ids: list[int] = []
        self._last_t: int | None = None
        self.picks = 0

    def reset(self, view: SceneView, k: int) -> None:
        self._ids, self._last_t, self.picks = [], None, 0

    def _pick(self, view: SceneView, k: int) -> list[int]:
        return nearest_ids(view.box_position, view.positions, k)

    def select(self, view: SceneView, k: int) -> list[int]:
        if _due(self._last_t, view.t, self.interval):
            self._ids = self._pick(view, k)
            self._last_t = view.t
            self.picks += 1
        return list(self._ids)


class PrivilegedSelector(DynamicKNN):
    """Oracle: the k nearest *fragile* objects by ground truth, topped up with the nearest others.

    Re-picks on the dynamic-knn schedule, so the only difference from dynamic-knn is the semantics
    (paper Table I, "privileged selection").
    """

    name = "privileged"

    def _pick(self, view: SceneView, k: int) -> list[int]:
        if view.privileged_classes is None:
            raise ValueError("the privileged selector needs SceneView.privileged_classes (ground-truth classes)")
        fragile = [i for i, c in enumerate(view.privileged_classes) if c == "fragile"]
        ids = nearest_ids(view.box_position, view.positions, k, candidates=fragile)
        if len(ids) < k:
            others = [i for i in range(len(view.names)) if i not in set(ids)]
            ids += nearest_ids(view.box_position, view.positions, k - len(ids), candidates=others)
        return ids


def criticality_first(box_position: np.ndarray, positions: np.ndarray, classes, k: int,
                      soft_reach: float = DEFAULT_SOFT_REACH) -> list[int]:
    """The k most safety-critical objects, in tiers, nearest to the held box first within a tier (``nearest_ids``):
    every fragile object and every soft one within ``soft_reach`` of the box; then the other soft ones; then the
    durable ones. A later tier fills the k slots only when the earlier ones hold fewer than k objects.

    Why soft objects within reach join the fragile tier: a fragile object must never be touched, a soft one only
    slowly, so far away the fragile one matters more; but a soft object the box is about to meet matters more than a
    fragile one it will pass at a distance, and a policy that never sees it hits it at speed ("among the objects that
    might come in contact, choose the more fragile ones", the paper's prompt). One rule for the privileged reference
    (``PrivilegedCriticality``, true classes) and the semantic selector (``semantics.semantic_backend``, the classes
    it decided)."""
    if soft_reach < 0:
        raise ValueError(f"soft_reach must be >= 0 m, got {soft_reach}")
    box = np.asarray(box_position, float)[:2]
    near = np.hypot(*(np.asarray(positions, float)[:, :2] - box).T) <= soft_reach if len(classes) else []
    tiers = ([i for i, c in enumerate(classes) if c == "fragile" or (c == "soft" and near[i])],
             [i for i, c in enumerate(classes) if c == "soft" and not near[i]],
             [i for i, c in enumerate(classes) if c not in ("fragile", "soft")])
    ids: list[int] = []
    for members in tiers:
        if len(ids) >= k:
            break
        ids += nearest_ids(box_position, positions, k - len(ids), candidates=members)
    return ids


class PrivilegedCriticality(DynamicKNN):
    """Oracle reference for semantic selection: ``criticality_first`` on the ground-truth classes (the nearest
    fragile objects and soft ones within reach, then the other soft ones, then durable ones), on the dynamic-knn
    schedule.

    ``privileged`` tops up with the nearest objects of any class; with soft objects in the scene that lets a durable
    one take a slot while a soft one nearby goes unseen (Table II)."""

    name = "privileged-criticality"

    def __init__(self, interval: int = DEFAULT_INTERVAL, soft_reach: float = DEFAULT_SOFT_REACH) -> None:
        super().__init__(interval)
        if soft_reach < 0:
            raise ValueError(f"soft_reach must be >= 0 m, got {soft_reach}")
        self.soft_reach = float(soft_reach)

    def _pick(self, view: SceneView, k: int) -> list[int]:
        if view.privileged_classes is None:
            raise ValueError("the privileged-criticality selector needs SceneView.privileged_classes")
        return criticality_first(view.box_position, view.positions, view.privileged_classes, k, self.soft_reach)


class DynamicRadius(DynamicKNN):
    """Dynamic k: every object whose centre is within ``radius`` (horizontal) of the manipulated box's centre,
    nearest first, at most k (the policy's slot count), re-picked on the dynamic-knn schedule.

    The number of picked objects varies from 0 to k, so the policy must accept absent slots: an object-set
    network (``rl/networks.py``, ``network="set"``) with the reducer's empty slots."""

    name = "dynamic-radius"
    variable_k = True
    """Returns between 0 and k ids (the episode runner accepts fewer than k from such a selector)."""

    def __init__(self, interval: int = DEFAULT_INTERVAL, radius: float = DEFAULT_RADIUS) -> None:
        super().__init__(interval)
        if radius <= 0:
            raise ValueError(f"the selection radius must be > 0 m, got {radius}")
        self.radius = float(radius)

    def _pick(self, view: SceneView, k: int) -> list[int]:
        ids = nearest_ids(view.box_position, view.positions, k)
        near = np.linalg.norm(view.positions[ids, :2] - view.box_position[:2], axis=1) <= self.radius if ids else []
        return [i for i, inside in zip(ids, near) if inside]


class FullSelector:
    """Every object, in id order: what a policy trained with k == N objects saw during training."""

    name = "full"

    def reset(self, view: SceneView, k: int) -> None:
        pass

    def select(self, view: SceneView, k: int) -> list[int]:
        return list(range(min(k, len(view.names))))


class ConservativeConstraints:
    """no_contact for every object: the safe choice when semantics are unknown (paper F^conser)."""

    name = "conservative"

    def assign(self, view: SceneView) -> list[str]:
        return ["no_contact"] * len(view.names)


class GroundTruthConstraints:
    """The constraint the judge uses for each object (class -> constraint), read from the privileged view."""

    name = "ground-truth"

    def assign(self, view: SceneView) -> list[str]:
        if view.privileged_classes is None:
            raise ValueError("the ground-truth constraint selector needs SceneView.privileged_classes")
        return [CONSTRAINT_OF_CLASS[c] for c in view.privileged_classes]
