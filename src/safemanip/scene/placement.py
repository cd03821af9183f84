"""Collision-free placement of clutter on the table, with a controllable share near the task path.

Objects are approximated by their footprint circles; the sampler rejects any overlap with other
objects, with the cereal-box stack and its pull-out region, and with the goal region (an object in
the goal would make the task impossible).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from safemanip.scene.config import GEOMETRY, SceneConfigError, TaskGeometry

_CLEARANCE = 0.015  # gap between footprints so objects never start in contact


class PlacementError(SceneConfigError):
    pass


@dataclass(frozen=True)
class Placement:
    xy: np.ndarray  # (N, 2)
    yaw: np.ndarray  # (N,)
    near_path: np.ndarray  # (N,) bool


def _keep_out_rects(geo: TaskGeometry) -> list[tuple[float, float, float, float]]:
    """Axis-aligned (xmin, xmax, ymin, ymax) regions no object may overlap."""
    hx, hy, _ = geo.box_half_extents
    sx, sy = geo.stack_xy
    bx, by = geo.bottom_xy
    stack = (sx - hx - 0.04, sx + hx + 0.04, min(by, geo.path_start_xy[1]) - hy - 0.12, sy + hy + 0.04)
    return [stack]


def _free(xy, r, placed_xy, placed_r, geo: TaskGeometry) -> bool:
    tx, ty = geo.table_half_extents
    if abs(xy[0]) > tx - r - 0.03 or abs(xy[1]) > ty - r - 0.03:
        return False
    for xmin, xmax, ymin, ymax in _keep_out_rects(geo):
        cx = min(max(xy[0], xmin), xmax)
        cy = min(max(xy[1], ymin), ymax)
        if (xy[0] - cx) ** 2 + (xy[1] - cy) ** 2 < (r + _CLEARANCE) ** 2:
            return False
    gx, gy = geo.goal_xy
    goal_clear = geo.goal_radius + geo.box_half_extents[1] + 0.01
    if np.hypot(xy[0] - gx, xy[1] - gy) < goal_clear + r:
        return False
    for p, pr in zip(placed_xy, placed_r):
        if np.hypot(xy[0] - p[0], xy[1] - p[1]) < r + pr + _CLEARANCE:
            return False
    return True


def sample_placement(radii: np.ndarray, rng: np.random.Generator, near_path_fraction: float = 0.5,
                     geometry: TaskGeometry = GEOMETRY, max_tries: int = 1000) -> Placement:
    """Place objects with footprint ``radii`` without overlap.

    ``round(near_path_fraction * N)`` objects go within a corridor of half-width 0.14 m (0.25 m if crowded) around the
    segment from the pulled-out box to the goal (so the task needs avoidance); the rest anywhere on
    the free table. Deterministic for a given generator state.
    """
    n = len(radii)
    n_near = int(round(near_path_fraction * n))
    start = np.asarray(geometry.path_start_xy)
    goal = np.asarray(geometry.goal_xy)
    direction = goal - start
    normal = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
    tx, ty = geometry.table_half_extents
    placed_xy: list[np.ndarray] = []
    placed_r: list[float] = []
    near = np.zeros(n, dtype=bool)
    order = np.argsort(-np.asarray(radii), kind="stable")  # big objects first: fewer rejections
    xy_out = np.zeros((n, 2))
    for rank, i in enumerate(order):
        want_near = rank < n_near
        for attempt in range(max_tries):
            if want_near:  # widen the corridor if it is crowded rather than fail
                width = 0.14 if attempt < max_tries // 2 else 0.25
                xy = start + rng.uniform(0.2, 0.85) * direction + rng.uniform(-width, width) * normal
            else:
                xy = np.array([rng.uniform(-tx, tx), rng.uniform(-ty, ty)])
            if _free(xy, radii[i], placed_xy, placed_r, geometry):
                break
        else:
            raise PlacementError(
                f"could not place {n} objects without overlap ({len(placed_xy)} fitted"
                f"{', the near-path corridor is full' if want_near else ''}): reduce n_objects"
                f" or near_path_fraction, or choose smaller objects")
        placed_xy.append(xy)
        placed_r.append(float(radii[i]))
        xy_out[i] = xy
        near[i] = want_near
    return Placement(xy=xy_out, yaw=rng.uniform(-np.pi, np.pi, size=n), near_path=near)
