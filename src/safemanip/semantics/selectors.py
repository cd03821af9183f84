"""Selectors (selection/base.py protocols) backed by a semantic backend, with fallbacks.

A backend can fail (network, timeouts, out-of-schema answers, cache misses). A rollout must not
stop because of that, so every failed query falls back to a metric heuristic for that query only,
logs a warning and is counted in ``stats.fallbacks``; the next query tries the backend again.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_TYPES
from safemanip.selection.base import SceneView, SelectorStats, nearest_ids
from safemanip.semantics.base import Backend, BackendError, ConstraintQuery, ObjectQuery, object_label
from safemanip.semantics.images import annotate, tile, to_png

log = logging.getLogger(__name__)

ObjectFallback = Callable[[SceneView, int], list[int]]


def dynamic_knn(view: SceneView, k: int) -> list[int]:
    """The k objects nearest (horizontally) to the manipulated box right now."""
    return nearest_ids(view.box_position, view.positions, k)


def conservative_constraints(view: SceneView) -> list[str]:
    """Every object gets no_contact: the safe default when nothing is known about semantics."""
    return ["no_contact"] * len(view.names)


class DynamicVLMSelector:
    """Re-picks the k relevant objects every ``query_interval`` control steps by asking ``backend``.

    Between queries the last selection is kept (the paper queries every four steps). When the
    backend wants images and the view can render, the annotated current frame is tiled after the
    frames of the previous ``history - 1`` queries (oldest left), as in the paper's Fig. 3.
    ``stats`` accumulates over episodes; read or replace it between evaluation runs.
    """

    def __init__(self, backend: Backend, query_interval: int = 4, fallback: ObjectFallback | None = None, *,
                 task: str | None = None, history: int = 2, name: str | None = None) -> None:
        if query_interval < 1:
            raise ValueError(f"query_interval must be >= 1, got {query_interval}")
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        self.backend = backend
        self.query_interval = int(query_interval)
        self.fallback = fallback or dynamic_knn
        self.task = task
        self.history = int(history)
        self.name = name or "dynamic-vlm"
        self.stats = SelectorStats()
        self.last_answer = None
        """The last successful ObjectAnswer (explanations are useful when inspecting rollouts)."""
        self._frames: list[np.ndarray] = []
        self._current: list[int] = []
        self._last_query_t: int | None = None

    def reset(self, view: SceneView, k: int) -> None:
        self._frames = []
        self._current = []
        self._last_query_t = None
        self.last_answer = None
        try:
            self.backend.prepare(view.names)
        except BackendError as exc:
            # preparation is an optimisation; the queries themselves will fall back if the backend is down
            log.warning("%s: backend prepare failed: %s", self.name, exc)

    def select(self, view: SceneView, k: int) -> list[int]:
        due = self._last_query_t is None or view.t - self._last_query_t >= self.query_interval or view.t < self._last_query_t
        if due or len(self._current) != min(k, len(view.names)):
            self._current = self._query(view, k)
            self._last_query_t = view.t
        return list(self._current)

    def _query(self, view: SceneView, k: int) -> list[int]:
        n = min(k, len(view.names))
        if n <= 0:
            return []
        self.stats.queries += 1
        start = time.perf_counter()
        try:
            order = nearest_ids(view.ee_position, view.positions, len(view.names))
            images = self._images(view) if self.backend.needs_images else None
            answer = self.backend.select_objects(ObjectQuery(view=view, k=k, order=order, task=self.task,
                                                             images=images))
            ids = answer.ids
            if len(ids) != n or len(set(ids)) != n or not all(0 <= i < len(view.names) for i in ids):
                raise BackendError(f"answer {ids} is not {n} distinct object ids of a {len(view.names)}-object scene")
            self.last_answer = answer
        except BackendError as exc:
            self.stats.fallbacks += 1
            log.warning("%s: t=%d object query failed, using fallback for this query: %s", self.name, view.t, exc)
            ids = self.fallback(view, n)
        self.stats.latencies_s.append(time.perf_counter() - start)
        return [int(i) for i in ids]

    def _images(self, view: SceneView) -> list[bytes] | None:
        if view.render is None:
            return None
        try:
            frame = view.render()
            labels = {i: object_label(i, name) for i, name in enumerate(view.names)}
            annotated = annotate(frame["image"], frame.get("boxes", {}), labels, frame.get("ee_path_px"))
        except Exception as exc:  # a broken renderer should degrade to a text-only query, not end the rollout
            log.warning("%s: t=%d rendering failed, asking with names only: %s", self.name, view.t, exc)
            return None
        self._frames = (self._frames + [annotated])[-self.history:]
        return [to_png(tile(self._frames))]


class VLMConstraintSelector:
    """Asks ``backend`` once per episode (at t = 0, or when the scene's names change) for constraint types.

    On failure every object gets the ``conservative`` answer (all no_contact) for that episode.
    """

    def __init__(self, backend: Backend, fallback: Callable[[SceneView], list[str]] | None = None, *,
                 task: str | None = None, name: str | None = None) -> None:
        self.backend = backend
        self.fallback = fallback or conservative_constraints
        self.task = task
        self.name = name or "constraint-vlm"
        self.stats = SelectorStats()
        self.last_answer = None
        self._names: tuple[str, ...] | None = None
        self._constraints: list[str] = []

    def reset(self) -> None:
        self._names = None
        self._constraints = []
        self.last_answer = None

    def assign(self, view: SceneView) -> list[str]:
        if view.t == 0 or self._names != tuple(view.names):
            self._constraints = self._query(view)
            self._names = tuple(view.names)
        return list(self._constraints)

    def _query(self, view: SceneView) -> list[str]:
        if not view.names:
            return []
        self.stats.queries += 1
        start = time.perf_counter()
        try:
            images = None
            if self.backend.needs_images and view.render is not None:
                try:
                    frame = view.render()
                    labels = {i: object_label(i, name) for i, name in enumerate(view.names)}
                    images = [to_png(annotate(frame["image"], frame.get("boxes", {}), labels))]
                except Exception as exc:
                    log.warning("%s: rendering failed, asking with names only: %s", self.name, exc)
            answer = self.backend.assign_constraints(ConstraintQuery(names=tuple(view.names), task=self.task,
                                                                     images=images))
            out = list(answer.constraints)
            if len(out) != len(view.names) or any(c not in CONSTRAINT_TYPES for c in out):
                raise BackendError(f"answer {out} is not one of {CONSTRAINT_TYPES} per object "
                                   f"for {len(view.names)} objects")
            self.last_answer = answer
        except BackendError as exc:
            self.stats.fallbacks += 1
            log.warning("%s: t=%d constraint query failed, using fallback: %s", self.name, view.t, exc)
            out = list(self.fallback(view))
        self.stats.latencies_s.append(time.perf_counter() - start)
        return out
