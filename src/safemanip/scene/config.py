"""Scene geometry and the small, validated scene config.

World frame: origin at the centre of the table top, x to the right (towards the goal), y away
from the robot, z up. The robot stands on the -y side, facing +y; the pull and the slide go to the
right, across the robot's front, where a Panda's end-effector is fastest (its first joint swings it).
"""

from __future__ import annotations

import numbers
import re
from dataclasses import dataclass, field

from safemanip.scene.catalog import SEMANTIC_CLASSES, load_catalog

MAX_OBJECTS = 8


@dataclass(frozen=True)
class TaskGeometry:
    """Fixed geometry of the slide-out task (metres, kilograms)."""

    table_half_extents: tuple[float, float] = (0.80, 0.45)
    """Half length (x) and half depth (y) of the table top."""
    box_half_extents: tuple[float, float, float] = (0.095, 0.135, 0.035)
    """Cereal box lying flat, its long side along y: 0.19 x 0.27 x 0.07 m."""
    box_mass: float = 0.35
    stack_xy: tuple[float, float] = (-0.40, 0.0)
    """Centre of the top box."""
    bottom_offset_x: float = 0.07
    """The bottom box sticks out this far to the right (+x, the pull direction) from under the top box; the
    fingers rest on that lip."""
    goal_xy: tuple[float, float] = (0.45, -0.15)
    """Centre of the goal region, to the right of the stack."""
    goal_radius: float = 0.08
    path_start_xy: tuple[float, float] = (-0.15, 0.0)
    """Where the bottom box is once it has been pulled out; clutter 'near the path' lies between here and the goal."""
    grasp_inset: float = 0.03
    """The pads press this far in from the bottom box's right edge [m], in the middle of the 7 cm lip: the further
    back from the edge the box would tip over, the more their push holds it flat while they drag it."""
    workspace_inset: float = 0.03
    """The manipulated box's centre must stay this far inside the table edge (else failure:oob)."""

    @property
    def bottom_xy(self) -> tuple[float, float]:
        return (self.stack_xy[0] + self.bottom_offset_x, self.stack_xy[1])

    @property
    def grasp_xy(self) -> tuple[float, float]:
        """Where the pads press: on the lip, ``grasp_inset`` in from the bottom box's right edge."""
        bx, by = self.bottom_xy
        return (bx + self.box_half_extents[0] - self.grasp_inset, by)


GEOMETRY = TaskGeometry()


class SceneConfigError(ValueError):
    """A scene request that cannot be built; the message says what to change."""


def parse_semantics(text: str) -> tuple[str, ...]:
    """Turn '2 fragile, 3 durable' into ('fragile', 'fragile', 'durable', 'durable', 'durable')."""
    classes: list[str] = []
    for chunk in filter(None, (c.strip() for c in text.split(","))):
        m = re.fullmatch(r"(\d+)\s+([a-z]+)", chunk)
        if not m or m.group(2) not in SEMANTIC_CLASSES:
            raise SceneConfigError(
                f"cannot read {chunk!r} in semantics {text!r}: write e.g. '2 fragile, 2 soft, 1 durable' "
                f"(classes: {', '.join(SEMANTIC_CLASSES)})")
        classes += [m.group(2)] * int(m.group(1))
    return tuple(classes)


