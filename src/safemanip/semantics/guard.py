"""A circuit breaker and time budgets around a semantic backend.

A server that hangs or fails on every request must not make an evaluation take hours: ``GuardedBackend``
passes queries through until ``max_failures`` consecutive queries have failed (the breaker opens) or the
time spent in queries exceeds the per-episode or per-run budget; from then on every query raises
``BackendError`` at once, so the selectors answer with their fallback (dynamic-knn for objects,
conservative for constraints). ``status()`` says whether and why, for the results. A backend with
``set_deadline`` (the openai one) is also told the time left in the budgets before each query, so that one
slow query cannot overrun them.
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

from safemanip.semantics.base import BackendError, ConstraintAnswer, ConstraintQuery, ObjectAnswer, ObjectQuery

DEFAULT_MAX_FAILURES = 5


class GuardedBackend:
    def __init__(self, inner, *, max_failures: int = DEFAULT_MAX_FAILURES, episode_budget_s: float | None = None,
                 run_budget_s: float | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        if max_failures < 1:
            raise ValueError(f"max_failures must be >= 1, got {max_failures}")
        self.inner = inner
        self.name = getattr(inner, "name", "backend")
        self.max_failures = int(max_failures)
        self.episode_budget_s, self.run_budget_s = episode_budget_s, run_budget_s
        self._clock = clock
        self.consecutive_failures = 0
        self.open_reason: str | None = None
        """Why the breaker opened (None while closed); it stays open for the rest of the run."""
        self.run_spent_s = self.episode_spent_s = 0.0

    def __getattr__(self, attr: str):  # model, cache, calls, ... of the wrapped backend
        if attr == "inner":
            raise AttributeError(attr)
        return getattr(self.inner, attr)

    @property
    def needs_images(self) -> bool:
        return getattr(self.inner, "needs_images", False)

    def describe(self) -> dict:
        return {**self.inner.describe(), "guard": {"max_failures": self.max_failures,
                                                   "episode_budget_s": self.episode_budget_s,
                                                   "run_budget_s": self.run_budget_s}}

    def new_episode(self) -> None:
        self.episode_spent_s = 0.0

    def prepare(self, names: Sequence[str]) -> None:
        self.new_episode()
        if self.open_reason is None:
            self._guarded(self.inner.prepare, names)

    def select_objects(self, query: ObjectQuery) -> ObjectAnswer:
        return self._guarded(self.inner.select_objects, query)

    def assign_constraints(self, query: ConstraintQuery) -> ConstraintAnswer:
        return self._guarded(self.inner.assign_constraints, query)

    def status(self) -> dict:
        return {"breaker_open": self.open_reason is not None, "reason": self.open_reason,
                "run_spent_s": round(self.run_spent_s, 3)}

    def _guarded(self, fn, arg):
        if self.open_reason is not None:
            raise BackendError(f"{self.name}: circuit breaker open ({self.open_reason}); using the fallback")
        if self.run_budget_s is not None and self.run_spent_s >= self.run_budget_s:
            self.open_reason = f"run time budget of {self.run_budget_s:g} s used up"
            raise BackendError(f"{self.name}: {self.open_reason}; using the fallback for the rest of the run")
        if self.episode_budget_s is not None and self.episode_spent_s >= self.episode_budget_s:
            raise BackendError(f"{self.name}: episode time budget of {self.episode_budget_s:g} s used up; using "
                               "the fallback for the rest of the episode")
        left = [budget - spent for budget, spent in ((self.run_budget_s, self.run_spent_s),
                                                      (self.episode_budget_s, self.episode_spent_s)) if budget is not None]
        set_deadline = getattr(self.inner, "set_deadline", None)
        if set_deadline is not None:  # the budgets bound the query itself, not only whether the next one starts
            set_deadline(min(left) if left else None)
        start = self._clock()
        try:
            out = fn(arg)
        except BackendError as exc:
            self.consecutive_failures += 1
            if self.consecutive_failures >= self.max_failures:
                self.open_reason = f"{self.consecutive_failures} consecutive failed queries, last: {exc}"
            raise
        finally:
            spent = self._clock() - start
            self.run_spent_s += spent
            self.episode_spent_s += spent
            if set_deadline is not None:
                set_deadline(None)
        self.consecutive_failures = 0
        return out
