"""The training loop keeps the learner busy (issue 42): evaluations run beside it, in a process of their own that
dies with it, and checkpoints append the replay buffer in chunks, from which a resume after kill -9 rebuilds the
very buffer of the checkpoint (same transitions, same slots, same insertion position).

The process tests run the real command, poll files and /proc with a deadline (they wait for conditions, never a
fixed time) and fail only on a hang."""

from __future__ import annotations

import copy
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from safemanip.env.observation import observation_dim
from safemanip.rl.buffer import FIELDS, ReplayBuffer, chunk_name, remove_unlisted_chunks, write_chunk
from safemanip.rl.checkpoint import (find_checkpoint, load_policy, read_checkpoint_meta, recover_checkpoint,
                                     write_checkpoint)
from safemanip.rl.config import TrainConfig
from conftest import SAFEMANIP, SUBPROCESS_ENV, assert_refused, descendants

OBS, ACT = 6, 3
HANG_S = 300.0
"""Bound of every condition wait: only a hang reaches it (a loaded machine makes the conditions slower, not false)."""


def transitions(n: int, rng: np.random.Generator, obs_dim: int = OBS) -> dict[str, np.ndarray]:
    return {"obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
            "act": rng.uniform(-1, 1, (n, ACT)).astype(np.float32),
            "next_obs": rng.normal(size=(n, obs_dim)).astype(np.float32),
            **{k: rng.normal(size=n).astype(np.float32) for k in ("l", "g", "next_l", "next_g")},
            "terminated": rng.random(n) < 0.2}


def assert_same_buffer(got: ReplayBuffer, want: ReplayBuffer) -> None:
    """The same transitions in the same slots, the same insertion position and count, and so the same samples."""
    assert (got.pos, got.size, got.added) == (want.pos, want.size, want.added)
    for k in FIELDS:
        np.testing.assert_array_equal(got.data[k], want.data[k], err_msg=k)
    a, b = got.sample(64, np.random.default_rng(7)), want.sample(64, np.random.default_rng(7))
    assert all(torch.equal(x, y) for x, y in zip(a, b))


def loaded(run: Path, capacity: int, obs_dim: int = OBS) -> ReplayBuffer:
    """The buffer a resume rebuilds from the run's newest complete checkpoint (what ``Trainer.restore`` does)."""
    ckpt = recover_checkpoint(run)
    buf = ReplayBuffer(capacity, obs_dim, ACT)
    buf.load(ckpt / "replay.npz", run / "replay")
    remove_unlisted_chunks(run / "replay", buf.chunks)
    return buf


def checkpoint(run: Path, buf: ReplayBuffer, updates: int) -> None:
    write_checkpoint(run, {"w": torch.full((2,), float(updates))}, buf,
                     {"updates": updates, "env_steps": buf.added, "elapsed_s": 1.0})


# ------------------------------------------------------------------------------------------ chunks, in-process
def test_each_checkpoint_appends_one_chunk_and_the_ring_comes_back_exactly(tmp_path):
    """Adds of every size against a 50-slot ring, one that overwrites it more than once between two checkpoints:
    after each checkpoint, the buffer rebuilt from the index and its chunks is the buffer, and only the chunks still
    holding a transition of the ring are on disk."""
    rng, run = np.random.default_rng(0), tmp_path / "run"
    buf = ReplayBuffer(50, OBS, ACT)
    for updates, n in enumerate((7, 30, 20, 120, 1, 49, 50, 33), start=1):
        buf.add_many(transitions(n, rng))
        checkpoint(run, buf, updates)
        chunk = sorted((run / "replay").iterdir())[-1]
        assert chunk.name == chunk_name(buf.added - min(n, 50))  # only what is new since the last checkpoint
        assert_same_buffer(loaded(run, 50), buf)
        assert sorted(p.name for p in (run / "replay").iterdir()) == [chunk_name(f) for f, _ in buf.chunks]
        first, count = buf.chunks[0]
        assert first <= buf.added - buf.size < first + count  # the oldest chunk kept still holds the oldest transition


