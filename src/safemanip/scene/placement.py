"""Collision-free placement of clutter on the table, with a controllable share near the task path.

Objects are approximated by their footprint circles; the sampler rejects any overlap with other
objects, with the cereal-box stack and its pull-out region, and with the goal region (an object in
the goal would make the task impossible).

With a ``Route`` (``sample_route``), the near-path objects stand just beside a bent way from the lane to
the goal that is kept clear for the held box and the hand, and no object may stand on it: the scene needs
avoidance but always leaves a way. Without one, objects stand anywhere in a corridor around the straight
path, which on a Panda's table walls off most scenes with three or more objects (the arm cannot hold the
box far enough aside to go round them; ``benchmarks/scene_feasibility.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from safemanip.scene.config import GEOMETRY, SceneConfigError, TaskGeometry

_CLEARANCE = 0.015  # gap between footprints so objects never start in contact

ROUTE_BEND = (-0.15, -0.06, 0.06, 0.12)
"""The route's sideways bend [m]: its waypoint sits off the straight path from the lane to the goal by a
uniform draw from [-0.15, -0.06] or [0.06, 0.12] (+: away from the robot; each side equally likely). The
outer bounds keep the held box where a Panda at its base can hold it (``scene.panda.holding_reach``): further
towards the robot the base is in the way, further away it is out of reach. The inner ones make the route
bend enough that objects inside the bend stand on the straight path."""
ROUTE_HAND_OVERHANG = 0.03
"""How far the Panda's hand and fingers stick out past the held box's pulled edge (+x) [m]."""
ROUTE_CLEARANCE = 0.02
"""Room kept around the held box and hand along the route [m] in the 'route' layout: the collision threshold d4
(1 cm) and 1 cm more, so a controller that follows the route is not judged to collide."""
NEAR_ROUTE_GAP = 0.06
"""A near-path object stands at most this far outside the route's kept-clear band [m] (0.30 if crowded)."""
NEAR_ROUTE_SPAN = (0.25, 0.75)
"""Where along the route (fractions of its length) near-path objects stand: around the bend, where the route
leaves the straight path."""
INNER_SHARE = 0.9
"""Share of near-path objects on the inside of the route's bend, where the straight path runs: those make a
controller that heads straight for the goal hit something, so the bend has to be followed."""


SCENE_KINDS = ("open", "gate", "exit")
"""What an episode's scene asks of a policy (recorded per episode as ``info["scene_kind"]``):

* ``open``: the route is clear; avoiding every object is enough (every scene of ``route`` and ``narrow``).
* ``gate``: semantic-only. One or two objects that may be touched (not ``no_contact``) stand on the route and
  fragile ones beside them, so that the scene is closed to a policy that avoids everything and open to one that
  avoids only the fragile objects (the env checks both with the planner's free-space map).
* ``exit``: one fragile object stands 0-8 cm past the end of the pull lane, so the fast pull that leaves the top
  box in place has to stop or turn right after the box comes out (the env checks the scene open).
"""


@dataclass(frozen=True)
class GateLayout:
    """Where a gate scene's objects stand (``SCENE_KINDS``)."""

    blockers: tuple[int, int] = (1, 2)
    """How many touchable objects stand on the route (drawn uniformly, at most as many as the scene has)."""
    along: tuple[float, float] = (0.3, 0.7)
    """Where along the route they stand (fractions of its length)."""
    off_centre: float = 0.04
    """How far off the route's centre line they may stand [m]."""
    flank_gap: float = 0.06
    """The fragile objects stand at most this far outside the route's band [m], beside the blockers ..."""
    flank_span: float = 0.12
    """... and at most this far along the route from a blocker [m]."""


@dataclass(frozen=True)
class ExitLayout:
    """Where an exit scene's probe stands (``SCENE_KINDS``)."""

    gap: tuple[float, float] = (0.10,0.20)
    """How far past the end of the pull lane its near edge stands [m], beyond d4: past the held box's right edge
    at the moment it has come out from under the top box (``TaskGeometry.path_start_xy``)."""
    across: float = 0.5
    """How far from the lane's centre line it stands, as a share of the box's half depth (13.5 cm)."""


