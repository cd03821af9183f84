"""Pick each finished benchmark run's policy and bring it into the repository.

    python results/training/promote.py [RUNS_DIR]       # default: runs/bench

For every run that reached its 400k-step budget (``train.sh``), the final policy and the best one of the
run's periodic evaluations are each evaluated on seed block 30 (200 episodes, used for this choice and for
nothing else; the reported numbers use other blocks), in the scenes the policy was trained in: N = k on its
own layout, or, for a selection-aware policy, N = 6 with dynamic-kNN. The better one (the final one on a tie)
is copied to ``src/safemanip/policies/NAME.safetensors`` (a shipped policy: ``--policy NAME`` finds it); the run's config, periodic evaluations and
summary to ``results/training/NAME/``, with the choice in ``choice.json``. Runs already promoted are
skipped.

Everything it reads (the runs folder, each run's ``summary.json``; for a run to promote its ``config.json``,
``evals.jsonl`` and policy files, and the folders it writes) is checked before the first evaluation starts: a
problem is one ``promote.py: error: ...`` line on stderr and exit code 2, never a traceback or an evaluation spent
on a run that cannot be promoted.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
POLICIES = ROOT / "src" / "safemanip" / "policies"
RECORDS = ROOT / "results" / "training"
SELECTION_BLOCK = 30
EPISODES = 200
BUDGET = 400_000
PROG = "promote.py"


class Refused(ValueError):
    """An input problem, reported in one line with exit code 2 before any evaluation."""


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _read_object(path: Path, what: str) -> dict:
    """A JSON object from ``path`` through the package's bounded reader, or Refused saying what is wrong."""
    from safemanip.util.files import JSONInputError, read_json_file

    if not path.is_file():
        raise Refused(f"{path}: no {what} file ({'a folder is in its place' if path.is_dir() else 'missing'})")
    try:
        data = read_json_file(path, str(path))
    except JSONInputError as err:
        raise Refused(f"{path}: the {what} is not valid JSON ({err.reason}); repair it or delete the run") from None
    except OSError as err:
        raise Refused(f"{path}: cannot read the {what} ({err.strerror or err})") from None
    if not isinstance(data, dict):
        raise Refused(f"{path}: the {what} must be a JSON object, got {type(data).__name__} ({json.dumps(data)[:60]}); "
                      f"repair it or delete the run")
    return data


def finished(run: Path) -> bool:
    """Whether the run reached its budget without an interruption (its summary is checked; no summary: still
    training or never started, so not finished)."""
    summary = run / "summary.json"
    if not summary.exists() and not summary.is_symlink():
        return False
    data = _read_object(summary, "summary")
    steps, interrupted = data.get("env_steps", 0), data.get("interrupted")
    if not _is_int(steps) or steps < 0:
        raise Refused(f"{summary}: env_steps must be a non-negative integer, got {json.dumps(steps)[:60]}")
    if interrupted is not None and not isinstance(interrupted, (str, dict)):
        raise Refused(f"{summary}: interrupted must be null or the signal's name, got {json.dumps(interrupted)[:60]}")
    return interrupted is None and steps >= BUDGET


def check_run(run: Path) -> tuple[dict, list[str]]:
    """A finished run's config and the policy files to evaluate ("policy", and "best" when present), each checked
    as the package checks a policy before use; Refused on the first problem."""
    from safemanip.rl.checkpoint import PolicyFileError, load_policy
    from safemanip.scene.config import MAX_OBJECTS

    config = _read_object(run / "config.json", "config")
    n = config.get("scene_objects")
    if n is not None and n is not False and not (_is_int(n) and 0 <= n <= MAX_OBJECTS):
        raise Refused(f"{run / 'config.json'}: scene_objects must be an integer 0..{MAX_OBJECTS} or null, "
                      f"got {json.dumps(n)[:60]}")
    if not (run / "evals.jsonl").is_file():
        raise Refused(f"{run}: the run is finished but has no evals.jsonl (its periodic evaluations, copied to "
                      f"results/training/{run.name}/); restore it or delete the run")
    if not (run / "policy.safetensors").is_file():
        raise Refused(f"{run}: the run is finished but holds no policy.safetensors (its final policy); restore it, "
                      f"or resume the run with safemanip train --resume {run}")
    which = [w for w in ("policy", "best") if (run / f"{w}.safetensors").exists()]
    for w in which:
        try:
            load_policy(run / f"{w}.safetensors")
        except PolicyFileError as err:
            raise Refused(str(err)) from None
    return config, which


