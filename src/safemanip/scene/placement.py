"""Collision-free placement of clutter on the table, with a controllable share near the task path.

Objects are approximated by their footprint circles; the sampler rejects any overlap with other
objects, with the cereal-box stack and its pull-out region, and with the goal region (an object in
the goal would make the task impossible).
"""

from __future__ import annotations

import math
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
    # the stack, its pull-out lane to the right, and the robot's side of it (where the arm reaches in)
    stack = (sx - hx - 0.04, max(bx, geo.path_start_xy[0]) + hx + 0.04, sy - hy - 0.12, sy + hy + 0.04)
    return [stack]


def _free(x: float, y: float, r: float, placed: list[tuple[float, float, float]], geo: TaskGeometry,
          keep_out: list[tuple[float, float, float, float]]) -> bool:
    """Scalar maths on Python floats: this runs a few times per object on every reset."""
    tx, ty = geo.table_half_extents
    if abs(x) > tx - r - 0.03 or abs(y) > ty - r - 0.03:
        return False
    for xmin, xmax, ymin, ymax in keep_out:
        cx = min(max(x, xmin), xmax)
        cy = min(max(y, ymin), ymax)
        if (x - cx) ** 2 + (y - cy) ** 2 < (r + _CLEARANCE) ** 2:
            return False
    gx, gy = geo.goal_xy
    # the box resting at the goal's centre must fit: its half-diagonal, plus a margin
    goal_clear = math.hypot(geo.box_half_extents[0], geo.box_half_extents[1]) + 0.01
    if math.hypot(x - gx, y - gy) < goal_clear + r:
        return False
    for px, py, pr in placed:
        if math.hypot(x - px, y - py) < r + pr + _CLEARANCE:
            return False
    return True


def sample_placement(radii: np.ndarray, rng: np.random.Generator, near_path_fraction: float = 0.5,
                     geometry: TaskGeometry = GEOMETRY, max_tries: int = 1000) -> Placement:
    """Place objects with footprint ``radii`` without overlap.

    ``round(near_path_fraction * N)`` objects go within a corridor of half-width 0.14 m (0.30 m if crowded) around the
    segment from the pulled-out box to the goal (so the task needs avoidance), as long as it has room
    (``near_path`` says which did); the rest anywhere on the free table. Deterministic for a given
    generator state.
    """
    n = len(radii)
    if n == 0:  # draws nothing, as the general path would
        return Placement(xy=np.zeros((0, 2)), yaw=np.zeros(0), near_path=np.zeros(0, dtype=bool))
    n_near = int(round(near_path_fraction * n))
    sx, sy = (float(v) for v in geometry.path_start_xy)
    dx, dy = geometry.goal_xy[0] - sx, geometry.goal_xy[1] - sy
    length = math.sqrt(dx * dx + dy * dy)  # as np.linalg.norm, so placements stay bit-identical
    nx, ny = -dy / length, dx / length
    tx, ty = geometry.table_half_extents
    keep_out = _keep_out_rects(geometry)
    placed: list[tuple[float, float, float]] = []
    near = np.zeros(n, dtype=bool)
    order = np.argsort(-np.asarray(radii), kind="stable")  # big objects first: fewer rejections
    xy_out = np.zeros((n, 2))
    for rank, i in enumerate(order.tolist()):
        want_near = rank < n_near
        r = float(radii[i])
        # a near-path object whose corridor is full (even widened) goes anywhere free instead
        for attempt in range(2 * max_tries if want_near else max_tries):
            near_try = want_near and attempt < max_tries
            if near_try:  # widen the corridor if it is crowded
                width = 0.14 if attempt < max_tries // 4 else 0.30
                along, across = rng.uniform(0.05, 0.95), rng.uniform(-width, width)
                x, y = sx + along * dx + across * nx, sy + along * dy + across * ny
            else:
                x, y = rng.uniform(-tx, tx), rng.uniform(-ty, ty)
            if _free(x, y, r, placed, geometry, keep_out):
                break
        else:
            raise PlacementError(
                f"could not place {n} objects without overlap ({len(placed)} fitted): reduce n_objects"
                f" or choose smaller objects")
        placed.append((x, y, r))
        xy_out[i] = x, y
        near[i] = near_try
    return Placement(xy=xy_out, yaw=rng.uniform(-np.pi, np.pi, size=n), near_path=near)
