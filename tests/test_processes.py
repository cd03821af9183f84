"""Process hygiene: no worker outlives a killed main process, SIGINT/SIGTERM save what is finished, and a
run resumes from the newest complete checkpoint into the folder it is given.

The kill tests run the real commands as subprocesses, wait until their worker processes are up, send
SIGKILL to the main process only (not its group: the workers must notice on their own) and check that
every process that descended from it is gone within 10 s."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from safemanip.rl.checkpoint import find_checkpoint, read_checkpoint, recover_checkpoint, write_checkpoint

TINY = {"k": 1, "hidden": [32, 32], "batch_size": 32, "buffer_size": 5000, "learning_starts": 300,
        "random_steps": 300, "eval_episodes": 2, "eval_every_s": 3, "checkpoint_every_s": 2, "log_every_s": 1,
        "envs_per_collector": 2, "env_steps_per_update": 2.0}
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            kids.setdefault(ppid, []).append(int(entry))
    return kids


def descendants(pid: int) -> set[int]:
    kids, out, todo = _children(), set(), [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def start(args, tmp_path: Path, log_name: str) -> subprocess.Popen:
    log = open(tmp_path / log_name, "w")
    return subprocess.Popen([sys.executable, "-m", "safemanip.cli", *map(str, args)], stdout=log,
                            stderr=subprocess.STDOUT, env=ENV, cwd=tmp_path, start_new_session=True)


def wait_for_workers(proc: subprocess.Popen, n: int, timeout: float = 90.0) -> set[int]:
    deadline = time.time() + timeout
    while time.time() < deadline:
        found = descendants(proc.pid)
        if len(found) >= n:
            time.sleep(1.0)  # let them get to work
            return descendants(proc.pid)
        assert proc.poll() is None, f"exited early with {proc.returncode}"
        time.sleep(0.2)
    raise AssertionError(f"fewer than {n} worker processes after {timeout} s")


def kill_and_check_orphans(proc: subprocess.Popen, workers: set[int]) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.time() + 10
    while time.time() < deadline and any(alive(p) for p in workers):
        time.sleep(0.2)
    left = [p for p in workers if alive(p)]
    for p in left:  # clean up before failing
        os.kill(p, signal.SIGKILL)
    assert not left, f"processes still alive 10 s after kill -9 of their parent: {left}"


def _tiny_config(tmp_path: Path, **extra) -> Path:
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps({**TINY, "minutes": 1.0, "total_env_steps": 10**7, **extra}))
    return cfg


@pytest.mark.slow
@pytest.mark.parametrize("extra", [{}, {"scene_objects": 3, "n_collectors": 2}], ids=["plain", "selection-aware-2-workers"])
def test_kill_9_of_train_leaves_no_process(tmp_path, extra):
    proc = start(["train", "--config", _tiny_config(tmp_path, **extra), "--out", tmp_path / "run", "--no-progress"],
                 tmp_path, "train.log")
    workers = wait_for_workers(proc, extra.get("n_collectors", 1))
    kill_and_check_orphans(proc, workers)


@pytest.mark.slow
def test_kill_9_of_eval_leaves_no_process(tmp_path):
    proc = start(["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "400", "--workers", "2", "--no-progress",
                  "--out", tmp_path / "ev"], tmp_path, "eval.log")
    workers = wait_for_workers(proc, 2)
    kill_and_check_orphans(proc, workers)
    assert not (tmp_path / "ev" / "summary.json").exists()


def test_reaper_kills_what_a_killed_process_left_behind(tmp_path):
    """util/reaper.py: a grandchild that would outlive its parent (as Ray's agents do) is killed with it."""
    script = ("import subprocess, sys, time\n"
              "from safemanip.util.reaper import start_reaper\n"
              "start_reaper()\n"
              "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])\n"
              "time.sleep(600)\n")
    proc = subprocess.Popen([sys.executable, "-c", script], env=ENV, start_new_session=True)
    workers = wait_for_workers(proc, 2, timeout=30.0)  # the reaper and the sleeper
    kill_and_check_orphans(proc, workers)


@pytest.mark.slow
def test_kill_9_of_a_ray_eval_leaves_no_process(tmp_path):
    """With --backend ray the local Ray instance (GCS, raylet, its workers) goes too."""
    pytest.importorskip("ray")
    proc = start(["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "400", "--workers", "2", "--backend", "ray",
                  "--no-progress", "--out", tmp_path / "ev"], tmp_path, "eval.log")
    workers = wait_for_workers(proc, 4, timeout=120.0)  # at least GCS, raylet and the two rollout workers
    kill_and_check_orphans(proc, workers)


@pytest.mark.slow
def test_kill_9_of_sweep_leaves_no_process(tmp_path):
    proc = start(["sweep", _sweep_config(tmp_path, 400), "--out", tmp_path / "sw", "--workers", "2", "--no-progress"], tmp_path, "sweep.log")
    workers = wait_for_workers(proc, 2)
    kill_and_check_orphans(proc, workers)


def _sweep_config(tmp_path: Path, episodes: int) -> Path:
    cfg = tmp_path / "s.json"
    cfg.write_text(json.dumps({"name": "s", "figure": "table", "episodes": episodes, "judge": "conservative",
                               "policies": ["policies/rarl-k2-conservative-s0.safetensors"], "n_objects": [3],
                               "selectors": ["dynamic-knn"]}))
    return cfg


def sigint_after(args, tmp_path: Path, log_name: str, seconds: float, expect: str) -> set[int]:
    """Start a command, wait until its two workers run for ``seconds``, send SIGINT to the main process
    and check it exits with 130 without a traceback, saying ``expect``; returns the worker pids."""
    proc = start(args, tmp_path, log_name)
    workers = wait_for_workers(proc, 2)
    time.sleep(seconds)
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=60) == 130
    text = (tmp_path / log_name).read_text()
    assert "Traceback" not in text and expect in text
    return workers


