"""The training loop: rollout workers fill the replay buffer, the learner updates, and the run is
evaluated, logged and checkpointed as it goes. Reads top to bottom."""

from __future__ import annotations

import csv
import json
import queue
import time
from collections import Counter, deque
from pathlib import Path

import numpy as np
import torch

from safemanip.evaluation.rollout import evaluate_actor
from safemanip.rl.buffer import ReplayBuffer
from safemanip.rl.checkpoint import find_checkpoint, read_checkpoint, save_policy, write_checkpoint
from safemanip.rl.collector import env_factory, make_pool
from safemanip.rl.config import ConfigError, TrainConfig
from safemanip.rl.learner import Learner
from safemanip.rl.networks import actor_arrays

EVAL_SEED_BASE = 1_000_000  # evaluation seeds are disjoint from every training seed
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
    return {"algorithm": cfg.algorithm, "k": cfg.n_objects, "constraints": cfg.constraints, "obs_dim": obs_dim,
            "act_dim": act_dim, "hidden": list(cfg.hidden), "env_kwargs": cfg.env_kwargs, "train_config": json.loads(cfg.to_json()),
            "env_steps": env_steps, "updates": updates, "wall_s": round(wall_s, 1), "eval": eval_result,
            "train_command": command}


def evaluate_now(actor, cfg: TrainConfig, episodes: int) -> dict:
    records = evaluate_actor(actor_arrays(actor), cfg.rollout_env_kwargs, [EVAL_SEED_BASE + i for i in range(episodes)])
    events = Counter(r["event"] for r in records)
    result = {"episodes": episodes, "success": events["success"] / episodes,
              "mean_length": float(np.mean([r["length"] for r in records]))}
    for event, n in events.items():
        if event != "success":
            result[event] = n / episodes
    return result


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True, command: str | None = None) -> Path:
    run_dir = Path(cfg.out_dir)
    checkpoint = find_checkpoint(run_dir) if resume else None
    if resume and checkpoint is None:
        raise ConfigError(f"--resume: no checkpoint in {run_dir}; start a new run without --resume")
    if not resume and find_checkpoint(run_dir) is not None:
        raise ConfigError(f"{run_dir} already holds a run: pass --resume to continue it, or choose another --out")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json())

    # ---- seeding, all in one place
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.torch_threads)

    probe = env_factory(cfg.rollout_env_kwargs)
    obs_dim, act_dim = probe.observation_space.shape[0], probe.action_space.shape[0]
    probe.close()
    learner = Learner(obs_dim, act_dim, cfg)
    print(f"learner: {learner.precision.device}, {learner.precision.dtype} ({learner.precision.reason}); "
          f"network {cfg.network}; rollouts: {cfg.backend}, {cfg.n_collectors} worker(s)")
    buffer = ReplayBuffer(cfg.buffer_size, obs_dim, act_dim)
    env_steps = updates = 0
    elapsed_before = 0.0
    restarts = 0
    best = {"success": -1.0}
    if checkpoint is not None:
        tensors, replay_path, meta = read_checkpoint(checkpoint)
        learner.load_state_tensors(tensors)
        learner.updates = updates = meta["updates"]
        buffer.load(replay_path)
        env_steps, elapsed_before = meta["env_steps"], meta["elapsed_s"]
        restarts = meta.get("restarts", 0) + 1
        best = meta.get("best", best)
        rng = np.random.default_rng([cfg.seed, restarts])
        print(f"resuming {run_dir} from {env_steps} env steps / {updates} updates ({elapsed_before / 60:.1f} min)")

    # ---- rollout workers on the other core(s): local processes or Ray actors
    pool = make_pool(cfg, cfg.rollout_env_kwargs, cfg.seed + 1000 * restarts, env_steps, updates)

    def broadcast() -> None:
        pool.broadcast(actor_arrays(learner.actor))

    broadcast()
    log = ScalarLog(run_dir)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.total_env_steps, initial=env_steps, unit="step", dynamic_ncols=True, smoothing=0.05)
    recent_events: deque[str] = deque(maxlen=200)
    last_metrics: dict[str, float] = {}
    start = time.perf_counter()
    last_log = last_eval = last_ckpt = start
    steps_at_log, updates_at_log = env_steps, updates
    last_eval_result: dict | None = None
    gamma = cfg.gamma_at(0.0)

    def elapsed() -> float:
        return elapsed_before + time.perf_counter() - start

    def save_checkpoint() -> None:
        meta = {"env_steps": env_steps, "updates": updates, "elapsed_s": elapsed(), "restarts": restarts,
                "best": best, "config": json.loads(cfg.to_json())}
        write_checkpoint(run_dir, learner.state_tensors(), buffer, meta)

    def run_eval() -> None:
        nonlocal last_eval_result, best
        result = evaluate_now(learner.actor, cfg, cfg.eval_episodes)
        result.update(env_steps=env_steps, updates=updates, wall_s=round(elapsed(), 1))
        last_eval_result = result
        log.log({f"eval/{k}": v for k, v in result.items() if isinstance(v, float) and k != "wall_s"},
                env_steps, updates, elapsed())
        with open(run_dir / "evals.jsonl", "a") as f:
            f.write(json.dumps(result) + "\n")
        if result["success"] >= best["success"]:
            best = result
            save_policy(run_dir / "best.safetensors", actor_arrays(learner.actor),
                        policy_meta(cfg, obs_dim, act_dim, result, env_steps, updates, elapsed(), command))

    try:
        while True:
            # ---- budget
            if env_steps >= cfg.total_env_steps or (cfg.minutes is not None and elapsed() >= 60 * cfg.minutes):
                break
            # ---- take in whatever the workers produced
            got = 0
            while True:
                try:
                    chunk, episodes = pool.get(0.05 if buffer.size < cfg.learning_starts and got == 0 else 0.0)
                except queue.Empty:
                    break
                buffer.add_many(chunk)
                recent_events.extend(e for e, _ in episodes)
                got += 1
            env_steps = pool.env_steps
            # ---- learn, at the configured update-to-data ratio
            can_update = buffer.size >= cfg.learning_starts and \
                updates < (env_steps - cfg.learning_starts) / cfg.env_steps_per_update + 1
            if can_update:
                gamma = cfg.gamma_at(env_steps / cfg.total_env_steps if cfg.minutes is None
                                     else max(env_steps / cfg.total_env_steps, elapsed() / (60 * cfg.minutes)))
                last_metrics = learner.update(buffer.sample(cfg.batch_size, rng), gamma)
                updates += 1
                pool.set_updates(updates)
                if updates % SYNC_EVERY == 0:
                    broadcast()
            elif got == 0:
                time.sleep(0.001)
            now = time.perf_counter()
            # ---- log
            if now - last_log >= cfg.log_every_s:
                dt = now - last_log
                rates = {"perf/env_steps_per_s": (env_steps - steps_at_log) / dt,
                         "perf/updates_per_s": (updates - updates_at_log) / dt}
                train_events = Counter(recent_events)
                n_ep = max(1, len(recent_events))
                rollout = {f"rollout/{k}": v / n_ep for k, v in train_events.items()}
                log.log({**rates, **last_metrics, **rollout, "train/gamma": gamma}, env_steps, updates, elapsed())
                if bar is not None:
                    bar.update(env_steps - bar.n)
                    post = {"steps/s": f"{rates['perf/env_steps_per_s']:.0f}", "upd/s": f"{rates['perf/updates_per_s']:.0f}"}
                    if last_eval_result:
                        post["eval"] = f"{100 * last_eval_result['success']:.0f}%"
                    bar.set_postfix(post)
                last_log, steps_at_log, updates_at_log = now, env_steps, updates
            # ---- evaluate
            if buffer.size >= cfg.learning_starts and now - last_eval >= cfg.eval_every_s:
                run_eval()
                last_eval = time.perf_counter()
            # ---- checkpoint
            if now - last_ckpt >= cfg.checkpoint_every_s:
                save_checkpoint()
                last_ckpt = time.perf_counter()
    finally:
        pool.close()
        if bar is not None:
            bar.close()
    run_eval()
    save_checkpoint()
    save_policy(run_dir / "policy.safetensors", actor_arrays(learner.actor),
                policy_meta(cfg, obs_dim, act_dim, last_eval_result, env_steps, updates, elapsed(), command))
    log.close()
    summary = {"env_steps": env_steps, "updates": updates, "wall_s": round(elapsed(), 1), "final_eval": last_eval_result,
               "best_eval": best, "learner": learner.precision.as_dict()}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return run_dir
