"""The paper's five findings, read off the benchmark's stored sweep cells, with a verdict each (``verdict.py``): the
status, findings and filter blocks of docs/results.md, between their ``<!-- status -->``, ``<!-- findings -->`` and
``<!-- filter -->`` markers, rewritten in place by ``safemanip bench findings`` (``--check``: written nowhere, exit 1 if the page is out of date).

A verdict needs every training seed of the benchmark on both sides of every comparison, and every cell the finding
compares in its sweep spec (``evaluation/sweeps/NAME.json``) measured; until then the finding says what it still
lacks.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from safemanip.bench.benchmark import Benchmark
from safemanip.bench.verdict import compare, entry, seeds, verdict
from safemanip.evaluation.registry import display_name
from safemanip.evaluation.sweep.grid import Cell, cells_of, record_id
from safemanip.evaluation.sweep.pooling import pool_seeds
from safemanip.evaluation.sweep.spec import load_config
from safemanip.evaluation.sweep.store import load_results

DEFAULT_DOC = Path("docs") / "results.md"
DEFAULT_RESULTS = Path("results")
"""The page and the stored cells, relative to the working folder (the repository's top, as for safemanip sweep)."""


class FindingsError(ValueError):
    """The results page or the stored cells cannot be read; the message says what to do."""


@dataclass(frozen=True)
class Stored:
    """The stored sweep cells under ``results`` and the training seeds a complete comparison pools."""

    results: Path
    needed: int

    def pooled(self, folder: str) -> tuple[list[dict], list[dict]]:
        """(policies pooled over their training seeds, planner references) of ``results/<folder>``."""
        results = load_results(self.results / folder)
        return (pool_seeds([r for r in results if r["cell"]["algorithm"] != "planner"]),
                [r for r in results if r["cell"]["algorithm"] == "planner"])

    def missing(self, sweep: str, wanted) -> tuple[int, int]:
        """(cells not measured yet, cells in all) among the sweep spec's cells that a finding compares
        (``wanted(cell)``). Without this a finding whose measured cells all had every seed would read as complete
        while whole policies (say pi_4..pi_6) were still missing from it."""
        spec = load_config(sweep)
        stored = {record_id(r["cell"]) for r in load_results(self.results / spec.folder)}
        expected = [c.id for c in cells_of(spec) if isinstance(c, Cell) and wanted(c)]
        return sum(1 for c in expected if c not in stored), len(expected)


def pick(results: list[dict], **want) -> dict | None:
    for r in results:
        if all(r["cell"].get(k) == v for k, v in want.items()):
            return r
    return None


def pct(r: dict | None, key: str = "success") -> str:
    if r is None:
        return "n/a"
    e = entry(r, key)
    return f"{100 * e['rate']:.1f}"


def finding_fig4(stored: Stored) -> tuple[str, str, str]:
    policies, bounds = stored.pooled("exit/fig4")
    parts, outcomes, complete = [], [], True
    for n in range(1, 7):
        rarl, vanilla = (pick(policies, algorithm=a, n_objects=n) for a in ("rarl", "vanilla"))
        if rarl is None or vanilla is None:
            continue
        complete &= seeds(rarl) >= stored.needed and seeds(vanilla) >= stored.needed
        outcomes += [compare(rarl, vanilla), compare(rarl, vanilla, "top_box", lower_is_better=True)]
        parts.append(f"N={n}: {pct(rarl)} vs {pct(vanilla)} (top box {pct(rarl, 'top_box')} vs {pct(vanilla, 'top_box')})")
    bound = ", ".join(f"N={r['cell']['n_objects']}: {pct(r)}" for r in sorted(bounds, key=lambda r: r["cell"]["n_objects"]))
    return ("; ".join(parts) or "not measured yet", bound or "",
            verdict(outcomes, complete, stored.needed, stored.missing("fig4", lambda c: True)))


WAYS = (("", "the paper's way"), ("selaware", "selection-aware"))  # how pi_k was trained (the cell's variant)


def verdicts_by_way(outcomes: dict[str, list[str]], complete: dict[str, bool], missing: dict[str, tuple[int, int]],
                    needed: int) -> str:
    """One verdict per way of training pi_k: the two need not agree, and one verdict over both would hide which one
    reproduces the paper."""
    text = "; ".join(f"{label}: {verdict(outcomes[v], complete[v], needed, missing[v])}" for v, label in WAYS
                     if outcomes[v] or missing[v][1])  # a way the sweep spec has but no cell measured yet says so
    return text or verdict([], True, needed)


def finding_fig5_selectors(stored: Stored) -> tuple[str, str, str]:
    policies, bounds = stored.pooled("exit/fig5")
    parts, outcomes, complete = [], {v: [] for v, _ in WAYS}, {v: True for v, _ in WAYS}
    for r in policies:
        c = r["cell"]
        if c["selector"] != "dynamic-knn":
            continue
        static = pick(policies, selector="static-knn", k=c["k"], n_objects=c["n_objects"], variant=c["variant"])
        if static is None:
            continue
        complete[c["variant"]] &= seeds(r) >= stored.needed and seeds(static) >= stored.needed
        outcomes[c["variant"]].append(compare(r, static))
        if c["n_objects"] == 6:
            parts.append(f"π_{c['k']}{' selection-aware' if c['variant'] else ''} at N=6: {pct(r)} vs {pct(static)}")
    bound = ", ".join(f"N={r['cell']['n_objects']}: {pct(r)}" for r in sorted(bounds, key=lambda r: r["cell"]["n_objects"]))
    missing = {v: stored.missing("fig5", lambda c, v=v: c.k < c.n_objects and c.variant == v) for v, _ in WAYS}
    return "; ".join(parts) or "not measured yet", bound, verdicts_by_way(outcomes, complete, missing, stored.needed)


def finding_fig5_full_state(stored: Stored) -> tuple[str, str, str]:
    """pi_2 and pi_4 under dynamic kNN against the full-state policy (trained the paper's way) at N = 5, 6."""
    policies, bounds = stored.pooled("exit/fig5")
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
                complete[variant] &= seeds(small) >= stored.needed and seeds(full) >= stored.needed
                outcomes[variant].append(compare(small, full))
                parts.append(f"N={n}: π_{k}{' sel.-aware' if variant else ''} {pct(small)} vs π_{n} {pct(full)}")
    missing = {v: stored.missing("fig5", lambda c, v=v: c.n_objects in (5, 6) and (
        (c.k == c.n_objects and not c.variant) or (c.k in (2, 4) and c.selector == "dynamic-knn" and c.variant == v)))
        for v, _ in WAYS}
    return "; ".join(parts) or "not measured yet", bound, verdicts_by_way(outcomes, complete, missing, stored.needed)


def name(r: dict, field: str = "selector") -> str:
    """The selector's name in a finding: what produced its answers (never 'VLM' for the offline classifier)."""
    return display_name(r["cell"][field], r["cell"].get("vlm"))


def finding_table1(stored: Stored) -> tuple[str, str, str]:
    policies, bounds = stored.pooled("gate/table1")
    parts, outcomes, complete = [], [], True
    for semantics in ("2 fragile, 3 durable", "3 fragile, 2 durable"):
        semantic = pick(policies, semantics=semantics, selector="semantic")
        for other in ("dynamic-knn", "static-knn"):
            knn = pick(policies, semantics=semantics, selector=other)
            if semantic is None or knn is None:
                continue
            complete &= seeds(semantic) >= stored.needed and seeds(knn) >= stored.needed
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
            verdict(outcomes, complete, stored.needed, stored.missing("table1", compared)))


