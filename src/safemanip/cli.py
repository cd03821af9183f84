"""The ``safemanip`` command."""

from __future__ import annotations

import argparse
import sys


def _cmd_demo(args) -> int:
    from safemanip.demo import print_report, run_demo

    result = run_demo(out_dir=args.out, controller=args.controller, seed=args.seed, n_objects=args.n_objects,
                      video=not args.no_video, camera=args.camera)
    print_report(result, result.summary)
    return 0


def _cmd_catalog(args) -> int:
    from safemanip.scene.catalog import load_catalog

    for obj in sorted(load_catalog().values(), key=lambda o: (o.semantic_class, o.name)):
        print(f"{obj.name}\t{obj.semantic_class}\t{obj.constraint}\t{obj.mass:.2f} kg")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="safemanip", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="one rollout in the default cluttered scene: video, JSON summary, report")
    demo.add_argument("--out", default="demo_output", help="output folder (default: demo_output)")
    demo.add_argument("--controller", default="scripted", choices=["scripted"])
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument("--n-objects", type=int, default=4)
    demo.add_argument("--camera", default="front", choices=["front", "top"])
    demo.add_argument("--no-video", action="store_true", help="skip rendering (faster, no OpenGL needed)")
    demo.set_defaults(func=_cmd_demo)

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
