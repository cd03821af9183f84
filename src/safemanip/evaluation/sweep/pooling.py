"""One method's training seeds as one result: what the table, the figures and the findings report for a method."""

from __future__ import annotations

import re
from pathlib import Path


def pooled_entry(entries: list[dict], counts: list[int], totals: list[int]) -> dict:
    """Rate entries of one method's training seeds as one: the mean rate, the Wilson interval of all their episodes
    together (``ci95``), the 95 % interval with training seeds as the unit (``ci95_seeds``: a two-stage cluster
    bootstrap, ``stats.seed_bootstrap_interval``), the lowest and highest seed (``spread``) and each seed's count
    and episodes (``seed_counts``, ``seed_totals``: what ``bench/verdict.py`` bootstraps a difference from). The
    pooled interval treats 3 x 1000 episodes as independent and understates the uncertainty when seeds disagree."""
    from safemanip.evaluation.stats import seed_bootstrap_interval, wilson_interval

    rates = [e["rate"] for e in entries]
    counts, totals = [int(c) for c in counts], [int(n) for n in totals]
    measured = [(c, n) for c, n in zip(counts, totals) if n > 0]  # a scene kind a seed never met has no rate
    return {"count": int(sum(counts)), "rate": float(sum(rates) / len(rates)),
            "ci95": list(wilson_interval(int(sum(counts)), int(sum(totals)))),
            "ci95_seeds": list(seed_bootstrap_interval(*zip(*measured))) if measured else [0.0, 1.0],
            "spread": [min(rates), max(rates)],
            "seeds": len(entries), "seed_counts": counts, "seed_totals": totals}


def pool_seeds(results: list[dict]) -> list[dict]:
    """The results with the cells of one method (all fields equal but the policy's training seed) pooled into one,
    whose rates are the mean over the seeds, with the Wilson interval of all their episodes and each rate's
    ``spread`` (lowest, highest seed). Cells of a policy without a training seed stay as they are."""
    groups: dict[tuple, list[dict]] = {}
    for r in results:
        c = r["cell"]
        if c.get("train_seed") is None:
            groups[("single", c["policy"], tuple(sorted(map(str, c.items()))))] = [r]
            continue
        rest = tuple((k, str(v)) for k, v in sorted(c.items()) if k not in ("policy", "train_seed"))
        groups.setdefault((re.sub(r"-s\d+$", "", Path(c["policy"]).stem),) + rest, []).append(r)
    out = []
    for members in groups.values():
        first = members[0]
        if first["cell"].get("train_seed") is None:
            out.append(first)
            continue
        cell = {**first["cell"], "policy": re.sub(r"-s\d+$", "", Path(first["cell"]["policy"]).stem),
                "train_seed": None}
        sums = [m["summary"] for m in members]
        totals = [s["episodes"] for s in sums]

        def pooled(get) -> dict:
            entries = [get(s) for s in sums]
            return pooled_entry(entries, [e["count"] for e in entries], totals)

        summary = {"episodes": int(sum(totals)), "success": pooled(lambda s: s["success"]),
                   "safety_violation": pooled(lambda s: s["safety_violation"]),
                   "categories": {c: pooled(lambda s, c=c: s["categories"][c]) for c in sums[0]["categories"]},
                   "mean_length": float(sum(s["mean_length"] for s in sums) / len(sums)),
                   "seeds": sorted(m["cell"]["train_seed"] for m in members)}
        kinds = sorted({k for s in sums for k in s.get("by_scene_kind", {})})
        if kinds and all(set(s.get("by_scene_kind", {})) == set(kinds) for s in sums):
            summary["by_scene_kind"] = {
                k: {"episodes": int(sum(s["by_scene_kind"][k]["episodes"] for s in sums)),
                    **{m: pooled_entry([s["by_scene_kind"][k][m] for s in sums],
                                       [s["by_scene_kind"][k][m]["count"] for s in sums],
                                       [s["by_scene_kind"][k]["episodes"] for s in sums])
                       for m in ("success", "top_box")}}
                for k in kinds}
        agreements = [s.get("reference_agreement") for s in sums]
        if all(agreements):  # the selections' agreement with the reference oracle, over every seed's queries
            queries, agreed = sum(a["queries"] for a in agreements), sum(a["agreed"] for a in agreements)
            summary["reference_agreement"] = {"queries": queries, "agreed": agreed, "rate": agreed / queries}
        interventions = [s.get("shield_interventions") for s in sums]
        if all(interventions):  # the safety filter's overridden steps, over every seed's steps
            overrides, steps = sum(i["overrides"] for i in interventions), sum(i["steps"] for i in interventions)
            summary["shield_interventions"] = {"overrides": overrides, "steps": steps, "rate": overrides / max(1, steps)}
        out.append({"cell": cell, "summary": summary})
    return out
