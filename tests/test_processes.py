"""Process hygiene: no worker outlives a killed main process, SIGINT/SIGTERM save what is finished, and a
run resumes from the newest complete checkpoint into the folder it is given.

The kill tests run the real commands as subprocesses, wait until their worker processes are up, send
SIGKILL to the main process only (not its group: the workers must notice on their own) and check that
every process that descended from it is gone within 10 s."""

from __future__ import annotations

import csv
import io
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
from conftest import SAFEMANIP, SUBPROCESS_ENV, TINY_TRAIN, cmdline, descendants


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def start(args, tmp_path: Path, log_name: str, env: dict | None = None) -> subprocess.Popen:
    log = open(tmp_path / log_name, "w")
    return subprocess.Popen([*SAFEMANIP, *map(str, args)], stdout=log, stderr=subprocess.STDOUT,
                            env=env or SUBPROCESS_ENV, cwd=tmp_path, start_new_session=True)


HANG_S = 300.0
"""Bound of every condition wait below: only a hang reaches it (on a loaded machine the conditions take longer,
they do not fail)."""


def wait_until(condition, what: str, proc: subprocess.Popen | None = None, timeout: float = HANG_S) -> None:
    """Poll ``condition()`` until it holds; fail if ``proc`` exits first or nothing happens for ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the command exited with {proc.returncode} before {what}")
        if time.monotonic() > deadline:
            raise AssertionError(f"not {what} within {timeout:g} s (a hang)")
        time.sleep(0.05)


def wait_gone(pids, timeout: float = 10.0) -> None:
    """Every process of ``pids`` ends within ``timeout`` s (the workers die with their parent); kill the rest."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.05)
    left = [p for p in pids if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"processes still alive {timeout:g} s after their parent ended: {left}"


def scratch_env(tmp_path: Path) -> tuple[dict, Path]:
    """An environment whose TMPDIR is a fresh folder: the evaluation workers' journals (one line per finished
    episode, ``evaluation/parallel.py``) show there, which is how the tests below see episodes finish."""
    scratch = tmp_path / "scratch"
    scratch.mkdir(exist_ok=True)
    return {**SUBPROCESS_ENV, "TMPDIR": str(scratch)}, scratch


def journal_lines(scratch: Path) -> list[int]:
    """Episodes finished so far by each worker of the running evaluation (lines of its journal)."""
    counts = []
    for journal in scratch.glob("safemanip-eval-*/worker-*.jsonl"):
        try:
            counts.append(journal.read_bytes().count(b"\n"))
        except OSError:  # the evaluation ended and removed its journals
            pass
    return counts


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
    cfg.write_text(json.dumps({**TINY_TRAIN, "minutes": 1.0, "total_env_steps": 10**7, **extra}))
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
    proc = subprocess.Popen([sys.executable, "-c", script], env=SUBPROCESS_ENV, start_new_session=True)
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


def _sweep_config(tmp_path: Path, episodes: int, selectors=("dynamic-knn",)) -> Path:
    """A sweep of one cell per selector (the shipped pi_2 in 3-object scenes, ``episodes`` each)."""
    cfg = tmp_path / "s.json"
    cfg.write_text(json.dumps({"name": "s", "figure": "table", "episodes": episodes, "judge": "conservative",
                               "policies": ["policies/rarl-k2-conservative-s0.safetensors"], "n_objects": [3],
                               "selectors": list(selectors)}))
    return cfg


def sigint_when(args, tmp_path: Path, log_name: str, ready, what: str, expect: str, env: dict | None = None) -> None:
    """Start a command, wait until its two workers are up and ``ready()`` holds, send SIGINT to the main process and
    check that it exits with 130 saying ``expect``, that its workers end with it, and that no traceback was printed
    (by it or by a worker)."""
    proc = start(args, tmp_path, log_name, env)
    workers = wait_for_workers(proc, 2)
    wait_until(ready, what, proc)
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=HANG_S) == 130, (tmp_path / log_name).read_text()[-2000:]
    wait_gone(workers)
    text = (tmp_path / log_name).read_text()
    assert "Traceback" not in text and expect in text, text[-2000:]


@pytest.mark.slow
def test_sigint_to_sweep_stops_cleanly_and_keeps_no_partial_cell(tmp_path):
    out = tmp_path / "sw"
    env, scratch = scratch_env(tmp_path)
    sigint_when(["sweep", _sweep_config(tmp_path, 2000), "--out", out, "--workers", "2", "--no-progress"], tmp_path,
                "sweep.log", lambda: sum(journal_lines(scratch)) >= 1, "an episode of the cell finished", "interrupted",
                env)
    assert not list((out / "cells").glob("*.json"))  # the interrupted cell is redone next time, not kept half-done


