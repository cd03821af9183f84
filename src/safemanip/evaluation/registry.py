"""The selector registry: every object and constraint selector by name, with the options they take.

It lives above what it assembles: the metric selectors of ``selection/selectors.py`` and the semantic
ones of ``semantics/selectors.py``. Adding a selector means adding an entry here (no import-time
registration).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from safemanip.selection.base import ConstraintSelector, ObjectSelector
from safemanip.selection.selectors import (DEFAULT_INTERVAL, DEFAULT_RADIUS, DEFAULT_SOFT_REACH,
                                           ConservativeConstraints, DynamicKNN, DynamicRadius, FullSelector,
                                           GroundTruthConstraints, PrivilegedCriticality, PrivilegedSelector,
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
    soft_reach: float = DEFAULT_SOFT_REACH
    """semantic (offline) and privileged-criticality: a soft object within this distance of the held box [m] ranks
    with the fragile ones (``criticality_first``)."""


def _vlm_backend(opts: SelectorOptions, ranking: str = "criticality"):
    """The semantic backend; ``ranking`` is how the offline one ranks objects (a VLM ranks them itself)."""
    from safemanip.semantics.commands import make_backend
    from safemanip.semantics.guard import DEFAULT_MAX_FAILURES, GuardedBackend

    backend = make_backend(opts.vlm_backend, model=opts.vlm_model, base_url=opts.vlm_base_url,
                           cache_dir=opts.vlm_cache, cache_mode="cache_only" if opts.vlm_cache_only else "readwrite",
                           timeout_s=opts.vlm_timeout or 30.0, ranking=ranking,
                           soft_reach=opts.soft_reach)
    if opts.vlm_backend != "openai":  # the offline classifier neither fails nor waits
        return backend
    return GuardedBackend(backend, max_failures=opts.vlm_max_failures or DEFAULT_MAX_FAILURES,
                          episode_budget_s=opts.vlm_episode_budget, run_budget_s=opts.vlm_run_budget)


def _semantic(ranking: str, name: str):
    def make(opts: SelectorOptions) -> ObjectSelector:
        from safemanip.semantics.selectors import DynamicVLMSelector

        return DynamicVLMSelector(_vlm_backend(opts, ranking), query_interval=opts.interval,
                                  history=opts.vlm_history, name=name)
    return make


def _vlm_constraints(opts: SelectorOptions) -> ConstraintSelector:
    from safemanip.semantics.selectors import VLMConstraintSelector

    return VLMConstraintSelector(_vlm_backend(opts), name="vlm")


OBJECT_SELECTORS: dict[str, Callable[[SelectorOptions], ObjectSelector]] = {
    "static-knn": lambda o: StaticKNN(),
    "dynamic-knn": lambda o: DynamicKNN(o.interval),
    "dynamic-radius": lambda o: DynamicRadius(o.interval, o.radius),
    "privileged": lambda o: PrivilegedSelector(o.interval),
    "privileged-criticality": lambda o: PrivilegedCriticality(o.interval, o.soft_reach),
    "full": lambda o: FullSelector(),
    "semantic": _semantic("criticality", "semantic"),
    "dynamic-vlm": _semantic("risk", "dynamic-vlm"),
}

CONSTRAINT_SELECTORS: dict[str, Callable[[SelectorOptions], ConstraintSelector]] = {
    "conservative": lambda o: ConservativeConstraints(),
    "ground-truth": lambda o: GroundTruthConstraints(),
    "vlm": _vlm_constraints,
}

USES_VLM = {"semantic", "dynamic-vlm", "vlm"}
"""Names whose factory builds a semantic backend (so the --vlm-* options apply)."""


_OFFLINE_NAMES = {"semantic": "semantic, criticality first (offline names)",
                  "dynamic-vlm": "semantic, risk-ranked (offline names; earlier rule)",
                  "vlm": "semantic constraints (offline names)"}
_VLM_NAMES = {"semantic": "VLM", "dynamic-vlm": "VLM", "vlm": "ConstraintVLM"}
_ORACLE_NAMES = {"privileged": "privileged (nearest fragile)",
                 "privileged-criticality": "privileged (nearest by true criticality)"}


def display_name(name: str, vlm: str | None = None) -> str:
    """How tables, figures and findings name an object or constraint selector: by what produced its answers, so
    that a row made by the offline name classifier is never called a VLM. ``vlm`` is the cell's backend identity
    (``evaluation.sweep.grid.vlm_identity``: 'semantic:FILE' offline, 'openai:MODEL' for a served model)."""
    if name in _VLM_NAMES and vlm and vlm.startswith("openai:"):
        return f"{_VLM_NAMES[name]} (openai: {vlm.split(':', 1)[1]})"
    return _OFFLINE_NAMES.get(name) or _ORACLE_NAMES.get(name) or name


def make_object_selector(name: str, options: SelectorOptions | None = None) -> ObjectSelector:
    if name not in OBJECT_SELECTORS:
        raise ValueError(f"unknown object selector {name!r}; choose one of {sorted(OBJECT_SELECTORS)}")
    return OBJECT_SELECTORS[name](options or SelectorOptions())


def make_constraint_selector(name: str, options: SelectorOptions | None = None) -> ConstraintSelector:
    if name not in CONSTRAINT_SELECTORS:
        raise ValueError(f"unknown constraint selector {name!r}; choose one of {sorted(CONSTRAINT_SELECTORS)}")
    return CONSTRAINT_SELECTORS[name](options or SelectorOptions())
