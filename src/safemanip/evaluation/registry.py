"""The selector registry: every object and constraint selector by name, with the options they take.

It lives above what it assembles: the metric selectors of ``selection/selectors.py`` and the semantic
ones of ``semantics/selectors.py``. Adding a selector means adding an entry here (no import-time
registration).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from safemanip.selection.base import ConstraintSelector, ObjectSelector
from safemanip.selection.selectors import (DEFAULT_INTERVAL, DEFAULT_RADIUS, ConservativeConstraints, DynamicKNN,
                                           DynamicRadius, FullSelector, GroundTruthConstraints, PrivilegedSelector,
                                           StaticKNN)


@dataclass(frozen=True)
class SelectorOptions:
    """Everything a selector factory may need; plain data so it can travel to worker processes."""

    interval: int = DEFAULT_INTERVAL
    radius: float = DEFAULT_RADIUS
    """dynamic-radius: pick the objects within this horizontal distance of the box's centre [m]."""
    vlm_backend: str = "semantic"
    vlm_model: str | None = None
    vlm_base_url: str | None = None
    vlm_cache: str | None = None
    vlm_cache_only: bool = False
    vlm_history: int = 2
    """Frames tiled per Dynamic-VLM query (paper: the images of the previous two queries)."""
    vlm_timeout: float | None = None
    """Seconds per request of the openai backend (None: its default, 30)."""
    vlm_episode_budget: float | None = None
    """Seconds of openai queries per episode before the selectors fall back for the rest of it."""
    vlm_run_budget: float | None = None
    """Seconds of openai queries per worker process before every later query falls back."""
    vlm_max_failures: int | None = None
    """Consecutive failed openai queries that open the circuit breaker (None: 5)."""


def _vlm_backend(opts: SelectorOptions):
    from safemanip.semantics.commands import make_backend
    from safemanip.semantics.guard import DEFAULT_MAX_FAILURES, GuardedBackend

    backend = make_backend(opts.vlm_backend, model=opts.vlm_model, base_url=opts.vlm_base_url,
                           cache_dir=opts.vlm_cache, cache_mode="cache_only" if opts.vlm_cache_only else "readwrite",
                           timeout_s=opts.vlm_timeout or 30.0)
    if opts.vlm_backend != "openai":  # the offline classifier neither fails nor waits
        return backend
    return GuardedBackend(backend, max_failures=opts.vlm_max_failures or DEFAULT_MAX_FAILURES,
                          episode_budget_s=opts.vlm_episode_budget, run_budget_s=opts.vlm_run_budget)


def _dynamic_vlm(opts: SelectorOptions) -> ObjectSelector:
    from safemanip.semantics.selectors import DynamicVLMSelector

    return DynamicVLMSelector(_vlm_backend(opts), query_interval=opts.interval, history=opts.vlm_history)


def _vlm_constraints(opts: SelectorOptions) -> ConstraintSelector:
    from safemanip.semantics.selectors import VLMConstraintSelector

    return VLMConstraintSelector(_vlm_backend(opts), name="vlm")


OBJECT_SELECTORS: dict[str, Callable[[SelectorOptions], ObjectSelector]] = {
    "static-knn": lambda o: StaticKNN(),
    "dynamic-knn": lambda o: DynamicKNN(o.interval),
    "dynamic-radius": lambda o: DynamicRadius(o.interval, o.radius),
    "privileged": lambda o: PrivilegedSelector(o.interval),
    "full": lambda o: FullSelector(),
    "dynamic-vlm": _dynamic_vlm,
}

CONSTRAINT_SELECTORS: dict[str, Callable[[SelectorOptions], ConstraintSelector]] = {
    "conservative": lambda o: ConservativeConstraints(),
    "ground-truth": lambda o: GroundTruthConstraints(),
    "vlm": _vlm_constraints,
}

USES_VLM = {"dynamic-vlm", "vlm"}
"""Names whose factory builds a semantic backend (so the --vlm-* options apply)."""


def make_object_selector(name: str, options: SelectorOptions | None = None) -> ObjectSelector:
    if name not in OBJECT_SELECTORS:
        raise ValueError(f"unknown object selector {name!r}; choose one of {sorted(OBJECT_SELECTORS)}")
    return OBJECT_SELECTORS[name](options or SelectorOptions())


def make_constraint_selector(name: str, options: SelectorOptions | None = None) -> ConstraintSelector:
    if name not in CONSTRAINT_SELECTORS:
        raise ValueError(f"unknown constraint selector {name!r}; choose one of {sorted(CONSTRAINT_SELECTORS)}")
    return CONSTRAINT_SELECTORS[name](options or SelectorOptions())
