"""Rollout workers: each simulates a few envs round-robin on its own core and streams transitions to the
learner, acting with the latest actor weights it has been sent (NumPy forward pass, no torch import).

One ``RolloutWorker`` class does the stepping; three pools run it:

  ``LocalPool``  worker *processes* (spawn) that loop on their own, pushing chunks into a queue and
                 holding the data rate through a shared counter of env steps and learner updates;
  ``RayPool``    Ray *actors*, one ``collect`` call per chunk: the learner keeps one call in flight per
                 actor and only issues the next while the data rate allows (same rule as the local
                 loop), sending new weights with the call when they changed. Ray actors can live on
                 other machines (``TrainConfig.address``); the learner stays in the driver process;
  ``InlinePool`` the workers in the learner's own process, one chunk at a time: deterministic for a seed.

Both produce the same transition dicts (``TRANSITION_KEYS``, float32 / bool arrays) from the same
``RolloutWorker.step_all`` code, so the buffer cannot tell them apart. The pools are given the env resolved in
this process (an ``EnvBuilder`` from ``rl.envs.env_builder``: the closed registry, or the factory passed to
``rl.train.train``) and hand it to the workers: its factory travels by reference, so it must be a module-level
class or function.
Local worker processes die with this one (``util.procs.run_as_worker``).
"""

from __future__ import annotations

import queue
import time

import numpy as np

from safemanip.rl.envs import EnvBuilder, env_builder

CHUNK = 256  # transitions per message: large enough to amortise IPC, small enough to stay fresh
NOISE_HORIZON = 300  # steps in one coloured-noise sequence: an episode's whole length at the default time limit
TRANSITION_KEYS = ("obs", "act", "next_obs", "l", "g", "next_l", "next_g", "terminated")  # = buffer.FIELDS


def allowed_env_steps(updates: int, learning_starts: int, steps_per_update: float) -> float:
    """Env steps the workers may have taken given the learner's updates (they do not run ahead further)."""
    return learning_starts + updates * steps_per_update + 2 * CHUNK


