"""Rollout workers: each simulates a few envs round-robin on its own core and streams transitions
to the learner, acting with the latest actor weights it has been sent (NumPy forward pass)."""

from __future__ import annotations

import queue
import time

import numpy as np

from safemanip.rl.envs import make_env as env_factory  # the closed env registry

CHUNK = 256  # transitions per message: large enough to amortise IPC, small enough to stay fresh


def run_collector(worker: int, env_kwargs: dict, seed: int, n_envs: int, data_q, weights_q, stop, counters,
                  random_steps: int, noise_std: float, learning_starts: int, steps_per_update: float) -> None:
    """Worker main loop. ``counters[0]`` is the total env steps (all workers), ``counters[1]`` learner updates."""
    from safemanip.rl.numpy_actor import NumpyActor

    rng = np.random.default_rng(seed + 7919 * worker)
    envs = [env_factory(env_kwargs) for _ in range(n_envs)]
    obs, infos = [], []
    for i, env in enumerate(envs):
        o, info = env.reset(seed=int(seed * 1000 + worker * 100 + i))
        obs.append(o)
        infos.append(info)
    actor = None
    buf: dict[str, list] = {k: [] for k in ("obs", "act", "next_obs", "l", "g", "next_l", "next_g", "terminated")}
    episodes: list[tuple[str, int]] = []
    import multiprocessing as mp

    parent = mp.parent_process()
    while not stop.is_set():
        if parent is not None and not parent.is_alive():  # the learner was killed: do not linger as an orphan
            return
        try:  # take the newest weights, drop older ones
            while True:
                actor_arrays = weights_q.get_nowait()
                actor = NumpyActor(actor_arrays) if actor is None else (actor.set(actor_arrays) or actor)
        except queue.Empty:
            pass
        # do not run ahead of the learner by more than the configured data rate
        allowed = learning_starts + counters[1] * steps_per_update + 2 * CHUNK
        if counters[0] > allowed:
            time.sleep(0.002)
            continue
        if actor is None or counters[0] < random_steps:
            actions = rng.uniform(-1, 1, size=(n_envs, *envs[0].action_space.shape))
        else:
            actions = actor(np.stack(obs))
            actions = np.clip(actions + rng.normal(0, noise_std, size=actions.shape), -1, 1)
        for i, env in enumerate(envs):
            next_o, _, terminated, truncated, info = env.step(actions[i])
            buf["obs"].append(obs[i])
            buf["act"].append(actions[i])
            buf["next_obs"].append(next_o)
            buf["l"].append(infos[i]["l"])
            buf["g"].append(infos[i]["g"])
            buf["next_l"].append(info["l"])
            buf["next_g"].append(info["g"])
            buf["terminated"].append(terminated)
            if terminated or truncated:
                episodes.append((info["event"], info["t"]))
                next_o, info = env.reset()
            obs[i], infos[i] = next_o, info
        with counters.get_lock():
            counters[0] += n_envs
        if len(buf["obs"]) >= CHUNK:
            chunk = {k: np.asarray(v, dtype=bool if k == "terminated" else np.float32) for k, v in buf.items()}
            data_q.put((chunk, episodes))
            buf = {k: [] for k in buf}
            episodes = []
