"""``safemanip eval`` and ``safemanip sweep``."""

from __future__ import annotations

import argparse
import json
import sys

from safemanip.cli.common import (CliError, add_compute_backend, add_config_flags, add_env_flags, add_vlm_options,
                                  env_flag_values, int_in)

EVAL_EXAMPLES = """examples:
  safemanip eval --policy rarl-k2-conservative-s0 --episodes 500 --seed-block 7 --judge conservative
      (k == N: the full-state policy in its own setting; a shipped policy by name)
  safemanip eval --policy rarl-k2-conservative-s0 --n-objects 6 --selector dynamic-knn \\
      --judge conservative --episodes 2000 --out results/k2-n6-dyn
  safemanip eval --policy rarl-k2-conservative-s0 --semantics "2 fragile, 3 durable" \\
      --selector semantic --episodes 500 --backend ray
  safemanip eval --policy runs/k2-all/policy.safetensors --semantics "2 fragile, 2 soft, 1 durable" \\
      --selector semantic --constraint-selector vlm --vlm-backend openai --vlm-model gpt-4o --vlm-cache vlm_cache

"nearest" (static-knn, dynamic-knn, privileged) = horizontal distance from an object's centre to the
centre of the manipulated (bottom) box. Policy slots are filled nearest first.
"""

SWEEP_EXAMPLES = """examples:
  safemanip sweep fig5                      run (or resume) the Fig. 5 grid, then draw it
  safemanip sweep fig6 --episodes 200       a quicker pass (cells are redone when the count changes)
  safemanip sweep fig5 --render-only        redraw figure and table from the stored cell results
  safemanip sweep fig4 --only '*-s0__*'     run only the cells whose id matches (here training seed 0's)
  safemanip sweep --list                    the shipped sweeps
  safemanip sweep table2 --vlm-backend openai --vlm-cache vlm_cache --vlm-timeout 20
                                            the VLM cells against a server, with the eval's limits
"""


def _cmd_eval(args) -> int:
    from dataclasses import fields

    from safemanip.evaluation.harness import EvalRequest, evaluate

    given = {f.name: getattr(args, f.name) for f in fields(EvalRequest) if getattr(args, f.name, None) is not None}
    req = EvalRequest(**{"policy": None, **given, "env": env_flag_values(args), "progress": not args.no_progress})
    report = evaluate(req)
    print(report["text"])
    if args.out:
        print(f"records: {args.out}/episodes.csv, summary: {args.out}/summary.json")
    if args.json:
        print(json.dumps({k: v for k, v in report["summary"].items() if k != "policy_meta"}, indent=1))
    stop = report["summary"].get("interrupted")
    if report["summary"].get("failed"):  # finished episodes are written; the run is incomplete
        from safemanip.evaluation.harness import failure_line

        print(f"safemanip eval: error: {failure_line(report['summary'], args.out)}", file=sys.stderr)
        return 1
    return 128 + stop["signum"] if stop else 0


def _cmd_sweep(args) -> int:
    from safemanip.evaluation.sweep.runner import run_sweep
    from safemanip.evaluation.sweep.spec import available

    if args.list or not args.name:
        if not args.list:
            raise CliError("name a sweep, e.g. `safemanip sweep fig5`; shipped: " + ", ".join(available()))
        for name in available():
            print(name)
        return 0
    from safemanip.evaluation.harness import VLM_FIELDS

    vlm = {f: getattr(args, f) for f in VLM_FIELDS if getattr(args, f)}
    status = run_sweep(args.name, episodes=args.episodes, out=args.out, workers=args.workers, backend=args.backend,
                       address=args.address, render_only=args.render_only, progress=not args.no_progress, vlm=vlm,
                       only=args.only)
    if status.get("interrupted"):
        return 128 + status["interrupted"]
    if not args.render_only and status["skipped"] and not (status["ran"] or status["done"]):
        raise CliError(f"every cell of sweep {args.name} was skipped: none of its policy files exists (the train "
                       "commands are above)")
    return 1 if status["failed"] else 0


def _add_run_options(p: argparse.ArgumentParser) -> None:
    add_compute_backend(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


EVAL_FLAGS = {"--policy": "policy", "--planner": "planner", "--n-objects": "n_objects", "--semantics": "semantics",
              "--selector": "selector", "--constraint-selector": "constraint_selector", "--judge": "judge",
              "--episodes": "episodes", "--seed-block": "seed_block", "--interval": "interval", "--pad": "pad",
              "--chunk-size": "chunk_size", "--out": "out", "--shield": "shield", "--soft-reach": "soft_reach"}
"""The ``EvalRequest`` fields with a flag (the compute and semantic-backend options are shared with the sweep:
``add_compute_backend``, ``add_vlm_options``). The env settings an evaluation may change (every one but
``harness.EVAL_FIXED``) have a flag each, generated from ``EnvConfig`` (``cli.common.add_env_flags``)."""


def register(subparsers) -> None:
    from safemanip.control.planner import PLANNER_AVOID
    from safemanip.env.config import ENV_CHOICES, EnvConfig
    from safemanip.evaluation.harness import EVAL_BOUNDS, EVAL_FIXED, JUDGES, EvalRequest
    from safemanip.evaluation.registry import CONSTRAINT_SELECTORS, OBJECT_SELECTORS
    from safemanip.evaluation.harness import SEED_STRIDE
    from safemanip.safety import SHIELDS

    ev = subparsers.add_parser(
        "eval", help="roll a policy out with object/constraint selection; success and failures with 95%% intervals",
        epilog=EVAL_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_flags(ev, EvalRequest, EVAL_FLAGS, EVAL_BOUNDS, {"selector": OBJECT_SELECTORS, "judge": JUDGES,
                                                                  "constraint_selector": CONSTRAINT_SELECTORS,
                                                                  "planner": PLANNER_AVOID, "shield": SHIELDS})
    scene = ev.add_argument_group("the env, where it differs from the one the policy was trained in")
    add_env_flags(scene, EnvConfig, skip=EVAL_FIXED, choices=ENV_CHOICES)
    add_vlm_options(ev)
    _add_run_options(ev)
    ev.add_argument("--json", action="store_true", help="also print the JSON summary")
    ev.set_defaults(func=_cmd_eval)

    sw = subparsers.add_parser("sweep", help="run a named experiment grid (resumable) and draw its figure/table",
                               epilog=SWEEP_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sw.add_argument("name", nargs="?", help="a shipped sweep (fig5, fig6, table1, ...) or a sweep .json file")
    sw.add_argument("--episodes", type=int_in(1, SEED_STRIDE), help="episodes per cell and training seed (default: the sweep's own, 1000 for the shipped ones)")
    sw.add_argument("--out", help="results folder (default: results/FOLDER, the sweep's own)")
    sw.add_argument("--render-only", action="store_true", help="only redraw figure and table from stored results")
    sw.add_argument("--only", action="append", metavar="PATTERN",
                    help="run only the cells whose id matches this shell-style pattern (repeatable); the figure "
                         "and table still show every stored cell")
    sw.add_argument("--list", action="store_true", help="list the shipped sweeps")
    add_vlm_options(sw)
    _add_run_options(sw)
    sw.set_defaults(func=_cmd_sweep)