class RolloutWorker:
    """``n_envs`` envs stepped round-robin with the exploration policy; ``collect`` returns transition chunks.
    ``env``: the env's kwargs for the registry, or an ``EnvBuilder`` already resolved (what the pools send)."""

    def __init__(self, env: dict | EnvBuilder, seed: int, worker: int, n_envs: int, noise_std: float,
                 noise_per_episode: bool = False, noise_color: float = 0.0):
        self.rng = np.random.default_rng(seed + 7919 * worker)
        self.noise_std = noise_std
        self.noise_per_episode = noise_per_episode
        self.noise_color = float(noise_color)
        self.env_noise = np.array([self._draw_noise() for _ in range(n_envs)])
        build = env if isinstance(env, EnvBuilder) else env_builder(env)
        self.envs = [build() for _ in range(n_envs)]
        # coloured noise: one unit-variance sequence per env, (NOISE_HORIZON, act_dim), started afresh each episode
        self.noise_seq: list[np.ndarray | None] = [None] * n_envs
        self.noise_t = [0] * n_envs
        self.obs, self.infos = [], []
        for i, e in enumerate(self.envs):
            o, info = e.reset(seed=int(seed * 1000 + worker * 100 + i))
            self.obs.append(o)
            self.infos.append(info)
        self.actor = None
        self.buf: dict[str, list] = {k: [] for k in TRANSITION_KEYS}
        self.episodes: list[tuple[str, int]] = []

    def _draw_noise(self) -> float:
        """This episode's noise std: ``noise_std``, or with ``noise_per_episode`` uniform in [0, noise_std]."""
        return float(self.rng.uniform(0.0, self.noise_std)) if self.noise_per_episode else self.noise_std

    def _unit_noise(self, shape: tuple[int, int]) -> np.ndarray:
        """(n_envs, act_dim) standard-normal exploration noise: white (independent every step) or, with
        ``noise_color`` beta > 0, the next step of each env's power-law (1/f^beta) sequence."""
        if not self.noise_color:
            return self.rng.normal(0.0, 1.0, size=shape)
        from colorednoise import powerlaw_psd_gaussian  # numpy only; imported where it is used

        out = np.empty(shape)
        for i in range(shape[0]):
            if self.noise_seq[i] is None or self.noise_t[i] >= NOISE_HORIZON:
                self.noise_seq[i] = powerlaw_psd_gaussian(self.noise_color, (shape[1], NOISE_HORIZON),
                                                          random_state=self.rng).T
                self.noise_t[i] = 0
            out[i] = self.noise_seq[i][self.noise_t[i]]
            self.noise_t[i] += 1
        return out

    def set_weights(self, arrays) -> None:
        from safemanip.rl.numpy_actor import make_numpy_actor

        self.actor = make_numpy_actor(arrays) if self.actor is None else (self.actor.set(arrays) or self.actor)

    def step_all(self, random: bool) -> int:
        """One action in every env (uniform random, or the actor plus Gaussian noise, white or coloured); returns
        the steps taken."""
        envs, buf = self.envs, self.buf
        if random or self.actor is None:
            actions = self.rng.uniform(-1, 1, size=(len(envs), *envs[0].action_space.shape))
        else:
            actions = self.actor(np.stack(self.obs))
            noise = self._unit_noise(actions.shape) * self.env_noise[:, None]
            actions = np.clip(actions + noise, -1, 1)
        for i, env in enumerate(envs):
            next_o, _, terminated, truncated, info = env.step(actions[i])
            buf["obs"].append(self.obs[i])
            buf["act"].append(actions[i])
            buf["next_obs"].append(next_o)
            buf["l"].append(self.infos[i]["l"])
            buf["g"].append(self.infos[i]["g"])
            buf["next_l"].append(info["l"])
            buf["next_g"].append(info["g"])
            buf["terminated"].append(terminated)  # a time-limit truncation is not terminal: it bootstraps
            if terminated or truncated:
                self.episodes.append((info["event"], info["t"]))
                next_o, info = env.reset()
                self.env_noise[i] = self._draw_noise()
                self.noise_seq[i] = None  # a new episode starts a new coloured sequence
            self.obs[i], self.infos[i] = next_o, info
        return len(envs)

    def pending(self) -> int:
        return len(self.buf["obs"])

    def take(self) -> tuple[dict[str, np.ndarray], list[tuple[str, int]]]:
        """The transitions and finished episodes gathered since the last take."""
        chunk = {k: np.asarray(v, dtype=bool if k == "terminated" else np.float32) for k, v in self.buf.items()}
        episodes = self.episodes
        self.buf, self.episodes = {k: [] for k in TRANSITION_KEYS}, []
        return chunk, episodes

    def collect(self, n_steps: int, random: bool, weights=None):
        """Step until at least ``n_steps`` transitions are gathered (the Ray actor's one call per chunk)."""
        if weights is not None:
            self.set_weights(weights)
        while self.pending() < n_steps:
            self.step_all(random)
        return self.take()


# ------------------------------------------------------------------------------------------ local processes
def run_collector(worker: int, env: EnvBuilder, seed: int, n_envs: int, data_q, weights_q, stop, counters,
                  random_steps: int, noise_std: float, learning_starts: int, steps_per_update: float,
                  noise_per_episode: bool = False, noise_color: float = 0.0) -> None:
    """Worker process main loop. ``counters[0]`` is the total env steps (all workers), ``counters[1]`` learner updates;
    ``counters[2]`` and ``counters[3]`` the microseconds the workers spent waiting for the learner (ahead of the data
    rate) and their CPU time since they started stepping (``LocalPool.activity``)."""
    import multiprocessing as mp

    rollout = RolloutWorker(env, seed, worker, n_envs, noise_std, noise_per_episode, noise_color)
    parent = mp.parent_process()
    cpu_published = time.process_time()
    while not stop.is_set():
        if parent is not None and not parent.is_alive():  # the learner was killed: do not linger as an orphan
            return
        try:  # take the newest weights, drop older ones
            while True:
                rollout.set_weights(weights_q.get_nowait())
        except queue.Empty:
            pass
        # do not run ahead of the learner by more than the configured data rate
        if counters[0] > allowed_env_steps(counters[1], learning_starts, steps_per_update):
            slept = time.perf_counter()
            time.sleep(0.002)
            with counters.get_lock():
                counters[2] += int(1e6 * (time.perf_counter() - slept))
            continue
        taken = rollout.step_all(counters[0] < random_steps)
        with counters.get_lock():
            counters[0] += taken
        if rollout.pending() >= CHUNK:
            data_q.put(rollout.take())
            cpu = time.process_time()
            with counters.get_lock():
                counters[3] += int(1e6 * (cpu - cpu_published))
            cpu_published = cpu