def check_output(folder: Path) -> None:
    from safemanip.util.files import check_output_dir

    problems = check_output_dir(folder, "the destination")
    if problems:
        raise Refused(problems[0])


def plan(runs: Path) -> list[tuple[Path, dict, list[str]]]:
    """Every run to promote, with its config and policy files, all checked before anything runs."""
    if not runs.exists():
        raise Refused(f"no runs folder {runs}; give the folder train.sh wrote its runs to (default runs/bench)")
    if not runs.is_dir():
        raise Refused(f"{runs} is a file, not a runs folder; give the folder train.sh wrote its runs to")
    try:
        entries = sorted(p for p in runs.iterdir() if p.is_dir())
    except OSError as err:
        raise Refused(f"cannot list the runs folder {runs} ({err.strerror or err})") from None
    todo = []
    for run in entries:
        if (POLICIES / f"{run.name}.safetensors").exists():
            continue  # promoted already
        if finished(run):
            todo.append((run, *check_run(run)))
    if todo:
        check_output(POLICIES)
        for run, _, _ in todo:
            check_output(RECORDS / run.name)
    return todo


def success(policy: Path, config: dict, out: Path) -> float:
    args = [sys.executable, "-m", "safemanip.cli", "eval", "--policy", str(policy), "--episodes", str(EPISODES),
            "--seed", str(SELECTION_BLOCK), "--no-progress", "--out", str(out)]
    if config.get("scene_objects"):
        args += ["--n-objects", str(config["scene_objects"]), "--selector", "dynamic-knn"]
    done = subprocess.run(args, stdout=subprocess.DEVNULL)
    if done.returncode != 0:
        raise RuntimeError(f"the evaluation of {policy} failed (exit code {done.returncode}, its message is above)")
    return json.loads((out / "summary.json").read_text())["success"]["rate"]


def promote(run: Path, config: dict, which: list[str]) -> None:
    name = run.name
    with tempfile.TemporaryDirectory() as tmp:
        rates = {w: success(run / f"{w}.safetensors", config, Path(tmp) / w) for w in which}
    chosen = "best" if rates.get("best", -1.0) > rates["policy"] else "policy"
    POLICIES.mkdir(parents=True, exist_ok=True)
    records = RECORDS / name
    records.mkdir(parents=True, exist_ok=True)
    for file in ("config.json", "evals.jsonl", "summary.json"):
        shutil.copy2(run / file, records / file)
    choice = {"block": SELECTION_BLOCK, "episodes": EPISODES, "success": rates,
              "chosen": "final" if chosen == "policy" else "best"}
    (records / "choice.json").write_text(json.dumps(choice, indent=1) + "\n")
    shutil.copy2(run / f"{chosen}.safetensors", POLICIES / f"{name}.safetensors")
    print(f"{name}: final {rates['policy']:.3f}, best {rates.get('best', float('nan')):.3f} -> {choice['chosen']}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    try:
        if len(argv) > 1 or (argv and argv[0].startswith("-")):
            raise Refused(f"expected at most one argument, the runs folder, got {' '.join(argv)[:200]!r} "
                          f"(usage: python results/training/promote.py [RUNS_DIR])")
        if argv and not argv[0].strip():
            raise Refused("the runs folder is empty; give a folder path (default runs/bench)")
        try:
            import safemanip  # noqa: F401
        except ImportError:
            raise Refused("the safemanip package is not importable; run this with the project's Python "
                          "(.venv/bin/python) or pip install -e . first") from None
        todo = plan(Path(argv[0]) if argv else ROOT / "runs" / "bench")
    except Refused as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 2
    try:
        for run, config, which in todo:
            promote(run, config, which)
    except RuntimeError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; the runs promoted so far are kept, run it again for the rest", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
