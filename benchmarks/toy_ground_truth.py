"""Retrain the reach-avoid learner on the toy double integrator from scratch and score it against the
exact grid solution (sign agreement, false-safe both ways, rollout precision): the metrics table.

    python benchmarks/toy_ground_truth.py --out runs/toy [--minutes 3] [--set gamma=0.998] [--fine]
    python benchmarks/toy_ground_truth.py --eval-only tests/data/toy_reach_avoid/model.safetensors

Same as ``python -m safemanip.toy``; the defaults are the settings of the shipped test model
(tests/data/toy_reach_avoid/README.md has its exact command and numbers). One training process plus
one rollout worker, one torch thread.
"""

from safemanip.toy.oracle import main

if __name__ == "__main__":
    raise SystemExit(main())