class LocalPool:
    """``cfg.n_collectors`` worker processes that die with this one; ``get`` returns (chunk, episodes) or
    raises ``queue.Empty``."""

    def __init__(self, cfg, build: EnvBuilder, seed: int, env_steps: int, updates: int):
        import multiprocessing as mp
        import os

        from safemanip.util.procs import run_as_worker

        ctx = mp.get_context("spawn")
        self.data_q = ctx.Queue(maxsize=64)
        self.weights_qs = [ctx.Queue(maxsize=2) for _ in range(cfg.n_collectors)]
        self.stop = ctx.Event()
        self.counters = ctx.Array("q", [env_steps, updates, 0, 0])  # see run_collector
        self.workers = [ctx.Process(target=run_as_worker, daemon=True,  # the workers die with this process
                                    args=(os.getpid(), run_collector, w, build, seed, cfg.envs_per_collector,
                                          self.data_q, self.weights_qs[w], self.stop, self.counters, cfg.random_steps,
                                          cfg.exploration_noise, cfg.learning_starts, cfg.env_steps_per_update,
                                          cfg.noise_per_episode, cfg.noise_color))
                        for w in range(cfg.n_collectors)]
        for q in self.weights_qs:  # never block this process's exit on a queue whose reader is gone
            q.cancel_join_thread()
        for w in self.workers:
            w.start()

    def dead(self) -> int | None:
        """The exit code of a worker that has died (an env error, out of memory), else None."""
        return next((w.exitcode for w in self.workers if w.exitcode is not None), None)

    @property
    def env_steps(self) -> int:
        return int(self.counters[0])

    def set_updates(self, updates: int) -> None:
        self.counters[1] = updates

    def activity(self) -> dict[str, float]:
        """Seconds the workers (summed) waited for the learner, ahead of the data rate, and their CPU seconds, since
        they started stepping: the training loop logs them per interval (who waits for whom, and whether a worker
        gets a whole core)."""
        return {"rollout_wait_s": self.counters[2] / 1e6, "rollout_cpu_s": self.counters[3] / 1e6}

    def broadcast(self, arrays) -> None:
        for q in self.weights_qs:
            try:
                q.put_nowait(arrays)
            except queue.Full:
                pass

    def get(self, timeout: float):
        return self.data_q.get(timeout=timeout) if timeout > 0 else self.data_q.get_nowait()

    def close(self) -> None:
        self.stop.set()
        for w in self.workers:
            w.join(timeout=5)
            if w.is_alive():
                w.kill()


