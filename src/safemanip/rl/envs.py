"""The closed registry of environments a run can train on, by name.

A training config (and a run folder's ``config.json`` on ``--resume``) names its env with one of the
keys of ``ENVS``; nothing read from a file is ever turned into an import path or a call. The module
and class of each entry are constants in this file, and the keyword arguments a config may pass to a
non-default env are listed with their types and ranges.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass

DEFAULT_ENV = "slide-out"


@dataclass(frozen=True)
class EnvEntry:
    module: str
    cls: str
    description: str
    extra_kwargs: dict[str, tuple[type, float, float]]
    """Keyword arguments a config may set through ``extra_env_kwargs``: name -> (type, min, max)."""


ENVS: dict[str, EnvEntry] = {
    "slide-out": EnvEntry("safemanip.env.slide_out", "SlideOutEnv",
                          "the paper's task: slide the bottom box out and to the goal through clutter", {}),
    "toy-double-integrator": EnvEntry("safemanip.toy.system", "ToyReachAvoidEnv",
                                      "planar double integrator with one obstacle (the learner's test oracle)",
                                      {"max_episode_steps": (int, 1, 100_000)}),
}

LEGACY_FACTORIES = {"safemanip.env.slide_out:SlideOutEnv": "slide-out",
                    "safemanip.rl.toy:ToyReachAvoidEnv": "toy-double-integrator"}
"""The two ``env_factory`` strings older run folders and policy files carry, and the names they mean.
Any other string is refused (it is never imported)."""


def env_choices() -> str:
    return ", ".join(f"{name!r} ({e.description})" for name, e in ENVS.items())


def check_env(name, extra_kwargs) -> list[str]:
    """Problems with an env name and its extra keyword arguments, as messages (empty: fine)."""
    if not isinstance(name, str) or name not in ENVS:
        return [f"env must be one of the registered envs, {env_choices()}; got {name!r}"]
    if not isinstance(extra_kwargs, dict):
        return [f"extra_env_kwargs must be a JSON object, got {type(extra_kwargs).__name__}"]
    allowed = ENVS[name].extra_kwargs
    problems = []
    for key, value in extra_kwargs.items():
        if key not in allowed:
            problems.append(f"extra_env_kwargs key {key!r} is not accepted by env {name!r}; accepted: "
                            f"{sorted(allowed) or 'none'}")
            continue
        typ, lo, hi = allowed[key]
        ok = isinstance(value, typ) and not isinstance(value, bool)
        if typ is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or not lo <= value <= hi:
            problems.append(f"extra_env_kwargs[{key!r}] must be a {typ.__name__} in [{lo}, {hi}], got {value!r}")
    return problems


def make_env(env_kwargs: dict):
    """Build one env from plain kwargs: ``env`` names a registry entry (default slide-out), the rest are
    that env's constructor arguments."""
    kwargs = dict(env_kwargs)
    name = kwargs.pop("env", DEFAULT_ENV)
    if name not in ENVS:
        raise ValueError(f"unknown env {name!r}; registered envs: {env_choices()}")
    entry = ENVS[name]
    return getattr(importlib.import_module(entry.module), entry.cls)(**kwargs)
