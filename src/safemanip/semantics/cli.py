"""CLI wiring of ``classify-constraints``, ``constraint-matrix`` and ``render-query``.

``safemanip.cli.build_parser`` calls ``register``. The work itself is in ``semantics/commands.py``;
this module turns flags into calls and every expected failure (unknown backend, no names, an
OpenAI-compatible server that is missing, down or answering out of schema, no OpenGL) into one
``safemanip <command>: error: ...`` line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

BACKENDS = ("semantic", "openai")

CLASSIFY_EXAMPLES = """examples:
  safemanip classify-constraints "red mug" "toy sheep" "plastic water bottle"
  safemanip classify-constraints --semantic-examples v1 "glass jar"      (the first example set, argmax)
  safemanip classify-constraints --backend openai --vlm-model gpt-4o "red mug"          (OPENAI_API_KEY set)
  safemanip classify-constraints --backend openai --vlm-base-url http://localhost:11434/v1 \\
      --vlm-model llava:13b --vlm-cache vlm_cache "red mug"                    (Ollama, answers cached)
  safemanip classify-constraints --backend openai --vlm-cache vlm_cache --vlm-cache-only "red mug"
      (replay recorded answers; never calls out)
"""

MATRIX_EXAMPLES = """examples:
  safemanip constraint-matrix --trials 200                  Tables III and IV, semantic backend
  safemanip constraint-matrix --trials 200 --name-variants  each appearance reworded ("the red mug", "Red Mug", ...)
  safemanip constraint-matrix --backend openai --vlm-model gpt-4o --vlm-cache vlm_cache --trials 200
"""

RENDER_EXAMPLES = """examples:
  safemanip render-query --seed 3 --out query_images                 the query at t = 8 (frames of t = 4 and 8)
  safemanip render-query --seed 11 --n-objects 7 --steps 12 --backend none
