"""Pick each finished benchmark run's policy and bring it into the repository.

    python results/training/promote.py [RUNS_DIR]       # default: runs/bench

For every run that reached its 400k-step budget (``train.sh``), the final policy and the best one of the
run's periodic evaluations are each evaluated on seed block 30 (200 episodes, used for this choice and for
nothing else; the reported numbers use other blocks), in the scenes the policy was trained in: N = k on its
own layout, or, for a selection-aware policy, N = 6 with dynamic-kNN. The better one (the final one on a tie)
is copied to ``src/safemanip/policies/NAME.safetensors`` (a shipped policy: ``--policy NAME`` finds it); the run's config, periodic evaluations and
summary to ``results/training/NAME/``, with the choice in ``choice.json``. Runs already promoted are
skipped.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
POLICIES = ROOT / "src" / "safemanip" / "policies"
RECORDS = ROOT / "results" / "training"
SELECTION_BLOCK = 30
EPISODES = 200
BUDGET = 400_000


def finished(run: Path) -> bool:
    summary = run / "summary.json"
    if not summary.is_file():
        return False
    data = json.loads(summary.read_text())
    return data.get("interrupted") is None and data.get("env_steps", 0) >= BUDGET


def success(policy: Path, config: dict, out: Path) -> float:
    args = ["safemanip", "eval", "--policy", str(policy), "--episodes", str(EPISODES), "--seed", str(SELECTION_BLOCK),
            "--no-progress", "--out", str(out)]
    if config.get("scene_objects"):
        args += ["--n-objects", str(config["scene_objects"]), "--selector", "dynamic-knn"]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "summary.json").read_text())["success"]["rate"]


def promote(run: Path) -> None:
    name = run.name
    if (POLICIES / f"{name}.safetensors").exists():
        return
    config = json.loads((run / "config.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        rates = {which: success(run / f"{which}.safetensors", config, Path(tmp) / which)
                 for which in ("policy", "best") if (run / f"{which}.safetensors").exists()}
    chosen = "best" if rates.get("best", -1.0) > rates["policy"] else "policy"
    POLICIES.mkdir(parents=True, exist_ok=True)
    records = RECORDS / name
    records.mkdir(parents=True, exist_ok=True)
    for file in ("config.json", "evals.jsonl", "summary.json"):
        shutil.copy2(run / file, records / file)
    choice = {"block": SELECTION_BLOCK, "episodes": EPISODES, "success": rates,
              "chosen": "final" if chosen == "policy" else "best"}
    (records / "choice.json").write_text(json.dumps(choice, indent=1) + "\n")
    shutil.copy2(run / f"{chosen}.safetensors", POLICIES / f"{name}.safetensors")
    print(f"{name}: final {rates['policy']:.3f}, best {rates.get('best', float('nan')):.3f} -> {choice['chosen']}")


def main() -> None:
    runs = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "runs" / "bench"
    for run in sorted(p for p in runs.iterdir() if p.is_dir()):
        if finished(run):
            promote(run)


if __name__ == "__main__":
    main()
