"""``safemanip eval`` and ``safemanip sweep``."""

from __future__ import annotations

import argparse
import json
import sys

from safemanip.cli.common import CliError, add_compute_backend, add_vlm_options, float_in, int_in
from safemanip.scene.embodiment import EMBODIMENTS
from safemanip.scene.placement import LAYOUTS

EVAL_EXAMPLES = """examples:
  safemanip eval --policy rarl-k2-conservative-s0 --episodes 500 --seed 7 --judge conservative
      (k == N: the full-state policy in its own setting; a shipped policy by name)
  safemanip eval --policy rarl-k2-conservative-s0 --n-objects 6 --selector dynamic-knn \\
      --judge conservative --episodes 2000 --out results/k2-n6-dyn
  safemanip eval --policy rarl-k2-conservative-s0 --semantics "2 fragile, 3 durable" \\
      --selector dynamic-vlm --episodes 500 --backend ray
  safemanip eval --policy runs/k2-all/policy.safetensors --semantics "2 fragile, 2 soft, 1 durable" \\
      --selector dynamic-vlm --constraints vlm --vlm-backend openai --vlm-model gpt-4o --vlm-cache vlm_cache

"nearest" (static-knn, dynamic-knn, privileged) = horizontal distance from an object's centre to the
centre of the manipulated (bottom) box. Policy slots are filled nearest first.
"""

SWEEP_EXAMPLES = """examples:
  safemanip sweep fig5                      run (or resume) the Fig. 5 grid, then draw it
  safemanip sweep fig6 --episodes 200       a quicker pass (cells are redone when the count changes)
  safemanip sweep fig5 --render-only        redraw figure and table from the stored cell results
  safemanip sweep --list                    the shipped sweeps
  safemanip sweep table2 --vlm-backend openai --vlm-cache vlm_cache --vlm-timeout 20
                                            the VLM cells against a server, with the eval's limits
"""


def _cmd_eval(args) -> int:
    from safemanip.evaluation.harness import EvalRequest, evaluate

    req = EvalRequest(policy=args.policy, n_objects=args.n_objects, semantics=args.semantics, selector=args.selector,
                      constraints=args.constraints, judge=args.judge, episodes=args.episodes, seed=args.seed,
                      workers=args.workers, backend=args.backend, address=args.address, out=args.out, pad=args.pad,
                      interval=args.interval, vlm_backend=args.vlm_backend, vlm_model=args.vlm_model,
                      vlm_base_url=args.vlm_base_url, vlm_cache=args.vlm_cache, vlm_cache_only=args.vlm_cache_only,
                      vlm_timeout=args.vlm_timeout, vlm_episode_budget=args.vlm_episode_budget,
                      vlm_run_budget=args.vlm_run_budget, vlm_max_failures=args.vlm_max_failures,
                      max_episode_steps=args.max_episode_steps, embodiment=args.embodiment, layout=args.layout,
                      gate_share=args.gate_share, exit_share=args.exit_share, planner=args.planner,
                      chunk_size=args.chunk_size, progress=not args.no_progress)
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
    from safemanip.evaluation.sweep import available, run_sweep

    if args.list or not args.name:
        if not args.list:
            raise CliError("name a sweep, e.g. `safemanip sweep fig5`; shipped: " + ", ".join(available()))
        for name in available():
            print(name)
        return 0
    from safemanip.evaluation.harness import VLM_FIELDS

    vlm = {f: getattr(args, f) for f in VLM_FIELDS if getattr(args, f)}
    status = run_sweep(args.name, episodes=args.episodes, out=args.out, workers=args.workers, backend=args.backend,
                       address=args.address, render_only=args.render_only, progress=not args.no_progress, vlm=vlm)
    if status.get("interrupted"):
        return 128 + status["interrupted"]
    if not args.render_only and status["skipped"] and not (status["ran"] or status["done"]):
        raise CliError(f"every cell of sweep {args.name} was skipped: none of its policy files exists (the train "
                       "commands are above)")
    return 1 if status["failed"] else 0