@dataclass(frozen=True)
class RouteLayout:
    """How tightly the clutter hems in the kept-clear route, and which kinds of scene a layout mixes. The open
    scenes of every layout leave the route open; they differ in how much room it has and how close the objects
    stand."""

    clearance: float
    """Room around the held box and hand along the route [m] (``Route.half_extents``)."""
    near_gap: float
    """A near-path object stands at most this far outside the route's band [m] (0.30 if crowded)."""
    inner_share: float
    """Share of near-path objects inside the bend (the rest stand on its outside)."""
    near_fraction: float
    """Share of the clutter beside the route when the scene config does not say (``near_path_fraction``)."""
    gate_share: float = 0.0
    """Share of the episodes whose scene is a gate (``SCENE_KINDS``), when the scene config does not say."""
    exit_share: float = 0.0
    """Share of the episodes whose scene is an exit probe, when the scene config does not say; the rest are open."""
    gate: GateLayout = GateLayout()
    exit: ExitLayout = ExitLayout()


_ROUTE = dict(clearance=ROUTE_CLEARANCE, near_gap=NEAR_ROUTE_GAP, inner_share=INNER_SHARE, near_fraction=0.5)
LAYOUTS = {
    # half the clutter just beside the route, nearly all of it inside the bend: cutting the corner collides
    "route": RouteLayout(**_ROUTE),
    # a channel: all the clutter 0-2 cm outside a band with only d4 (1 cm) to spare, on both sides of it, so
    # the held box must follow the bend to within a few centimetres all the way
    "narrow": RouteLayout(clearance=0.01, near_gap=0.02, inner_share=0.5, near_fraction=1.0),
    # half the scenes semantic-only: what only a policy that tells touchable objects from fragile ones can solve
    # (the paper's Tables I and II)
    "gate": RouteLayout(**_ROUTE, gate_share=0.5),
    # half the scenes with a fragile object just past the pull lane: speed for the top box against stopping
    # distance (the paper's Fig. 4, its dynamic interaction)
    "exit": RouteLayout(**_ROUTE, exit_share=0.5),
}
"""The layouts by name (``SceneConfig.layout``; ``clear_route=False`` is the straight-corridor one)."""


class PlacementError(SceneConfigError):
    pass


@dataclass(frozen=True)
class Route:
    """A way for the held box's centre from the lane to the goal: two straight legs through a waypoint. A band
    around it (``half_extents`` around every point, the box and hand plus the layout's clearance) stays clear."""

    points: np.ndarray  # (M, 2) the box centre every ~2 cm along the way
    half_extents: tuple[float, float]  # of the axis-aligned rectangle kept clear around each point
    waypoint: tuple[float, float]
    bend: float  # the waypoint's offset from the straight path [m], + away from the robot
    layout: RouteLayout = LAYOUTS["route"]  # how close the near-path objects stand beside it


@dataclass(frozen=True)
class Placement:
    xy: np.ndarray  # (N, 2)
    yaw: np.ndarray  # (N,)
    near_path: np.ndarray  # (N,) bool
    route: Route | None = None
    kind: str = "open"  # ``SCENE_KINDS``
    roles: tuple[str, ...] = ()  # per object in gate and exit scenes: "blocker", "flank", "probe" or ""


def sample_route(rng: np.random.Generator, geometry: TaskGeometry = GEOMETRY, spacing: float = 0.02,
                 layout: RouteLayout = LAYOUTS["route"]) -> Route:
    """A route bent sideways by ``ROUTE_BEND`` at a uniform point 35–65 % of the way (two draws from ``rng``),
    its band ``layout.clearance`` wider than the held box and hand."""
    start, goal = np.asarray(geometry.path_start_xy, float), np.asarray(geometry.goal_xy, float)
    along, side = rng.uniform(0.35, 0.65), rng.uniform(-1.0, 1.0)
    far_neg, near_neg, near_pos, far_pos = ROUTE_BEND
    bend = near_neg - side * (far_neg - near_neg) if side < 0 else near_pos + side * (far_pos - near_pos)
    direction = goal - start
    normal = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
    waypoint = start + along * direction + bend * normal
    legs = []
    for a, b in ((start, waypoint), (waypoint, goal)):
        count = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing)) + 1)
        legs.append(a + np.linspace(0.0, 1.0, count)[:, None] * (b - a))
    hx, hy, _ = geometry.box_half_extents
    half = (hx + ROUTE_HAND_OVERHANG + layout.clearance, hy + layout.clearance)
    return Route(points=np.concatenate([legs[0], legs[1][1:]]), half_extents=half,
                 waypoint=(float(waypoint[0]), float(waypoint[1])), bend=float(bend), layout=layout)