def test_chunks_a_kill_left_half_written_or_unlisted_are_ignored_and_removed_on_resume(tmp_path):
    rng, run = np.random.default_rng(1), tmp_path / "run"
    buf = ReplayBuffer(40, OBS, ACT)
    for updates, n in enumerate((25, 30), start=1):
        buf.add_many(transitions(n, rng))
        checkpoint(run, buf, updates)
    at_checkpoint = copy.deepcopy(buf)
    # what a kill during the next checkpoint leaves: its chunk written (no checkpoint lists it), a later chunk cut off
    # in its temporary file, and garbage under a chunk's name
    buf.add_many(transitions(12, rng))
    unlisted = write_chunk(run / "replay", *buf.take_unsaved())
    half = run / "replay" / f".{chunk_name(buf.added)}.a1b2c3.tmp"
    half.write_bytes(unlisted.read_bytes()[:300])
    (run / "replay" / chunk_name(10**6)).write_bytes(b"\0" * 100)
    assert_same_buffer(loaded(run, 40), at_checkpoint)
    assert not unlisted.exists() and not half.exists() and not (run / "replay" / chunk_name(10**6)).exists()


class Killed(BaseException):
    """Where the simulated kill -9 stops the writer."""


def _commit_points(monkeypatch, kill_at: int | None) -> dict:
    """Count (and at ``kill_at`` stop at) every rename and removal a checkpoint write makes: the moments at which
    what is on disk changes meaning."""
    calls = {"n": 0}

    def stoppable(fn):
        def call(*args, **kwargs):
            calls["n"] += 1
            if calls["n"] == kill_at:
                raise Killed
            return fn(*args, **kwargs)
        return call

    monkeypatch.setattr(os, "replace", stoppable(os.replace))
    monkeypatch.setattr(shutil, "rmtree", stoppable(shutil.rmtree))
    monkeypatch.setattr(Path, "unlink", stoppable(Path.unlink))
    return calls


def test_a_kill_at_any_moment_of_a_checkpoint_write_resumes_the_old_or_the_new_buffer_exactly(tmp_path, monkeypatch):
    """The write is stopped at each of its renames and removals in turn (the last run is not stopped): the newest
    complete checkpoint is then the old one or the new one, its buffer comes back exactly, and the run goes on from
    it (its next checkpoint comes back exactly too). The write under test wraps the ring, so that it also removes a
    chunk the new checkpoint no longer needs."""
    def prepared(run: Path) -> tuple[ReplayBuffer, ReplayBuffer, ReplayBuffer]:
        rng = np.random.default_rng(2)
        buf = ReplayBuffer(40, OBS, ACT)
        for updates, n in enumerate((25, 10), start=1):
            buf.add_many(transitions(n, rng))
            checkpoint(run, buf, updates)
        old = copy.deepcopy(buf)
        buf.add_many(transitions(30, rng))  # overwrites all of the first chunk
        return buf, old, copy.deepcopy(buf)

    with monkeypatch.context() as m:
        buf, _, _ = prepared(tmp_path / "count")
        calls = _commit_points(m, None)
        checkpoint(tmp_path / "count", buf, 3)
    points = calls["n"]
    assert points >= 5
    outcomes = set()
    for kill_at in range(1, points + 2):
        run = tmp_path / f"kill-{kill_at}"
        buf, old, new = prepared(run)
        with monkeypatch.context() as m:
            _commit_points(m, kill_at)
            try:
                checkpoint(run, buf, 3)
            except Killed:
                pass
        resumed = loaded(run, 40)
        updates = read_checkpoint_meta(run / "checkpoint")["updates"]
        outcomes.add(updates)
        assert_same_buffer(resumed, new if updates == 3 else old)
        resumed.add_many(transitions(17, np.random.default_rng(kill_at)))
        checkpoint(run, resumed, 4)
        assert_same_buffer(loaded(run, 40), resumed)
    assert outcomes == {2, 3}  # both sides of the commit were hit


def test_a_checkpoint_of_the_single_file_format_is_read_and_the_next_one_writes_chunks(tmp_path):
    """Checkpoints before issue 42 held the whole buffer in replay.npz: --resume reads it (the same buffer), and the
    run's next checkpoint writes all of it as chunks."""
    rng, run = np.random.default_rng(3), tmp_path / "run"
    buf = ReplayBuffer(30, OBS, ACT)
    buf.add_many(transitions(47, rng))  # wrapped
    checkpoint(run, ReplayBuffer(30, OBS, ACT), 1)
    buf.save(run / "checkpoint" / "replay.npz")  # the old format, as the old writer left it
    shutil.rmtree(run / "replay", ignore_errors=True)
    back = loaded(run, 30)
    assert (back.pos, back.size) == (buf.pos, buf.size)
    for k in FIELDS:
        np.testing.assert_array_equal(back.data[k], buf.data[k])
    back.add_many(transitions(5, rng))
    checkpoint(run, back, 2)
    assert_same_buffer(loaded(run, 30), back)


