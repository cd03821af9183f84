"""The safety filter's two checks (issue 45), read off the stored cells of the sweeps that run every cell without
and with it on the same scenes (``fig4-filter``, ``table1-filter``): the filter block of docs/results.md, rewritten
by ``safemanip bench findings``.

Per method and setting (training seeds pooled), the cell without the filter beside the cell with it: success,
safety violations of every kind, timeouts and the share of steps the filter overrode the policy. Two checks:
  - with the filter, violations of every kind are at most 1 % (the mean over training seeds; the worst seed shown,
    and the share that is the task policy's own: the top box moved, the box out of the workspace);
  - the success the filter costs is at most 3 points (the mean over seeds), asked of every Fig. 4 cell and of every
    Table I cell whose selector knows the objects' classes (the privileged and semantic selectors, the offline
    proximity ranker too). A kNN cell protects every object, so it stops before a durable blocker it used to push
    through: its successes that came from crashing through are expected to go, and its cost is shown, not checked.
The 95 % interval of the change has training seeds as the unit (``stats.seed_bootstrap_difference``); it treats the
two cells as independent although they share their scenes, so it is wider than a paired interval would be.
"""

from __future__ import annotations

import re
from pathlib import Path

from safemanip.bench.verdict import entry
from safemanip.evaluation.registry import display_name
from safemanip.evaluation.stats import seed_bootstrap_difference

FILTER_SWEEPS = (("fig4-filter", "exit/fig4-filter", "Fig. 4"), ("table1-filter", "gate/table1-filter", "Table I"))
"""(sweep, its results folder, the experiment it repeats with the filter)."""
MAX_VIOLATION = 0.01
MAX_COST = 0.03
TASK_KINDS = ("top_box", "out_of_workspace")
"""Violations that are the task policy's (the filter only guards objects; braking mid-pull would drag the top box):
shown apart, though the check counts every kind."""
KNOWS_CLASSES = ("privileged", "semantic", "dynamic-vlm")
"""Object selectors (name prefixes) whose classes the filter protects by: the cost check applies to them."""


def method(cell) -> tuple:
    """What a cell (a stored cell's dict or a ``Cell``) measures apart from its training seed and the filter."""
    get = cell.get if isinstance(cell, dict) else lambda name: getattr(cell, name)
    group = re.sub(r"-s\d+$", "", Path(get("policy")).stem)
    return (group, get("n_objects"), get("semantics") or "", get("selector"), get("constraints"))


def _rates(results: list[dict], key: str) -> list[float]:
    """Each result's rate of ``key``: success, safety_violation or a failure category."""
    return [entry(r, key)["rate"] for r in results]


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def rows(results: list[dict], experiment: str) -> list[dict]:
    """One row per method and setting with both cells stored for the same training seeds."""
    methods: dict[tuple, dict] = {}
    for r in results:
        if r["cell"]["algorithm"] == "planner":
            continue
        methods.setdefault(method(r["cell"]), {}).setdefault(r["cell"].get("shield"), {})[
            r["cell"].get("train_seed")] = r
    out = []
    for key, by_shield in sorted(methods.items(), key=lambda kv: tuple(map(str, kv[0]))):
        without, with_ = by_shield.get(None, {}), by_shield.get("brake", {})
        seeds = sorted(set(without) & set(with_), key=str)
        if not seeds:
            continue
        off, on = [without[s] for s in seeds], [with_[s] for s in seeds]
        counts = lambda rs: ([r["summary"]["success"]["count"] for r in rs],  # noqa: E731
                             [r["summary"]["episodes"] for r in rs])
        change = seed_bootstrap_difference(*counts(on), *counts(off))
        overrides = [r["summary"].get("shield_interventions") or {} for r in on]
        group, n, semantics, selector, constraints = key
        checked_cost = experiment == "Fig. 4" or selector.startswith(KNOWS_CLASSES)
        row = {"experiment": experiment, "group": group, "n_objects": n, "semantics": semantics,
               "selector": selector, "constraints": constraints, "seeds": len(seeds),
               "success_without": _mean(_rates(off, "success")), "success_with": _mean(_rates(on, "success")),
               "violation_without": _mean(_rates(off, "safety_violation")), "violation_with": _mean(_rates(on, "safety_violation")),
               "violation_with_worst_seed": max(_rates(on, "safety_violation")),
               "task_violation_with": _mean([sum(r) for r in zip(*(_rates(on, k) for k in TASK_KINDS))]),
               "timeout_with": _mean(_rates(on, "timeout")), "change_ci95": change,
               "overridden": sum(o.get("overrides", 0) for o in overrides) / max(1, sum(o.get("steps", 0)
                                                                                        for o in overrides)),
               "cost_checked": checked_cost}
        row["cost"] = row["success_without"] - row["success_with"]
        row["violation_ok"] = row["violation_with"] <= MAX_VIOLATION
        row["cost_ok"] = row["cost"] <= MAX_COST if checked_cost else None
        out.append(row)
    return out


