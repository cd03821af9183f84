"""The ``safemanip`` command."""

from __future__ import annotations

import argparse
import sys


def _cmd_demo(args) -> int:
    from safemanip.demo import print_report, run_demo

    result = run_demo(out_dir=args.out, controller=args.controller, policy=args.policy, seed=args.seed,
                      n_objects=args.n_objects, video=not args.no_video, camera=args.camera, selector=args.selector)
    print_report(result, result.summary)
    return 0


def _cmd_catalog(args) -> int:
    from safemanip.scene.catalog import load_catalog

    for obj in sorted(load_catalog().values(), key=lambda o: (o.semantic_class, o.name)):
        print(f"{obj.name}\t{obj.semantic_class}\t{obj.constraint}\t{obj.mass:.2f} kg")
    return 0


def _cmd_train(args) -> int:
    import shlex
    from dataclasses import fields

    from safemanip.rl.config import TrainConfig
    from safemanip.rl.train import train

    if args.resume:
        from pathlib import Path

        cfg_path = Path(args.resume) / "config.json"
        if not cfg_path.exists():
            raise FileNotFoundError(f"--resume {args.resume}: no config.json there; is it a run folder?")
        cfg = TrainConfig.from_file(cfg_path)
    else:
        base = TrainConfig.from_file(args.config).__dict__ if args.config else {}
        overrides = {f.name: getattr(args, f.name) for f in fields(TrainConfig)
                     if getattr(args, f.name, None) is not None}
        if "minutes" in overrides and overrides["minutes"] <= 0:
            overrides["minutes"] = None
        cfg = TrainConfig.from_dict({**base, **overrides})  # validated here, before any work starts
    command = "safemanip " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    run_dir = train(cfg, resume=bool(args.resume), progress=not args.no_progress, command=command)
    summary = (run_dir / "summary.json").read_text()
    print(f"run finished: {run_dir}\n{summary}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="safemanip", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="one rollout in the default cluttered scene: video, JSON summary, report")
    demo.add_argument("--out", default="demo_output", help="output folder (default: demo_output)")
    demo.add_argument("--controller", default="policy", choices=["policy", "scripted"],
                      help="the shipped reach-avoid policy (default) or the scripted baseline")
    demo.add_argument("--policy", default="rarl-k2-conservative", help="policy file or shipped policy name")
    demo.add_argument("--selector", default="dynamic-knn", help="object selector feeding the policy its k objects")
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument("--n-objects", type=int, default=4)
    demo.add_argument("--camera", default="front", choices=["front", "top"])
    demo.add_argument("--no-video", action="store_true", help="skip rendering (faster, no OpenGL needed)")
    demo.set_defaults(func=_cmd_demo)

    tr = sub.add_parser("train", help="train a reach-avoid (rarl) or vanilla DDPG policy")
    tr.add_argument("--config", help="JSON file with TrainConfig fields (flags override it)")
    tr.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run from its last checkpoint")
    tr.add_argument("--algorithm", choices=["rarl", "vanilla"])
    tr.add_argument("--n-objects", "--k", dest="n_objects", type=int, help="clutter objects in training scenes (k)")
    tr.add_argument("--constraints", choices=["conservative", "all"])
    tr.add_argument("--total-env-steps", dest="total_env_steps", type=int)
    tr.add_argument("--minutes", type=float, help="wall-clock budget (0: none)")
    tr.add_argument("--seed", type=int)
    tr.add_argument("--out", dest="out_dir", help="run folder (checkpoints, logs, policies)")
    tr.add_argument("--gamma", type=float)
    tr.add_argument("--gamma-start", dest="gamma_start", type=float)
    tr.add_argument("--env-steps-per-update", dest="env_steps_per_update", type=float)
    tr.add_argument("--eval-every-s", dest="eval_every_s", type=float)
    tr.add_argument("--eval-episodes", dest="eval_episodes", type=int)
    tr.add_argument("--checkpoint-every-s", dest="checkpoint_every_s", type=float)
    tr.add_argument("--no-progress", action="store_true")
    # learner speed, network, selection-aware training and rollout backend (TrainConfig fields of the same names)
    tr.add_argument("--device", choices=["auto", "cpu", "cuda"], help="learner device (default auto)")
    tr.add_argument("--precision", choices=["auto", "bf16", "fp32"], help="forward passes in bf16 autocast or fp32")
    tr.add_argument("--network", choices=["mlp", "set"], help="flat MLP (paper) or object-set network (any k)")
    tr.add_argument("--scene-objects", dest="scene_objects", type=int,
                    help="selection-aware training: N objects per scene, the selector picks the policy's k")
    tr.add_argument("--selector", choices=["dynamic-knn", "dynamic-radius"], help="selector for selection-aware training")
    tr.add_argument("--selection-radius", dest="selection_radius", type=float, help="dynamic-radius radius [m]")
    tr.add_argument("--backend", choices=["local", "ray"], help="rollout workers as local processes or Ray actors")
    tr.add_argument("--address", help="Ray cluster address (HOST:PORT); default: a local Ray instance")
    tr.add_argument("--workers", dest="n_collectors", type=int, help="rollout workers (processes or Ray actors)")
    tr.set_defaults(func=_cmd_train)

    from safemanip.evaluation.commands import register as register_evaluation

    register_evaluation(sub)  # eval and sweep
    from safemanip.semantics.cli import register as register_semantics; register_semantics(sub)  # noqa: E702

    catalog = sub.add_parser("catalog", help="list the object catalog: name, class, constraint, mass")
    catalog.set_defaults(func=_cmd_catalog)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as err:  # config and input errors: say what to change, no traceback
        print(f"safemanip {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