@pytest.mark.slow
def test_sigint_to_eval_writes_the_finished_episodes(tmp_path):
    out = tmp_path / "ev"
    env, scratch = scratch_env(tmp_path)
    # a worker with 5 episodes journalled has handed its first two chunks (of 2) back, the last a whole episode ago
    sigint_when(["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "2000", "--workers", "2", "--chunk-size",
                 "2", "--no-progress", "--out", out], tmp_path, "eval.log", lambda: max(journal_lines(scratch), default=0) >= 5,
                "two chunks finished", "interrupted by SIGINT", env)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"]["signal"] == "SIGINT" and 0 < summary["episodes"] < 2000
    with open(out / "episodes.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == summary["episodes"]


@pytest.mark.slow
@pytest.mark.parametrize("command", ["eval", "sweep"])
def test_sigint_while_the_workers_start_leaves_no_traceback_and_no_process(tmp_path, command):
    """SIGINT as soon as the first worker process exists, while the pool is still sending the workers their start-up
    data: a worker cut off then used to print `_pickle.UnpicklingError: pickle data was truncated` (or EOFError,
    FileNotFoundError) with a traceback, and was not ended by the pool."""
    out = tmp_path / "out"
    args = (["eval", "--policy", "rarl-k2-conservative-s0", "--episodes", "2000"] if command == "eval"
            else ["sweep", _sweep_config(tmp_path, 2000)])
    proc = start([*args, "--workers", "2", "--no-progress", "--out", out], tmp_path, "run.log")
    seen: set[int] = set()

    def a_worker_starts() -> bool:
        found = descendants(proc.pid)
        seen.update(found)
        return any("spawn_main" in cmdline(p) for p in found)

    wait_until(a_worker_starts, "a worker process started", proc)
    os.kill(proc.pid, signal.SIGINT)
    while proc.poll() is None:  # every process it starts before it ends
        seen.update(descendants(proc.pid))
        time.sleep(0.01)
    assert proc.returncode == 130
    wait_gone(seen)  # then a worker's traceback would be in the log too
    text = (tmp_path / "run.log").read_text()
    assert "Traceback" not in text and "Error" not in text and "interrupted" in text, text[-3000:]


def test_signals_deferred_holds_a_stop_until_the_block_ends_and_a_second_one_stops_at_once():
    from safemanip.util.procs import Interrupted, signals_deferred, stop_on_signals

    steps = []
    with pytest.raises(Interrupted) as stop, stop_on_signals():
        with signals_deferred():
            signal.raise_signal(signal.SIGINT)
            steps.append("the block went on")
    assert steps == ["the block went on"] and stop.value.signum == signal.SIGINT
    with pytest.raises(Interrupted) as stop, stop_on_signals():
        with signals_deferred():
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGTERM)
            steps.append("not reached")
    assert steps == ["the block went on"] and stop.value.signum == signal.SIGTERM
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # every handler is back


def test_a_worker_whose_start_up_data_is_cut_off_exits_without_a_traceback():
    """The worker side (``util/procs.py``, ``QuietSpawnProcess``): start-up data cut off by a parent that was killed
    while sending it is an exit with code 1 and nothing on stderr; the whole data still starts the process."""
    import multiprocessing.context as mpc
    from multiprocessing import reduction

    from safemanip.util.procs import QuietSpawnProcess

    process = QuietSpawnProcess(target=print, args=(list(range(50_000)),))
    buffer = io.BytesIO()
    mpc.set_spawning_popen(object())  # what the spawn start method sets while it pickles a process
    try:
        reduction.dump(process, buffer)
    finally:
        mpc.set_spawning_popen(None)
    data = buffer.getvalue()
    # what a spawned worker itself does with its start-up data (multiprocessing's own format, made by this test)
    load = "import pickle, sys; p = pickle.load(sys.stdin.buffer); print(type(p).__name__, len(p._args[0]))"
    for cut, code, stdout in ((len(data), 0, "QuietSpawnProcess 50000\n"), (len(data) // 2, 1, "")):
        done = subprocess.run([sys.executable, "-c", load], input=data[:cut], capture_output=True, env=SUBPROCESS_ENV,
                              timeout=120)
        assert (done.returncode, done.stdout.decode(), done.stderr.decode()) == (code, stdout, ""), done.stderr[-2000:]


# ------------------------------------------------------------------------------------------ sweeps: locks, kills, resume
def _cells(spec: Path) -> list[str]:
    from safemanip.evaluation.sweep.grid import cells_of
    from safemanip.evaluation.sweep.spec import load_config

    return [c.id for c in cells_of(load_config(str(spec)))]


def _stored_cells(out: Path) -> dict[str, dict]:
    """The cell results of a sweep folder, each of which must be whole JSON (a half-written one fails here)."""
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))}