@pytest.mark.slow
def test_sigint_to_sweep_stops_cleanly_and_keeps_no_partial_cell(tmp_path):
    out = tmp_path / "sw"
    workers = sigint_after(["sweep", _sweep_config(tmp_path, 2000), "--out", out, "--workers", "2", "--no-progress"],
                           tmp_path, "sweep.log", 2, "interrupted")
    assert not list((out / "cells").glob("*.json"))  # the interrupted cell is redone next time, not kept half-done
    time.sleep(1)
    assert not any(alive(p) for p in workers)


@pytest.mark.slow
def test_sigint_to_eval_writes_the_finished_episodes(tmp_path):
    out = tmp_path / "ev"
    workers = sigint_after(["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "2000", "--workers", "2",
                            "--chunk-size", "2", "--no-progress", "--out", out], tmp_path, "eval.log", 4,
                           "interrupted by SIGINT")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"]["signal"] == "SIGINT" and 0 < summary["episodes"] < 2000
    with open(out / "episodes.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == summary["episodes"]
    time.sleep(1)
    assert not any(alive(p) for p in workers)


@pytest.mark.slow
def test_sigterm_to_train_saves_a_checkpoint_and_the_policy(tmp_path):
    run = tmp_path / "run"
    proc = start(["train", "--config", _tiny_config(tmp_path), "--out", run, "--no-progress"], tmp_path, "train.log")
    deadline = time.time() + 90
    while time.time() < deadline and not (run / "scalars.csv").exists():
        time.sleep(0.3)
    time.sleep(2)
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM, (tmp_path / "train.log").read_text()[-2000:]
    text = (tmp_path / "train.log").read_text()
    assert "Traceback" not in text and "safemanip train --resume" in text
    summary = json.loads((run / "summary.json").read_text())
    assert summary["interrupted"] == "SIGTERM"
    _, _, meta = read_checkpoint(find_checkpoint(run))
    assert meta["env_steps"] == summary["env_steps"] and (run / "policy.safetensors").exists()


# ------------------------------------------------------------------------------------------ resume integrity
class _Replay:
    def save(self, path):
        Path(path).write_bytes(b"replay")


def _checkpoint(run: Path, updates: int) -> None:
    write_checkpoint(run, {"w": torch.full((2,), float(updates))}, _Replay(),
                     {"updates": updates, "env_steps": 10 * updates, "elapsed_s": 1.0})


@pytest.mark.parametrize("crash", ["after checkpoint -> checkpoint.old", "before any rename", "no crash"])
def test_recover_takes_the_newest_complete_checkpoint_whichever_rename_it_stopped_between(tmp_path, crash):
    run = tmp_path / "run"
    _checkpoint(run, 100)
    _checkpoint(run, 200)  # the swap completes: checkpoint = 200
    newest = 200
    if crash != "no crash":  # rebuild the state a kill between the renames of the next write leaves
        shutil.copytree(run / "checkpoint", run / "checkpoint.new")
        meta = json.loads((run / "checkpoint.new" / "meta.json").read_text())
        (run / "checkpoint.new" / "meta.json").write_text(json.dumps({**meta, "updates": 300, "env_steps": 3000}))
        newest = 300
        if crash == "after checkpoint -> checkpoint.old":
            os.replace(run / "checkpoint", run / "checkpoint.old")
    assert recover_checkpoint(run) == run / "checkpoint"
    assert json.loads((run / "checkpoint" / "meta.json").read_text())["updates"] == newest
    assert not (run / "checkpoint.new").exists() and not (run / "checkpoint.old").exists()


def test_an_incomplete_new_checkpoint_is_ignored(tmp_path):
    run = tmp_path / "run"
    _checkpoint(run, 100)
    (run / "checkpoint.new").mkdir()
    (run / "checkpoint.new" / "state.safetensors").write_bytes(b"half")  # killed while writing: no meta.json
    assert recover_checkpoint(run) == run / "checkpoint"
    assert json.loads((run / "checkpoint" / "meta.json").read_text())["updates"] == 100


def test_truncate_logs_drops_rows_after_the_checkpoint(tmp_path):
    from safemanip.rl.train import truncate_logs

    with open(tmp_path / "scalars.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["wall_s", "env_steps", "updates", "name", "value"])
        for steps in (100, 200, 300, 400):
            w.writerow(["1.0", steps, steps // 4, "loss", "0.1"])
    (tmp_path / "evals.jsonl").write_text("".join(json.dumps({"env_steps": s, "success": 0.5}) + "\n"
                                                  for s in (150, 350)) + '{"env_steps": 45')  # torn last line
    truncate_logs(tmp_path, 250)
    with open(tmp_path / "scalars.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert [int(r[1]) for r in rows[1:]] == [100, 200]
    assert [json.loads(line)["env_steps"] for line in (tmp_path / "evals.jsonl").read_text().splitlines()] == [150]


@pytest.mark.slow
def test_resume_of_a_copied_run_after_a_crash_between_renames(tmp_path):
    """Kill -9 a run, copy its folder, leave the copy as a crash between the checkpoint renames leaves it
    (the newest checkpoint only as checkpoint.new, an older one as checkpoint.old), add log rows from
    after the checkpoint; resuming the copy continues from the newest checkpoint, writes into the copy
    only, and its logs never go backwards."""
    run = tmp_path / "run"
    proc = start(["train", "--config", _tiny_config(tmp_path), "--out", run, "--no-progress"], tmp_path, "t1.log")
    deadline = time.time() + 90
    while time.time() < deadline:
        ckpt = find_checkpoint(run)
        if ckpt is not None and json.loads((ckpt / "meta.json").read_text())["updates"] > 0:
            break
        time.sleep(0.3)
    else:
        proc.kill()
        pytest.fail("no checkpoint within 90 s")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    recover_checkpoint(copy)
    meta = json.loads((copy / "checkpoint" / "meta.json").read_text())
    shutil.copytree(copy / "checkpoint", copy / "checkpoint.old")
    old_meta = {**meta, "updates": 0, "env_steps": 0}
    (copy / "checkpoint.old" / "meta.json").write_text(json.dumps(old_meta))
    os.replace(copy / "checkpoint", copy / "checkpoint.new")
    with open(copy / "scalars.csv", "a", newline="") as f:
        csv.writer(f).writerow(["999.0", meta["env_steps"] + 10**6, 0, "ghost", "1"])
    config = json.loads((copy / "config.json").read_text())  # a budget may change on resume: a short one
    (copy / "config.json").write_text(json.dumps({**config, "total_env_steps": meta["env_steps"] + 2000}))
    before = sorted(p.name for p in run.iterdir())
    done = subprocess.run([sys.executable, "-m", "safemanip.cli", "train", "--resume", str(copy), "--no-progress"],
                          capture_output=True, text=True, timeout=180, env=ENV)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert f"from {meta['env_steps']} env steps / {meta['updates']} updates" in done.stdout
    assert sorted(p.name for p in run.iterdir()) == before and not (run / "summary.json").exists()
    assert json.loads((copy / "config.json").read_text())["out_dir"] == str(copy)
    with open(copy / "scalars.csv", newline="") as f:
        rows = list(csv.reader(f))[1:]
    steps = [int(r[1]) for r in rows]
    assert "ghost" not in {r[3] for r in rows} and steps == sorted(steps)
    assert json.loads((copy / "summary.json").read_text())["updates"] > meta["updates"]
