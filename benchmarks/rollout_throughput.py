"""Env steps per second delivered by the rollout pool, local processes against Ray actors, no learner.

    python benchmarks/rollout_throughput.py [--seconds 20] [--workers 1] [--k 2] [--repeats 2]

Each measurement starts a pool (``rl/collector.py``) with the data-rate limit lifted, waits for its first
chunk, then counts the transitions that arrive over ``--seconds``; backends alternate. Actions are
uniformly random (the pool's random-exploration phase), so episodes are short and resets frequent.
"""

from __future__ import annotations

import argparse
import queue
import time

from safemanip.rl.collector import make_pool
from safemanip.rl.config import TrainConfig
from safemanip.rl.envs import env_builder


def rate(backend: str, seconds: float, workers: int, k: int) -> float:
    cfg = TrainConfig(k=k, n_collectors=workers, envs_per_collector=4, learning_starts=10**9, batch_size=32,
                      backend=backend)
    pool = make_pool(cfg, env_builder(cfg.rollout_env_kwargs), seed=0)
    try:
        pool.get(120)  # start-up (process spawn / ray.init) is not counted
        got, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            try:
                got += len(pool.get(0.5)[0]["obs"])
            except queue.Empty:
                pass
        return got / (time.perf_counter() - t0)
    finally:
        pool.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--k", type=int, default=2)
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args()
    rates: dict[str, list[float]] = {"local": [], "ray": []}
    for _ in range(args.repeats):
        for backend in rates:
            rates[backend].append(rate(backend, args.seconds, args.workers, args.k))
    for backend, values in rates.items():
        print(f"{backend:<6} {args.workers} worker(s) x 4 envs, k={args.k}: "
              f"{' / '.join(f'{v:.0f}' for v in values)} env steps/s")


if __name__ == "__main__":
    main()