@pytest.mark.slow
def test_a_second_sweep_on_the_same_folder_is_refused_in_one_line(tmp_path):
    spec, out = _sweep_config(tmp_path, 2000), tmp_path / "sw"
    first = start(["sweep", spec, "--out", out, "--workers", "2", "--no-progress"], tmp_path, "first.log")
    try:
        lock = out / ".lock"
        wait_until(lambda: lock.exists() and lock.read_text() == str(first.pid), "the first sweep holds the folder", first)
        second = subprocess.run([*SAFEMANIP, "sweep", str(spec), "--out", str(out),
                                 "--workers", "2", "--no-progress"], capture_output=True, text=True, env=SUBPROCESS_ENV,
                                cwd=tmp_path, timeout=HANG_S)
        assert second.returncode == 2, second.stdout[-1000:] + second.stderr[-1000:]
        assert second.stderr.splitlines() == [f"safemanip sweep: error: --out {out} is in use by a running process (pid "
                                              f"{first.pid}); wait for it to finish or choose another --out"]
        assert "Traceback" not in second.stdout and first.poll() is None  # the first one goes on, undisturbed
    finally:
        workers = descendants(first.pid)
        os.kill(first.pid, signal.SIGINT)
        assert first.wait(timeout=HANG_S) == 130
        wait_gone(workers)
    assert not _stored_cells(out)


@pytest.mark.slow
def test_kill_9_in_the_middle_of_a_sweep_cell_leaves_no_cell_and_a_rerun_completes_it(tmp_path):
    spec, out = _sweep_config(tmp_path, 12, selectors=("static-knn", "dynamic-knn")), tmp_path / "sw"
    args = ["sweep", spec, "--out", out, "--workers", "2", "--no-progress"]
    env, scratch = scratch_env(tmp_path)
    proc = start(args, tmp_path, "first.log", env)
    wait_until(lambda: sum(journal_lines(scratch)) >= 1, "an episode of the first cell finished", proc)
    workers = descendants(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    wait_gone(workers)
    assert _stored_cells(out) == {}, "the first cell was stored: the kill came after it, not in the middle of it"
    assert not [p.name for p in (out / "cells").rglob("*.json")]  # nor an episode file or summary of the cell
    again = start(args, tmp_path, "again.log")
    assert again.wait(timeout=HANG_S) == 0, (tmp_path / "again.log").read_text()[-2000:]
    stored = _stored_cells(out)
    assert sorted(stored) == sorted(_cells(spec)) and all(c["summary"]["episodes"] == 12 for c in stored.values())
    assert "Traceback" not in (tmp_path / "first.log").read_text() + (tmp_path / "again.log").read_text()


@pytest.mark.slow
def test_sigint_in_a_sweep_then_the_same_command_resumes_without_losing_a_cell(tmp_path):
    spec, out = _sweep_config(tmp_path, 12, selectors=("static-knn", "dynamic-knn")), tmp_path / "sw"
    first_cell, second_cell = _cells(spec)
    args = ["sweep", spec, "--out", out, "--workers", "2", "--no-progress"]
    env, scratch = scratch_env(tmp_path)

    def second_cell_runs() -> bool:  # the first cell is stored (its journals are gone) and the second has episodes
        return (out / "cells" / f"{first_cell}.json").exists() and sum(journal_lines(scratch)) >= 1

    sigint_when(args, tmp_path, "first.log", second_cell_runs, "the second cell running", "interrupted", env)
    stored = _stored_cells(out)
    assert sorted(stored) == [first_cell], "the second cell finished before the SIGINT: nothing was interrupted"
    kept = (out / "cells" / f"{first_cell}.json").read_bytes()
    again = start(args, tmp_path, "again.log")
    assert again.wait(timeout=HANG_S) == 0, (tmp_path / "again.log").read_text()[-2000:]
    text = (tmp_path / "again.log").read_text()
    assert f"{first_cell}: done already" in text and f"{second_cell}: success" in text and "Traceback" not in text
    assert (out / "cells" / f"{first_cell}.json").read_bytes() == kept  # not redone, not rewritten
    stored = _stored_cells(out)
    assert sorted(stored) == sorted([first_cell, second_cell])
    assert all(c["summary"]["episodes"] == 12 for c in stored.values())


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
def _checkpoint(run: Path, updates: int) -> None:
    from safemanip.rl.buffer import ReplayBuffer

    write_checkpoint(run, {"w": torch.full((2,), float(updates))}, ReplayBuffer(4, 2, 1),
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
    done = subprocess.run([*SAFEMANIP, "train", "--resume", str(copy), "--no-progress"],
                          capture_output=True, text=True, timeout=180, env=SUBPROCESS_ENV)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert f"from {meta['env_steps']} env steps / {meta['updates']} updates" in done.stdout
    assert sorted(p.name for p in run.iterdir()) == before and not (run / "summary.json").exists()
    assert json.loads((copy / "config.json").read_text())["out_dir"] == str(copy)
    with open(copy / "scalars.csv", newline="") as f:
        rows = list(csv.reader(f))[1:]
    steps = [int(r[1]) for r in rows]
    assert "ghost" not in {r[3] for r in rows} and steps == sorted(steps)
    assert json.loads((copy / "summary.json").read_text())["updates"] > meta["updates"]
