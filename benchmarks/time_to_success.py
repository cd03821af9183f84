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


def first_reaching(run: Path, threshold: float) -> dict:
    evals = [json.loads(line) for line in (run / "evals.jsonl").read_text().splitlines() if line.strip()]
    best = max(evals, key=lambda e: e["success"]) if evals else None
    hit = next((e for e in evals if e["success"] >= threshold), None)
    return {"run": str(run), "evals": len(evals), "hit": hit, "best": best}


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

        cfg = TrainConfig(algorithm=args.algorithm, k=2, constraints="conservative", minutes=args.minutes,
                          gamma_start=0.9, seed=args.seed, out_dir=str(args.out))
        runs.append(train(cfg, progress=True))
    if not runs:
        p.error("give run folders or --train")
    print(f"{'run':<44} {'evals':>5} {'threshold':>9} {'first eval >=':>13} {'wall min':>8} "
          f"{'env steps':>10} {'updates':>8} {'best':>6}")
    for run in runs:
        for threshold in args.threshold:
            r = first_reaching(run, threshold)
            best = f"{100 * r['best']['success']:.0f}%" if r["best"] else "-"
            if r["hit"]:
                h = r["hit"]
                print(f"{r['run']:<44} {r['evals']:>5} {100 * threshold:>8.0f}% {100 * h['success']:>12.0f}% "
                      f"{h['wall_s'] / 60:>8.1f} {h['env_steps']:>10} {h['updates']:>8} {best:>6}")
            else:
                print(f"{r['run']:<44} {r['evals']:>5} {100 * threshold:>8.0f}% {'not reached':>13} {'-':>8} "
                      f"{'-':>10} {'-':>8} {best:>6}")

if __name__ == "__main__":
    main()
