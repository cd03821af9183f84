"""``results/training/promote.py`` on bad runs folders (issue 44): everything it reads is checked before the first
evaluation, and a problem is one ``promote.py: error: ...`` line on stderr and exit code 2, never a traceback.

Run as a real subprocess on folders under ``tmp_path``. Every case here is refused before an evaluation or a
write, so nothing lands in ``src/safemanip/policies`` or ``results/training``; the subprocess timeout only bounds
a hang (the script used to spend a 200-episode evaluation before failing on a run without its final policy)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, SUBPROCESS_ENV, make_policy

PROMOTE = ROOT / "results" / "training" / "promote.py"
POLICIES = ROOT / "src" / "safemanip" / "policies"
RECORDS = ROOT / "results" / "training"
RUN = "promote-test-run"  # not a shipped policy's name: nothing of it may exist in the repository
FINISHED = {"env_steps": 400_000, "interrupted": None}


def promote(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(PROMOTE), *map(str, args)], capture_output=True, text=True,
                          timeout=300, env=SUBPROCESS_ENV, cwd=ROOT)


def assert_refused(done: subprocess.CompletedProcess, message: str) -> None:
    assert done.returncode == 2, (done.returncode, done.stdout[-500:], done.stderr[-2000:])
    assert "Traceback" not in done.stderr and "Traceback" not in done.stdout
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("promote.py: error: ") and message in lines[0], done.stderr
    assert not (POLICIES / f"{RUN}.safetensors").exists() and not (RECORDS / RUN).exists()


def finished_run(runs: Path, summary=FINISHED, policy: bool = True, best: bool = True) -> Path:
    """A run folder as train.sh leaves a finished run: config, periodic evaluations, summary and policies."""
    run = runs / RUN
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"k": 1, "constraints": "conservative", "scene_objects": None}))
    (run / "evals.jsonl").write_text(json.dumps({"env_steps": 400_000, "success": 0.5}) + "\n")
    (run / "summary.json").write_text(summary if isinstance(summary, str) else json.dumps(summary))
    if policy:
        make_policy(run / "policy.safetensors", 1)
    if best:
        make_policy(run / "best.safetensors", 1, seed=1)
    return run


@pytest.fixture(autouse=True)
def _not_in_the_repository():
    assert not (POLICIES / f"{RUN}.safetensors").exists() and not (RECORDS / RUN).exists()


def test_a_missing_runs_folder_is_one_line(tmp_path):
    assert_refused(promote(tmp_path / "runs"), "no runs folder")


def test_a_runs_path_that_is_a_file_is_one_line(tmp_path):
    (tmp_path / "runs").write_text("not a folder")
    assert_refused(promote(tmp_path / "runs"), "is a file, not a runs folder")


@pytest.mark.parametrize("text,message", [
    ("[]", "must be a JSON object, got list"),
    ("{env_steps: 400000", "the summary is not valid JSON"),
    ("", "the summary is not valid JSON"),
    ('{"env_steps": NaN, "interrupted": null}', "the summary is not valid JSON"),
    ('{"env_steps": "400000", "interrupted": null}', "env_steps must be a non-negative integer"),
], ids=["list", "not-json", "empty", "nan", "steps-a-string"])
def test_a_bad_summary_is_one_line(tmp_path, text, message):
    finished_run(tmp_path / "runs", summary=text)
    assert_refused(promote(tmp_path / "runs"), message)


def test_a_finished_run_without_its_final_policy_is_refused_before_any_evaluation(tmp_path):
    """It used to evaluate best.safetensors for 200 episodes first, then fail with KeyError: 'policy'."""
    finished_run(tmp_path / "runs", policy=False)
    assert_refused(promote(tmp_path / "runs"), "holds no policy.safetensors")


def test_a_damaged_policy_file_is_refused_before_any_evaluation(tmp_path):
    run = finished_run(tmp_path / "runs")
    data = (run / "best.safetensors").read_bytes()
    (run / "best.safetensors").write_bytes(data[:len(data) - 40])
    assert_refused(promote(tmp_path / "runs"), "best.safetensors")


@pytest.mark.parametrize("what,text,message", [
    ("config.json", "{k: 1", "the config is not valid JSON"),
    ("config.json", '{"scene_objects": "six"}', "scene_objects must be an integer"),
    ("evals.jsonl", None, "has no evals.jsonl"),
], ids=["config-not-json", "config-scene-objects", "no-evals"])
def test_a_finished_run_with_a_bad_record_is_one_line(tmp_path, what, text, message):
    run = finished_run(tmp_path / "runs")
    if text is None:
        (run / what).unlink()
    else:
        (run / what).write_text(text)
    assert_refused(promote(tmp_path / "runs"), message)


def test_runs_not_finished_are_skipped_and_nothing_is_evaluated(tmp_path):
    runs = tmp_path / "runs"
    finished_run(runs, summary={"env_steps": 1000, "interrupted": "SIGINT"}, policy=False)
    (runs / "still-training").mkdir()  # no summary yet
    done = promote(runs)
    assert done.returncode == 0 and done.stdout == "" and "Traceback" not in done.stderr, done.stderr


def test_extra_arguments_are_one_line(tmp_path):
    assert_refused(promote(tmp_path, tmp_path), "at most one argument")
