"""The slide-out env's settings as one typed, validated config: what a policy was trained in (its metadata's
``env_kwargs`` is this config's ``kwargs()``), what an evaluation changes of it (``dataclasses.replace``), and
what builds the env (``SlideOutEnv(config)``, or its fields as keywords). The scene part is checked by ``scene.config.SceneConfig``
and the robot by the embodiment registry, so a bad value is refused with a message before anything is built.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_TYPES
from safemanip.scene.config import SceneConfig, parse_semantics
from safemanip.scene.embodiment import EMBODIMENTS
from safemanip.scene.placement import LAYOUTS
from safemanip.util.values import brief, is_int, is_real, is_strings

CONSTRAINT_MODES = ("ground_truth", "conservative", "random")
"""How an episode's constraint types are chosen: from the catalog, all no_contact, or drawn at random."""
SLOT_ORDERS = ("index", "nearest")
ENV_CHOICES = {"constraints": CONSTRAINT_MODES, "layout": LAYOUTS, "embodiment": EMBODIMENTS, "slot_order": SLOT_ORDERS}
"""The settings that name one of a closed set, and the set (the registries themselves for layouts and robots, so a
registered one is taken at once): what ``EnvConfig`` checks and what the command line offers."""


TRAINED_SETTINGS = ("slot_order", "action_curve", "object_size")
"""Settings that belong to a policy (its observation and its action): an evaluation always runs the policy's own."""


class EnvConfigError(ValueError):
    """Settings the env cannot take; the message says what to change."""


