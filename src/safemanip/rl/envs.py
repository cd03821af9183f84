"""The closed registry of environments a run can train on, by name.

A training config (and a run folder's ``config.json`` on ``--resume``) names its env with one of the
keys of ``ENVS``; nothing read from a file is ever turned into an import path or a call. Each entry's
class comes from a function in this file, and the keyword arguments a config may pass to a
non-default env are listed with their types and ranges.

Envs built outside ``rl`` (``PROVIDED_ENVS``) have their name fixed here and their factory passed in by
whoever calls the training loop (``rl.train.train(cfg, env_factory=...)``): ``slide-out-selected``,
the selection-aware training env (``TrainConfig.scene_objects``/``selector``), is
``selection.training_env.SelectedSlotsEnv``, which ``safemanip train`` passes (so ``rl`` imports nothing from
``selection``, and nothing registers itself by being imported). A config never names these envs:
``TrainConfig.rollout_env_kwargs`` chooses one from the typed fields. Worker processes and Ray actors are handed
an ``EnvBuilder`` resolved in the parent (the factory travels by reference: a module-level class or function).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

DEFAULT_ENV = "slide-out"
SELECTED_ENV = "slide-out-selected"


def _slide_out():
    from safemanip.env.slide_out import SlideOutEnv

    return SlideOutEnv


def _toy_double_integrator():
    from safemanip.toy.system import ToyReachAvoidEnv

    return ToyReachAvoidEnv


@dataclass(frozen=True)
class EnvEntry:
    env_class: Callable[[], type]
    """Returns the env class (imported on first use: the toy's users need not load MuJoCo)."""
    description: str
    extra_kwargs: dict[str, tuple[type, float, float]]
    """Keyword arguments a config may set through ``extra_env_kwargs``: name -> (type, min, max)."""


ENVS: dict[str, EnvEntry] = {
    "slide-out": EnvEntry(_slide_out,
                          "the paper's task: slide the bottom box out and to the goal through clutter", {}),
    "toy-double-integrator": EnvEntry(_toy_double_integrator,
                                      "planar double integrator with one obstacle (the learner's test oracle)",
                                      {"max_episode_steps": (int, 1, 100_000)}),
}

PROVIDED_ENVS: dict[str, tuple[str, str, str]] = {
    SELECTED_ENV: ("the slide-out env with N objects seen through an object selector that fills the policy's k slots "
                   "(selection-aware training: scene_objects, selector)", "safemanip.selection.training_env",
                   "SelectedSlotsEnv"),
}
"""Envs whose factory another package provides, by name -> (description, module, factory): the caller of
``rl.train.train`` passes that factory as ``env_factory``; this module never imports it. Not nameable by a
config's ``env`` key."""


def env_choices() -> str:
    return ", ".join(f"{name!r} ({e.description})" for name, e in ENVS.items())


def check_env(name, extra_kwargs) -> list[str]:
    """Problems with an env name and its extra keyword arguments, as messages (empty: fine)."""
    if not isinstance(name, str) or name not in ENVS:
        return [f"env_name must be one of the registered envs, {env_choices()}; got {name!r}"]
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


@dataclass(frozen=True)
class EnvBuilder:
    """A resolved env: its factory and constructor arguments. Plain data that pickles (the factory by
    reference), so a parent resolves the name once and its worker processes or Ray actors build from it."""

    factory: Callable
    kwargs: dict = field(default_factory=dict)

    def __call__(self):
        return self.factory(**self.kwargs)


def env_builder(env_kwargs: dict, factory: Callable | None = None) -> EnvBuilder:
    """Resolve plain kwargs: ``env`` names a registry entry (default slide-out) or a provided env, the rest are
    that env's constructor arguments. ``factory``, if given, builds the env from them instead of the registry's
    class; a provided env needs it (``PROVIDED_ENVS`` says which)."""
    kwargs = dict(env_kwargs)
    name = kwargs.pop("env", DEFAULT_ENV)
    if name not in ENVS and name not in PROVIDED_ENVS:
        raise ValueError(f"unknown env {name!r}; registered envs: {env_choices()}")
    if factory is not None:
        return EnvBuilder(factory, kwargs)
    if name in PROVIDED_ENVS:
        description, module, factory_name = PROVIDED_ENVS[name]
        raise ValueError(f"env {name!r} ({description}) is built outside rl, so its factory must be passed in: "
                         f"from {module} import {factory_name}, then train(cfg, env_factory={factory_name}) "
                         f"(safemanip train does)")
    return EnvBuilder(ENVS[name].env_class(), kwargs)


def make_env(env_kwargs: dict, factory: Callable | None = None):
    """Build one env from plain kwargs (see ``env_builder``)."""
    return env_builder(env_kwargs, factory)()