@dataclass(frozen=True)
class SceneConfig:
    """Which clutter goes on the table. Validated on construction."""

    n_objects: int = 4
    """Number of clutter objects, 0 to 8 (the two cereal boxes are extra)."""
    names: tuple[str, ...] | None = None
    """Exact catalog names to place (length n_objects). Overrides ``classes``."""
    classes: tuple[str, ...] | None = None
    """Semantic class per object (fragile/soft/durable); names are drawn from the catalog per episode.
    None: any class."""
    near_path_fraction: float | None = None
    """Share of the clutter placed near the path from the pulled-out box to the goal (None: the layout's own,
    ``placement.LAYOUTS``; 0.5 without a route)."""
    clear_route: bool = True
    """Keep a route from the lane to the goal clear for the held box and the hand (``placement.sample_route``),
    with the near-path objects beside it, so every scene can be solved. False: the near-path objects stand
    anywhere around the straight path (a superseded layout, docs/results-history.md), which walls off most
    scenes with N >= 3 for a Panda."""
    layout: str = "route"
    """How tightly the clutter hems in the route and which kinds of scene the episodes mix (``placement.LAYOUTS``):
    'route' (the default; open scenes), 'narrow' (a channel: every object beside the route, on both sides, 1 cm to
    spare), 'gate' (half the scenes semantic-only) or 'exit' (half with a fragile object past the pull lane)."""
    gate_share: float | None = None
    """Share of the episodes whose scene is a gate (semantic-only: ``placement.SCENE_KINDS``); None: the layout's."""
    exit_share: float | None = None
    """Share of the episodes whose scene is an exit probe; None: the layout's. The rest are open scenes."""
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        if isinstance(self.n_objects, numbers.Integral) and not isinstance(self.n_objects, bool):
            object.__setattr__(self, "n_objects", int(self.n_objects))
        if not isinstance(self.n_objects, int) or not 0 <= self.n_objects <= MAX_OBJECTS:
            raise SceneConfigError(f"n_objects must be an integer from 0 to {MAX_OBJECTS}, got {self.n_objects!r}")
        if self.near_path_fraction is not None and not 0.0 <= self.near_path_fraction <= 1.0:
            raise SceneConfigError(f"near_path_fraction must be in [0, 1], got {self.near_path_fraction}")
        from safemanip.scene.placement import LAYOUTS  # placement imports this module's geometry

        if self.layout not in LAYOUTS:
            raise SceneConfigError(f"layout must be one of {', '.join(LAYOUTS)}, got {self.layout!r}")
        for name in ("gate_share", "exit_share"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                                      or not 0.0 <= value <= 1.0):
                raise SceneConfigError(f"{name} must be a share from 0 to 1 (or None: the layout's own), got {value!r}")
        gate, exit_ = self.kind_shares
        if gate + exit_ > 1.0 + 1e-9:
            raise SceneConfigError(f"gate_share + exit_share must be at most 1 (the rest are open scenes), got "
                                   f"{gate} + {exit_}")
        if (gate or exit_) and not self.clear_route:
            raise SceneConfigError("gate and exit scenes are placed around a kept-clear route: drop clear_route=False")
        if not self.clear_route and self.layout != "route":
            raise SceneConfigError(f"layout {self.layout!r} keeps a route clear: drop clear_route=False (the "
                                   f"straight-corridor layout) or the layout")
        catalog = load_catalog()
        if self.names is not None:
            object.__setattr__(self, "names", tuple(self.names))
            unknown = [n for n in self.names if n not in catalog]
            if unknown:
                raise SceneConfigError(
                    f"unknown object name(s) {unknown}; pick from the catalog (`safemanip catalog` lists them)")
            if len(self.names) != self.n_objects:
                raise SceneConfigError(f"{len(self.names)} names given for n_objects={self.n_objects}: make them match")
            if len(set(self.names)) != len(self.names):
                raise SceneConfigError(f"object names must be distinct, got {list(self.names)}")
        if self.classes is not None:
            object.__setattr__(self, "classes", tuple(self.classes))
            bad = [c for c in self.classes if c not in SEMANTIC_CLASSES]
            if bad:
                raise SceneConfigError(f"unknown class(es) {bad}; use {SEMANTIC_CLASSES}")
            if len(self.classes) != self.n_objects:
                raise SceneConfigError(
                    f"{len(self.classes)} classes given for n_objects={self.n_objects}: give one class per object")
            for c in SEMANTIC_CLASSES:
                have = sum(o.semantic_class == c for o in catalog.values())
                want = self.classes.count(c)
                if want > have:
                    raise SceneConfigError(f"asked for {want} {c} objects but the catalog has only {have}")

    @property
    def kind_shares(self) -> tuple[float, float]:
        """(gate, exit) shares of the episodes: the config's, or its layout's where it says None."""
        from safemanip.scene.placement import LAYOUTS

        layout = LAYOUTS[self.layout]
        return (float(layout.gate_share if self.gate_share is None else self.gate_share),
                float(layout.exit_share if self.exit_share is None else self.exit_share))

    @property
    def near_fraction(self) -> float:
        """``near_path_fraction``, or the layout's default share when it is None."""
        if self.near_path_fraction is not None:
            return self.near_path_fraction
        from safemanip.scene.placement import LAYOUTS

        return LAYOUTS[self.layout].near_fraction if self.clear_route else 0.5
