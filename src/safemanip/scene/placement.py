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
    # two uniform draws u per try, mapped as rng.uniform(low, high) maps them (low + (high - low) * u, bit
    # for bit), so the placements are those of drawing one try at a time
    def corridor(width: float):
        def to_xy(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            along, across = 0.05 + (0.95 - 0.05) * u[:, 0], -width + (width - -width) * u[:, 1]
            return sx + along * dx + across * nx, sy + along * dy + across * ny
        return to_xy

    def anywhere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return -tx + (tx - -tx) * u[:, 0], -ty + (ty - -ty) * u[:, 1]

    placed: list[tuple[float, float, float]] = []
    near = np.zeros(n, dtype=bool)
    order = np.argsort(-np.asarray(radii), kind="stable")  # big objects first: fewer rejections
    xy_out = np.zeros((n, 2))
    for rank, i in enumerate(order.tolist()):
        want_near = rank < n_near
        r = float(radii[i])
        # tries in the corridor (widened if it is crowded), then anywhere free if it is full even so
        phases = [(max_tries // 4, corridor(0.14)), (max_tries - max_tries // 4, corridor(0.30)),
                  (max_tries, anywhere)] if want_near else [(max_tries, anywhere)]
        found = None
        for tries, to_xy in phases:
            found = _first_free(rng, tries, r, placed, geometry, keep_out, to_xy)
            if found is not None:
                near_try = to_xy is not anywhere
                break
        if found is None:
            raise PlacementError(
                f"could not place {n} objects without overlap ({len(placed)} fitted): reduce n_objects"
                f" or choose smaller objects")
        x, y = found
        placed.append((x, y, r))
        xy_out[i] = x, y
        near[i] = near_try
    return Placement(xy=xy_out, yaw=rng.uniform(-np.pi, np.pi, size=n), near_path=near)


def _first_free(rng: np.random.Generator, tries: int, r: float, placed: list[tuple[float, float, float]],
                geo: TaskGeometry, keep_out: list, to_xy) -> tuple[float, float] | None:
    """The first of up to ``tries`` candidates (two uniform draws each, mapped to x, y by ``to_xy``)
    that ``_free`` accepts, consuming exactly the draws a one-at-a-time loop would: the same placements
    for the same generator state, several times faster.

    Candidates are drawn in batches; after the first (small) one, a batch is screened with array maths that
    only rejects what is clearly taken (a slack of 1e-9 m), and the survivors are confirmed in order by
    ``_free``, the one rule. Only the
    batch that holds the winner is partly used, so its draws are rewound and the used ones re-drawn.
    """
    done = 0
    while done < tries:
        batch = min(tries - done, 16 if done == 0 else 128)  # most objects fit within a few tries
        state = rng.bit_generator.state
        u = rng.random(2 * batch).reshape(batch, 2)  # (first, second) draw of each try, in draw order
        xs, ys = to_xy(u)
        # a first small batch is checked directly (the winner is usually among its first tries, and
        # NumPy's per-call overhead would cost more); later, crowded batches are screened first
        candidates = range(batch) if done == 0 else np.flatnonzero(_maybe_free(xs, ys, r, placed, geo, keep_out))
        xl, yl = xs.tolist(), ys.tolist()
        for j in candidates:
            x, y = xl[j], yl[j]
            if _free(x, y, r, placed, geo, keep_out):
                rng.bit_generator.state = state
                rng.random(2 * (j + 1))
                return x, y
        done += batch
    return None


def _maybe_free(xs: np.ndarray, ys: np.ndarray, r: float, placed: list[tuple[float, float, float]],
                geo: TaskGeometry, keep_out: list, slack: float = 1e-9) -> np.ndarray:
    """``_free``'s tests on arrays, each loosened by ``slack`` (m): a superset of what ``_free`` accepts.
    Few, broadcast operations: on a batch of 16 tries NumPy's per-call overhead is the cost."""
    tx, ty = geo.table_half_extents
    ok = (np.abs(xs) <= tx - r - 0.03 + slack) & (np.abs(ys) <= ty - r - 0.03 + slack)
    for xmin, xmax, ymin, ymax in keep_out:
        ex, ey = xs - np.minimum(np.maximum(xs, xmin), xmax), ys - np.minimum(np.maximum(ys, ymin), ymax)
        ok &= ex * ex + ey * ey >= (r + _CLEARANCE - slack) ** 2
    gx, gy = geo.goal_xy
    goal_clear = math.hypot(geo.box_half_extents[0], geo.box_half_extents[1]) + 0.01
    # circles to stay out of: the goal's, then every placed object's (centre x, y, keep-out distance)
    circles = np.array([(gx, gy, goal_clear + r)] + [(px, py, r + pr + _CLEARANCE) for px, py, pr in placed])
    ex, ey = xs[:, None] - circles[:, 0], ys[:, None] - circles[:, 1]
    ok &= (ex * ex + ey * ey >= (circles[:, 2] - slack) ** 2).all(axis=1)
    return ok
