"""``classify-constraints``, ``constraint-matrix`` and ``render-query``.

The work itself is in ``semantics/commands.py``; this module turns flags into calls and every expected
failure (unknown backend, no names, an OpenAI-compatible server that is missing, down or answering out
of schema, no OpenGL) into one ``safemanip <command>: error: ...`` line on stderr and exit code 2.
The semantic backend is chosen with ``--vlm-backend``, as in ``eval`` (``--backend`` is the compute
backend there).
"""

from __future__ import annotations

import argparse
import json
import os

from safemanip.cli.common import SEED, CliError, float_in, int_in
from safemanip.semantics.base import VLM_BACKENDS
from safemanip.semantics.commands import OBJECT_SETS

CLASSIFY_EXAMPLES = """examples:
  safemanip classify-constraints "red mug" "toy sheep" "plastic water bottle"
  safemanip classify-constraints --semantic-examples v1 "glass jar"      (the first example set, argmax)
  safemanip classify-constraints --vlm-backend openai --vlm-model gpt-4o "red mug"          (OPENAI_API_KEY set)
  safemanip classify-constraints --vlm-backend openai --vlm-base-url http://localhost:11434/v1 \\
      --vlm-model llava:13b --vlm-cache vlm_cache "red mug"                    (Ollama, answers cached)
  safemanip classify-constraints --vlm-backend openai --vlm-cache vlm_cache --vlm-cache-only "red mug"
      (replay recorded answers; never calls out)
"""

MATRIX_EXAMPLES = """examples:
  safemanip constraint-matrix --trials 200                  Tables III and IV, semantic backend
  safemanip constraint-matrix --trials 200 --name-variants  each appearance reworded ("the red mug", "Red Mug", ...)
  safemanip constraint-matrix --vlm-backend openai --vlm-model gpt-4o --vlm-cache vlm_cache --trials 200
"""

RENDER_EXAMPLES = """examples:
  safemanip render-query --seed 3 --out query_images                 the query at t = 8 (frames of t = 4 and 8)
  safemanip render-query --seed 11 --n-objects 7 --steps 12 --vlm-backend none
"""


CommandError = CliError


def _add_backend_options(p: argparse.ArgumentParser, default: str = "semantic", allow_none: bool = False) -> None:
    choices = VLM_BACKENDS + (("none",) if allow_none else ())
    none_help = "; none: no backend (the k nearest are picked)" if allow_none else ""
    g = p.add_argument_group("semantic backend")
    g.add_argument("--backend", dest="compute_backend", help=argparse.SUPPRESS)
    g.add_argument("--vlm-backend", dest="backend", default=default, choices=choices,
                   help=f"semantic: offline sentence-embedding classifier (default); openai: any OpenAI-compatible "
                        f"chat-completions server{none_help}")
    g.add_argument("--semantic-examples", metavar="VERSION",
                   help="semantic backend: example set and decision rule, a version v1 ... v6 (default: v6) or the "
                        "file name of a shipped class-example set (class_examples_v6.json); nothing else is read")
    g.add_argument("--vlm-base-url", metavar="URL",
                   help="openai backend: server base URL ending in /v1 (default: the OpenAI API, needs OPENAI_API_KEY)")
    g.add_argument("--vlm-model", metavar="M", help="openai backend: model name (default: gpt-4o)")
    g.add_argument("--vlm-cache", metavar="DIR", help="openai backend: on-disk response cache directory")
    g.add_argument("--vlm-cache-only", action="store_true",
                   help="openai backend: answer from --vlm-cache only; a miss is an error, nothing is sent")
    g.add_argument("--vlm-timeout", type=float_in(0, 600, lo_open=True), default=30.0, metavar="S",
                   help="openai backend: per-request timeout in seconds (default 30)")
    g.add_argument("--vlm-attempts", type=int_in(1, 100), default=3, metavar="N",
                   help="openai backend: attempts per query, with exponential back-off (default 3)")


def _backend_from_args(args):
    from safemanip.semantics.commands import make_backend

    if args.compute_backend is not None:
        raise CommandError("--backend names the compute backend (local|ray) of eval and sweep; the semantic backend "
                           f"is chosen with --vlm-backend ({'|'.join(VLM_BACKENDS)})")
    if args.backend == "none":
        return None
    if args.backend != "openai":
        for flag in ("vlm_base_url", "vlm_model", "vlm_cache"):
            if getattr(args, flag):
                raise CommandError(f"--{flag.replace('_', '-')} applies to --vlm-backend openai only")
        if args.vlm_cache_only:
            raise CommandError("--vlm-cache-only applies to --vlm-backend openai only")
    if args.backend == "openai":
        if args.semantic_examples:
            raise CommandError("--semantic-examples applies to --vlm-backend semantic only")
        if args.vlm_cache_only and not args.vlm_cache:
            raise CommandError("--vlm-cache-only needs --vlm-cache DIR (the directory holding the recorded answers)")
        if args.vlm_cache and not args.vlm_cache_only:  # answers are stored: the folder must take them
            from safemanip.semantics.cache import cache_dir_problems

            problems = cache_dir_problems(args.vlm_cache)
            if problems:
                raise CommandError(problems[0])
        if not args.vlm_base_url and not os.environ.get("OPENAI_API_KEY") and not args.vlm_cache_only:
            raise CommandError(
                "the openai backend has no server to talk to: set OPENAI_API_KEY for the OpenAI API, or point "
                "--vlm-base-url at an OpenAI-compatible server (e.g. http://localhost:11434/v1 for Ollama, "
                "http://localhost:8000/v1 for vLLM), or replay recorded answers with --vlm-cache DIR --vlm-cache-only")
        try:
            import openai  # noqa: F401
        except ImportError as exc:
            raise CommandError("the openai backend needs the 'openai' package: pip install openai") from exc
    try:
        return make_backend(args.backend, model=args.vlm_model, base_url=args.vlm_base_url, cache_dir=args.vlm_cache,
                            cache_mode="cache_only" if args.vlm_cache_only else "readwrite",
                            timeout_s=args.vlm_timeout, attempts=args.vlm_attempts,
                            semantic_examples=args.semantic_examples)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc


