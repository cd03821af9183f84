"""One evaluation episode of a k-object policy in an N-object scene, judged on the full scene.

Per control step: build the SceneView, let the object selector pick (it re-picks on its own
schedule), build s_rel with the reducer from the picked ids and the constraint types assigned at
t = 0, act, step the env. The env is the judge: its failure set holds all N objects with the
judge's constraint types, whatever the policy was shown. A collision is attributed to the selection
that chose the action leading into it (the ids the policy saw at the last step).

Outcome categories (``CATEGORIES``), one per episode:
  success, top_box (top box left its safe set), out_of_workspace (the held box left the table),
  collision_unselected / collision_selected (a no_contact object closer than the collision threshold,
  split by whether it was among the objects the policy saw), soft_contact (a soft object hit faster
  than the speed limit; whether it was selected is in the record's ``selected`` column), timeout,
  unstable (the simulation blew up; neither a success nor a safety violation).

Each record also keeps the selection history (``selections``: the ids at every step where they changed) and how
often, at the queries of the shared schedule, the selection equalled the reference oracle's, the k nearest
objects by true criticality (``reference_agreed`` of ``reference_queries``).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_OF_CLASS
from safemanip.selection.base import ConstraintSelector, ObjectSelector
from safemanip.selection.reducer import Reducer
from safemanip.selection.selectors import DEFAULT_INTERVAL, DEFAULT_SOFT_REACH, criticality_first
from safemanip.selection.view import CLASS_OF_CONSTRAINT, EnvViewBuilder

CATEGORIES = ("success", "top_box", "out_of_workspace", "collision_unselected", "collision_selected",
              "soft_contact", "timeout", "unstable")
CATEGORY_LABELS = {"success": "success", "top_box": "top box out of its safe set",
                   "out_of_workspace": "held box out of workspace", "collision_unselected": "collision with unselected",
                   "collision_selected": "collision with selected", "soft_contact": "soft-contact too fast",
                   "timeout": "timeout", "unstable": "unstable simulation"}
SAFETY_VIOLATIONS = ("top_box", "out_of_workspace", "collision_unselected", "collision_selected", "soft_contact")
_FIXED = {"success": "success", "failure:dyn": "top_box", "failure:oob": "out_of_workspace", "timeout": "timeout",
          "unstable": "unstable"}


def format_selections(changes: list[tuple[int, tuple[int, ...]]]) -> str:
    """Compact selection history: ``t:ids`` at every step where the selected set changed, e.g. ``0:1,4;8:1,2``."""
    return ";".join(f"{t}:{','.join(map(str, ids))}" for t, ids in changes)


def parse_selections(text: str) -> list[tuple[int, tuple[int, ...]]]:
    out = []
    for part in filter(None, text.split(";")):
        t, ids = part.split(":")
        out.append((int(t), tuple(int(i) for i in ids.split(",") if i != "")))
    return out


def _stat(selector, field: str) -> int:
    stats = getattr(selector, "stats", None)
    return int(getattr(stats, field, 0)) if stats is not None else 0


def _breaker_open(*selectors) -> str:
    """"yes" when a selector's semantic backend has its circuit breaker open (it answers with the fallback
    for the rest of the run), "no" when it is closed, "" when no selector has a guarded backend."""
    states = [getattr(s, "backend", None) for s in selectors]
    states = [b.status()["breaker_open"] for b in states if callable(getattr(b, "status", None))]
    return "" if not states else ("yes" if any(states) else "no")


def shield_constraints(object_selector, constraint_selector, assigned: list[str], view) -> list[str]:
    """The constraint type per object a safety filter protects, from the cell's best semantic source: the constraint
    selector's types when it is semantic or ground truth; else the object selector's classes when it has them (the
    privileged selectors read the true classes, the offline semantic one decides them); else every object no_contact.
    So a filter adds safety without hiding what a selector fails to know (issue 45)."""
    if getattr(constraint_selector, "name", "") in ("vlm", "ground-truth"):
        return list(assigned)
    classes = None
    if getattr(object_selector, "name", "").startswith("privileged"):
        classes = view.privileged_classes
    elif hasattr(getattr(object_selector, "backend", None), "classify"):
        classes = object_selector.backend.classify(view.names)
    if classes is None:
        return ["no_contact"] * len(view.names)
    return [CONSTRAINT_OF_CLASS[c] for c in classes]


def run_episode(env, actor: Callable[[np.ndarray], np.ndarray], reducer: Reducer, object_selector: ObjectSelector,
                constraint_selector: ConstraintSelector, seed: int, *, builder: EnvViewBuilder | None = None,
                after_reset: Callable | None = None, on_step: Callable | None = None, shield=None,
                soft_reach: float = DEFAULT_SOFT_REACH) -> dict:
    """Roll one episode out and return its record (plain types, ready for CSV/JSON).

    ``after_reset(env)`` may edit the scene right after the reset (tests place objects by hand);
    ``on_step(env, info, ids)`` sees every step (the demo records frames and margins with it); ``shield`` (a safety
    filter, ``safety.SHIELDS``) may override the policy's action every step; ``soft_reach`` is the reference oracle's
    (``criticality_first``), the same as the selectors'.
    """
    builder = builder or EnvViewBuilder()
    env.reset(seed=int(seed))
    kind = env.placement.kind
    if after_reset is not None:
        after_reset(env)
    builder.reset(env)
    n, k = len(env.names), reducer.k
    state = env.scene_state()
    view = builder.view(env, state, 0)
    object_selector.reset(view, k)
    if hasattr(constraint_selector, "reset"):  # the VLM one caches its answer per scene
        constraint_selector.reset()
    q0 = (_stat(object_selector, "queries"), _stat(object_selector, "fallbacks"),
          _stat(constraint_selector, "queries"), _stat(constraint_selector, "fallbacks"))
    # constraint types are chosen once per episode at t = 0 and kept (paper Sec. IV-C)
    assigned = [str(c) for c in constraint_selector.assign(view)]
    if len(assigned) != n:
        raise RuntimeError(f"constraint selector {constraint_selector.name!r} gave {len(assigned)} types for {n} objects")
    want = min(k, n)
    up_to = getattr(object_selector, "variable_k", False)  # dynamic k: any number of objects up to k
    protected = shield_constraints(object_selector, constraint_selector, assigned, view) if shield is not None else None
    overrides = shield.stats.overrides if shield is not None else 0
    changes: list[tuple[int, tuple[int, ...]]] = []
    ids: list[int] = []
    t = 0
    # how often the selection equals the reference oracle's (the k nearest by true criticality, ``criticality_first``)
    # at the queries of the shared schedule (every DEFAULT_INTERVAL steps): the selector's agreement, per episode
    reference_queries = reference_agreed = 0
    while True:
        ids = [int(i) for i in object_selector.select(view, k)] if want else []
        if (len(ids) > want if up_to else len(ids) != want) or len(set(ids)) != len(ids) \
                or any(not 0 <= i < n for i in ids):
            raise RuntimeError(f"object selector {object_selector.name!r} returned {ids}: expected "
                               f"{'at most ' if up_to else ''}{want} distinct ids of a {n}-object scene")
        key = tuple(sorted(ids))
        if not changes or changes[-1][1] != key:
            changes.append((t, key))
        if want and t % DEFAULT_INTERVAL == 0 and view.privileged_classes is not None:
            reference = criticality_first(view.box_position, view.positions, view.privileged_classes, want, soft_reach)
            reference_queries += 1
            reference_agreed += tuple(sorted(reference)) == key
        obs = reducer(state, ids, assigned)
        action = actor(obs[None])[0]
        if shield is not None:
            action = shield.filter(env, action, protected)
        _, _, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(env, info, ids)
        if terminated or truncated:
            break
        t = int(info["t"])
        state = env.scene_state()
        view = builder.view(env, state, t)

    return _record(env, info, seed, ids, assigned, changes, kind, {
        "object_queries": _stat(object_selector, "queries") - q0[0],
        "object_fallbacks": _stat(object_selector, "fallbacks") - q0[1],
        "constraint_queries": _stat(constraint_selector, "queries") - q0[2],
        "constraint_fallbacks": _stat(constraint_selector, "fallbacks") - q0[3],
        "vlm_breaker_open": _breaker_open(object_selector, constraint_selector),
        "reference_queries": reference_queries, "reference_agreed": reference_agreed,
        "shield_overrides": (shield.stats.overrides - overrides) if shield is not None else 0})


def run_planner_episode(env, planner, seed: int) -> dict:
    """One episode of the privileged planner (``control.planner.GridPlanner``), which sees the whole scene: the
    bound a cell's policy is measured against, on the same scenes. Its record has the policy's columns (nothing
    selected, nothing queried)."""
    _, info = env.reset(seed=int(seed))
    kind = env.placement.kind
    planner.reset(env)
    while True:
        _, _, terminated, truncated, info = env.step(planner.act(info, env))
        if terminated or truncated:
            break
    everything = tuple(range(len(env.names)))
    return _record(env, info, seed, list(everything), list(env.constraints), [(0, everything)], kind,
                   {"object_queries": 0, "object_fallbacks": 0, "constraint_queries": 0, "constraint_fallbacks": 0,
                    "vlm_breaker_open": "", "reference_queries": 0, "reference_agreed": 0, "shield_overrides": 0})


def _record(env, info: dict, seed: int, ids: list[int], assigned: list[str], changes: list, kind: str,
            counters: dict) -> dict:
    """An episode's record from its last step (plain types, ready for CSV/JSON): the one place an env event becomes
    a category."""
    event, obj = info["event"], info["object_id"]
    selected = None if obj is None else obj in ids
    if event in _FIXED:
        category = _FIXED[event]
    elif event == "failure:hard":
        category = "collision_selected" if selected else "collision_unselected"
    elif event == "failure:soft":
        category = "soft_contact"
    else:  # a new env event must be classified here before it can be counted
        raise RuntimeError(f"unknown env event {event!r}")
    outcome = "success" if category == "success" else ("failure" if category in SAFETY_VIOLATIONS else category)
    return {
        "seed": int(seed), "outcome": outcome, "category": category, "event": event, "length": int(info["t"]),
        "scene_kind": kind,
        "box_speed": round(float(np.linalg.norm(env.scene_state().bottom_vel)), 4),  # at the end: placed, not passing
        "object": info["object"] or "", "object_id": "" if obj is None else int(obj),
        "object_class": "" if obj is None else CLASS_OF_CONSTRAINT[env.constraints[obj]],
        "selected": "" if selected is None else ("yes" if selected else "no"),
        "names": ";".join(env.names), "judge_constraints": ";".join(env.constraints),
        "assigned_constraints": ";".join(assigned), "selections": format_selections(changes),
        "selection_changes": len(changes) - 1, **counters,
    }