# ------------------------------------------------------------------------------------------ resume, in-process
TINY = {"k": 1, "hidden": (16, 16), "batch_size": 8, "learning_starts": 8, "random_steps": 8, "env": {"max_episode_steps": 20},
        "eval_episodes": 2, "device": "cpu", "precision": "fp32", "backend": "inline", "minutes": None}


def checkpointed_run(tmp_path: Path, rounds=(150, 120), capacity: int = 200) -> tuple[Path, TrainConfig, ReplayBuffer]:
    """A run folder with real checkpoints of a (random) buffer, as the training loop writes them, and no training."""
    from safemanip.rl.learner import Learner

    run = tmp_path / "run"
    run.mkdir()
    cfg = TrainConfig(**TINY, buffer_size=capacity, out_dir=str(run), total_env_steps=1)
    obs_dim = observation_dim(1)
    learner, buf, rng = Learner(obs_dim, ACT, cfg), ReplayBuffer(capacity, obs_dim, ACT), np.random.default_rng(4)
    for updates, n in enumerate(rounds, start=1):
        buf.add_many(transitions(n, rng, obs_dim))
        write_checkpoint(run, learner.state_tensors(), buf,
                         {"env_steps": buf.added, "updates": updates, "elapsed_s": 1.0, "restarts": 0,
                          "best": {"success": -1.0}, "evals": 0, "config": json.loads(cfg.to_json())})
    (run / "config.json").write_text(cfg.to_json())
    return run, cfg, buf


def test_resume_rebuilds_the_buffer_of_the_checkpoint_and_ignores_what_a_kill_left(tmp_path):
    """``train --resume`` (inline; the budget already used, so it only evaluates and checkpoints once more) with an
    unlisted chunk and a cut-off temporary file beside the checkpoint's chunks: the buffer it goes on with is the
    checkpoint's, and the leftovers are gone."""
    from safemanip.rl.train import train

    run, cfg, buf = checkpointed_run(tmp_path)
    stray = write_chunk(run / "replay", buf.added, transitions(9, np.random.default_rng(5), observation_dim(1)))
    (run / "replay" / f".{chunk_name(buf.added + 9)}.x.tmp").write_bytes(b"cut off")
    train(cfg, resume=True, progress=False)
    assert_same_buffer(loaded(run, 200, observation_dim(1)), buf)
    assert not stray.exists() and not list((run / "replay").glob(".*"))
    assert json.loads((run / "summary.json").read_text())["final_eval"]["episodes"] == 2


def test_resume_refuses_a_damaged_chunk_and_says_how_to_recover(capsys, tmp_path):
    run, _, buf = checkpointed_run(tmp_path)
    chunk = run / "replay" / chunk_name(buf.chunks[-1][0])
    chunk.write_bytes(chunk.read_bytes()[:-40])
    err = assert_refused(capsys, ["train", "--resume", run, "--no-progress"], "the replay buffer cannot be restored")
    assert str(chunk) in err and "truncated or damaged" in err and f"--init-from {run}" in err
    chunk.unlink()
    assert_refused(capsys, ["train", "--resume", run, "--no-progress"], f"{chunk} is missing (the checkpoint lists it)")


# ------------------------------------------------------------------------------------------ evaluation beside training
def _random_actor_arrays(seed: int = 0):
    from safemanip.rl.networks import Actor, actor_arrays

    torch.manual_seed(seed)
    return actor_arrays(Actor(observation_dim(1), ACT, (16, 16)))


