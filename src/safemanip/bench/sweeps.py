"""``safemanip bench sweep``: the benchmark's reported sweeps, one after another, through the sweep runner
(``evaluation.sweep.runner.run_sweep``, what ``safemanip sweep NAME`` runs). Each sweep's spec reports on the block
benchmark.json gives it (checked when the benchmark is loaded)."""

from __future__ import annotations

from safemanip.bench.benchmark import Benchmark, BenchmarkError


def run_sweeps(bench: Benchmark, names: list[str] | None, log=print, **options) -> int:
    """Run (or resume) each sweep; ``options`` go to ``run_sweep`` (workers, backend, address, render_only,
    progress). Exit code 0, 1 (a cell failed or every cell of a sweep was skipped for missing policies) or 128 + the
    signal that stopped a sweep (the sweeps after it are not started)."""
    from safemanip.evaluation.sweep.runner import run_sweep

    names = list(names or bench.reporting)
    unknown = [n for n in names if n not in bench.reporting]
    if unknown:
        raise BenchmarkError(f"{', '.join(unknown)}: not a sweep the benchmark reports; its sweeps are "
                             f"{', '.join(bench.reporting)} (any other runs with safemanip sweep NAME)")
    code = 0
    for name in names:
        log(f"== sweep {name} (block {bench.reporting[name]})")
        status = run_sweep(name, log=log, **options)
        if status.get("interrupted"):
            return 128 + status["interrupted"]
        if status["failed"] or (not options.get("render_only") and status["skipped"]
                                and not (status["ran"] or status["done"])):
            code = 1
    return code
