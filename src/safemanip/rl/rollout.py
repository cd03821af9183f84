"""Roll an actor out for independent episodes of a registered env (the training loop's periodic
evaluation; the selector-aware evaluation of ``safemanip eval`` is ``evaluation/episode.py``)."""

from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import asdict, dataclass

import numpy as np

from safemanip.rl.envs import EnvBuilder


@dataclass
class EpisodeRecord:
    seed: int
    event: str
    object: str | None
    length: int
    names: list[str]
    constraints: list[str]


def run_episode(env, act, seed: int) -> EpisodeRecord:
    obs, info = env.reset(seed=seed)
    while True:
        obs, _, terminated, truncated, info = env.step(act(obs))
        if terminated or truncated:
            break
    return EpisodeRecord(seed, info["event"], info["object"], info["t"], list(info["names"]), list(info["constraints"]))


def _worker(args) -> list[dict]:
    policy_arrays, build, seeds = args
    from safemanip.rl.numpy_actor import make_numpy_actor

    actor = make_numpy_actor(policy_arrays)
    env = build()
    return [asdict(run_episode(env, actor, s)) for s in seeds]


def evaluate_actor(actor_arrays: list[np.ndarray] | dict[str, np.ndarray], build: EnvBuilder, seeds: list[int],
                   workers: int = 1) -> list[dict]:
    """Deterministic rollouts of the actor on the given seeds; records in seed order. ``build``: the env, resolved
    by the caller (``rl.envs.env_builder``); worker processes get it as it is (its factory by reference)."""
    if workers <= 1:
        return _worker((actor_arrays, build, seeds))
    chunks = [seeds[i::workers] for i in range(workers)]
    from safemanip.util.procs import die_with_parent

    with mp.get_context("spawn").Pool(workers, initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
        parts = pool.map(_worker, [(actor_arrays, build, c) for c in chunks if c])
    by_seed = {r["seed"]: r for part in parts for r in part}
    return [by_seed[s] for s in seeds]
