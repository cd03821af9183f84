"""The paper's five findings, read off the benchmark's stored sweep cells, with a verdict each: the table in
docs/results.md between its ``<!-- findings -->`` markers, rewritten in place.

    python results/findings.py            # after safemanip sweep fig4 / fig5 / table1 / table2
    python results/findings.py --check    # exit 1 if docs/results.md is out of date with the stored cells

A comparison of two methods in one cell pools each method's training seeds (``evaluation.sweep.pool_seeds``). One
method is better only if both tests agree: the 95 % interval of the difference of the two success rates, bootstrapped
with training seeds as the unit (``compare``), lies wholly above 0, and its lowest training seed scores at least the
other's highest; otherwise the cell is a tie. (Until issue 44 the first test was "its pooled Wilson interval lies
wholly above the other's"; the rule changed after the cells were measured, see docs/results.md.) A finding holds if its
method wins at least one of its comparisons and loses none; it is within the interval if every comparison is a tie;
it does not hold if the method loses at least one and wins none; mixed otherwise. A verdict needs three training
seeds on both sides of every comparison and every cell the finding compares in its sweep spec
(``src/safemanip/evaluation/sweeps/NAME.json``) measured; until then the finding says what it still lacks.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from safemanip.evaluation.registry import display_name  # noqa: E402
from safemanip.evaluation.stats import seed_bootstrap_difference  # noqa: E402
from safemanip.evaluation.sweep import Cell, cells_of, load_config, load_results, pool_seeds  # noqa: E402
from safemanip.util.files import atomic_write_text  # noqa: E402

DOC = ROOT / "docs" / "results.md"
SEEDS = 3


def pooled(folder: str) -> tuple[list[dict], list[dict]]:
    """(policies pooled over their training seeds, planner references) of ``results/<folder>``."""
    results = load_results(ROOT / "results" / folder)
    return (pool_seeds([r for r in results if r["cell"]["algorithm"] != "planner"]),
            [r for r in results if r["cell"]["algorithm"] == "planner"])


def pick(results: list[dict], **want) -> dict | None:
    for r in results:
        if all(r["cell"].get(k) == v for k, v in want.items()):
            return r
    return None


def entry(r: dict, key: str = "success") -> dict:
    return r["summary"][key] if key in ("success", "safety_violation") else r["summary"]["categories"][key]


def seeds(r: dict) -> int:
    return len(r["summary"].get("seeds", [0]))


def per_seed(r: dict, key: str = "success") -> tuple[list[int], list[int]]:
    """(successes, episodes) of each training seed of ``r`` on ``key``; a result of one policy is one seed."""
    e = entry(r, key)
    if "seed_counts" in e:
        return list(e["seed_counts"]), list(e["seed_totals"])
    return [int(e["count"])], [int(r["summary"]["episodes"])]


def difference(a: dict, b: dict, key: str = "success") -> tuple[float, float]:
    """95 % interval of ``a``'s rate minus ``b``'s on ``key``, training seeds as the unit (two-stage cluster
    bootstrap of each method, fixed RNG seed: ``stats.seed_bootstrap_difference``)."""
    return seed_bootstrap_difference(*per_seed(a, key), *per_seed(b, key))


def compare(a: dict, b: dict, key: str = "success", lower_is_better: bool = False) -> str:
    """'win', 'tie' or 'loss' of ``a`` against ``b`` on ``key``.

    ``a`` wins only if two tests agree: (1) the 95 % interval of the difference of the two rates, bootstrapped with
    training seeds as the unit (resample each method's seeds, then each seed's episodes from its own rate;
    ``difference``), lies wholly above 0 (below 0 when ``lower_is_better``), and (2) ``a``'s worst training seed
    scores at least ``b``'s best. 'loss' is the same with the roles swapped; anything else is a tie.

    Why the bootstrap: a method's seeds are three different policies that spread up to 12 points (34 on gate
    scenes), so the Wilson interval of 3 x 1000 pooled episodes, which counts every episode as independent,
    understates the uncertainty; and the interval of the difference, not two separate intervals, is the test of
    "a differs from b". Why the seed test is kept: with three seeds the percentile bootstrap is optimistic (it sees
    only 10 distinct seed sets and underestimates the between-seed variance by a third, where a t interval on 2
    degrees of freedom would be more than twice as wide as a normal one); the seed test is distribution-free, and
    with 3 seeds against 3 it is the exact one-sided rank test at its smallest attainable level (1 ordering in
    C(6, 3) = 20, p = 0.05). The bootstrap keeps seeds separated by less than the episodes' noise from deciding a
    cell, the seed test one lucky or unlucky seed. On the stored cells the seed test still decides two: RARL
    against Vanilla at N = 1 (Fig. 4) and dynamic against static kNN for pi_3 at N = 4 (Fig. 5), where the
    bootstrapped difference is above 0 but a seed of the other method beats a seed of the first."""
    lo, hi = difference(a, b, key)
    (a_lo, a_hi), (b_lo, b_hi) = (entry(r, key).get("spread", [entry(r, key)["rate"]] * 2) for r in (a, b))
    if lower_is_better:
        lo, hi = -hi, -lo
        (a_lo, a_hi), (b_lo, b_hi) = (-a_hi, -a_lo), (-b_hi, -b_lo)
    if lo > 0 and a_lo >= b_hi:
        return "win"
    if hi < 0 and b_lo >= a_hi:
        return "loss"
    return "tie"


def missing_cells(sweep: str, wanted, results: Path = ROOT / "results") -> tuple[int, int]:
    """(cells not measured yet, cells in all) among the sweep spec's cells that a finding compares (``wanted(cell)``).
    Without this a finding whose measured cells all had three seeds would read as complete while whole policies
    (say pi_4..pi_6) were still missing from it."""
    cfg = load_config(sweep)
    stored = {Cell(**r["cell"]).id for r in load_results(results / cfg["folder"])}
    expected = [c.id for c in cells_of(cfg) if c.algorithm != "planner" and wanted(c)]
    return sum(1 for c in expected if c not in stored), len(expected)


def verdict(outcomes: list[str], complete: bool, missing: tuple[int, int] = (0, 0)) -> str:
    if not outcomes:
        return "not measured yet"
    wins, losses = outcomes.count("win"), outcomes.count("loss")
    text = ("holds" if wins and not losses else "within the interval" if not wins and not losses
            else "does not hold" if losses and not wins else "mixed")
    text += f" ({wins} better, {outcomes.count('tie')} tied, {losses} worse)"
    if not complete:
        text += f"; fewer than {SEEDS} training seeds so far"
    if missing[0]:
        text += f"; provisional, {missing[1] - missing[0]} of its {missing[1]} cells measured"
    return text


def pct(r: dict | None, key: str = "success") -> str:
    if r is None:
        return "n/a"
    e = entry(r, key)
    return f"{100 * e['rate']:.1f}"


def finding_fig4() -> tuple[str, str, str]:
    policies, bounds = pooled("exit/fig4")
    parts, outcomes, complete = [], [], True
    for n in range(1, 7):
        rarl, vanilla = (pick(policies, algorithm=a, n_objects=n) for a in ("rarl", "vanilla"))
        if rarl is None or vanilla is None:
            continue
        complete &= seeds(rarl) >= SEEDS and seeds(vanilla) >= SEEDS
        outcomes += [compare(rarl, vanilla), compare(rarl, vanilla, "top_box", lower_is_better=True)]
        parts.append(f"N={n}: {pct(rarl)} vs {pct(vanilla)} (top box {pct(rarl, 'top_box')} vs {pct(vanilla, 'top_box')})")
    bound = ", ".join(f"N={r['cell']['n_objects']}: {pct(r)}" for r in sorted(bounds, key=lambda r: r["cell"]["n_objects"]))
    return ("; ".join(parts) or "not measured yet", bound or "",
            verdict(outcomes, complete, missing_cells("fig4", lambda c: True)))


WAYS = (("", "the paper's way"), ("selaware", "selection-aware"))  # how pi_k was trained (the cell's variant)


def verdicts_by_way(outcomes: dict[str, list[str]], complete: dict[str, bool], missing: dict[str, tuple[int, int]]) -> str:
    """One verdict per way of training pi_k: the two need not agree, and one verdict over both would hide which one
    reproduces the paper."""
    text = "; ".join(f"{label}: {verdict(outcomes[v], complete[v], missing[v])}" for v, label in WAYS
                     if outcomes[v] or missing[v][1])  # a way the sweep spec has but no cell measured yet says so
    return text or verdict([], True)


def finding_fig5_selectors() -> tuple[str, str, str]:
    policies, bounds = pooled("exit/fig5")
    parts, outcomes, complete = [], {v: [] for v, _ in WAYS}, {v: True for v, _ in WAYS}
    for r in policies:
        c = r["cell"]
        if c["selector"] != "dynamic-knn":
            continue
        static = pick(policies, selector="static-knn", k=c["k"], n_objects=c["n_objects"], variant=c["variant"])
        if static is None:
            continue
        complete[c["variant"]] &= seeds(r) >= SEEDS and seeds(static) >= SEEDS
        outcomes[c["variant"]].append(compare(r, static))
        if c["n_objects"] == 6:
            parts.append(f"π_{c['k']}{' selection-aware' if c['variant'] else ''} at N=6: {pct(r)} vs {pct(static)}")
    bound = ", ".join(f"N={r['cell']['n_objects']}: {pct(r)}" for r in sorted(bounds, key=lambda r: r["cell"]["n_objects"]))
    missing = {v: missing_cells("fig5", lambda c, v=v: c.k < c.n_objects and c.variant == v) for v, _ in WAYS}
    return "; ".join(parts) or "not measured yet", bound, verdicts_by_way(outcomes, complete, missing)


def finding_fig5_full_state() -> tuple[str, str, str]:
    """pi_2 and pi_4 under dynamic kNN against the full-state policy (trained the paper's way) at N = 5, 6."""
    policies, bounds = pooled("exit/fig5")
    parts, outcomes, complete = [], {v: [] for v, _ in WAYS}, {v: True for v, _ in WAYS}
    bound = ", ".join(f"N={r['cell']['n_objects']}: {pct(r)}" for r in sorted(bounds, key=lambda r: r["cell"]["n_objects"])
                      if r["cell"]["n_objects"] in (5, 6))
    for n in (5, 6):
        full = pick(policies, k=n, n_objects=n, variant="")
        if full is None:
            continue
        for k in (2, 4):
            for variant, _ in WAYS:
                small = pick(policies, k=k, n_objects=n, selector="dynamic-knn", variant=variant)
                if small is None:
                    continue
                complete[variant] &= seeds(small) >= SEEDS and seeds(full) >= SEEDS
                outcomes[variant].append(compare(small, full))
                parts.append(f"N={n}: π_{k}{' sel.-aware' if variant else ''} {pct(small)} vs π_{n} {pct(full)}")
    missing = {v: missing_cells("fig5", lambda c, v=v: c.n_objects in (5, 6) and (
        (c.k == c.n_objects and not c.variant) or (c.k in (2, 4) and c.selector == "dynamic-knn" and c.variant == v)))
        for v, _ in WAYS}
    return "; ".join(parts) or "not measured yet", bound, verdicts_by_way(outcomes, complete, missing)


def name(r: dict, field: str = "selector") -> str:
    """The selector's name in a finding: what produced its answers (never 'VLM' for the offline classifier)."""
    return display_name(r["cell"][field], r["cell"].get("vlm"))


def finding_table1() -> tuple[str, str, str]:
    policies, bounds = pooled("gate/table1")
    parts, outcomes, complete = [], [], True
    for semantics in ("2 fragile, 3 durable", "3 fragile, 2 durable"):
        semantic = pick(policies, semantics=semantics, selector="semantic")
        for other in ("dynamic-knn", "static-knn"):
            knn = pick(policies, semantics=semantics, selector=other)
            if semantic is None or knn is None:
                continue
            complete &= seeds(semantic) >= SEEDS and seeds(knn) >= SEEDS
            outcomes.append(compare(semantic, knn))
            parts.append(f"{semantics}: {name(semantic)} {pct(semantic)} vs {other} {pct(knn)}")
        privileged = pick(policies, semantics=semantics, selector="privileged")
        if semantic is not None and privileged is not None:
            agreement = semantic["summary"].get("reference_agreement") or {}
            parts.append(f"{semantics}: privileged selection {pct(privileged)}"
                         + (f", the semantic selection equal to it at {100 * agreement['rate']:.1f} % of queries"
                            if agreement else ""))
    bound = "; ".join(f"{r['cell']['semantics']}, avoiding {r['cell']['policy_constraints']}: {pct(r)}" for r in bounds)
    compared = lambda c: c.selector in ("semantic", "dynamic-knn", "static-knn")  # noqa: E731
    return ("; ".join(parts) or "not measured yet", bound,
            verdict(outcomes, complete, missing_cells("table1", compared)))


def finding_table2() -> tuple[str, str, str]:
    policies, bounds = pooled("gate/table2")
    parts, outcomes, complete = [], [], True
    for k in (2, 3):
        conservative = pick(policies, k=k, selector="dynamic-knn", constraints="conservative")
        for selector in ("dynamic-knn", "semantic"):
            semantic = pick(policies, k=k, selector=selector, constraints="vlm")
            if semantic is None or conservative is None:
                continue
            complete &= seeds(semantic) >= SEEDS and seeds(conservative) >= SEEDS
            outcomes.append(compare(semantic, conservative))
            parts.append(f"π_{k}: {name(semantic)} + {name(semantic, 'constraints')} {pct(semantic)} vs dynamic-kNN + "
                         f"conservative {pct(conservative)}")
        best = pick(policies, k=k, selector="semantic", constraints="vlm")
        reference = pick(policies, k=k, selector="privileged-criticality", constraints="ground-truth")
        if best is not None and reference is not None:
            parts.append(f"π_{k}: reference (privileged by true criticality + ground-truth types) {pct(reference)}, "
                         f"the semantic setting {pct(best)}")
    bound = "; ".join(f"N={r['cell']['n_objects']}, avoiding {r['cell']['policy_constraints']}: {pct(r)}" for r in bounds)
    compared = lambda c: c.constraints == "vlm" and c.selector in ("dynamic-knn", "semantic") or (  # noqa: E731
        c.selector == "dynamic-knn" and c.constraints == "conservative")
    return ("; ".join(parts) or "not measured yet", bound,
            verdict(outcomes, complete, missing_cells("table2", compared)))


FINDINGS = [
    ("RARL beats Vanilla-RL, with fewer top-box violations (Fig. 4, exit scenes)",
     "RARL above Vanilla at every N = 1..6, fewer violations", finding_fig4, "safemanip sweep fig4"),
    ("dynamic kNN beats static kNN (Figs. 5, 6)", "better in every (k, N) cell", finding_fig5_selectors,
     "safemanip sweep fig5"),
    ("π_{k<N} comparable to or better than the full state at N = 5, 6 (Fig. 5)", "π_2 comparable, π_4 better",
     finding_fig5_full_state, "safemanip sweep fig5"),
    ("the semantic selector beats kNN with mixed semantics (Table I, gate scenes)",
     "Dynamic-VLM (GPT-4o) 80.8 / 63.0 vs dynamic-kNN 66.8 / 54.8, privileged 91.6 / 69.1", finding_table1,
     "safemanip sweep table1"),
    ("semantic constraints beat conservative ones (Table II, gate scenes)",
     "ConstraintVLM + Dynamic-VLM (GPT-4o) 57.2 / 53.3 vs conservative 53.6 / 49.2", finding_table2,
     "safemanip sweep table2"),
]


def table() -> str:
    lines = ["| # | the paper's finding | paper | ours (success %, pooled over training seeds) | planner reference | "
             "verdict | regenerate |", "|---|---|---|---|---|---|---|"]
    for i, (claim, paper, measure, command) in enumerate(FINDINGS, 1):
        ours, bound, outcome = measure()
        lines.append(f"| {i} | {claim} | {paper} | {ours} | {bound} | {outcome} | `{command}` |")
    return "\n".join(lines)


def status() -> str:
    """Which of the benchmark's policies are in (``src/safemanip/policies``), from the queue's own list of runs."""
    wanted = 54  # results/training/train.sh: 18 settings (RARL and Vanilla k = 1..6, selection-aware k = 2..5, pi_2^all and
    # pi_3^all) x training seeds 0, 1, 2
    have = sorted(p.stem for p in (ROOT / "src" / "safemanip" / "policies").glob("*-s[0-9].safetensors"))
    if not have:
        return f"0 of {wanted} policies trained and brought in."
    return (f"{len(have)} of {wanted} policies trained and brought in: " + ", ".join(f"`{h}`" for h in have) + ".")


def rewrite(text: str, marker: str, body: str) -> str:
    block = f"<!-- {marker} -->\n{body}\n<!-- /{marker} -->"
    text, n = re.subn(rf"<!-- {marker} -->.*?<!-- /{marker} -->", block, text, flags=re.S)
    if n != 1:
        raise SystemExit(f"{DOC} has no <!-- {marker} --> ... <!-- /{marker} --> block to rewrite")
    return text


def render() -> str:
    """docs/results.md with its status and findings blocks rebuilt from the shipped policies and stored cells."""
    return rewrite(rewrite(DOC.read_text(), "status", status()), "findings", table())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if docs/results.md differs from what the stored cells give")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        if text != DOC.read_text():
            print(f"{DOC} is out of date with the stored cells and policies: run python results/findings.py "
                  "and commit it", file=sys.stderr)
            return 1
        return 0
    atomic_write_text(DOC, text)  # a crash mid-write leaves the old page, not half a table
    print(text[text.index("<!-- status -->"):])
    return 0


if __name__ == "__main__":
    sys.exit(main())