@dataclass(frozen=True)
class EnvConfig:
    n_objects: int = 4
    """Clutter objects in every scene (N), 0 to 8."""
    constraints: str | tuple[str, ...] = "ground_truth"
    """Each object's constraint type: 'conservative' (all no_contact), 'random' (drawn per object and episode) or
    'ground_truth' (its catalog class). In Python also one type per object, the same every episode."""
    names: tuple[str, ...] | None = None
    """The scene's objects by catalog name, the same every episode (None: drawn per episode)."""
    classes: tuple[str, ...] | None = None
    """Semantic class of each object (names drawn from the catalog per episode); None: any class. From keywords,
    a description such as '2 fragile, 1 soft' also works."""
    near_path_fraction: float | None = None
    """Share of the clutter placed beside the route, 0 to 1 (default: the layout's own)."""
    clear_route: bool = True
    """Keep a route to the goal clear (False: the superseded straight-corridor layout)."""
    layout: str = "route"
    """Which scenes the episodes draw. (The registry is ``scene.placement.LAYOUTS``.)"""
    gate_share: float | None = None
    """Share of gate scenes, 0 to 1 (default: the layout's)."""
    exit_share: float | None = None
    """Share of exit scenes, 0 to 1 (default: the layout's)."""
    max_episode_steps: int = 300
    """Episode length in control steps."""
    slot_order: str = "index"
    """Order of the observation's object slots: 'index' (the scene's order) or 'nearest' (to the held box first)."""
    embodiment: str = "panda"
    """The robot: the Franka Panda arm, or the idealised floating hand. (``scene.embodiment.EMBODIMENTS``.)"""
    action_curve: float = 1.0
    """Action to commanded speed: 1.7 m/s x |a|^action_curve, 1 (linear) to 4."""
    object_size: bool = False
    """Each observation slot also carries the object's footprint radius."""

    def __post_init__(self):
        """Every setting checked here, once, for every way in (keywords, ``gym.make``, a policy's metadata): each
        bad one is named with what it must be, before anything is built."""
        problems = []
        if not (isinstance(self.constraints, str) and self.constraints in CONSTRAINT_MODES
                or is_strings(self.constraints) and all(c in CONSTRAINT_TYPES for c in self.constraints)):
            problems.append(f"constraints must be one of {CONSTRAINT_MODES} or a list of {CONSTRAINT_TYPES} (one per "
                            f"object), got {brief(self.constraints)}")
        elif not isinstance(self.constraints, str) and is_int(self.n_objects) and len(self.constraints) != self.n_objects:
            problems.append(f"constraints must give one type per object ({self.n_objects}), got {len(self.constraints)}")
        if self.names is not None and not is_strings(self.names):
            problems.append(f"names must be a list of catalog names (or None), got {brief(self.names)}")
        if self.classes is not None and not is_strings(self.classes):
            problems.append("classes must be a list of semantic classes or a description such as '2 fragile, 1 soft' "
                            f"(or None), got {brief(self.classes)}")
        if self.near_path_fraction is not None and not (is_real(self.near_path_fraction)
                                                        and 0 <= self.near_path_fraction <= 1):
            problems.append(f"near_path_fraction must be a number in [0, 1] (or None), got {brief(self.near_path_fraction)}")
        if not isinstance(self.layout, str):  # which names: the scene config says
            problems.append(f"layout must be one of {', '.join(map(repr, LAYOUTS))}, got {brief(self.layout)}")
        for name in ("embodiment", "slot_order"):
            allowed = ENV_CHOICES[name]
            value = getattr(self, name)
            if not isinstance(value, str) or value not in allowed:
                problems.append(f"{name} must be one of {', '.join(map(repr, allowed))}, got {brief(value)}")
        if not (is_int(self.max_episode_steps) and 1 <= self.max_episode_steps <= 100_000):
            problems.append(f"max_episode_steps must be an integer from 1 to 100000, got {brief(self.max_episode_steps)}")
        if not (is_real(self.action_curve) and math.isfinite(self.action_curve) and 1.0 <= self.action_curve <= 4.0):
            problems.append(f"action_curve must be a number from 1 (linear) to 4, got {brief(self.action_curve)}")
        for name in ("clear_route", "object_size"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                problems.append(f"{name} must be true or false, got {brief(getattr(self, name))}")
        if problems:
            raise EnvConfigError("invalid env settings: " + "; ".join(problems))
        # one type per field from here on (a NumPy integer or bool from a caller becomes a Python one)
        for name, kind in (("max_episode_steps", int), ("action_curve", float), ("clear_route", bool),
                           ("object_size", bool)):
            object.__setattr__(self, name, kind(getattr(self, name)))
        for name in ("names", "classes", "constraints"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
        try:
            self.scene()
        except ValueError as err:
            raise EnvConfigError(f"invalid env settings: {err}") from None

    def scene(self) -> SceneConfig:
        """The scene part, checked."""
        return SceneConfig(n_objects=self.n_objects, names=self.names, classes=self.classes,
                           near_path_fraction=self.near_path_fraction, clear_route=self.clear_route,
                           layout=self.layout, gate_share=self.gate_share, exit_share=self.exit_share)

    def kwargs(self) -> dict:
        """The keyword arguments of ``SlideOutEnv`` (and a policy's recorded ``env_kwargs``); settings at their
        'not given' value (None) are left out, so that a record only names what was set."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None and f.name in ("names", "classes", "gate_share", "exit_share"):
                continue
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_kwargs(cls, kwargs: dict, where: str = "env settings") -> "EnvConfig":
        """A config from keywords (``SlideOutEnv``'s, ``gym.make``'s) or recorded ``env_kwargs`` (a policy's
        metadata); keys it does not know are refused, keys an older record lacks take their defaults."""
        if not isinstance(kwargs, dict):
            raise EnvConfigError(f"{where}: expected an object of env settings, got {type(kwargs).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise EnvConfigError(f"{where}: unknown setting(s) {unknown}; the env takes {sorted(known)}")
        values = dict(kwargs)
        if isinstance(values.get("classes"), str):  # '2 fragile, 1 soft'
            try:
                values["classes"] = parse_semantics(values["classes"])
            except ValueError as err:
                raise EnvConfigError(f"invalid env settings: {err}") from None
        return cls(**values)  # lists become tuples in __post_init__