def finding_table2(stored: Stored) -> tuple[str, str, str]:
    policies, bounds = stored.pooled("gate/table2")
    parts, outcomes, complete = [], [], True
    for k in (2, 3):
        conservative = pick(policies, k=k, selector="dynamic-knn", constraints="conservative")
        for selector in ("dynamic-knn", "semantic"):
            semantic = pick(policies, k=k, selector=selector, constraints="vlm")
            if semantic is None or conservative is None:
                continue
            complete &= seeds(semantic) >= stored.needed and seeds(conservative) >= stored.needed
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
            verdict(outcomes, complete, stored.needed, stored.missing("table2", compared)))


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


def table(stored: Stored) -> str:
    lines = ["| # | the paper's finding | paper | ours (success %, pooled over training seeds) | planner reference | "
             "verdict | regenerate |", "|---|---|---|---|---|---|---|"]
    for i, (claim, paper, measure, command) in enumerate(FINDINGS, 1):
        ours, bound, outcome = measure(stored)
        lines.append(f"| {i} | {claim} | {paper} | {ours} | {bound} | {outcome} | `{command}` |")
    return "\n".join(lines)


def status(bench: Benchmark, policies: Path) -> str:
    """Which of the benchmark's policies are in the policies folder."""
    wanted = bench.runs
    have = sorted(r.name for r in wanted if (Path(policies) / f"{r.name}.safetensors").is_file())
    if not have:
        return f"0 of {len(wanted)} policies trained and brought in."
    return (f"{len(have)} of {len(wanted)} policies trained and brought in: " + ", ".join(f"`{h}`" for h in have)
            + ".")


def rewrite(text: str, marker: str, body: str, doc: Path) -> str:
    block = f"<!-- {marker} -->\n{body}\n<!-- /{marker} -->"
    text, n = re.subn(rf"<!-- {marker} -->.*?<!-- /{marker} -->", lambda _: block, text, flags=re.S)
    if n != 1:
        raise FindingsError(f"{doc} has no <!-- {marker} --> ... <!-- /{marker} --> block to rewrite; add one where "
                            f"the {marker} belongs, or give the results page with --doc")
    return text


def render(doc: Path, bench: Benchmark, policies: Path, results: Path) -> tuple[str, str]:
    """(the page as it is, the page with its status and findings blocks rebuilt from the policies and stored cells)."""
    if not Path(doc).is_file():
        raise FindingsError(f"no results page {doc}: run this from the repository's top folder, or give the page "
                            f"with --doc")
    if not Path(results).is_dir():
        raise FindingsError(f"no results folder {results}: run this from the repository's top folder, or give it "
                            f"with --results")
    text = Path(doc).read_text()
    stored = Stored(Path(results), len(bench.seeds))
    page = rewrite(rewrite(text, "status", status(bench, policies), doc), "findings", table(stored), doc)
    return text, rewrite(page, "filter", filter_table(stored), doc)


def filter_table(stored: Stored) -> str:
    """The safety filter's checks on every cell of the sweeps run without and with it (``filter_checks.py``)."""
    from safemanip.bench import filter_checks

    rows, expected = [], {}
    for sweep, folder, experiment in filter_checks.FILTER_SWEEPS:
        rows += filter_checks.rows(load_results(stored.results / folder), experiment)
        expected[experiment] = len({filter_checks.method(c) for c in cells_of(load_config(sweep))
                                    if isinstance(c, Cell)})
    return filter_checks.table(rows, expected, stored.needed)
