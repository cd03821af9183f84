"""``safemanip eval``: roll a policy out on fixed seeds and report rates with 95% Wilson intervals."""

from __future__ import annotations

import csv
import json
from collections import Counter
from pathlib import Path

import numpy as np

from safemanip.evaluation.rollout import evaluate_actor
from safemanip.evaluation.stats import rate_line, wilson_interval

FAILURE_ORDER = ("failure:dyn", "failure:oob", "failure:hard", "failure:soft", "timeout", "unstable")


def summarize(records: list[dict]) -> dict:
    n = len(records)
    events = Counter(r["event"] for r in records)
    rates = {}
    for event in ("success", *FAILURE_ORDER):
        lo, hi = wilson_interval(events[event], n)
        rates[event] = {"count": events[event], "rate": events[event] / n if n else 0.0, "ci95": [lo, hi]}
    violations = sum(events[e] for e in FAILURE_ORDER if e.startswith("failure"))
    lo, hi = wilson_interval(violations, n)
    return {"episodes": n, "rates": rates, "safety_violation": {"count": violations, "rate": violations / max(n, 1),
                                                                "ci95": [lo, hi]},
            "mean_length": float(np.mean([r["length"] for r in records])) if n else 0.0}


def format_summary(summary: dict, title: str) -> str:
    n = summary["episodes"]
    lines = [title, rate_line("success", summary["rates"]["success"]["count"], n),
             rate_line("safety violation", summary["safety_violation"]["count"], n)]
    labels = {"failure:dyn": "top box out of safe set", "failure:oob": "out of workspace",
              "failure:hard": "no-contact collision", "failure:soft": "soft-contact too fast",
              "timeout": "timeout", "unstable": "unstable simulation"}
    for event in FAILURE_ORDER:
        lines.append("  " + rate_line(labels[event], summary["rates"][event]["count"], n, width=26))
    lines.append(f"mean episode length: {summary['mean_length']:.1f} steps")
    return "\n".join(lines)


def write_records(out: Path, records: list[dict], summary: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(records[0].keys()))
        writer.writeheader()
        for r in records:
            writer.writerow({k: (";".join(map(str, v)) if isinstance(v, list) else v) for k, v in r.items()})
    (out / "summary.json").write_text(json.dumps(summary, indent=1))


def evaluate_policy_file(policy: str, episodes: int = 500, seed: int = 0, workers: int = 2,
                         n_objects: int | None = None, out: str | None = None) -> dict:
    from safemanip.rl.checkpoint import load_policy

    actor, meta = load_policy(policy)
    env_kwargs = dict(meta["env_kwargs"])
    if n_objects is not None and n_objects != meta["k"]:
        raise ValueError(f"this policy sees exactly k={meta['k']} objects; scenes with more objects need a "
                         f"selector (see `safemanip eval --help`), so use --n-objects {meta['k']}")
    arrays = [a for pair in actor.weights for a in (pair[0].T, pair[1])]
    seeds = [seed * 100_000 + i for i in range(episodes)]
    records = evaluate_actor(arrays, env_kwargs, seeds, workers=workers)
    summary = summarize(records)
    summary.update(policy=str(policy), env_kwargs=env_kwargs, seeds=[seeds[0], seeds[-1]])
    if out:
        write_records(Path(out), records, summary)
    title = f"{policy}: {meta['algorithm']} k={meta['k']} ({meta['constraints']}), {episodes} episodes, seeds {seeds[0]}..{seeds[-1]}"
    return {"summary": summary, "records": records, "text": format_summary(summary, title)}