"""


class CommandError(Exception):
    """An input or backend problem to report in one line (exit code 2)."""


def _add_backend_options(p: argparse.ArgumentParser, default: str = "semantic", allow_none: bool = False) -> None:
    choices = BACKENDS + (("none",) if allow_none else ())
    none_help = "; none: no backend (the k nearest are picked)" if allow_none else ""
    g = p.add_argument_group("backend")
    g.add_argument("--backend", default=default, choices=choices,
                   help=f"semantic: offline sentence-embedding classifier (default); openai: any OpenAI-compatible "
                        f"chat-completions server{none_help}")
    g.add_argument("--semantic-examples", metavar="VERSION",
                   help="semantic backend: example set and decision rule, v1, v2 or v3 (default: v3), or a file name "
                        "in safemanip/semantics/data")
    g.add_argument("--vlm-base-url", metavar="URL",
                   help="openai backend: server base URL ending in /v1 (default: the OpenAI API, needs OPENAI_API_KEY)")
    g.add_argument("--vlm-model", metavar="M", help="openai backend: model name (default: gpt-4o)")
    g.add_argument("--vlm-cache", metavar="DIR", help="openai backend: on-disk response cache directory")
    g.add_argument("--vlm-cache-only", action="store_true",
                   help="openai backend: answer from --vlm-cache only; a miss is an error, nothing is sent")
    g.add_argument("--vlm-timeout", type=float, default=30.0, metavar="S",
                   help="openai backend: per-request timeout in seconds (default 30)")
    g.add_argument("--vlm-attempts", type=int, default=3, metavar="N",
                   help="openai backend: attempts per query, with exponential back-off (default 3)")


def _backend_from_args(args):
    from safemanip.semantics.commands import make_backend

    if args.backend == "none":
        return None
    if args.backend != "openai":
        for flag in ("vlm_base_url", "vlm_model", "vlm_cache"):
            if getattr(args, flag):
                raise CommandError(f"--{flag.replace('_', '-')} applies to --backend openai only")
        if args.vlm_cache_only:
            raise CommandError("--vlm-cache-only applies to --backend openai only")
    if args.backend == "openai":
        if args.semantic_examples:
            raise CommandError("--semantic-examples applies to --backend semantic only")
        if args.vlm_cache_only and not args.vlm_cache:
            raise CommandError("--vlm-cache-only needs --vlm-cache DIR (the directory holding the recorded answers)")
        if not args.vlm_base_url and not os.environ.get("OPENAI_API_KEY") and not args.vlm_cache_only:
            raise CommandError(
                "the openai backend has no server to talk to: set OPENAI_API_KEY for the OpenAI API, or point "
                "--vlm-base-url at an OpenAI-compatible server (e.g. http://localhost:11434/v1 for Ollama, "
                "http://localhost:8000/v1 for vLLM), or replay recorded answers with --vlm-cache DIR --vlm-cache-only")
        if args.vlm_timeout <= 0 or args.vlm_attempts < 1:
            raise CommandError("--vlm-timeout must be > 0 and --vlm-attempts >= 1")
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


def _run(command: str, fn) -> int:
    """Call ``fn()``; expected failures become one line on stderr and exit code 2."""
    from safemanip.semantics.base import BackendError

    try:
        return fn()
    except (CommandError, BackendError, ValueError) as exc:
        print(f"safemanip {command}: error: {exc}", file=sys.stderr)
        return 2


def _cmd_classify(args) -> int:
    def run() -> int:
        from safemanip.semantics.commands import classify_constraints

        names = [n.strip() for n in args.names if n.strip()]
        if not names:
            raise CommandError("give at least one object name, e.g. "
                               "safemanip classify-constraints 'red mug' 'toy sheep'")
        backend = _backend_from_args(args)
        print(classify_constraints(backend, names, task=args.task))
        return 0

    return _run("classify-constraints", run)


def _cmd_matrix(args) -> int:
    def run() -> int:
        from safemanip.semantics.commands import constraint_matrix

        if args.trials < 1:
            raise CommandError(f"--trials must be >= 1, got {args.trials}")
        backend = _backend_from_args(args)
        text, result = constraint_matrix(backend, trials=args.trials, seed=args.seed,
                                         objects_per_scene=args.objects_per_scene, name_variants=args.name_variants,
                                         task=args.task, objects=args.objects)
        if result["failed_trials"] == args.trials:
            raise CommandError(f"every one of the {args.trials} trials failed (see the warnings above); "
                               "no table to print")
        print(text)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(result, f, indent=1)
            print(f"results: {args.json}")
        return 0

    return _run("constraint-matrix", run)


def _cmd_render_query(args) -> int:
    def run() -> int:
        from safemanip.semantics.commands import render_query

        if args.steps < 0 or args.n_objects < 1 or args.k < 1 or args.interval < 1 or args.history < 1:
            raise CommandError("--steps must be >= 0 and --n-objects, --k, --interval, --history >= 1")
        backend = _backend_from_args(args)
        try:
            text, _ = render_query(args.seed, args.out, n_objects=args.n_objects, steps=args.steps, k=args.k,
                                   interval=args.interval, history=args.history, camera=args.camera,
                                   backend=backend, task=args.task)
        except RuntimeError as exc:  # renderer / OpenGL problems; BackendError is handled by _run
            from safemanip.semantics.base import BackendError
            if isinstance(exc, BackendError):
                raise
            raise CommandError(str(exc)) from exc
        print(text)
        return 0

    return _run("render-query", run)


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
    cm.add_argument("--trials", type=int, default=200, help="random scenes to ask about (default 200, as the paper)")
    cm.add_argument("--seed", type=int, default=0)
    cm.add_argument("--objects-per-scene", type=int, default=6, help="objects per trial (default 6)")
    cm.add_argument("--objects", default="catalog", choices=["catalog", "paper", "heldout"],
                    help="test names: every catalog object (default), the paper's eight objects (what its Tables III "
                         "and IV are over), or the shipped held-out name list")
    cm.add_argument("--name-variants", action="store_true",
                    help="reword each appearance mildly ('the red mug', 'Red Mug', 'small red mug', ...)")
    cm.add_argument("--task", help="task description for the prompt (default: the slide-out task)")
    cm.add_argument("--json", metavar="PATH", help="also write the tables and settings as JSON")
    _add_backend_options(cm)
    cm.set_defaults(func=_cmd_matrix)

    rq = subparsers.add_parser("render-query", epilog=RENDER_EXAMPLES, formatter_class=fmt,
                               help="write the annotated image and object list Dynamic-VLM sends, "
                                    "for a scripted rollout")
    rq.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    rq.add_argument("--out", default="render_query", help="output folder (default: render_query)")
    rq.add_argument("--n-objects", type=int, default=4, help="clutter objects (default 4)")
    rq.add_argument("--steps", type=int, default=8,
                    help="control steps to run; the image is that of the last query at or before this step (default 8)")
    rq.add_argument("--k", type=int, default=2, help="objects to select (default 2)")
    rq.add_argument("--interval", type=int, default=4, help="steps between queries (default 4, the paper's)")
    rq.add_argument("--history", type=int, default=2, help="query frames tiled side by side (default 2, the paper's)")
    rq.add_argument("--camera", default="front", choices=["front", "top"])
    rq.add_argument("--task", help="task description for the prompt (default: the slide-out task)")
    _add_backend_options(rq, allow_none=True)
    rq.set_defaults(func=_cmd_render_query)
