"""The object catalog: everyday tabletop objects as MuJoCo primitives, loaded from ``objects.json``.

The catalog is data, not code: add an object by adding an entry to the JSON file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import mujoco
import numpy as np

SEMANTIC_CLASSES = ("fragile", "soft", "durable")
CONSTRAINT_TYPES = ("no_contact", "soft_contact", "any_contact")
CONSTRAINT_OF_CLASS = {"fragile": "no_contact", "soft": "soft_contact", "durable": "any_contact"}
_PRIMITIVES = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1}


@dataclass(frozen=True)
class Part:
    """One primitive of an object's shape, posed relative to the object's base centre."""

    type: str
    size: tuple[float, ...]
    pos: tuple[float, float, float]
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CatalogObject:
    name: str
    semantic_class: str
    mass: float
    rgba: tuple[float, float, float, float]
    parts: tuple[Part, ...]

    @property
    def constraint(self) -> str:
        """Ground-truth constraint type implied by the semantic class."""
        return CONSTRAINT_OF_CLASS[self.semantic_class]

    @property
    def footprint_radius(self) -> float:
        """Radius of a vertical cylinder around the base centre that contains every part (xy only)."""
        radius = 0.0
        for part in self.parts:
            reach = _part_horizontal_reach(part)
            radius = max(radius, (part.pos[0] ** 2 + part.pos[1] ** 2) ** 0.5 + reach)
        return radius

    @property
    def footprint_rect(self) -> tuple[float, float, float, float]:
        """The rectangle, in the object's own frame, that contains every part seen from above: (centre x, centre y,
        half x, half y) [m], what a perception system's oriented bounding box reports. Each part is bounded by the box
        around it (a cylinder by its square), posed with its euler angles; the object is inside this rectangle and
        inside the ``footprint_radius`` circle, so a distance to either is never more than the distance to it."""
        corners = np.concatenate([_part_corners(part) for part in self.parts])
        lo, hi = corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        return float(centre[0]), float(centre[1]), float(half[0]), float(half[1])

    @property
    def height(self) -> float:
        return max(p.pos[2] + _part_vertical_reach(p) for p in self.parts)


def _part_horizontal_reach(part: Part) -> float:
    s = part.size
    if part.type == "box":
        return (s[0] ** 2 + s[1] ** 2 + (s[2] ** 2 if any(part.euler) else 0.0)) ** 0.5
    if part.type in ("cylinder", "capsule"):
        return s[0] + (s[1] if any(part.euler) else 0.0)
    return s[0]


def _part_corners(part: Part) -> np.ndarray:
    """The 8 corners (8, 3) of the box around ``part`` in the object's frame: its half sizes (a cylinder's radius,
    radius, half length; a capsule's half length plus its caps), turned by its euler angles (MuJoCo's default
    intrinsic x-y-z sequence, as the scene builder passes them) and moved to its position."""
    s = part.size
    if part.type == "box":
        half = s
    elif part.type == "sphere":
        half = (s[0], s[0], s[0])
    else:  # cylinder, capsule (its caps add a radius to each end)
        half = (s[0], s[0], s[1] + (s[0] if part.type == "capsule" else 0.0))
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    quat, rot = np.zeros(4), np.zeros(9)
    mujoco.mju_euler2Quat(quat, np.asarray(part.euler, dtype=float), "xyz")
    mujoco.mju_quat2Mat(rot, quat)
    return (signs * np.asarray(half, dtype=float)) @ rot.reshape(3, 3).T + np.asarray(part.pos, dtype=float)


def _part_vertical_reach(part: Part) -> float:
    s = part.size
    if part.type == "box":
        return max(s) if any(part.euler) else s[2]
    if part.type == "cylinder":
        return max(s) if any(part.euler) else s[1]
    if part.type == "capsule":
        return s[0] + (0.0 if any(part.euler) else s[1])
    return s[0]


class CatalogError(ValueError):
    pass


def _parse(raw: dict) -> dict[str, CatalogObject]:
    objects: dict[str, CatalogObject] = {}
    for i, entry in enumerate(raw.get("objects", [])):
        where = f"catalog entry {i} ({entry.get('name', '?')!r})"
        if entry.get("class") not in SEMANTIC_CLASSES:
            raise CatalogError(f"{where}: class must be one of {SEMANTIC_CLASSES}, got {entry.get('class')!r}")
        parts = []
        for part in entry["parts"]:
            n = _PRIMITIVES.get(part["type"])
            if n is None or len(part["size"]) != n:
                raise CatalogError(f"{where}: part {part} needs a type in {list(_PRIMITIVES)} with that many sizes")
            parts.append(Part(part["type"], tuple(part["size"]), tuple(part["pos"]), tuple(part.get("euler", (0, 0, 0)))))
        name = entry["name"]
        if name in objects:
            raise CatalogError(f"{where}: duplicate name")
        objects[name] = CatalogObject(name, entry["class"], float(entry["mass"]), tuple(entry["rgba"]), tuple(parts))
    return objects


@lru_cache(maxsize=1)
def load_catalog() -> dict[str, CatalogObject]:
    """All catalog objects by name (cached; the file ships inside the package)."""
    text = resources.files("safemanip.scene").joinpath("objects.json").read_text()
    return _parse(json.loads(text))


def names_of_class(semantic_class: str) -> list[str]:
    return sorted(n for n, o in load_catalog().items() if o.semantic_class == semantic_class)
