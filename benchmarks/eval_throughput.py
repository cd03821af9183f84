"""Evaluation throughput: dynamic-knn at N = 6 on 1 and 2 local workers and on a local Ray instance, in one run.

    python benchmarks/eval_throughput.py [--episodes 200] [--policy policies/rarl-k2-conservative.safetensors]

Uses the given policy, else the first policy file under policies/, else a randomly initialised actor
of the paper's shape (k = 2, 3 x 256 ReLU) -- the output says which. The same seeds run on every
backend, and the records are checked to be identical. Wall time includes starting the worker
processes (not Ray's own start-up, which is printed separately: a long-lived cluster pays it once).
Episode length decides the rate, so env steps/s are printed too, and the time 2000 episodes (the
paper's count per cell) would take at the measured mean length and at the worst case of 300 steps.
"""

from __future__ import annotations

import argparse
import glob
import time

import numpy as np

from safemanip.env.observation import observation_dim
from safemanip.evaluation.parallel import EvalSpec, run_local, run_ray
from safemanip.evaluation.registry import SelectorOptions


def random_actor(k: int, hidden=(256, 256, 256), seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    sizes = [observation_dim(k), *hidden, 3]
    arrays = []
    for i in range(len(sizes) - 1):  # PyTorch's default nn.Linear initialisation range
        bound = 1 / np.sqrt(sizes[i])
        arrays += [rng.uniform(-bound, bound, (sizes[i + 1], sizes[i])).astype(np.float32),
                   rng.uniform(-bound, bound, sizes[i + 1]).astype(np.float32)]
    return arrays


def make_spec(policy: str | None, n_objects: int, max_steps: int | None) -> tuple[EvalSpec, str]:
    candidates = [policy] if policy else sorted(glob.glob("policies/*.safetensors"))
    for path in candidates:
        from safemanip.evaluation.harness import EvalRequest, prepare
        from safemanip.rl.checkpoint import load_policy

        _, meta = load_policy(path)
        if meta["k"] > n_objects or "factory" in meta.get("env_kwargs", {}):
            continue
        # the spec `safemanip eval` would run (embodiment, action curve, object sizes, layout from the policy)
        prep = prepare(EvalRequest(policy=path, n_objects=n_objects, selector="dynamic-knn", judge="ground-truth",
                                   episodes=1, env={"max_episode_steps": max_steps}))
        return prep.spec, f"policy {path} ({meta['algorithm']} k={meta['k']} {meta['constraints']})"
    env_kwargs = {"n_objects": n_objects, "constraints": "ground_truth", "near_path_fraction": 0.5,
                  "max_episode_steps": max_steps or 300}
    return (EvalSpec(random_actor(2), 2, "conservative", env_kwargs, "dynamic-knn", "conservative", SelectorOptions()),
            "NO POLICY FILE FOUND: a randomly initialised k=2 actor (3 x 256 ReLU); its episodes end early, "
            "so episodes/s overstates a trained policy's -- read env steps/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--policy", help="policy file (default: the first under policies/, else a random actor)")
    ap.add_argument("--n-objects", type=int, default=6)
    ap.add_argument("--max-episode-steps", type=int, help="cap episode length (default: the policy's, 300)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-ray", action="store_true")
    args = ap.parse_args()

    spec, what = make_spec(args.policy, args.n_objects, args.max_episode_steps)
    seeds = [args.seed * 100_000 + i for i in range(args.episodes)]
    print(f"{what}\ndynamic-knn (re-pick every 4 steps), N = {args.n_objects}, {args.episodes} episodes per row")

    rows, reference = [], None
    runs = [("local", 1), ("local", 2)] + ([] if args.skip_ray else [("ray", 2)])
    for backend, workers in runs:
        extra = ""
        if backend == "ray":
            import ray

            t0 = time.perf_counter()
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
            extra = f"ray.init {time.perf_counter() - t0:.1f} s"
            try:
                start = time.perf_counter()
                records = run_ray(spec, seeds, workers)
                wall = time.perf_counter() - start
            finally:
                ray.shutdown()
        else:
            start = time.perf_counter()
            records = run_local(spec, seeds, workers)
            wall = time.perf_counter() - start
        same = "reference" if reference is None else ("yes" if records == reference else "NO")
        reference = reference or records
        steps = sum(r["length"] for r in records)
        rows.append((backend, workers, wall, len(records) / wall, steps / wall, steps / len(records), same, extra))

    print(f"\n{'backend':8s} {'workers':>7s} {'wall s':>8s} {'episodes/s':>11s} {'env steps/s':>12s} "
          f"{'mean len':>9s} {'2000 ep (mean len)':>19s} {'2000 ep (300 steps)':>20s} {'same records':>13s}")
    for backend, workers, wall, eps, sps, mean_len, same, extra in rows:
        print(f"{backend:8s} {workers:7d} {wall:8.1f} {eps:11.2f} {sps:12.0f} {mean_len:9.1f} "
              f"{2000 / eps / 60:15.1f} min {2000 * 300 / sps / 60:16.1f} min {same:>13s}  {extra}")
    outcomes = {}
    for r in reference:
        outcomes[r["category"]] = outcomes.get(r["category"], 0) + 1
    print(f"\noutcomes: {outcomes}")


if __name__ == "__main__":
    main()
