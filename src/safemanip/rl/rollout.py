"""Roll an actor out for independent episodes of a registered env: the training loop's periodic evaluation (the
selector-aware evaluation of ``safemanip eval`` is ``evaluation/episode.py``).

The training loop evaluates beside training, never while the learner waits: ``EvalProcess`` runs the episodes in
a process of its own (spawned, at a lower CPU priority, dying with the learner's process) on a copy of the actor's
weights, and the loop takes the result in when it is there. ``InlineEvaluator`` runs them at once in the calling
process, for the ``inline`` backend (one process, deterministic for a seed). Both compute the result with
``evaluate_weights``, so the same weights give the same result either way.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing as mp
import os
import queue
from collections import Counter
from dataclasses import asdict, dataclass

import numpy as np

from safemanip.rl.envs import EnvBuilder

EVAL_SEED_BASE = 1_000_000  # evaluation seeds are disjoint from every training seed
EVAL_NICENESS = 10
"""The evaluation process's niceness: it takes the CPU time the learner and the rollout workers leave (a rollout
worker waits whenever it is ahead of the data rate), and at most about a tenth of a core they want."""


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


def evaluate_weights(arrays: list[np.ndarray] | dict[str, np.ndarray], build: EnvBuilder, episodes: int) -> dict:
    """The training loop's evaluation of actor weights: ``episodes`` held-out seeds, the success rate, the mean
    length and the rate of every other ending."""
    records = evaluate_actor(arrays, build, [EVAL_SEED_BASE + i for i in range(episodes)])
    events = Counter(r["event"] for r in records)
    result = {"episodes": episodes, "success": events["success"] / episodes,
              "mean_length": float(np.mean([r["length"] for r in records]))}
    for event, n in events.items():
        if event != "success":
            result[event] = n / episodes
    return result


@dataclass(eq=False)  # compared by identity: its arrays have no single truth value
class EvalRequest:
    """Weights to evaluate, and where the run was when they were taken (the result is recorded under these)."""

    arrays: list[np.ndarray] | dict[str, np.ndarray]
    env_steps: int
    updates: int
    wall_s: float


class InlineEvaluator:
    """Evaluations in the calling process, run at once by ``submit`` (the ``inline`` backend)."""

    def __init__(self, build: EnvBuilder, episodes: int):
        self.build, self.episodes = build, episodes
        self.done: list[tuple[EvalRequest, dict]] = []

    idle = True

    def submit(self, request: EvalRequest) -> None:
        self.done.append((request, evaluate_weights(request.arrays, self.build, self.episodes)))

    def take(self) -> list[tuple[EvalRequest, dict]]:
        """The (request, result) pairs finished since the last call."""
        done, self.done = self.done, []
        return done

    wait = take

    def dead(self) -> int | None:
        return None

    def close(self) -> None:
        pass


def _evaluate_forever(build: EnvBuilder, episodes: int, requests, results) -> None:
    """The evaluation process: evaluate every set of weights it is sent, send the result back, until it is ended."""
    with contextlib.suppress(OSError):
        os.nice(EVAL_NICENESS)
    with contextlib.suppress(Exception):  # its name in ps/top (Linux): PR_SET_NAME
        ctypes.CDLL(None).prctl(15, b"safemanip-eval", 0, 0, 0)
    while True:
        results.put(evaluate_weights(requests.get(), build, episodes))


class EvalProcess:
    """One evaluation at a time in a process of its own, beside training. ``submit`` hands it weights (when
    ``idle``), ``take`` returns the result once it is there, without waiting; ``wait`` waits for it (at the run's
    end, when nothing is left to overlap). The process dies with this one, kill -9 included
    (``util.procs.run_as_worker``), and ``close`` ends it."""

    def __init__(self, build: EnvBuilder, episodes: int):
        from safemanip.util.procs import QuietSpawnContext, run_as_worker, signals_deferred

        ctx = QuietSpawnContext()
        self.requests, self.results = ctx.Queue(), ctx.Queue()
        self.requests.cancel_join_thread()  # never block this process's exit on weights nobody will read
        self.process = ctx.Process(target=run_as_worker, daemon=True, name="safemanip-eval",
                                   args=(os.getpid(), _evaluate_forever, build, episodes, self.requests, self.results))
        with signals_deferred():  # a stop half-way through its start-up data would leave a process nobody ends
            self.process.start()
        self.pending: EvalRequest | None = None

    @property
    def idle(self) -> bool:
        return self.pending is None

    def submit(self, request: EvalRequest) -> None:
        assert self.pending is None, "one evaluation at a time"
        self.pending = request
        self.requests.put(request.arrays)

    def take(self, timeout: float = 0.0) -> list[tuple[EvalRequest, dict]]:
        if self.pending is None:
            return []
        try:
            result = self.results.get(timeout=timeout) if timeout > 0 else self.results.get_nowait()
        except queue.Empty:
            return []
        request, self.pending = self.pending, None
        return [(request, result)]

    def wait(self) -> list[tuple[EvalRequest, dict]]:
        """The evaluation in flight, waited for; [] if there is none or the process died (``dead`` says so)."""
        while self.pending is not None and self.dead() is None:
            done = self.take(timeout=0.5)
            if done:
                return done
        return []

    def dead(self) -> int | None:
        """The exit code of the evaluation process if it ended (an env error, out of memory), else None."""
        return self.process.exitcode

    def close(self) -> None:
        """End the process; an evaluation in flight is dropped (nothing of it was recorded)."""
        if self.process.is_alive():
            self.process.kill()
        self.process.join(timeout=5)
        self.pending = None


def make_evaluator(backend: str, build: EnvBuilder, episodes: int) -> InlineEvaluator | EvalProcess:
    """Evaluations beside training in their own process, or in this process at once for the ``inline`` backend
    (single process, deterministic for a seed)."""
    return InlineEvaluator(build, episodes) if backend == "inline" else EvalProcess(build, episodes)
