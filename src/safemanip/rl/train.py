"""The training loop: rollout workers fill the replay buffer, the learner updates, and the run is
evaluated, logged and checkpointed as it goes, the evaluations and the checkpoint writes beside the learner
(``rl/rollout.py``'s evaluation process, ``rl/checkpoint.py``'s writer thread). Reads top to bottom."""

from __future__ import annotations

import csv
import io
import json
import os
import pickle
import queue
import shutil
import signal
import time
from collections import Counter, deque
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from safemanip.rl.buffer import ReplayBuffer, ReplayFileError, remove_unlisted_chunks
from safemanip.rl.checkpoint import (CHECKPOINT_NAMES, REPLAY_DIR, CheckpointError, CheckpointWriter, find_checkpoint,
                                     read_checkpoint, read_checkpoint_meta, recover_checkpoint, save_policy)
from safemanip.rl.collector import make_pool
from safemanip.rl.config import ConfigError, TrainConfig, load_run_config
from safemanip.rl.envs import EnvBuilder, env_builder
from safemanip.rl.learner import Learner
from safemanip.rl.networks import actor_arrays
from safemanip.rl.precision import cpu_model
from safemanip.rl.rollout import EvalRequest, evaluate_weights, make_evaluator
from safemanip.util.files import OutputLock, atomic_write_text, check_output_dir, parse_json, read_json_file
from safemanip.util.procs import WorkerDied, describe_exit, stop_on_signals

SYNC_EVERY = 50  # learner updates between actor-weight broadcasts to the workers


class ScalarLog:
    """TensorBoard scalars and a CSV of the same numbers."""

    def __init__(self, run_dir: Path):
        from torch.utils.tensorboard import SummaryWriter

        self.tb = SummaryWriter(str(run_dir / "tb"))
        new = not (run_dir / "scalars.csv").exists()
        self.file = open(run_dir / "scalars.csv", "a", newline="")
        self.csv = csv.writer(self.file)
        if new:
            self.csv.writerow(["wall_s", "env_steps", "updates", "name", "value"])

    def log(self, scalars: dict[str, float], env_steps: int, updates: int, wall_s: float) -> None:
        for name, value in scalars.items():
            self.tb.add_scalar(name, value, env_steps)
            self.csv.writerow([f"{wall_s:.1f}", env_steps, updates, name, f"{value:.6g}"])
        self.file.flush()

    def close(self) -> None:
        self.tb.close()
        self.file.close()


def policy_meta(cfg: TrainConfig, obs_dim: int, act_dim: int, eval_result: dict | None, env_steps: int, updates: int,
                wall_s: float, command: str | None) -> dict:
    return {"algorithm": cfg.algorithm, "k": cfg.k, "constraints": cfg.constraint_set, "obs_dim": obs_dim,
            "act_dim": act_dim, "hidden": list(cfg.hidden), "env_kwargs": cfg.env_kwargs, "train_config": json.loads(cfg.to_json()),
            "env_steps": env_steps, "updates": updates, "wall_s": round(wall_s, 1), "eval": eval_result,
            "train_command": command}


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True, command: str | None = None,
          run_dir: str | Path | None = None, env_factory: Callable | None = None) -> Path:
    """Train (or, with ``resume``, continue) the run in ``run_dir`` (default ``cfg.out_dir``).

    ``env_factory`` builds the env the rollout workers and the evaluations run, called with the keyword arguments
    of ``cfg.rollout_env_kwargs`` (``env`` left out); None builds the registry's env the config names
    (``rl/envs.py``). Selection-aware training (``cfg.scene_objects``) needs
    ``selection.training_env.SelectedSlotsEnv`` here (``safemanip train`` passes it; without it the call is refused
    with that message). Worker processes receive it pickled by reference: a module-level class or function.

    The folder is locked for the whole run (a second process on it is refused). SIGINT/SIGTERM stop the
    run at the next safe point: a checkpoint and ``policy.safetensors`` are written and the summary says
    ``"interrupted"``; ``--resume`` continues from there."""
    # the env is resolved before anything is written: a missing factory, or one the worker processes cannot
    # receive, is refused here (Ray's actors take whatever cloudpickle sends)
    build = env_builder(cfg.rollout_env_kwargs, env_factory)
    if cfg.backend == "local":
        try:
            pickle.dumps(build)
        except (pickle.PicklingError, AttributeError, TypeError) as err:
            raise ConfigError(f"env_factory {env_factory!r} cannot be sent to the rollout worker processes ({err}): "
                              f"pass a module-level class or function, or use backend 'inline'") from None
    run_dir = Path(run_dir or cfg.out_dir)
    problems = check_output_dir(run_dir, "--resume" if resume else "--out")
    if problems:
        raise ConfigError(problems[0])
    warm = None if resume else warm_start(cfg)  # checked before the run folder exists; a resumed run's
    with OutputLock(run_dir, "--resume" if resume else "--out"):  # checkpoint already holds its start
        return _train_locked(cfg, run_dir, resume, progress, command, build, warm)


