"""The slide-out env's settings as one typed, validated config: what a policy was trained in (its metadata's
``env_kwargs`` is this config's ``kwargs()``), what an evaluation changes of it (``dataclasses.replace``), and
what builds the env (``SlideOutEnv(**config.kwargs())``). The scene part is checked by ``scene.config.SceneConfig``
and the robot by the embodiment registry, so a bad value is refused with a message before anything is built.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, fields

from safemanip.env.arguments import CONSTRAINT_MODES
from safemanip.scene.config import SceneConfig
from safemanip.scene.embodiment import EMBODIMENTS


class EnvConfigError(ValueError):
    """Settings the env cannot take; the message says what to change."""


@dataclass(frozen=True)
class EnvConfig:
    n_objects: int = 4
    """Clutter objects in every scene (N), 0 to 8."""
    constraints: str = "ground_truth"
    """How each episode's constraint types are chosen: 'ground_truth' (each object's catalog class), 'conservative'
    (every object no_contact) or 'random' (drawn per object: training all constraint types)."""
    classes: tuple[str, ...] | None = None
    """Semantic class of each object (names drawn from the catalog per episode); None: any class."""
    near_path_fraction: float | None = None
    """Share of the clutter beside the route (None: the layout's own)."""
    clear_route: bool = True
    """Keep a route to the goal clear (False: the superseded straight-corridor layout)."""
    layout: str = "route"
    """Scene layout (``scene.placement.LAYOUTS``)."""
    gate_share: float | None = None
    """Share of gate scenes (None: the layout's)."""
    exit_share: float | None = None
    """Share of exit scenes (None: the layout's)."""
    max_episode_steps: int = 300
    """Episode length in control steps."""
    slot_order: str = "index"
    """Object slots of the env's own observation: scene order or nearest to the held box first."""
    embodiment: str = "panda"
    """Robot (``scene.embodiment.EMBODIMENTS``)."""
    action_curve: float = 1.0
    """Commanded speed = 1.7 m/s x |a|^action_curve."""
    object_size: bool = False
    """Each observation slot also carries the object's footprint radius."""

    def __post_init__(self):
        problems = []
        if self.constraints not in CONSTRAINT_MODES:
            problems.append(f"constraints must be one of {CONSTRAINT_MODES}, got {self.constraints!r}")
        if self.slot_order not in ("index", "nearest"):
            problems.append(f"slot_order must be 'index' or 'nearest', got {self.slot_order!r}")
        if self.embodiment not in EMBODIMENTS:
            problems.append(f"embodiment must be one of {sorted(EMBODIMENTS)}, got {self.embodiment!r}")
        if not (isinstance(self.max_episode_steps, numbers.Integral) and not isinstance(self.max_episode_steps, bool)
                and 1 <= self.max_episode_steps <= 100_000):
            problems.append(f"max_episode_steps must be an integer from 1 to 100000, got {self.max_episode_steps!r}")
        if not (isinstance(self.action_curve, numbers.Real) and not isinstance(self.action_curve, bool)
                and 1.0 <= self.action_curve <= 4.0):
            problems.append(f"action_curve must be a number from 1 (linear) to 4, got {self.action_curve!r}")
        for name in ("clear_route", "object_size"):
            if not isinstance(getattr(self, name), bool):
                problems.append(f"{name} must be true or false, got {getattr(self, name)!r}")
        if problems:
            raise EnvConfigError("invalid env settings: " + "; ".join(problems))
        try:
            self.scene()
        except ValueError as err:
            raise EnvConfigError(f"invalid env settings: {err}") from None

    def scene(self) -> SceneConfig:
        """The scene part, checked."""
        return SceneConfig(n_objects=self.n_objects, classes=self.classes, near_path_fraction=self.near_path_fraction,
                           clear_route=self.clear_route, layout=self.layout, gate_share=self.gate_share,
                           exit_share=self.exit_share)

    def kwargs(self) -> dict:
        """The keyword arguments of ``SlideOutEnv`` (and a policy's recorded ``env_kwargs``); settings at their
        'not given' value (None) are left out, so that a record only names what was set."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None and f.name in ("classes", "gate_share", "exit_share"):
                continue
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_kwargs(cls, kwargs: dict, where: str = "env settings") -> "EnvConfig":
        """A config from recorded ``env_kwargs`` (a policy's metadata); keys it does not know are refused, keys an
        older record lacks take their defaults."""
        if not isinstance(kwargs, dict):
            raise EnvConfigError(f"{where}: expected an object of env settings, got {type(kwargs).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise EnvConfigError(f"{where}: unknown setting(s) {unknown}; the env takes {sorted(known)}")
        values = dict(kwargs)
        if values.get("classes") is not None:
            values["classes"] = tuple(values["classes"])
        return cls(**values)
