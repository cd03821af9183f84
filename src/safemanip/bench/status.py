"""``safemanip bench status``: one line per run (promoted, finished, partial, started or missing) and per reported
sweep (its cells stored), read from the records alone; nothing is run or written."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from safemanip.bench.benchmark import Benchmark
from safemanip.bench.runs import RunRecord, run_records

NEXT_STEP = {"finished": "promote it: safemanip bench promote", "partial": "resume it: safemanip bench train",
             "started": "train it: safemanip bench train", "missing": "train it: safemanip bench train"}


def run_line(record: RunRecord, budget: int) -> str:
    if record.problem:
        return f"{record.run.name}: {record.state}, cannot be used: {record.problem}"
    text = f"{record.run.name}: {record.state}"
    if record.state == "partial":
        text += f", {record.env_steps:,} of {budget:,} env steps" + (
            f", stopped by {record.stopped_by}" if record.stopped_by else "")
    return text + (f" ({NEXT_STEP[record.state]})" if record.state in NEXT_STEP else "")


def sweep_line(name: str, block: int, results: Path) -> str:
    from safemanip.evaluation.sweep.grid import cells_of, record_id
    from safemanip.evaluation.sweep.spec import load_config
    from safemanip.evaluation.sweep.store import load_results

    spec = load_config(name)
    folder = Path(results) / spec.folder
    wanted = {c.id for c in cells_of(spec)}
    stored = {record_id(r["cell"]) for r in load_results(folder)} & wanted if folder.is_dir() else set()
    return (f"sweep {name}: {len(stored)} of {len(wanted)} cells stored in {folder} (block {block})"
            + ("" if len(stored) == len(wanted) else f" (run the rest: safemanip bench sweep {name})"))


def status_lines(bench: Benchmark, runs_dir: Path, policies: Path, results: Path) -> list[str]:
    records = run_records(bench, bench.runs, runs_dir, policies)
    lines = [run_line(r, bench.budget_env_steps) for r in records]
    counts = Counter(r.state for r in records)
    lines.append(f"{len(records)} runs: " + ", ".join(f"{counts[s]} {s}" for s in
                                                       ("promoted", "finished", "partial", "started", "missing")))
    lines += [sweep_line(name, block, results) for name, block in bench.reporting.items()]
    return lines