def truncate_logs(run_dir: Path, env_steps: int, evals: int | None = None, best: dict | None = None) -> int:
    """Drop the log rows written after the checkpoint a run resumes from, so the logs never go backwards
    (scalars.csv, evals.jsonl) and best.safetensors matches the resumed history; returns the evaluations kept.

    ``evals`` and ``best``: the number of evaluations the checkpoint had recorded and its best one (checkpoints
    since issue 42). An evaluation runs beside training, so one of weights from before the checkpoint may have
    been recorded after it: the first ``evals`` records are kept, and best.safetensors only if it is ``best``'s.
    Without them (older checkpoints) records and best.safetensors are kept by their env steps."""
    scalars = run_dir / "scalars.csv"
    if scalars.exists():
        rows = []
        with open(scalars, newline="", errors="replace") as f:
            try:
                for row in csv.reader(f):
                    rows.append(row)
            except csv.Error:  # a damaged line (e.g. torn by a kill): keep what came before it
                pass
        kept = rows[:1] + [r for r in rows[1:] if len(r) == 5 and r[1].isdigit() and len(r[1]) < 19
                           and int(r[1]) <= env_steps]
        if len(kept) != len(rows):
            text = io.StringIO()
            csv.writer(text).writerows(kept)
            atomic_write_text(scalars, text.getvalue())
    evals_file = run_dir / "evals.jsonl"
    kept_lines = []
    if evals_file.exists():
        for line in evals_file.read_text(errors="replace").splitlines():
            try:
                steps = parse_json(line, "a line of evals.jsonl", max_bytes=100_000)["env_steps"]
                if isinstance(steps, int) and not isinstance(steps, bool) and steps <= env_steps:
                    kept_lines.append(line)
            except (ValueError, KeyError, TypeError):
                pass  # a torn last line from a kill, or a line that is not an evaluation: dropped
        if evals is not None:
            kept_lines = kept_lines[:evals]
        atomic_write_text(evals_file, "".join(x + "\n" for x in kept_lines))
    best_file = run_dir / "best.safetensors"
    if best_file.exists():
        from safemanip.rl.checkpoint import PolicyFileError, load_policy
        try:
            best_meta = load_policy(best_file)[1]
        except PolicyFileError:
            best_meta = {"env_steps": env_steps + 1}
        best_steps = best_meta.get("env_steps", 0)
        if not isinstance(best_steps, int):
            best_steps = env_steps + 1
        discarded = best_steps > env_steps if best is None else best_meta.get("eval") != best
        if discarded:  # from the discarded segment: keep it aside, not as the run's best
            os.replace(best_file, run_dir / f"best.discarded-{best_steps}.safetensors")
    return len(kept_lines)


WARM_START_FIELDS = ("algorithm", "k", "network", "set_embed", "hidden", "twin_critics", "env.object_size",
                     "env.embodiment", "env.action_curve")
