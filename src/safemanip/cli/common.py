"""What every sub-command shares: the error convention (one ``safemanip <command>: error: ...`` line on
stderr and exit code 2, never a traceback), argparse types that refuse non-finite and out-of-range
numbers before any work starts, and the compute/semantic backend flag vocabulary:

  --backend      compute: where episodes run (local | ray)
  --vlm-backend  semantics: who answers object/constraint queries (semantic | openai)
"""

from __future__ import annotations

import argparse
import math


class CliError(ValueError):
    """An input problem to report in one line (exit code 2)."""


def int_in(lo: int, hi: int):
    """argparse type: an integer in [lo, hi]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be in {lo}..{hi:,}, got {value:,}")
        return value
    parse.__name__ = "integer"
    return parse


def float_in(lo: float, hi: float, lo_open: bool = False):
    """argparse type: a finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if value < lo or value > hi or (lo_open and value == lo):
            raise argparse.ArgumentTypeError(f"must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value:g}")
        return value
    parse.__name__ = "number"
    return parse


def bounded(kind: type, bounds):
    """argparse type: an int or a finite float within ``bounds`` (an ``rl.config.Bounds``), with the same message
    as the config's own check."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, got {text!r}") \
                from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if not bounds.contains(value):
            raise argparse.ArgumentTypeError(f"must be in {bounds}, got {value:g}")
        return value
    parse.__name__ = "integer" if kind is int else "number"
    return parse


def add_config_flags(parser: argparse.ArgumentParser, cls: type, flags: dict[str, str], bounds: dict,
                     choices: dict, extra_help: dict[str, str] | None = None) -> None:
    """One argparse option per ``flags`` entry (flag -> field of the dataclass ``cls``), generated from the field:
    its type from the annotation (a bool is a switch), its range and choices from ``bounds`` and ``choices`` (the
    tables the config checks itself against), its help from the field's docstring (``util.docs.field_docs``), first
    sentence, plus ``extra_help`` for what only the command line has. Unset flags are None: the config's default."""
    from dataclasses import fields

    from safemanip.util.docs import field_docs, first_sentence

    docs = field_docs(cls)
    types = {f.name: f.type for f in fields(cls)}
    for flag, name in flags.items():
        kind = types[name].replace(" | None", "").strip()
        help_ = first_sentence(docs.get(name, "")) + ((" " + extra_help[name]) if extra_help and name in extra_help else "")
        help_ = help_.replace("%", "%%")
        if kind == "bool":
            parser.add_argument(flag, dest=name, action="store_const", const=True, default=None, help=help_)
            continue
        typ = None
        if kind in ("int", "float") and name in bounds:
            typ = bounded(int if kind == "int" else float, bounds[name])
        elif kind in ("int", "float"):
            typ = int if kind == "int" else float
        allowed = sorted(choices[name]) if name in choices else None
        parser.add_argument(flag, dest=name, type=typ, choices=allowed, default=None, help=help_)


ENV_DEST = "env:"
"""Where the env flags' values land in the parsed arguments: ``env:layout`` for ``--layout``."""


def add_env_flags(parser: argparse.ArgumentParser, cls: type, skip: tuple[str, ...], choices: dict) -> None:
    """One option per field of the env config ``cls`` (``env.config.EnvConfig``) but ``skip``, generated from the
    field alone, so that a new env setting is on the command line the moment it is in the config: ``--layout``
    for ``layout``, a bool as ``--object-size`` / ``--no-object-size``, choices from ``choices``, help from the
    docstring. Fields holding lists (names, classes) are set through a config file. The config checks ranges itself.
    Each value lands in ``args`` under ``ENV_DEST + field`` (None: not given; ``env_flag_values`` collects them)."""
    from dataclasses import fields

    from safemanip.util.docs import field_docs, first_sentence

    docs = field_docs(cls)
    for f in fields(cls):
        kind = f.type.replace(" | None", "").strip()
        if f.name in skip or kind.startswith("tuple"):
            continue
        flag, dest = env_flag(f.name), ENV_DEST + f.name
        help_ = first_sentence(docs.get(f.name, "")).replace("%", "%%")
        if kind == "bool":
            parser.add_argument(flag, dest=dest, action=argparse.BooleanOptionalAction, default=None, help=help_)
        else:
            typ = {"int": int_in(-2**63, 2**63 - 1), "float": float_in(-math.inf, math.inf)}.get(kind)
            allowed = sorted(choices[f.name]) if f.name in choices else None
            parser.add_argument(flag, dest=dest, type=typ, choices=allowed, default=None, help=help_,
                                metavar=None if allowed else f.name.upper())


def env_flag(name: str) -> str:
    """The command-line flag of an env setting: ``--gate-share`` for ``gate_share``."""
    return "--" + name.replace("_", "-")


def env_flag_values(args: argparse.Namespace) -> dict:
    """{env setting: value} of the env flags given (``add_env_flags``)."""
    return {key[len(ENV_DEST):]: value for key, value in vars(args).items()
            if key.startswith(ENV_DEST) and value is not None}


SEED = int_in(0, 2**31 - 1)
"""Every command's --seed: a non-negative integer numpy and MuJoCo accept."""


def add_compute_backend(p: argparse.ArgumentParser) -> None:
    from safemanip.evaluation.parallel import BACKENDS

    p.add_argument("--workers", type=int_in(1, 256), default=2,
                   help="parallel workers (local processes or Ray CPUs; default 2)")
    p.add_argument("--backend", default="local", choices=BACKENDS,
                   help="compute: local: spawn processes on this machine; ray: Ray tasks (default: local)")
    p.add_argument("--address", help="Ray cluster address for --backend ray (default: start a local Ray instance)")


def add_vlm_options(p) -> None:
    """The semantic-backend options of eval and sweep (``VLM_FIELDS`` of the evaluation harness)."""
    from safemanip.semantics.base import VLM_BACKENDS

    vlm = p.add_argument_group("semantic backend (for --selector semantic / dynamic-vlm and --constraint-selector vlm)")
    vlm.add_argument("--vlm-backend", choices=VLM_BACKENDS,
                     help="semantic: offline embedding model (default); openai: any OpenAI-compatible server")
    vlm.add_argument("--vlm-model", help="model name for --vlm-backend openai (default gpt-4o)")
    vlm.add_argument("--vlm-base-url", help="server URL for --vlm-backend openai (default: OpenAI)")
    vlm.add_argument("--vlm-cache", metavar="DIR", help="answer cache folder for --vlm-backend openai")
    vlm.add_argument("--vlm-cache-only", action="store_true", help="never call the server; a cache miss falls back")
    add_vlm_budget(vlm)


def add_vlm_budget(p) -> None:
    """--vlm-timeout and the time budgets of the openai backend (eval and sweep)."""
    p.add_argument("--vlm-timeout", type=float_in(0, 600, lo_open=True), metavar="S",
                   help="openai backend: per-request timeout in seconds (default 30)")
    p.add_argument("--vlm-episode-budget", type=float_in(0, 86_400, lo_open=True), metavar="S",
                   help="openai backend: seconds of VLM queries per episode; after that the episode's "
                        "selectors use their fallback (default: none)")
    p.add_argument("--vlm-run-budget", type=float_in(0, 30 * 86_400, lo_open=True), metavar="S",
                   help="openai backend: seconds of VLM queries per worker process over the run; after that "
                        "every query falls back (default: none)")
    p.add_argument("--vlm-max-failures", type=int_in(1, 10_000), metavar="N",
                   help="openai backend: consecutive failed queries after which the circuit breaker opens and "
                        "the fallback answers for the rest of the run (default 5)")
