#!/usr/bin/env bash
# Every policy of the benchmark (docs/results.md), trained one after another on the two cores, resumable.
#
#   bash results/training/train.sh [RUNS_DIR]      # default: runs/bench (git-ignored)
#
# Every run adds a small penalty on the actor's pre-tanh action (1e-3 mean(u^2)): without it the actor of
# rarl-k3-conservative-s0 saturated within 2k updates (every action at the tanh bounds, its gradient gone) and
# never recovered, 0 % success at 83k updates; the penalty is negligible for |u| < 1.
#
# Each run stops at 400k environment steps (100k learner updates: the data rate is held at 4 steps per update),
# the same budget for every method; --minutes only guards against a stalled run. A finished or promoted run is skipped, an
# interrupted one resumed from its newest checkpoint. The queue goes by finding, not by seed, so a partial queue
# completes whole findings (each is judged over three seeds): Table I's pi_2 first, then Table II's two (findings 4
# and 5), then pi_3..pi_6 conservative (with pi_2, the paper's way of Figs. 5 and 6: findings 2 and 3), then the
# selection-aware policies of Fig. 5, then Fig. 4's RARL at k = 1 and Vanilla-RL at k = 1..6 (finding 1). The
# finished policies go to src/safemanip/policies/ (results/training/promote.py), their training records to
# results/training/NAME/.
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${1:-runs/bench}
mkdir -p "$RUNS"
COMMON=(--object-size --action-curve 2 --gamma 0.98 --gamma-start 0.9 --learning-rate-final 1e-4
        --actor-preactivation-penalty 1e-3 --precision bf16 --total-env-steps 400000 --minutes 240 --no-progress)

run() {  # run NAME FLAGS...
  local name=$1; shift
  local out="$RUNS/$name"
  # a promoted policy is the record of a finished run (its runs folder may be gone, e.g. on another machine)
  if [ -f "src/safemanip/policies/$name.safetensors" ]; then return; fi
  if [ -f "$out/summary.json" ] && python3 -c "import json, sys; s = json.load(open(sys.argv[1]))
sys.exit(0 if s['interrupted'] is None and s['env_steps'] >= 400000 else 1)" "$out/summary.json"; then return; fi
  if [ -f "$out/checkpoint/meta.json" ]; then
    echo "$(date -u +%H:%M) resume $name"; safemanip train --resume "$out" --no-progress >> "$out.log" 2>&1
  else
    echo "$(date -u +%H:%M) train $name"; safemanip train "$@" "${COMMON[@]}" --out "$out" > "$out.log" 2>&1
  fi
}

SEEDS=(0 1 2)
for seed in "${SEEDS[@]}"; do  # Table I (finding 4): pi_2 conservative
  run "rarl-k2-conservative-s$seed" --algorithm rarl --k 2 --constraints conservative --layout exit --seed "$seed"
done
for seed in "${SEEDS[@]}"; do  # Table II (finding 5): pi_2^all and pi_3^all
  run "rarl-k2-all-s$seed" --algorithm rarl --k 2 --constraints all --layout gate --seed "$seed"
  run "rarl-k3-all-s$seed" --algorithm rarl --k 3 --constraints all --layout gate --seed "$seed"
done
for seed in "${SEEDS[@]}"; do  # Figs. 5 and 6, the paper's way: pi_3..pi_6 (pi_2 is Table I's)
  for k in 3 4 5 6; do
    run "rarl-k$k-conservative-s$seed" --algorithm rarl --k "$k" --constraints conservative --layout exit --seed "$seed"
  done
done
for seed in "${SEEDS[@]}"; do  # Fig. 5 selection-aware
  for k in 2 3 4 5; do
    run "rarl-k$k-conservative-selaware-s$seed" --algorithm rarl --k "$k" --constraints conservative --layout exit \
        --scene-objects 6 --scene-objects-min "$k" --selector dynamic-knn --seed "$seed"
  done
done
for seed in "${SEEDS[@]}"; do  # Fig. 4: RARL (k = 2..6 above) against Vanilla-RL
  run "rarl-k1-conservative-s$seed" --algorithm rarl --k 1 --constraints conservative --layout exit --seed "$seed"
  for k in 1 2 3 4 5 6; do
    run "vanilla-k$k-conservative-s$seed" --algorithm vanilla --k "$k" --constraints conservative --layout exit --seed "$seed"
  done
done
