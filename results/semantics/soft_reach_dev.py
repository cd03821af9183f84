"""Choose criticality_first's soft_reach on development block 40 (issue 41), never on a reporting block.

Why: on Table II's scenes the criticality-first rule (soft_reach 0: every fragile object before any soft one) leaves
pi_2^all blind to the soft object on its route, and most of its failures are fast soft contacts. The paper's prompt
asks for "among the objects that might come in contact, the more fragile ones": a soft object the box is about to
meet should hold a slot. soft_reach is the distance from the held box within which a soft object ranks with the
fragile ones (``safemanip.selection.selectors.criticality_first``).

Procedure, fixed before any of these episodes ran:
- grid: soft_reach in 0 (the earlier rule), 0.2, 0.3, 0.4 m and 10 m (every soft object with the fragile ones);
- cells: Table II's two settings (pi_2^all at N = 5, 2 fragile + 2 soft + 1 durable; pi_3^all at N = 6, 2 fragile +
  2 soft + 2 durable; gate scenes only, ground-truth judge), three training seeds, 300 episodes each, seed block 40;
  the semantic selector with semantic constraints (offline names) and the privileged-criticality reference with
  ground-truth constraints, both under the same soft_reach;
- choice: the soft_reach with the highest mean success of the six semantic cells; a value within 1 point of the
  best yields to the smaller one (closer to the paper's "fragile first"). The reference's numbers are reported, not
  used for the choice.
- Table I's scenes have no soft object and the default classifier calls none of the catalog's fragile or durable
  objects soft (results/semantics/constraint-matrix-catalog.txt), so soft_reach cannot change a Table I selection.

Run: python results/semantics/soft_reach_dev.py [--out /tmp/soft-reach-dev] (resumable: finished cells are kept);
it writes results/semantics/soft-reach-dev40.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from safemanip.evaluation.harness import EvalRequest, evaluate

GRID = (0.0, 0.2, 0.3, 0.4, 10.0)
SETTINGS = (("rarl-k2-all", 5, "2 fragile, 2 soft, 1 durable"), ("rarl-k3-all", 6, "2 fragile, 2 soft, 2 durable"))
PAIRS = (("semantic", "vlm"), ("privileged-criticality", "ground-truth"))
SEEDS = (0, 1, 2)
EPISODES = 300
BLOCK = 40
TABLE = Path(__file__).with_name("soft-reach-dev40.md")


def run_cell(out: Path, reach: float, policy: str, n: int, semantics: str, selector: str, constraints: str) -> dict:
    folder = out / f"reach{reach:g}" / f"{policy}__{selector}"
    if (folder / "summary.json").exists():  # kept only if whole: a cut-off cell runs again
        summary = json.loads((folder / "summary.json").read_text())
        if summary["episodes"] == EPISODES and not summary.get("interrupted") and not summary.get("failed"):
            return summary
    summary = evaluate(EvalRequest(policy=policy, n_objects=n, semantics=semantics, selector=selector,
                                   constraint_selector=constraints, judge="ground-truth", episodes=EPISODES,
                                   seed_block=BLOCK, layout="gate", gate_share=1.0, soft_reach=reach, workers=2,
                                   out=str(folder)))["summary"]
    if summary.get("interrupted") or summary.get("failed"):
        raise SystemExit(f"{folder}: cut off after {summary['episodes']} episodes; run the script again to resume")
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="/tmp/soft-reach-dev", help="folder for the cells' records")
    out = Path(parser.parse_args().out)
    rows, means = [], {}
    for reach in GRID:
        for selector, constraints in PAIRS:
            for base, n, semantics in SETTINGS:
                rates, agree = [], []
                for seed in SEEDS:
                    summary = run_cell(out, reach, f"{base}-s{seed}", n, semantics, selector, constraints)
                    rates.append(100 * summary["success"]["rate"])
                    agree.append(100 * (summary.get("reference_agreement") or {}).get("rate", float("nan")))
                    print(f"soft_reach {reach:g} {selector} {base}-s{seed}: {rates[-1]:.1f} %", flush=True)
                rows.append((reach, selector, base, rates, float(np.mean(agree))))
                means.setdefault((reach, selector), []).extend(rates)
    score = {reach: float(np.mean(means[(reach, "semantic")])) for reach in GRID}
    best = max(score.values())
    chosen = min(reach for reach in GRID if score[reach] >= best - 1.0)
    lines = ["# soft_reach on development block 40 (issue 41)", "",
             "Made by `python results/semantics/soft_reach_dev.py` (its docstring is the procedure, fixed before the "
             f"runs). Gate scenes only, {EPISODES} episodes per cell and training seed, ground-truth judge; success "
             "in % per training seed (0, 1, 2) and their mean; agreement = share of queries whose selection equals "
             "the privileged-criticality reference's under the same soft_reach. Semantic = the offline name "
             "classifier (class_examples_v6), not a VLM.", "",
             "| soft_reach (m) | selector | policy | seeds 0 / 1 / 2 | mean | agreement |", "|---|---|---|---|---|---|"]
    for reach, selector, base, rates, agree in rows:
        lines.append(f"| {reach:g} | {selector} | {base} | {' / '.join(f'{r:.1f}' for r in rates)} | "
                     f"{np.mean(rates):.1f} | {agree:.1f} |")
    lines += ["", "Mean of the six semantic cells: " + ", ".join(f"{r:g} m: {score[r]:.1f}" for r in GRID) + ".",
              f"Chosen by the rule: soft_reach = {chosen:g} m."]
    TABLE.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
