"""What a runs folder (``safemanip bench train --out``) and the policies folder hold for each run of the benchmark,
read from the records alone: the run's ``summary.json`` (written last by a run that stopped), its checkpoint and its
``config.json``. ``bench train``, ``promote`` and ``status`` all judge a run here, so they agree on what finished means.

A run is
  promoted   its policy is in the policies folder (the record of a finished run; its run folder may be gone)
  finished   its summary says it reached the budget without being stopped
  partial    it has a checkpoint: ``bench train`` resumes it
  started    its folder exists without a checkpoint (stopped within its first minutes): trained again from the start
  missing    no folder yet
A record that cannot be read (a ``summary.json`` that is not a run's summary, a ``config.json`` of another recipe)
is the run's ``problem``: every command refuses to act on such a run and says how to repair it.
"""

from __future__ import annotations

import json
import reprlib
from dataclasses import dataclass
from pathlib import Path

from safemanip.bench.benchmark import Benchmark, Run


class RecordError(ValueError):
    """A record of a run that cannot be used; the message names the file and the fix."""


@dataclass(frozen=True)
class RunRecord:
    run: Run
    folder: Path
    state: str
    """'promoted', 'finished', 'partial', 'started' or 'missing' (see the module's docstring)."""
    env_steps: int = 0
    """Environment steps done, by the summary or the newest checkpoint (0 when neither says)."""
    stopped_by: str | None = None
    """The signal that stopped a partial run, from its summary."""
    problem: str | None = None


def read_object(path: Path, what: str) -> dict:
    """A JSON object from ``path`` through the package's bounded reader, or RecordError saying what is wrong."""
    from safemanip.util.files import JSONInputError, read_json_file

    if not path.is_file():
        raise RecordError(f"{path}: no {what} file ({'a folder is in its place' if path.is_dir() else 'missing'})")
    try:
        data = read_json_file(path, str(path))
    except JSONInputError as err:
        raise RecordError(f"{path}: the {what} is not valid JSON ({err.reason}); repair it or delete the run") from None
    except OSError as err:
        raise RecordError(f"{path}: cannot read the {what} ({err.strerror or err})") from None
    if not isinstance(data, dict):
        raise RecordError(f"{path}: the {what} must be a JSON object, got {type(data).__name__} "
                          f"({reprlib.repr(data)}); repair it or delete the run")
    return data


def read_summary(folder: Path) -> tuple[int, str | None]:
    """(env_steps, the signal that stopped it or None) of a run's summary.json, checked."""
    path = folder / "summary.json"
    data = read_object(path, "summary")
    steps, interrupted = data.get("env_steps", 0), data.get("interrupted")
    if type(steps) is not int or steps < 0:
        raise RecordError(f"{path}: env_steps must be a non-negative integer, got {reprlib.repr(steps)}; repair it or "
                          f"delete the run")
    if interrupted is not None and not isinstance(interrupted, str):
        raise RecordError(f"{path}: interrupted must be null or the signal's name, got {reprlib.repr(interrupted)}; "
                          f"repair it or delete the run")
    return steps, interrupted


def run_record(bench: Benchmark, run: Run, runs_dir: Path, policies: Path) -> RunRecord:
    """What the records say about ``run`` (never raises for a damaged record: that is the record's problem)."""
    from safemanip.rl.checkpoint import find_checkpoint

    folder = Path(runs_dir) / run.name
    if (Path(policies) / f"{run.name}.safetensors").is_file():
        return RunRecord(run, folder, "promoted", bench.budget_env_steps)
    if not folder.exists():
        return RunRecord(run, folder, "missing")
    if not folder.is_dir():
        return RunRecord(run, folder, "missing", problem=f"{folder} is a file, not a run folder; move it away")
    steps, stopped_by, problem = 0, None, None
    if (folder / "summary.json").exists() or (folder / "summary.json").is_symlink():
        try:
            steps, stopped_by = read_summary(folder)
        except RecordError as err:
            problem = str(err)
        if problem is None and stopped_by is None and steps >= bench.budget_env_steps:
            return RunRecord(run, folder, "finished", steps)
    checkpoint = find_checkpoint(folder)
    if checkpoint is None:
        return RunRecord(run, folder, "started", steps, stopped_by, problem)
    if (folder / "config.json").exists():
        problem = problem or config_problem(bench, run, folder)
    try:  # a run stopped by a kill has no new summary: its checkpoint says how far it got
        steps = max(steps, int(json.loads((checkpoint / "meta.json").read_text())["env_steps"]))
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return RunRecord(run, folder, "partial", steps, stopped_by, problem)


def config_problem(bench: Benchmark, run: Run, folder: Path) -> str | None:
    """Why the run in ``folder`` is not the benchmark's run of that name (its config.json differs from what
    benchmark.json gives it, bar the folder), or None."""
    from safemanip.rl.config import ConfigError, load_run_config

    try:
        cfg, _ = load_run_config(folder / "config.json")
    except ConfigError as err:
        return f"{err}; repair it or delete the run"
    recorded = json.loads(cfg.to_json())
    wanted = json.loads(bench.config(run, cfg.out_dir).to_json())
    differ = [f"{k} {recorded.get(k)!r} there, {wanted.get(k)!r} in the benchmark" for k in wanted
              if recorded.get(k) != wanted[k]]
    if not differ:
        return None
    return (f"{folder} was trained with other settings than {bench.source} gives {run.name} ({'; '.join(differ[:4])}"
            f"{'; ...' if len(differ) > 4 else ''}): delete or move the folder to train the run anew, or use the "
            f"benchmark file it was trained with (--benchmark)")


def run_records(bench: Benchmark, runs: list[Run], runs_dir: Path, policies: Path) -> list[RunRecord]:
    return [run_record(bench, run, runs_dir, policies) for run in runs]