"""What a run started from another run's networks must share with it: the networks' shapes and the meaning of
their inputs and outputs. Scenes (scene_objects, selector), budgets and learning rates may differ."""
NETWORK_PARTS = ("actor", "critic", "actor_targ", "critic_targ")


def warm_start(cfg: TrainConfig) -> tuple[dict, dict] | None:
    """(network tensors, provenance) from the newest checkpoint of ``cfg.init_from``, checked against ``cfg``
    before anything is written; None without ``init_from``."""
    if cfg.init_from is None:
        return None
    source = Path(cfg.init_from)
    checkpoint = find_checkpoint(source) if source.is_dir() else None
    if checkpoint is None:
        raise ConfigError(f"--init-from {source}: no complete checkpoint there; give a training run's folder "
                          f"(the --out of an earlier safemanip train)")
    src, _ = load_run_config(source / "config.json")  # only its network and task fields are read
    there, here = json.loads(src.to_json()), json.loads(cfg.to_json())
    differ = [f"{name} is {setting(there, name)!r} there but {setting(here, name)!r} here" for name in WARM_START_FIELDS
              if setting(there, name) != setting(here, name)]
    if differ:
        raise ConfigError(f"--init-from {source}: its networks do not fit this run ({'; '.join(differ)}); "
                          f"train with the source run's values")
    tensors, _, meta = read_checkpoint(checkpoint)
    networks = {k: v for k, v in tensors.items() if k.split(".")[0] in NETWORK_PARTS}
    return networks, {"run": str(source), "env_steps": meta["env_steps"], "updates": meta["updates"],
                      "elapsed_s": round(meta["elapsed_s"], 1)}


RESUME_FIELDS = ("algorithm", "k", "network", "set_embed", "hidden", "twin_critics", "env", "env_name",
                 "extra_env_kwargs", "scene_objects", "scene_objects_min", "selector", "selection_radius",
                 "selection_interval", "buffer_size")
"""What a resumed run's config.json must share with its checkpoint: the networks' shapes and the meaning of their
inputs and outputs, the task and its scenes (every env setting), and the replay buffer's size. Budgets, rates and
logging may differ."""


def setting(config: dict, name: str):
    """A setting of a config as written to config.json, by its dotted name ('env.layout')."""
    for part in name.split("."):
        config = config.get(part) if isinstance(config, dict) else None
    return config


def resume_mismatch(cfg: TrainConfig, meta: dict) -> list[str]:
    """The RESUME_FIELDS on which ``cfg`` differs from the config recorded in a checkpoint's ``meta``, the env
    setting by setting (fields an older checkpoint did not record are not compared)."""
    recorded = meta.get("config")
    if not isinstance(recorded, dict):
        return []
    now = json.loads(cfg.to_json())
    names = []
    for name in RESUME_FIELDS:
        both = (now.get(name), recorded.get(name))
        if name == "env" and all(isinstance(value, dict) for value in both):
            names += [f"env.{key}" for key in sorted(set(both[0]) | set(both[1]))]
        elif name in recorded:
            names.append(name)
    return [f"{name} is {setting(now, name)!r} in config.json but {setting(recorded, name)!r} in the checkpoint"
            for name in names if setting(now, name) != setting(recorded, name)]


def recovery_hint(run_dir: Path) -> str:
    """How to go on from a run whose checkpoint cannot be resumed."""
    return (f"Restore the damaged file from a backup, or start a new run: safemanip train --config "
            f"{run_dir / 'config.json'} --out NEW_FOLDER (the policies trained so far stay in {run_dir})")


