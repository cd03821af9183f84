"""``safemanip demo`` and ``safemanip catalog``."""

from __future__ import annotations

from safemanip.cli.common import SEED, CliError, float_in, int_in
from safemanip.scene.embodiment import EMBODIMENTS


def _cmd_demo(args) -> int:
    from safemanip.demo import print_report, run_demo
    from safemanip.util.files import check_output_dir

    problems = check_output_dir(args.out)
    if problems:
        raise CliError(problems[0])
    result = run_demo(out_dir=args.out, controller=args.controller, policy=args.policy, seed=args.seed,
                      n_objects=args.n_objects, video=not args.no_video, camera=args.camera, selector=args.selector,
                      fps=args.fps, slowmo=args.slowmo, embodiment=args.embodiment)
    print_report(result, result.summary)
    return 0


def _cmd_catalog(args) -> int:
    from safemanip.scene.catalog import load_catalog

    for obj in sorted(load_catalog().values(), key=lambda o: (o.semantic_class, o.name)):
        print(f"{obj.name}\t{obj.semantic_class}\t{obj.constraint}\t{obj.mass:.2f} kg")
    return 0


def register(sub) -> None:
    from safemanip.scene.config import MAX_OBJECTS

    demo = sub.add_parser("demo", help="one rollout in the default cluttered scene: video, JSON summary, report")
    demo.add_argument("--out", default="demo_output", help="output folder (default: demo_output)")
    demo.add_argument("--controller", default="policy", choices=["policy", "scripted", "planner"],
                      help="the shipped reach-avoid policy (default), the scripted baseline, or the privileged "
                           "planner that sees the whole scene")
    demo.add_argument("--policy", default="rarl-k2-conservative-s0", help="policy file or shipped policy name")
    demo.add_argument("--selector", default="dynamic-knn", help="object selector feeding the policy its k objects")
    demo.add_argument("--seed", type=SEED, default=7)
    demo.add_argument("--n-objects", type=int_in(0, MAX_OBJECTS), default=4, help="objects in the scene (N)")
    demo.add_argument("--camera", default="front", choices=["front", "top"])
    demo.add_argument("--embodiment", choices=sorted(EMBODIMENTS),
                      help="robot (default: the policy's own; the Panda for the scripted controller and the planner)")
    demo.add_argument("--no-video", action="store_true", help="skip rendering (faster, no OpenGL needed)")
    demo.add_argument("--fps", type=int, default=50, choices=[20, 25, 50, 100],
                      help="video frames per simulated second, rendered between control steps (default 50)")
    demo.add_argument("--slowmo", type=float_in(1, 100), default=1.0,
                      help="play the video this many times slower than real time (default 1)")
    demo.set_defaults(func=_cmd_demo)

    catalog = sub.add_parser("catalog", help="list the object catalog: name, class, constraint, mass")
    catalog.set_defaults(func=_cmd_catalog)