def _cmd_classify(args) -> int:
    from safemanip.semantics.commands import classify_constraints

    names = [n.strip() for n in args.names if n.strip()]
    if not names:
        raise CommandError("give at least one object name, e.g. safemanip classify-constraints 'red mug' 'toy sheep'")
    backend = _backend_from_args(args)
    print(classify_constraints(backend, names, task=args.task))
    return 0


def _cmd_matrix(args) -> int:
    from safemanip.semantics.commands import constraint_matrix
    from safemanip.util.files import atomic_write_text, check_output_file

    if args.json:
        problems = check_output_file(args.json, "--json")
        if problems:
            raise CommandError(problems[0])
    backend = _backend_from_args(args)
    text, result = constraint_matrix(backend, trials=args.trials, seed=args.seed,
                                     objects_per_scene=args.objects_per_scene, name_variants=args.name_variants,
                                     task=args.task, objects=args.objects)
    if result["failed_trials"] == args.trials:
        raise CommandError(f"every one of the {args.trials} trials failed (see the warnings above); no table to print")
    print(text)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        atomic_write_text(args.json, json.dumps(result, indent=1))
        print(f"results: {args.json}")
    return 0


def _cmd_render_query(args) -> int:
    from safemanip.semantics.base import BackendError
    from safemanip.semantics.commands import render_query
    from safemanip.util.files import check_output_dir

    problems = check_output_dir(args.out)
    if problems:
        raise CommandError(problems[0])
    backend = _backend_from_args(args)
    try:
        text, _ = render_query(args.seed, args.out, n_objects=args.n_objects, steps=args.steps, k=args.k,
                               interval=args.interval, history=args.history, camera=args.camera,
                               backend=backend, task=args.task)
    except BackendError:
        raise
    except RuntimeError as exc:  # renderer / OpenGL problems
        raise CommandError(str(exc)) from exc
    print(text)
    return 0


def register(subparsers) -> None:
    """Add ``classify-constraints``, ``constraint-matrix`` and ``render-query`` to the ``safemanip`` parser."""
    fmt = argparse.RawDescriptionHelpFormatter

    cl = subparsers.add_parser("classify-constraints", epilog=CLASSIFY_EXAMPLES, formatter_class=fmt,
                               help="constraint type (no/soft/any_contact) for any object names you type")
    cl.add_argument("names", nargs="+", metavar="NAME", help="object names (quote multi-word names)")
    cl.add_argument("--task", help="task description for the prompt (default: the slide-out task)")
    _add_backend_options(cl)
    cl.set_defaults(func=_cmd_classify)

    cm = subparsers.add_parser("constraint-matrix", epilog=MATRIX_EXAMPLES, formatter_class=fmt,
                               help="the paper's Table III (GT vs predicted constraint) and Table IV (per object)")
    cm.add_argument("--trials", type=int_in(1, 100_000), default=200, help="random scenes to ask about (default 200, as the paper)")
    cm.add_argument("--seed", type=SEED, default=0)
    cm.add_argument("--objects-per-scene", type=int_in(1, 100), default=6, help="objects per trial (default 6)")
    cm.add_argument("--objects", default="catalog", choices=OBJECT_SETS,
                    help="test names: every catalog object (default), the paper's eight objects (what its Tables III "
                         "and IV are over), or the shipped held-out name lists (v1, or v2: no word shared with any example name)")
    cm.add_argument("--name-variants", action="store_true",
                    help="reword each appearance mildly ('the red mug', 'Red Mug', 'small red mug', ...)")
    cm.add_argument("--task", help="task description for the prompt (default: the slide-out task)")
    cm.add_argument("--json", metavar="PATH", help="also write the tables and settings as JSON")
    _add_backend_options(cm)
    cm.set_defaults(func=_cmd_matrix)

    rq = subparsers.add_parser("render-query", epilog=RENDER_EXAMPLES, formatter_class=fmt,
                               help="write the annotated image and object list Dynamic-VLM sends, "
                                    "for a scripted rollout")
    rq.add_argument("--seed", type=SEED, default=0, help="scene seed (default 0)")
    rq.add_argument("--out", default="render_query", help="output folder (default: render_query)")
    rq.add_argument("--n-objects", type=int_in(1, 8), default=4, help="clutter objects (default 4)")
    rq.add_argument("--steps", type=int_in(0, 10_000), default=8,
                    help="control steps to run; the image is that of the last query at or before this step (default 8)")
    rq.add_argument("--k", type=int_in(1, 8), default=2, help="objects to select (default 2)")
    rq.add_argument("--interval", type=int_in(1, 10_000), default=4, help="steps between queries (default 4, the paper's)")
    rq.add_argument("--history", type=int_in(1, 8), default=2, help="query frames tiled side by side (default 2, the paper's)")
    rq.add_argument("--camera", default="front", choices=["front", "top"])
    rq.add_argument("--task", help="task description for the prompt (default: the slide-out task)")
    _add_backend_options(rq, allow_none=True)
    rq.set_defaults(func=_cmd_render_query)