def no_checkpoint_message(run_dir: Path) -> str:
    """Why ``--resume`` finds no complete checkpoint in ``run_dir``, and what to do."""
    found = []
    for name in CHECKPOINT_NAMES:
        folder = run_dir / name
        if not folder.is_dir():
            continue
        missing = [f for f in ("meta.json", "state.safetensors", "replay.npz") if not (folder / f).is_file()]
        if missing:
            found.append(f"{folder} lacks {', '.join(missing)}")
            continue
        try:
            read_checkpoint_meta(folder)
        except CheckpointError as err:
            found.append(str(err))
    if not found:
        return f"--resume: no complete checkpoint in {run_dir}; start a new run without --resume"
    return f"--resume {run_dir}: no usable checkpoint: {'; '.join(found)}. {recovery_hint(run_dir)}"


def _train_locked(cfg: TrainConfig, run_dir: Path, resume: bool, progress: bool, command: str | None,
                  build: EnvBuilder, warm: tuple[dict, dict] | None = None) -> Path:
    checkpoint = recover_checkpoint(run_dir) if resume else None
    if resume and checkpoint is None:
        raise ConfigError(no_checkpoint_message(run_dir))
    if not resume and find_checkpoint(run_dir) is not None:
        raise ConfigError(f"{run_dir} already holds a run: pass --resume to continue it, or choose another --out")
    resumed = None
    if checkpoint is not None:  # every file of the checkpoint and its fit to config.json, before anything is written
        try:
            resumed = read_checkpoint(checkpoint)
        except ValueError as err:  # CheckpointError, PolicyFileError
            raise CheckpointError(f"--resume {run_dir}: {err}. {recovery_hint(run_dir)}") from err
        differ = resume_mismatch(cfg, resumed[2])
        if differ:
            raise ConfigError(f"--resume {run_dir}: its config.json no longer matches the checkpoint it resumes "
                              f"({'; '.join(differ)}): these change the network or the task, so the checkpoint cannot "
                              f"continue under them. Restore config.json (the checkpoint's own settings are under "
                              f"\"config\" in {checkpoint / 'meta.json'}), or start a new run with --out")
    cfg.out_dir = str(run_dir)  # the folder actually written (a copied run folder is its own run)
    atomic_write_text(run_dir / "config.json", cfg.to_json())
    trainer = Trainer(cfg, run_dir, command, build)
    if resumed is not None:
        trainer.restore(resumed, checkpoint)
    else:
        trainer.start_fresh(warm)
    trainer.run(progress)
    return run_dir