def wait_for(condition, what: str, timeout: float = HANG_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not {what} within {timeout:g} s (a hang)")
        time.sleep(0.05)


def test_the_evaluation_process_gives_the_result_of_the_synchronous_path():
    from safemanip.rl.envs import env_builder
    from safemanip.rl.rollout import EvalProcess, EvalRequest, InlineEvaluator, evaluate_weights

    build = env_builder(TrainConfig(**TINY).env_kwargs)
    arrays = _random_actor_arrays()
    request = EvalRequest(arrays, 10, 2, 1.5)
    process = EvalProcess(build, 3)
    try:
        process.submit(request)
        assert not process.idle
        done = process.wait()
    finally:
        process.close()
    inline = InlineEvaluator(build, 3)
    inline.submit(request)
    assert done == inline.take() == [(request, evaluate_weights(arrays, build, 3))]
    assert done[0][1]["episodes"] == 3


def test_the_best_policy_holds_the_weights_that_were_evaluated_not_the_current_ones(tmp_path):
    """The learner goes on while its weights are evaluated; the result arrives later, and ``best.safetensors`` and
    the evaluation record hold the evaluated weights and their counters."""
    from safemanip.rl.envs import env_builder
    from safemanip.rl.networks import actor_arrays
    from safemanip.rl.rollout import EvalProcess
    from safemanip.rl.train import ScalarLog, Trainer

    run = tmp_path / "run"
    run.mkdir()
    cfg = TrainConfig(**{**TINY, "backend": "local"}, out_dir=str(run))
    trainer = Trainer(cfg, run, None, env_builder(cfg.rollout_env_kwargs))
    trainer.evaluator, trainer.log_file = EvalProcess(trainer.build, cfg.eval_episodes), ScalarLog(run)
    try:
        trainer.env_steps, trainer.updates = 300, 40
        evaluated = actor_arrays(trainer.learner.actor)
        trainer.evaluate()
        with torch.no_grad():  # the learner's next updates, made before the result is taken in
            for p in trainer.learner.actor.parameters():
                p.add_(0.5)
        trainer.env_steps, trainer.updates = 900, 99

        def recorded() -> bool:
            trainer.take_evaluations()
            return trainer.evaluator.idle

        wait_for(recorded, "the evaluation recorded")
    finally:
        trainer.evaluator.close()
        trainer.log_file.close()
    actor, meta = load_policy(run / "best.safetensors")
    for got, want, now in zip(actor.arrays(), evaluated, actor_arrays(trainer.learner.actor)):
        np.testing.assert_array_equal(got, want)
        assert not np.array_equal(got, now)
    record = json.loads((run / "evals.jsonl").read_text())
    assert (record["env_steps"], record["updates"]) == (meta["env_steps"], meta["updates"]) == (300, 40)
    assert meta["eval"] == record == trainer.best


def _tiny_config(tmp_path: Path, **extra) -> Path:
    from conftest import TINY_TRAIN

    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps({**TINY_TRAIN, "minutes": 2.0, "total_env_steps": 10**7, **extra}))
    return cfg


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _comm(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


@pytest.mark.slow
@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_the_evaluation_process_ends_with_the_training_process(tmp_path, stop):
    """kill -9 of the training process (alone, not its group), SIGTERM or SIGINT while evaluations run: the
    evaluation process (and every other process the run started) is gone with it; a stop by signal is a clean one."""
    run = tmp_path / "run"
    with open(tmp_path / "train.log", "w") as log:
        proc = subprocess.Popen([*SAFEMANIP, "train", "--config", _tiny_config(tmp_path, eval_every_s=0.5,
                                 eval_episodes=4), "--out", run, "--no-progress"], stdout=log, stderr=subprocess.STDOUT,
                                env=SUBPROCESS_ENV, start_new_session=True)
    try:
        def evaluating() -> bool:
            assert proc.poll() is None, (tmp_path / "train.log").read_text()[-2000:]
            evals = run / "evals.jsonl"
            return any(_comm(p) == "safemanip-eval" for p in descendants(proc.pid)) and evals.exists() \
                and evals.read_text().count("\n") >= 1

        wait_for(evaluating, "an evaluation recorded by the evaluation process")
        started = descendants(proc.pid)
        os.kill(proc.pid, stop)
        code = proc.wait(timeout=HANG_S)
        wait_for(lambda: not any(_alive(p) for p in started), "every process of the run gone", timeout=10.0)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for p in descendants(proc.pid):
            os.kill(p, signal.SIGKILL)
    text = (tmp_path / "train.log").read_text()
    if stop != signal.SIGKILL:
        assert code == 128 + stop and "Traceback" not in text, text[-2000:]
        assert json.loads((run / "summary.json").read_text())["interrupted"] == signal.Signals(stop).name


# ------------------------------------------------------------------------------------------ kill -9 and resume
def _buffer_of(run: Path, checkpoint_dir: Path, capacity: int) -> ReplayBuffer:
    buf = ReplayBuffer(capacity, observation_dim(1), ACT)
    buf.load(checkpoint_dir / "replay.npz", run / "replay")
    return buf


@pytest.mark.slow
def test_resume_after_kill_9_loses_at_most_one_checkpoint_interval_and_rebuilds_the_buffer_exactly(tmp_path):
    """The inline backend is deterministic for its seed, so a run killed with SIGKILL collected the very transitions
    an uninterrupted run with the same seed did, up to the kill. Its newest complete checkpoint before the kill
    survives it, is at most one interval (plus one write) old, and the buffer rebuilt from it, and the one the
    resumed run ends with, hold exactly the reference run's transitions in the same slots."""
    base = {"k": 1, "hidden": [32, 32], "batch_size": 32, "buffer_size": 6000, "learning_starts": 300,
            "random_steps": 300, "eval_episodes": 1, "eval_every_s": 86400, "checkpoint_every_s": 1, "log_every_s": 1,
            "envs_per_collector": 2, "env_steps_per_update": 2.0, "backend": "inline", "precision": "fp32",
            "minutes": None, "env": {"max_episode_steps": 50}, "seed": 11}
    (tmp_path / "ref.json").write_text(json.dumps({**base, "total_env_steps": 3000}))
    (tmp_path / "killed.json").write_text(json.dumps({**base, "total_env_steps": 10**7}))
    ref, killed = tmp_path / "ref", tmp_path / "killed"
    done = subprocess.run([*SAFEMANIP, "train", "--config", tmp_path / "ref.json", "--out", ref, "--no-progress"],
                          capture_output=True, text=True, env=SUBPROCESS_ENV, timeout=HANG_S)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    reference = _buffer_of(ref, ref / "checkpoint", 6000)

    with open(tmp_path / "killed.log", "w") as log:
        proc = subprocess.Popen([*SAFEMANIP, "train", "--config", tmp_path / "killed.json", "--out", killed,
                                 "--no-progress"], stdout=log, stderr=subprocess.STDOUT, env=SUBPROCESS_ENV,
                                start_new_session=True)
    seen: set[int] = set()

    def two_checkpoints() -> bool:
        assert proc.poll() is None, (tmp_path / "killed.log").read_text()[-2000:]
        ckpt = find_checkpoint(killed)
        if ckpt is not None:
            try:
                seen.add(read_checkpoint_meta(ckpt)["updates"])
            except ValueError:  # swapped away while it was read
                pass
        return len(seen - {0}) >= 2

    try:
        wait_for(two_checkpoints, "two checkpoints with updates")
        newest = find_checkpoint(killed)
        before = read_checkpoint_meta(newest)["updates"] if newest is not None else 0
        os.killpg(proc.pid, signal.SIGKILL)  # the whole group, mid-run, no clean-up
        killed_at = time.time()
        proc.wait()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    ckpt = recover_checkpoint(killed)
    meta = read_checkpoint_meta(ckpt)
    assert meta["updates"] >= before  # no checkpoint complete before the kill is lost
    assert killed_at - (ckpt / "meta.json").stat().st_mtime <= base["checkpoint_every_s"] + 10.0
    rebuilt = _buffer_of(killed, ckpt, 6000)
    n = min(rebuilt.added, reference.added)
    assert rebuilt.added == rebuilt.size and n > 300
    for k in FIELDS:
        np.testing.assert_array_equal(rebuilt.data[k][:n], reference.data[k][:n], err_msg=k)
        assert not rebuilt.data[k][rebuilt.added:].any()  # the slots beyond its insertion position are empty

    config = json.loads((killed / "config.json").read_text())  # a budget may change on resume: a short one
    (killed / "config.json").write_text(json.dumps({**config, "total_env_steps": meta["env_steps"] + 600}))
    done = subprocess.run([*SAFEMANIP, "train", "--resume", killed, "--no-progress"], capture_output=True, text=True,
                          env=SUBPROCESS_ENV, timeout=HANG_S)
    assert done.returncode == 0 and "resuming" in done.stdout, done.stdout[-2000:] + done.stderr[-2000:]
    after = _buffer_of(killed, killed / "checkpoint", 6000)
    assert after.added > rebuilt.added
    for k in FIELDS:  # the resumed run went on from the checkpoint's buffer, in place
        np.testing.assert_array_equal(after.data[k][:rebuilt.added], rebuilt.data[k][:rebuilt.added], err_msg=k)
