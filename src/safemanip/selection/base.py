"""The seam every relevance selector plugs into.

A *view* is what a real robot could observe at time t: object names, positions and velocities,
the past path of the end-effector and of the manipulated (bottom) box, and optionally a way to
render camera images. Ground-truth semantics are in the view too, but only selectors whose name
says ``privileged`` or ``ground-truth`` may read them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from safemanip.util.nearest import nearest_ids  # noqa: F401  (the one definition of "nearest")


@dataclass
class SceneView:
    t: int
    """Control step (0 at reset)."""
    names: tuple[str, ...]
    """Clutter object names; the index in this tuple is the object id."""
    positions: np.ndarray
    """(N, 3) object centres in the world frame [m]."""
    velocities: np.ndarray
    """(N, 3) object linear velocities [m/s]."""
    ee_path: np.ndarray
    """(T, 3) end-effector positions from reset up to and including now."""
    box_path: np.ndarray
    """(T, 3) manipulated-box centre positions from reset up to and including now."""
    box_velocity: np.ndarray
    """(3,) manipulated-box linear velocity now [m/s]."""
    privileged_classes: tuple[str, ...] | None = None
    """Ground-truth semantic class per object (fragile/soft/durable). Privileged selectors only."""
    render: Callable[[], dict] | None = field(default=None, repr=False)
    """Optional: returns {"image": HxWx3 uint8, "boxes": {id: (x0, y0, x1, y1)}, "ee_path_px": (T, 2)} for the
    query camera (pixel boxes of the clutter objects and the end-effector path projected into the image).
    Built lazily by ``selection.view.EnvViewBuilder``: nothing is rendered unless a selector calls it."""

    @property
    def ee_position(self) -> np.ndarray:
        return self.ee_path[-1]

    @property
    def box_position(self) -> np.ndarray:
        return self.box_path[-1]


class ObjectSelector(Protocol):
    """Picks the k relevant clutter objects; called every control step, re-picks when it decides to."""

    name: str

    def reset(self, view: SceneView, k: int) -> None: ...

    def select(self, view: SceneView, k: int) -> list[int]:
        """Object ids of the k relevant objects (fewer only if the scene has fewer)."""
        ...


class ConstraintSelector(Protocol):
    """Assigns a constraint type (no_contact / soft_contact / any_contact) to every object in the scene."""

    name: str

    def assign(self, view: SceneView) -> list[str]: ...


@dataclass
class SelectorStats:
    """Counters a selector reports into evaluation results (e.g. VLM fallbacks)."""

    queries: int = 0
    fallbacks: int = 0
    latencies_s: list[float] = field(default_factory=list)

    def as_dict(self) -> dict:
        lat = np.asarray(self.latencies_s) if self.latencies_s else np.zeros(1)
        return {"queries": self.queries, "fallbacks": self.fallbacks,
                "latency_median_s": float(np.median(lat)), "latency_p95_s": float(np.percentile(lat, 95))}