class Trainer:
    """One training run, phase by phase. ``run`` is the loop and reads top to bottom: ``collect`` takes in the
    rollout workers' transitions, ``update`` takes learner steps at the configured data rate, and ``log``,
    ``evaluate`` and ``checkpoint`` run on their own clocks; ``finish`` saves the policy and the summary.

    Neither an evaluation nor a checkpoint makes the learner wait: ``evaluate`` hands a copy of the actor's weights
    to the evaluation process and ``take_evaluations`` records the result when it is there (the ``inline`` backend
    evaluates at once, in this process); ``checkpoint`` hands a copy of the state and of the transitions added
    since the last checkpoint to the writer thread."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, command: str | None, build: EnvBuilder):
        self.cfg, self.run_dir, self.command = cfg, run_dir, command
        self.build = build
        """The env of the rollouts and evaluations (``cfg.rollout_env_kwargs`` with its factory)."""
        # ---- seeding, all in one place (a resumed run reseeds the sampler in ``restore``)
        self.rng = np.random.default_rng(cfg.seed)
        torch.manual_seed(cfg.seed)
        torch.set_num_threads(cfg.torch_threads)

        probe = build()
        self.obs_dim, self.act_dim = probe.observation_space.shape[0], probe.action_space.shape[0]
        probe.close()
        self.learner = Learner(self.obs_dim, self.act_dim, cfg)
        print(f"learner: {self.learner.precision.device}, {self.learner.precision.dtype} "
              f"({self.learner.precision.reason}); network {cfg.network}; rollouts: {cfg.backend}, "
              f"{cfg.n_collectors} worker(s)")
        self.buffer = ReplayBuffer(cfg.buffer_size, self.obs_dim, self.act_dim)
        self.env_steps = self.updates = 0
        self.elapsed_before = 0.0
        self.restarts = 0
        self.best: dict = {"success": -1.0}
        self.last_eval_result: dict | None = None
        self.evals_recorded = 0  # lines of evals.jsonl: a checkpoint records how many belong to it
        self.last_metrics: dict[str, float] = {}
        self.recent_events: deque[str] = deque(maxlen=200)
        self.gamma = cfg.gamma_at(0.0)
        self.learning_rate = cfg.learning_rate_at(0.0)
        self.interrupted = self.worker_failed = None
        self.pool = self.log_file = self.bar = self.evaluator = None
        self.learner_idle_s = 0.0  # time the loop slept with no update allowed and no data in (waiting for data)
        self.writer = CheckpointWriter()
        self.start = time.perf_counter()

    # ------------------------------------------------------------------ the run's start
    def restore(self, resumed: tuple, checkpoint: Path) -> None:
        """Continue from a checkpoint read (and checked) by ``read_checkpoint``."""
        cfg, run_dir = self.cfg, self.run_dir
        tensors, replay_path, meta = resumed
        try:
            self.learner.load_state_tensors(tensors)
        except (RuntimeError, KeyError, ValueError) as err:  # shapes or names that do not fit this config's networks
            raise CheckpointError(f"--resume {run_dir}: the networks in {checkpoint / 'state.safetensors'} do not fit "
                                  f"its config.json ({str(err)[:200]}). {recovery_hint(run_dir)}") from err
        self.learner.updates = self.updates = meta["updates"]
        try:  # the index in the checkpoint, the transitions in the chunks it lists (or, before issue 42, in it)
            self.buffer.load(replay_path, run_dir / REPLAY_DIR)
        except ReplayFileError as err:
            raise CheckpointError(f"--resume {run_dir}: the replay buffer cannot be restored: {err}. The run cannot "
                                  f"continue exactly from this checkpoint; to keep its networks, start a new run from "
                                  f"them (fresh replay buffer): safemanip train --config {run_dir / 'config.json'} "
                                  f"--init-from {run_dir} --out NEW_FOLDER; or restore the damaged file from a "
                                  f"backup") from err
        remove_unlisted_chunks(run_dir / REPLAY_DIR, self.buffer.chunks)  # what a kill left of a later checkpoint
        self.env_steps, self.elapsed_before = meta["env_steps"], meta["elapsed_s"]
        self.restarts = meta.get("restarts", 0) + 1
        self.best = meta.get("best", self.best)
        self.rng = np.random.default_rng([cfg.seed, self.restarts])
        self.evals_recorded = truncate_logs(run_dir, self.env_steps, meta.get("evals"),
                                            self.best if "evals" in meta else None)
        print(f"resuming {run_dir} from {self.env_steps} env steps / {self.updates} updates "
              f"({self.elapsed_before / 60:.1f} min)")

    def start_fresh(self, warm: tuple[dict, dict] | None) -> None:
        """Clear the leftovers of a run killed before its first checkpoint; start from ``warm`` networks if given."""
        run_dir = self.run_dir
        for stale in ("scalars.csv", "evals.jsonl", "summary.json", "init_from.json"):
            (run_dir / stale).unlink(missing_ok=True)
        shutil.rmtree(run_dir / "tb", ignore_errors=True)
        shutil.rmtree(run_dir / REPLAY_DIR, ignore_errors=True)
        if warm is not None:
            self.learner.load_state_tensors(warm[0])  # networks only: fresh optimiser moments, empty replay buffer
            atomic_write_text(run_dir / "init_from.json", json.dumps(warm[1], indent=1))  # survives --resume
            print(f"networks from {warm[1]['run']} ({warm[1]['updates']} updates, {warm[1]['env_steps']} env steps, "
                  f"{warm[1]['elapsed_s'] / 60:.1f} min of training before this run)")

    # ------------------------------------------------------------------ the loop
    def run(self, progress: bool) -> None:
        cfg = self.cfg
        # rollout workers on the other core(s): local processes (dying with this one), Ray actors, or inline
        self.pool = make_pool(cfg, self.build, cfg.seed + 1000 * self.restarts, self.env_steps, self.updates)
        try:
            try:
                # evaluations beside training: a process of their own (dying with this one), or inline
                self.evaluator = make_evaluator(cfg.backend, self.build, cfg.eval_episodes)
                self.broadcast()
                self.log_file = ScalarLog(self.run_dir)
                if progress:
                    from tqdm import tqdm

                    self.bar = tqdm(total=cfg.total_env_steps, initial=self.env_steps, unit="step",
                                    dynamic_ncols=True, smoothing=0.05)
                self.start = time.perf_counter()
                self.loop()
            finally:
                self.pool.close()
                if self.bar is not None:
                    self.bar.close()
            self.finish()
        finally:
            if self.evaluator is not None:
                self.evaluator.close()

    def loop(self) -> None:
        cfg = self.cfg
        last_log = last_eval = last_ckpt = last_alive_check = self.start
        self.steps_at_log, self.updates_at_log = self.env_steps, self.updates
        self.idle_at_log, self.activity_at_log = self.learner_idle_s, self.pool.activity()
        with stop_on_signals(raise_exc=False) as stopped:
            while not self.done(stopped):
                got = self.collect()
                if self.worker_failed:
                    break
                if not self.update() and got == 0:
                    slept = time.perf_counter()
                    time.sleep(0.001)
                    self.learner_idle_s += time.perf_counter() - slept
                now = time.perf_counter()
                if now - last_alive_check >= 1.0:  # once a second: off the learner's path
                    # (a worker ended by a SIGTERM to the whole process group is no failure: the run stops for it)
                    if stopped["signum"] is None and self.workers_dead():
                        break
                    self.take_evaluations()
                    last_alive_check = now
                if now - last_log >= cfg.log_every_s:
                    self.log(now - last_log)
                    last_log = now
                if self.buffer.size >= cfg.learning_starts and now - last_eval >= cfg.eval_every_s \
                        and self.evaluator.idle:  # one evaluation at a time: a slow one delays the next
                    self.evaluate()
                    last_eval = time.perf_counter()
                if now - last_ckpt >= cfg.checkpoint_every_s:
                    self.checkpoint()
                    last_ckpt = time.perf_counter()

    def done(self, stopped: dict) -> bool:
        """The budget is used up, or SIGINT/SIGTERM asked for a stop (checked here: no update is cut in half)."""
        cfg = self.cfg
        if stopped["signum"] is not None:
            self.interrupted = signal.Signals(stopped["signum"]).name
            return True
        return self.env_steps >= cfg.total_env_steps or (cfg.minutes is not None and self.elapsed() >= 60 * cfg.minutes)

    def collect(self) -> int:
        """Take in whatever the workers produced; returns the number of chunks."""
        got = 0
        while True:
            try:
                wait = 0.05 if self.buffer.size < self.cfg.learning_starts and got == 0 else 0.0
                chunk, episodes = self.pool.get(wait)
            except queue.Empty:
                break
            except WorkerDied as err:  # a Ray actor that died: reported by its call
                self.worker_failed = str(err)
                break
            self.buffer.add_many(chunk)
            self.recent_events.extend(e for e, _ in episodes)
            got += 1
        self.env_steps = self.pool.env_steps
        return got

    def update(self) -> bool:
        """One learner update, if the data rate allows it: gamma and the learning rate follow the budget used."""
        cfg = self.cfg
        if self.buffer.size < cfg.learning_starts or \
                self.updates >= (self.env_steps - cfg.learning_starts) / cfg.env_steps_per_update + 1:
            return False
        budget_used = self.env_steps / cfg.total_env_steps if cfg.minutes is None \
            else max(self.env_steps / cfg.total_env_steps, self.elapsed() / (60 * cfg.minutes))
        self.gamma = cfg.gamma_at(budget_used)
        if cfg.learning_rate_final is not None:
            self.learning_rate = cfg.learning_rate_at(budget_used)
            self.learner.set_learning_rate(self.learning_rate)
        self.last_metrics = self.learner.update(self.buffer.sample(cfg.batch_size, self.rng), self.gamma)
        self.updates += 1
        self.pool.set_updates(self.updates)
        if self.updates % SYNC_EVERY == 0:
            self.broadcast()
        return True

    def broadcast(self) -> None:
        self.pool.broadcast(actor_arrays(self.learner.actor))

    def workers_dead(self) -> bool:
        """A worker that died (an env error, out of memory) ends the run with its exit code; so does the evaluation
        process."""
        dead = self.pool.dead()
        if dead is not None:
            self.worker_failed = f"a rollout worker {describe_exit(dead)}"
        elif self.evaluator.dead() is not None:
            self.worker_failed = f"the evaluation process {describe_exit(self.evaluator.dead())}"
        return self.worker_failed is not None

    def log(self, dt: float) -> None:
        rates = {"perf/env_steps_per_s": (self.env_steps - self.steps_at_log) / dt,
                 "perf/updates_per_s": (self.updates - self.updates_at_log) / dt,
                 "perf/learner_waiting": (self.learner_idle_s - self.idle_at_log) / dt}
        # who waits for whom: the learner for data (above), the rollout workers for the learner (ahead of the data
        # rate); and the workers' CPU per env step (a worker with a whole core to itself: 1000 / env_throughput.py's rate)
        activity, before = self.pool.activity(), self.activity_at_log
        if "rollout_wait_s" in activity:
            rates["perf/rollout_waiting"] = (activity["rollout_wait_s"] - before["rollout_wait_s"]) / (
                dt * self.cfg.n_collectors)
        if "rollout_cpu_s" in activity and self.env_steps > self.steps_at_log:
            rates["perf/rollout_cpu_ms_per_step"] = 1e3 * (activity["rollout_cpu_s"] - before["rollout_cpu_s"]) / (
                self.env_steps - self.steps_at_log)
        n_ep = max(1, len(self.recent_events))
        rollout = {f"rollout/{k}": v / n_ep for k, v in Counter(self.recent_events).items()}
        self.log_file.log({**rates, **self.last_metrics, **rollout, "train/gamma": self.gamma,
                           "train/learning_rate": self.learning_rate}, self.env_steps, self.updates, self.elapsed())
        if self.bar is not None:
            self.bar.update(self.env_steps - self.bar.n)
            post = {"steps/s": f"{rates['perf/env_steps_per_s']:.0f}", "upd/s": f"{rates['perf/updates_per_s']:.0f}"}
            if self.last_eval_result:
                post["eval"] = f"{100 * self.last_eval_result['success']:.0f}%"
            self.bar.set_postfix(post)
        self.steps_at_log, self.updates_at_log = self.env_steps, self.updates
        self.idle_at_log, self.activity_at_log = self.learner_idle_s, activity

    def evaluate(self) -> None:
        """Held-out episodes with a copy of the current actor, beside training (``inline``: here and now)."""
        self.evaluator.submit(EvalRequest(actor_arrays(self.learner.actor), self.env_steps, self.updates,
                                          round(self.elapsed(), 1)))
        self.take_evaluations()

    def take_evaluations(self) -> None:
        for request, result in self.evaluator.take():
            self.record_evaluation(request, result)

    def record_evaluation(self, request: EvalRequest, result: dict) -> None:
        """Log a finished evaluation under the counters of the weights it evaluated; the best so far is kept as
        ``best.safetensors``: those weights, not the actor's current ones."""
        result.update(env_steps=request.env_steps, updates=request.updates, wall_s=request.wall_s)
        self.last_eval_result = result
        # scalars.csv is a log in time order: its eval/ rows go under the counters of when the result came in
        self.log_file.log({f"eval/{k}": v for k, v in result.items() if isinstance(v, float) and k != "wall_s"},
                          self.env_steps, self.updates, self.elapsed())
        with open(self.run_dir / "evals.jsonl", "a") as f:  # one whole line per write
            f.write(json.dumps(result) + "\n")
        self.evals_recorded += 1
        if result["success"] >= self.best["success"]:
            self.best = result
            save_policy(self.run_dir / "best.safetensors", request.arrays,
                        policy_meta(self.cfg, self.obs_dim, self.act_dim, result, request.env_steps, request.updates,
                                    request.wall_s, self.command))

    def checkpoint(self, wait: bool = False) -> None:
        """Hand a checkpoint to the writer thread (``wait``: and wait until it is on disk)."""
        meta = {"env_steps": self.env_steps, "updates": self.updates, "elapsed_s": self.elapsed(),
                "restarts": self.restarts, "best": self.best, "evals": self.evals_recorded,
                "config": json.loads(self.cfg.to_json())}
        self.writer.submit(self.run_dir, self.learner.state_tensors(), self.buffer, meta)
        if wait:
            self.writer.wait()

    # ------------------------------------------------------------------ the run's end
    def finish(self) -> None:
        """Evaluate once more (unless stopped), checkpoint, save the policy and the summary."""
        run_dir = self.run_dir
        if self.worker_failed is not None:  # the learner and its buffer are whole: save them, then report
            print(f"{self.worker_failed}: stopping; saving a checkpoint and the current policy (no final evaluation)")
        elif self.interrupted is None:
            self.final_evaluation()
        else:
            print(f"{self.interrupted}: stopping; saving a checkpoint and the current policy (no final evaluation)")
        if self.interrupted is not None or self.worker_failed is not None:
            self.take_evaluations()  # one that has finished; one still running is dropped (nothing of it recorded)
        self.checkpoint(wait=True)
        save_policy(run_dir / "policy.safetensors", actor_arrays(self.learner.actor),
                    self.policy_meta(self.last_eval_result))
        self.log_file.close()
        summary = {"env_steps": self.env_steps, "updates": self.updates, "wall_s": round(self.elapsed(), 1),
                   "final_eval": self.last_eval_result, "best_eval": self.best, "interrupted": self.interrupted,
                   "worker_failed": self.worker_failed, "learner": {**self.learner.precision.as_dict(), "cpu": cpu_model()}}
        if (run_dir / "init_from.json").exists():  # whose networks this run started from: count its training too
            try:
                summary["init_from"] = read_json_file(run_dir / "init_from.json", max_bytes=100_000)
            except (OSError, ValueError) as err:
                summary["init_from"] = {"unreadable": str(err)[:200]}
        atomic_write_text(run_dir / "summary.json", json.dumps(summary, indent=1))
        if self.worker_failed is not None:
            raise WorkerDied(f"{self.worker_failed}; the run stopped after {self.env_steps} env steps and saved a "
                             f"checkpoint and its policy in {run_dir}; continue with: safemanip train --resume {run_dir}")

    def final_evaluation(self) -> None:
        """The final actor, evaluated here and now (nothing is left to overlap) while the evaluation in flight, of
        earlier weights, finishes beside it; both recorded, in the order of their weights."""
        request = EvalRequest(actor_arrays(self.learner.actor), self.env_steps, self.updates, round(self.elapsed(), 1))
        result = evaluate_weights(request.arrays, self.build, self.cfg.eval_episodes)
        for earlier in self.evaluator.wait():
            self.record_evaluation(*earlier)
        self.record_evaluation(request, result)

    def elapsed(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.start

    def policy_meta(self, eval_result: dict | None) -> dict:
        return policy_meta(self.cfg, self.obs_dim, self.act_dim, eval_result, self.env_steps, self.updates,
                           self.elapsed(), self.command)