def _route_frame(route: Route) -> tuple:
    """The route's segments once per placement: (points, steps, lengths, cumulative lengths, unit normals)."""
    steps = np.diff(route.points, axis=0)
    seg_len = np.linalg.norm(steps, axis=1)
    normals = np.stack([-steps[:, 1], steps[:, 0]], axis=1) / seg_len[:, None]
    return route.points, steps, seg_len, np.concatenate([[0.0], np.cumsum(seg_len)]), normals


def _beside_route(route: Route, frame: tuple, r: float, gap: float):
    """Map two uniform draws per try to a point just outside the route's band: the first picks where along the
    way (``NEAR_ROUTE_SPAN``), the second the side (the inside of the bend with the layout's ``inner_share``)
    and how far out (uniform, up to ``gap`` beyond the band's edge)."""
    points, steps, seg_len, cum, normals = frame
    hx, hy = route.half_extents
    inner_sign = 1.0 if route.bend >= 0 else -1.0
    inner_share = route.layout.inner_share

    def to_xy(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = (NEAR_ROUTE_SPAN[0] + (NEAR_ROUTE_SPAN[1] - NEAR_ROUTE_SPAN[0]) * u[:, 0]) * cum[-1]
        seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(steps) - 1)
        base = points[seg] + ((s - cum[seg]) / seg_len[seg])[:, None] * steps[seg]
        n = normals[seg]
        inner = u[:, 1] < inner_share
        beyond = np.where(inner, u[:, 1] / inner_share, (u[:, 1] - inner_share) / (1.0 - inner_share)) * gap
        # the band's half-width across the way (the kept rectangle's support along the normal), the object's
        # radius and clearance, then 0 to ``gap`` more; the straight path lies on the -normal side of both legs
        # when the route bends to +normal
        out = np.abs(n[:, 0]) * hx + np.abs(n[:, 1]) * hy + r + _CLEARANCE + 1e-6 + beyond
        offset = np.where(inner, -inner_sign, inner_sign) * out
        return base[:, 0] + offset * n[:, 0], base[:, 1] + offset * n[:, 1]
    return to_xy


def _keep_out_rects(geo: TaskGeometry) -> list[tuple[float, float, float, float]]:
    """Axis-aligned (xmin, xmax, ymin, ymax) regions no object may overlap."""
    hx, hy, _ = geo.box_half_extents
    sx, sy = geo.stack_xy
    bx, by = geo.bottom_xy
    # the stack, its pull-out lane to the right, and the robot's side of it (where the arm reaches in)
    stack = (sx - hx - 0.04, max(bx, geo.path_start_xy[0]) + hx + 0.04, sy - hy - 0.12, sy + hy + 0.04)
    return [stack]


def _free(x: float, y: float, r: float, placed: list[tuple[float, float, float]], geo: TaskGeometry,
          keep_out: list[tuple[float, float, float, float]], route: Route | None = None) -> bool:
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
    if route is not None:
        return bool(_route_gap_squared(np.array([x]), np.array([y]), route)[0] >= (r + _CLEARANCE) ** 2)
    return True


def _route_gap_squared(xs: np.ndarray, ys: np.ndarray, route: Route) -> np.ndarray:
    """Squared distance from each point to the route's kept-clear band (the union of its rectangles)."""
    hx, hy = route.half_extents
    ex = np.maximum(np.abs(xs[:, None] - route.points[:, 0]) - hx, 0.0)
    ey = np.maximum(np.abs(ys[:, None] - route.points[:, 1]) - hy, 0.0)
    return (ex * ex + ey * ey).min(axis=1)


def sample_placement(radii: np.ndarray, rng: np.random.Generator, near_path_fraction: float = 0.5,
                     geometry: TaskGeometry = GEOMETRY, max_tries: int = 1000, route: Route | None = None,
                     kind: str = "open", fragile: np.ndarray | None = None) -> Placement:
    """Place objects with footprint ``radii`` without overlap.

    ``round(near_path_fraction * N)`` objects go near the task path, as long as it has room (``near_path`` says
    which did); the rest anywhere on the free table. Without a ``route``, near means within a corridor of
    half-width 0.14 m (0.30 m if crowded) around the segment from the pulled-out box to the goal. With one,
    near means at most the route layout's ``near_gap`` (0.30 m if crowded) outside the route's band, and no object stands
    on the band. Deterministic for a given generator state.

    ``kind`` (which needs a route) first places the objects that have a role in it (``SCENE_KINDS``): in a
    ``gate``, 1-2 of the objects that are not ``fragile`` stand on the route and the fragile ones beside them; in
    an ``exit``, one fragile object stands past the pull lane. The rest are placed as in an open scene. A scene
    that lacks what its kind needs (a gate without a touchable object, an exit without a fragile one) is placed
    as an open one and says so (``Placement.kind``).
    """
    n = len(radii)
    if n == 0:  # draws nothing, as the general path would
        return Placement(xy=np.zeros((0, 2)), yaw=np.zeros(0), near_path=np.zeros(0, dtype=bool), route=route)
    if kind not in SCENE_KINDS:
        raise PlacementError(f"unknown scene kind {kind!r}: use one of {SCENE_KINDS}")
    if kind != "open":
        if route is None:
            raise PlacementError(f"a {kind} scene is placed around a route: keep clear_route on")
        return _place_by_roles(np.asarray(radii, dtype=float), rng, near_path_fraction, geometry, max_tries, route,
                               kind, np.ones(n, dtype=bool) if fragile is None else np.asarray(fragile, dtype=bool))
    return _place_open(radii, rng, near_path_fraction, geometry, max_tries, route)