def _add_run_options(p: argparse.ArgumentParser) -> None:
    add_compute_backend(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


def register(subparsers) -> None:
    from safemanip.evaluation.harness import SEED_STRIDE
    from safemanip.evaluation.registry import CONSTRAINT_SELECTORS, OBJECT_SELECTORS
    from safemanip.scene.config import MAX_OBJECTS

    ev = subparsers.add_parser(
        "eval", help="roll a policy out with object/constraint selection; success and failures with 95%% intervals",
        epilog=EVAL_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    ev.add_argument("--policy", help="policy file (.safetensors), a shipped policy's name or a training run folder")
    ev.add_argument("--planner", choices=["all", "fragile"],
                    help="instead of a policy, the privileged planner keeping clear of all objects or of the fragile "
                         "ones only: the bound on the same scenes (give --n-objects or --semantics)")
    ev.add_argument("--n-objects", type=int_in(0, MAX_OBJECTS),
                    help="clutter objects N (default: the number of --semantics classes, else the policy's k)")
    ev.add_argument("--semantics", help="classes of the clutter, e.g. '2 fragile, 3 durable' (default: any objects)")
    ev.add_argument("--selector", help=f"object selector: {', '.join(OBJECT_SELECTORS)} "
                                       "(default: full when N == k, required otherwise)")
    ev.add_argument("--constraints",
                    help=f"constraint selector: {', '.join(CONSTRAINT_SELECTORS)} (default: conservative for a "
                         "conservative policy, which always gets no_contact anyway; ground-truth for an 'all' one)")
    ev.add_argument("--judge", default="ground-truth", choices=["ground-truth", "conservative"],
                    help="failure set over all N objects: catalog ground truth, or every object no_contact (F^conser)")
    ev.add_argument("--episodes", type=int_in(1, SEED_STRIDE), default=500)
    ev.add_argument("--seed", type=int_in(0, 2**31 // SEED_STRIDE - 1), default=0,
                    help="episode seeds are seed*100000 + i")
    ev.add_argument("--interval", type=int_in(1, 100_000), default=4,
                    help="re-selection interval of dynamic selectors (steps)")
    ev.add_argument("--pad", action="store_true",
                    help="allow N < k: fill empty policy slots with far-away dummy objects")
    ev.add_argument("--max-episode-steps", type=int_in(1, 100_000), help="override the policy's episode length")
    ev.add_argument("--layout", choices=list(LAYOUTS),
                    help="scene layout: route, narrow, gate or exit (default: the one the policy was trained on)")
    ev.add_argument("--gate-share", type=float_in(0.0, 1.0),
                    help="share of gate (semantic-only) scenes, 1 for gates only (default: the layout's)")
    ev.add_argument("--exit-share", type=float_in(0.0, 1.0),
                    help="share of exit scenes (a fragile object past the pull lane), 1 for those only (default: the "
                         "layout's)")
    ev.add_argument("--embodiment", choices=sorted(EMBODIMENTS),
                    help="robot to evaluate on (default: the policy's own; another one is refused)")
    ev.add_argument("--chunk-size", type=int_in(1, 100_000), help="episodes per worker task (default: about 8 tasks per worker)")
    add_vlm_options(ev)
    _add_run_options(ev)
    ev.add_argument("--out", help="folder for episodes.csv and summary.json")
    ev.add_argument("--json", action="store_true", help="also print the JSON summary")
    ev.set_defaults(func=_cmd_eval)

    sw = subparsers.add_parser("sweep", help="run a named experiment grid (resumable) and draw its figure/table",
                               epilog=SWEEP_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sw.add_argument("name", nargs="?", help="a shipped sweep (fig5, fig6, table1, ...) or a sweep .json file")
    sw.add_argument("--episodes", type=int_in(1, SEED_STRIDE), help="episodes per cell (default: the sweep's, 2000 for the figures)")
    sw.add_argument("--out", help="results folder (default: results/FOLDER, the sweep's own)")
    sw.add_argument("--render-only", action="store_true", help="only redraw figure and table from stored results")
    sw.add_argument("--list", action="store_true", help="list the shipped sweeps")
    add_vlm_options(sw)
    _add_run_options(sw)
    sw.set_defaults(func=_cmd_sweep)