# ------------------------------------------------------------------------------------------ Ray actors
class RayPool:
    """``cfg.n_collectors`` Ray actors running ``RolloutWorker``; same interface as ``LocalPool``.

    Connects to ``cfg.address`` (a running cluster) or starts a local Ray instance, unless Ray is
    already initialised (tests start a small one themselves). Random exploration is decided per chunk
    (``env_steps < random_steps`` when the chunk is requested) where local workers decide per step, so
    the switch to the actor can come up to one chunk per worker later."""

    def __init__(self, cfg, build: EnvBuilder, seed: int, env_steps: int, updates: int):
        import ray

        self.owns_ray = not ray.is_initialized()
        if self.owns_ray:
            from safemanip.util.procs import init_ray

            init_ray(cfg.address, None)
        self.ray = ray
        self.cfg = cfg
        remote = ray.remote(num_cpus=1)(RolloutWorker)
        self.actors = [remote.remote(build, seed, w, cfg.envs_per_collector, cfg.exploration_noise,
                                      cfg.noise_per_episode, cfg.noise_color)
                       for w in range(cfg.n_collectors)]
        self.env_steps, self.updates = int(env_steps), int(updates)
        self.in_flight: dict = {}  # ObjectRef -> actor index
        self.idle = set(range(len(self.actors)))
        self.weights_ref = None
        self.stale: set[int] = set()

    def set_updates(self, updates: int) -> None:
        self.updates = updates

    def activity(self) -> dict[str, float]:
        return {}  # not measured for Ray actors

    def dead(self) -> int | None:
        """Ray reports a dead actor as an error from ``get`` (``ray.get`` raises): nothing to poll."""
        return None

    def broadcast(self, arrays) -> None:
        self.weights_ref = self.ray.put(arrays)
        self.stale = set(range(len(self.actors)))

    def _submit(self) -> None:
        cfg = self.cfg
        for w in sorted(self.idle):
            ahead = self.env_steps + CHUNK * (len(self.in_flight) + 1)
            if ahead > allowed_env_steps(self.updates, cfg.learning_starts, cfg.env_steps_per_update) + CHUNK:
                return
            weights = self.weights_ref if w in self.stale else None
            ref = self.actors[w].collect.remote(CHUNK, self.env_steps < cfg.random_steps, weights)
            self.stale.discard(w)
            self.idle.discard(w)
            self.in_flight[ref] = w

    def get(self, timeout: float):
        self._submit()
        if not self.in_flight:
            if timeout > 0:
                time.sleep(min(timeout, 0.002))
            raise queue.Empty
        ready, _ = self.ray.wait(list(self.in_flight), num_returns=1, timeout=max(timeout, 0.0))
        if not ready:
            raise queue.Empty
        w = self.in_flight.pop(ready[0])
        self.idle.add(w)
        try:
            chunk, episodes = self.ray.get(ready[0])
        except self.ray.exceptions.RayError as err:  # the actor died (killed, out of memory) or its env failed
            from safemanip.util.procs import WorkerDied

            first = (str(err).strip().splitlines() or [""])[0][:200]
            raise WorkerDied(f"Ray rollout actor {w} failed ({err.__class__.__name__}: {first})") from None
        self.env_steps += len(chunk["obs"])
        self._submit()
        return chunk, episodes

    def close(self) -> None:
        for actor in self.actors:
            self.ray.kill(actor)
        self.actors, self.in_flight = [], {}
        if self.owns_ray:  # a Ray instance (or cluster connection) this pool opened
            self.ray.shutdown()


# ------------------------------------------------------------------------------------------ in this process
class InlinePool:
    """``cfg.n_collectors`` ``RolloutWorker``s in the learner's own process; same interface as ``LocalPool``. ``get``
    collects one chunk (from the workers in turn) whenever the data rate allows, so a run is deterministic for its
    seed: slower than a worker on another core, but what a short test of the real training loop needs."""

    def __init__(self, cfg, build: EnvBuilder, seed: int, env_steps: int, updates: int):
        self.cfg = cfg
        self.workers = [RolloutWorker(build, seed, w, cfg.envs_per_collector, cfg.exploration_noise,
                                      cfg.noise_per_episode, cfg.noise_color) for w in range(cfg.n_collectors)]
        self.env_steps, self.updates, self.turn = int(env_steps), int(updates), 0

    def set_updates(self, updates: int) -> None:
        self.updates = updates

    def activity(self) -> dict[str, float]:
        return {}  # the workers step when the loop asks: they never wait, and share the learner's CPU

    def dead(self) -> int | None:
        return None

    def broadcast(self, arrays) -> None:
        for worker in self.workers:
            worker.set_weights(arrays)

    def get(self, timeout: float):
        cfg = self.cfg
        if self.env_steps + CHUNK > allowed_env_steps(self.updates, cfg.learning_starts, cfg.env_steps_per_update) + CHUNK:
            raise queue.Empty
        worker = self.workers[self.turn]
        self.turn = (self.turn + 1) % len(self.workers)
        chunk, episodes = worker.collect(CHUNK, self.env_steps < cfg.random_steps)
        self.env_steps += len(chunk["obs"])
        return chunk, episodes

    def close(self) -> None:
        for worker in self.workers:
            for env in worker.envs:
                env.close()


POOLS = {"local": LocalPool, "ray": RayPool, "inline": InlinePool}
"""The rollout backends by name (``TrainConfig.backend``)."""


def make_pool(cfg, build: EnvBuilder, seed: int, env_steps: int = 0, updates: int = 0):
    """The rollout workers of ``cfg.backend``: local processes, Ray actors, or inline in this process, each
    building its envs with ``build``."""
    return POOLS[cfg.backend](cfg, build, seed, env_steps, updates)
