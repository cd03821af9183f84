"""Wall-clock and env steps until the evaluation success rate first reaches a threshold.

    python benchmarks/time_to_success.py RUN_DIR [RUN_DIR ...] [--threshold 0.6 0.7 0.8]
    python benchmarks/time_to_success.py --train --minutes 35 [--algorithm rarl] [--seed 0] [--out runs/tts]

Reads each run's ``evals.jsonl`` (one line per periodic evaluation on held-out seeds, written by
``safemanip train``) and prints one row per run. With ``--train`` it first trains a k=2
conservative policy with the shipped recipe (gamma annealed from 0.9) and then reports on it. The
wall-clock column is the learner's elapsed time at that evaluation, evaluation time included.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def read_evals(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "evals.jsonl").read_text().splitlines() if line.strip()]


def first_reaching(evals: list[dict], threshold: float) -> dict | None:
    """The first periodic evaluation at or above ``threshold``, or None."""
    return next((e for e in evals if e["success"] >= threshold), None)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="*", type=Path)
    p.add_argument("--threshold", type=float, nargs="+", default=[0.8],
                   help="one row per run and threshold (fractions, e.g. 0.6 0.7 0.8)")
    p.add_argument("--train", action="store_true", help="train a fresh run first")
    p.add_argument("--minutes", type=float, default=35.0)
    p.add_argument("--algorithm", default="rarl")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("runs/time-to-success"))
    args = p.parse_args()
    runs = list(args.runs)
    if args.train:
        from safemanip.rl.config import TrainConfig
        from safemanip.rl.train import train

        cfg = TrainConfig(algorithm=args.algorithm, k=2, env={"constraints": "conservative"}, minutes=args.minutes,
                          gamma_start=0.9, seed=args.seed, out_dir=str(args.out))
        runs.append(train(cfg, progress=True))
    if not runs:
        p.error("give run folders or --train")
    print(f"{'run':<44} {'evals':>5} {'threshold':>9} {'first eval >=':>13} {'wall min':>8} "
          f"{'env steps':>10} {'updates':>8} {'best':>6}")
    for run in runs:
        evals = read_evals(run)
        best = f"{100 * max(e['success'] for e in evals):.0f}%" if evals else "-"
        for threshold in args.threshold:
            h = first_reaching(evals, threshold)
            if h:
                print(f"{str(run):<44} {len(evals):>5} {100 * threshold:>8.0f}% {100 * h['success']:>12.0f}% "
                      f"{h['wall_s'] / 60:>8.1f} {h['env_steps']:>10} {h['updates']:>8} {best:>6}")
            else:
                print(f"{str(run):<44} {len(evals):>5} {100 * threshold:>8.0f}% {'not reached':>13} {'-':>8} "
                      f"{'-':>10} {'-':>8} {best:>6}")


if __name__ == "__main__":
    main()