def _place_open(radii: np.ndarray, rng: np.random.Generator, near_path_fraction: float, geometry: TaskGeometry,
                max_tries: int, route: Route | None, placed: list[tuple[float, float, float]] | None = None,
                skip: frozenset[int] = frozenset()) -> Placement:
    """An open scene's placement (``sample_placement``); the objects in ``skip`` already stand in ``placed``."""
    n = len(radii)
    n_near = int(round(near_path_fraction * (n - len(skip))))
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

    frame = _route_frame(route) if route is not None else None
    placed = [] if placed is None else placed
    near = np.zeros(n, dtype=bool)
    order = [i for i in np.argsort(-np.asarray(radii), kind="stable").tolist() if i not in skip]  # big first
    xy_out = np.zeros((n, 2))
    for rank, i in enumerate(order):
        want_near = rank < n_near
        r = float(radii[i])
        # tries in the corridor (widened if it is crowded), then anywhere free if it is full even so
        if route is None:
            close, crowded = corridor(0.14), corridor(0.30)
        else:
            close, crowded = (_beside_route(route, frame, r, route.layout.near_gap),
                             _beside_route(route, frame, r, 0.30))
        phases = [(max_tries // 4, close), (max_tries - max_tries // 4, crowded),
                  (max_tries, anywhere)] if want_near else [(max_tries, anywhere)]
        found = None
        for tries, to_xy in phases:
            found = _first_free(rng, tries, r, placed, geometry, keep_out, to_xy, route)
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
    return Placement(xy=xy_out, yaw=rng.uniform(-np.pi, np.pi, size=n), near_path=near, route=route)


EXIT_CLEARANCE = 0.01
"""An exit probe's near edge stands at least this far past the lane [m]: d4, so that a box that stops right at
the end of the lane is not yet judged to touch it."""


def _place_by_roles(radii: np.ndarray, rng: np.random.Generator, near_path_fraction: float, geometry: TaskGeometry,
                    max_tries: int, route: Route, kind: str, fragile: np.ndarray) -> Placement:
    """A gate or exit scene (``sample_placement``): the objects with a role first, then the rest as in an open one."""
    n = len(radii)
    layout = route.layout
    roles = [""] * n
    placed: list[tuple[float, float, float]] = []
    at: dict[int, tuple[float, float]] = {}
    keep_out = _keep_out_rects(geometry)
    touchable, breakable = np.flatnonzero(~fragile).tolist(), np.flatnonzero(fragile).tolist()
    if kind == "gate" and touchable:
        gate = layout.gate
        count = min(int(rng.integers(gate.blockers[0], gate.blockers[1] + 1)), len(touchable))
        frame = _route_frame(route)
        for i in [touchable[j] for j in rng.permutation(len(touchable))[:count].tolist()]:
            # on the route's centre line, where it runs between its ends: the band itself is no obstacle here
            found = _first_free(rng, max_tries, float(radii[i]), placed, geometry, keep_out,
                                _on_route(frame, gate.along, gate.off_centre))
            if found is not None:
                at[i] = found
                placed.append((*found, float(radii[i])))
                roles[i] = "blocker"
        anchors = list(at.values())
        for i in breakable if anchors else []:  # beside the band, either side, close to a blocker
            found = _first_free(rng, max_tries, float(radii[i]), placed, geometry, keep_out,
                                _beside_anchor(route, frame, float(radii[i]), gate.flank_gap, gate.flank_span,
                                               anchors), route)
            if found is not None:
                at[i] = found
                placed.append((*found, float(radii[i])))
                roles[i] = "flank"
    elif kind == "exit" and breakable:
        probe = layout.exit
        i = breakable[int(rng.integers(len(breakable)))]
        r = float(radii[i])
        hx, hy, _ = geometry.box_half_extents
        lane_end = geometry.path_start_xy[0] + hx  # the held box's right edge as it comes out
        u = rng.random(2)
        x = lane_end + EXIT_CLEARANCE + r + probe.gap[0] + (probe.gap[1] - probe.gap[0]) * float(u[0])
        y = geometry.path_start_xy[1] + (2 * float(u[1]) - 1) * probe.across * hy
        at[i] = (x, y)
        placed.append((x, y, r))
        roles[i] = "probe"
    if not at:  # the scene lacks what its kind needs: an open one
        return _place_open(radii, rng, near_path_fraction, geometry, max_tries, route)
    rest = _place_open(radii, rng, near_path_fraction, geometry, max_tries, route, placed, frozenset(at))
    xy, near = rest.xy.copy(), rest.near_path.copy()
    for i, point in at.items():
        xy[i], near[i] = point, True
    return Placement(xy=xy, yaw=rest.yaw, near_path=near, route=route, kind=kind, roles=tuple(roles))


def _on_route(frame: tuple, along: tuple[float, float], off_centre: float):
    """Map two uniform draws to a point on the route's centre line between ``along`` (fractions of its length),
    up to ``off_centre`` to either side."""
    points, steps, seg_len, cum, normals = frame

    def to_xy(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = (along[0] + (along[1] - along[0]) * u[:, 0]) * cum[-1]
        seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(steps) - 1)
        base = points[seg] + ((s - cum[seg]) / seg_len[seg])[:, None] * steps[seg]
        offset = (2 * u[:, 1] - 1) * off_centre
        return base[:, 0] + offset * normals[seg, 0], base[:, 1] + offset * normals[seg, 1]
    return to_xy


def _beside_anchor(route: Route, frame: tuple, r: float, gap: float, span: float, anchors: list[tuple[float, float]]):
    """Map two uniform draws to a point just outside the route's band (up to ``gap`` beyond its edge, either
    side), at most ``span`` along the route from one of the ``anchors`` (which one: the first draw)."""
    points, steps, seg_len, cum, normals = frame
    hx, hy = route.half_extents
    # how far along the route each anchor stands: at its nearest route point
    anchor_s = np.array([cum[int(np.argmin(np.hypot(points[:, 0] - ax, points[:, 1] - ay)))] for ax, ay in anchors])

    def to_xy(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scaled = u[:, 0] * len(anchors)
        pick = np.minimum(scaled.astype(int), len(anchors) - 1)
        s = np.clip(anchor_s[pick] + (2 * (scaled - pick) - 1) * span, 0.0, cum[-1])
        seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(steps) - 1)
        base = points[seg] + ((s - cum[seg]) / seg_len[seg])[:, None] * steps[seg]
        n = normals[seg]
        left = u[:, 1] < 0.5
        side = np.where(left, -1.0, 1.0)
        beyond = np.where(left, 2 * u[:, 1], 2 * u[:, 1] - 1) * gap
        out = np.abs(n[:, 0]) * hx + np.abs(n[:, 1]) * hy + r + _CLEARANCE + 1e-6 + beyond
        return base[:, 0] + side * out * n[:, 0], base[:, 1] + side * out * n[:, 1]
    return to_xy


def _first_free(rng: np.random.Generator, tries: int, r: float, placed: list[tuple[float, float, float]],
                geo: TaskGeometry, keep_out: list, to_xy, route: Route | None = None) -> tuple[float, float] | None:
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
        candidates = range(batch) if done == 0 else np.flatnonzero(_maybe_free(xs, ys, r, placed, geo, keep_out, route))
        xl, yl = xs.tolist(), ys.tolist()
        for j in candidates:
            x, y = xl[j], yl[j]
            if _free(x, y, r, placed, geo, keep_out, route):
                rng.bit_generator.state = state
                rng.random(2 * (j + 1))
                return x, y
        done += batch
    return None


def _maybe_free(xs: np.ndarray, ys: np.ndarray, r: float, placed: list[tuple[float, float, float]],
                geo: TaskGeometry, keep_out: list, route: Route | None = None, slack: float = 1e-9) -> np.ndarray:
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
    if route is not None:
        ok &= _route_gap_squared(xs, ys, route) >= (r + _CLEARANCE - slack) ** 2
    return ok
