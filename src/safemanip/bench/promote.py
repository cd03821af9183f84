"""``safemanip bench promote``: each finished run's policy into the policies folder.

For every run that reached the budget, the final policy and the best one of its periodic evaluations are each
evaluated on the benchmark's selection block (used for this choice and nothing else; the reported numbers use other
blocks), in the scenes the policy was trained in: N = k on its own layout, or for a selection-aware policy N =
scene_objects with dynamic kNN. The better one (the final one on a tie) is copied to ``POLICIES/NAME.safetensors``
and listed in ``POLICIES/manifest.json`` (``rl/policy_index.py``: how --policy NAME finds it);
the run's config, periodic evaluations and summary to ``RECORDS/NAME/``, with the choice in ``choice.json``. Runs
already promoted are skipped.

Everything read is checked before the first evaluation: the runs folder, every run's summary, and for each run to
promote its config (the benchmark's own for that run), evaluations and policy files, and the folders written. All
problems are reported together, before an evaluation is spent on a run that cannot be promoted.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from safemanip.bench.benchmark import Benchmark
from safemanip.bench.runs import RecordError, RunRecord, config_problem, run_records

DEFAULT_RECORDS = Path("results") / "training"
"""Where the training records of promoted runs go (relative to the working folder: the repository's top)."""


@dataclass(frozen=True)
class Candidate:
    record: RunRecord
    scene_objects: int | None
    """The run's training scenes' N for a selection-aware run (evaluated there with dynamic kNN), else None."""
    files: tuple[str, ...]
    """The policy files to compare: 'policy' (the final one) and, when the run kept one, 'best'."""


def plan(bench: Benchmark, runs_dir: Path, policies: Path, records: Path) -> list[Candidate]:
    """Every run to promote, all checked before anything is evaluated; RecordError lists every problem."""
    from safemanip.util.files import check_output_dir

    runs_dir = Path(runs_dir)
    if not runs_dir.exists():
        raise RecordError(f"no runs folder {runs_dir}; give the folder safemanip bench train wrote its runs to "
                          f"(--runs, default runs/bench)")
    if not runs_dir.is_dir():
        raise RecordError(f"{runs_dir} is a file, not a runs folder; give the folder safemanip bench train wrote "
                          f"its runs to (--runs)")
    problems, todo = [], []
    for record in run_records(bench, bench.runs, runs_dir, policies):
        if record.state == "promoted":
            continue
        if record.problem:  # e.g. a damaged summary: whether the run finished cannot be told
            problems.append(record.problem)
        elif record.state == "finished":
            candidate, found = _check_run(bench, record)
            problems += found
            if candidate is not None:
                todo.append(candidate)
    if todo:
        from safemanip.rl.policy_index import PolicyIndexError, read_manifest

        problems += check_output_dir(policies, "the policies folder")
        try:
            read_manifest(policies)
        except PolicyIndexError as err:  # found now, not after the first evaluation
            problems.append(str(err))
        for candidate in todo:
            problems += check_output_dir(records / candidate.record.run.name, "the records folder")
    if problems:
        raise RecordError(f"nothing promoted: {len(problems)} problem(s):\n  - " + "\n  - ".join(problems))
    return todo


def _check_run(bench: Benchmark, record: RunRecord) -> tuple[Candidate | None, list[str]]:
    """A finished run's candidate (its config the benchmark's, its files whole), or its problems."""
    from safemanip.rl.checkpoint import PolicyFileError, load_policy
    from safemanip.rl.config import ConfigError, load_run_config

    folder, problems = record.folder, []
    problem = config_problem(bench, record.run, folder)
    if problem:
        problems.append(problem)
    if not (folder / "evals.jsonl").is_file():
        problems.append(f"{folder}: the run is finished but has no evals.jsonl (its periodic evaluations, kept with "
                        f"its records); restore it or delete the run")
    if not (folder / "policy.safetensors").is_file():
        problems.append(f"{folder}: the run is finished but holds no policy.safetensors (its final policy); restore "
                        f"it, or delete the run and train it again")
    files = tuple(f for f in ("policy", "best") if (folder / f"{f}.safetensors").is_file())
    for f in files:
        try:
            load_policy(folder / f"{f}.safetensors")
        except PolicyFileError as err:
            problems.append(f"{err}; restore it or delete the run")
    if problems:
        return None, problems
    try:
        cfg, _ = load_run_config(folder / "config.json")
    except ConfigError as err:  # checked by config_problem already; kept for a file changed since
        return None, [str(err)]
    return Candidate(record, cfg.scene_objects, files), []


def success_rate(bench: Benchmark, policy: Path, scene_objects: int | None, out: Path) -> float:
    """The policy's success rate on the selection block, in its training scenes."""
    from safemanip.evaluation.harness import EvalRequest, evaluate, failure_line
    from safemanip.util.procs import Interrupted, WorkerDied

    scenes = {"n_objects": scene_objects, "selector": "dynamic-knn"} if scene_objects else {}
    report = evaluate(EvalRequest(policy=str(policy), episodes=bench.selection_episodes,
                                  seed_block=bench.selection_block, out=str(out), **scenes))
    summary = report["summary"]
    if summary.get("interrupted"):
        raise Interrupted(summary["interrupted"]["signum"])
    if summary.get("failed"):
        raise WorkerDied(f"the evaluation of {policy} failed: {failure_line(summary, str(out))}; nothing of this run "
                         f"was promoted, run the command again")
    return summary["success"]["rate"]


def _index(policies: Path, name: str, record: Path, chosen: str) -> None:
    """List the promoted policy in the folder's manifest (``rl/policy_index.py``), through which --policy NAME
    finds it; the manifest is rewritten atomically, so a kill leaves the old or the new one."""
    from safemanip.rl.checkpoint import load_policy
    from safemanip.rl.policy_index import entry_for, read_manifest, write_manifest

    entries = read_manifest(policies)
    _, meta = load_policy(policies / f"{name}.safetensors")
    entries[name] = entry_for(policies, policies / f"{name}.safetensors", meta,
                              os.path.relpath(record, policies), chosen)
    write_manifest(policies, entries)


def promote(bench: Benchmark, candidate: Candidate, policies: Path, records: Path, log=print) -> dict:
    """Evaluate the candidate's policy files, copy the better one and the run's records; returns the choice."""
    run, folder = candidate.record.run, candidate.record.folder
    with tempfile.TemporaryDirectory(prefix="safemanip-promote-") as tmp:
        rates = {f: success_rate(bench, folder / f"{f}.safetensors", candidate.scene_objects, Path(tmp) / f)
                 for f in candidate.files}
    chosen = "best" if rates.get("best", -1.0) > rates["policy"] else "policy"
    choice = {"block": bench.selection_block, "episodes": bench.selection_episodes, "success": rates,
              "chosen": "final" if chosen == "policy" else "best"}
    kept = Path(records) / run.name
    kept.mkdir(parents=True, exist_ok=True)
    for name in ("config.json", "evals.jsonl", "summary.json"):
        shutil.copy2(folder / name, kept / name)
    (kept / "choice.json").write_text(json.dumps(choice, indent=1) + "\n")
    # the policy last, and whole or not at all: its presence is what "promoted" means
    Path(policies).mkdir(parents=True, exist_ok=True)
    partial = Path(policies) / f".{run.name}.safetensors.partial"
    shutil.copy2(folder / f"{chosen}.safetensors", partial)
    os.replace(partial, Path(policies) / f"{run.name}.safetensors")
    _index(Path(policies), run.name, kept, choice["chosen"])
    log(f"{run.name}: final {rates['policy']:.3f}, best {rates.get('best', float('nan')):.3f} -> {choice['chosen']}")
    return choice
