"""The ``safemanip`` command: one parser, one error convention (``cli/common.py``).

Sub-commands are registered by the modules of this package: ``train`` (``cli/train.py``), ``eval`` and
``sweep`` (``cli/evaluate.py``), ``classify-constraints``, ``constraint-matrix`` and ``render-query``
(``cli/semantics.py``), ``demo`` and ``catalog`` (``cli/demo.py``), and ``bench`` with its own sub-commands
(``cli/bench.py``). Expected failures (a bad flag, config, file or server) are one line on stderr and exit code 2
(credentials redacted); a worker process that died ends the run with one line and exit code 1 after saving what was
finished; SIGINT/SIGTERM end a command with 128 + the signal number after saving what was finished.
"""

from __future__ import annotations

import argparse
import sys


class Parser(argparse.ArgumentParser):
    """argparse with the package's error convention: one ``safemanip <command>: error: ...`` line (and where
    to find help) on stderr, exit code 2."""

    def error(self, message: str):
        from safemanip.util.secrets import redact

        self.exit(2, f"{self.prog}: error: {redact(message)} (see: {self.prog} --help)\n")


DESCRIPTION = ("Safe robot manipulation in clutter with task-relevant reach-avoid reinforcement learning: train "
               "policies, evaluate them with object and constraint selection, run the paper's experiments.")
"""What ``safemanip --help`` says first (the module docstring above is for developers)."""


def build_parser() -> argparse.ArgumentParser:
    from safemanip.cli import bench, demo, evaluate, semantics, train

    parser = Parser(prog="safemanip", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True)
    demo.register(sub)
    train.register(sub)
    evaluate.register(sub)
    semantics.register(sub)
    bench.register(sub)
    return parser


def expected_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean "bad input or unavailable service", answered with exit code 2."""
    from safemanip.semantics.base import BackendError

    return (ValueError, FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError, BackendError)


def main(argv: list[str] | None = None) -> int:
    from safemanip.util.procs import Interrupted, WorkerDied
    from safemanip.util.secrets import redact

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # --help (0) or a bad flag (2, message printed)
        return int(done.code or 0) if not isinstance(done.code, str) else 2
    try:
        return args.func(args)
    except Interrupted as stop:
        print(f"safemanip {args.command}: {stop}; what was finished is saved", file=sys.stderr)
        return stop.exit_code
    except KeyboardInterrupt:
        print(f"safemanip {args.command}: interrupted", file=sys.stderr)
        return 130
    except WorkerDied as err:  # the run stopped and kept what was finished; the message says how to go on
        print(f"safemanip {args.command}: error: {redact(err)}", file=sys.stderr)
        return err.exit_code
    except expected_errors() as err:  # say what to change, no traceback (and never a credential)
        print(f"safemanip {args.command}: error: {redact(err)}", file=sys.stderr)
        return 2