def _label(row: dict) -> str:
    if row["experiment"] == "Fig. 4":
        return f"{row['group'].split('-')[0]}, N = {row['n_objects']}"
    return f"{row['semantics']}, {display_name(row['selector'])}"


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def table(stored_rows: list[dict], expected: dict[str, int], seeds_needed: int) -> str:
    """The markdown block: the checks' summary, then one line per row. ``expected``: rows each experiment should
    have once every cell is stored."""
    if not stored_rows:
        return "Not measured yet: `safemanip sweep fig4-filter`, `safemanip sweep table1-filter`."
    lines = []
    for experiment, want in expected.items():
        have = [r for r in stored_rows if r["experiment"] == experiment]
        whole = [r for r in have if r["seeds"] >= seeds_needed]
        if not have:
            lines.append(f"- **{experiment}**: not measured yet.")
            continue
        if not whole:
            lines.append(f"- **{experiment}**: {len(have)} of {want} settings measured so far, none yet with every "
                         f"training seed; no check is judged before.")
            continue
        bad_v = [r for r in whole if not r["violation_ok"]]
        costed = [r for r in whole if r["cost_checked"]]
        bad_c = [r for r in costed if not r["cost_ok"]]
        worst_v = max(whole, key=lambda r: r["violation_with"]) if whole else None
        worst_c = max(costed, key=lambda r: r["cost"]) if costed else None
        state = "" if len(whole) == want else f" ({len(whole)} of {want} settings with every training seed so far)"
        text = f"- **{experiment}**{state}: violations at most 1 % in {len(whole) - len(bad_v)} of {len(whole)}"
        if worst_v:
            text += f" (highest: {_label(worst_v)}, {_pct(worst_v['violation_with'])} %)"
        text += f"; success cost at most 3 points in {len(costed) - len(bad_c)} of {len(costed)} checked"
        if worst_c and worst_c["cost"] > 0:
            text += f" (largest: {_label(worst_c)}, {_pct(worst_c['cost'])} points)"
        elif worst_c:
            text += " (the filter raised success in every one)"
        lines.append(text + ".")
    lines += ["", "| experiment | setting | success without / with the filter (%) | change {seed interval} | "
                  "violations without / with (worst seed; of it top box or workspace) | timeouts with | "
                  "steps overridden | checks |",
              "|---|---|---|---|---|---|---|---|"]
    for r in stored_rows:
        lo, hi = r["change_ci95"]
        checks = "violations " + ("ok" if r["violation_ok"] else "**over 1 %**")
        if r["cost_checked"]:
            checks += ", cost " + ("ok" if r["cost_ok"] else "**over 3 points**")
        seeds = "" if r["seeds"] >= seeds_needed else f" ({r['seeds']} seed{'s' * (r['seeds'] > 1)})"
        lines.append(f"| {r['experiment']} | {_label(r)}{seeds} | {_pct(r['success_without'])} / "
                     f"{_pct(r['success_with'])} | {_pct(-r['cost'])} {{{_pct(lo)}, {_pct(hi)}}} | "
                     f"{_pct(r['violation_without'])} / {_pct(r['violation_with'])} "
                     f"({_pct(r['violation_with_worst_seed'])}; {_pct(r['task_violation_with'])}) | "
                     f"{_pct(r['timeout_with'])} | "
                     f"{_pct(r['overridden'])} | {checks} |")
    return "\n".join(lines)
