"""A privileged planner: the fast pull, then a path through the clutter's free space to the goal.

It sees the whole scene (every object's shape and pose, not the k slots a policy sees), so it is a
reference, not a method of the paper: it says what the task allows within the arm's limits, and its
episodes measure each benchmark cell's bound (``safemanip eval --planner``).

Free space is the held box centre's, on a 1 cm grid over the table: a grid point is free if the box,
translating at its fixed orientation (the controller holds the hand's), keeps every object part that
reaches below the box's top more than d4 + ``clearance`` away, and stays clear of the top box. From the
goal region a geodesic distance field is spread over the free points (8-connected). Each control step
the box heads for the point a few centimetres down that field, at a speed that lets it brake to rest
in the goal; close to the goal it approaches exponentially and settles. It ignores the arm's links
above the box; the env still judges them.

The pull goes straight out of the lane (heading aside slows the arm and drags the top box along) and brakes in
time for whatever stands straight ahead of it, as an exit scene asks. ``avoid="fragile"`` maps only the objects the
episode's constraints make ``no_contact`` and drives through the others, slowly through soft ones: the bound of a
policy that knows which objects it may touch. Where its map is walled off the planner stays put (a timeout).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from safemanip.scene.panda import holding_reach

GRID = 0.01
"""Grid spacing of the planner's free-space map [m] (``scene_feasibility.py``'s box-alone test uses 5 mm)."""

PLANNER_AVOID = ("all", "fragile")
"""What the planner keeps clear of: every object, or only those the episode's constraints make ``no_contact``
(it drives through the others, soft ones at the planned speeds of at most 0.8 m/s)."""

_NEIGHBOURS = [(dx, dy, math.hypot(dx, dy)) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]


def part_extents(env, objects=None) -> list[tuple[float, float, float, float, float]]:
    """Vertical cylinders (x, y, radius, z low, z high) covering every object geom at its current pose (of the
    objects with the ids ``objects`` only, if given).

    A round part is one cylinder. An elongated footprint (an upright box longer than wide, a cylinder or
    capsule lying down) is a row of cylinders along its long axis, each covering a slice no longer than
    half its width: a single circle around a smartphone would be twice as wide as the phone.
    """
    m, d, idx = env.model, env.data, env.index
    parts = []
    ids = range(len(idx.object_bodies)) if objects is None else objects
    bodies = set(int(idx.object_bodies[i]) for i in ids)
    for g in range(m.ngeom):
        if int(m.geom_bodyid[g]) not in bodies:
            continue
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        rotation = d.geom_xmat[g].reshape(3, 3)
        upright = abs(rotation[2, 2]) > 0.999  # the geom's own z axis is vertical
        x, y, z = d.geom_xpos[g]
        if kind == mujoco.mjtGeom.mjGEOM_SPHERE or (kind in (mujoco.mjtGeom.mjGEOM_CYLINDER,
                                                            mujoco.mjtGeom.mjGEOM_CAPSULE) and upright):
            cap = size[0] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            half_height = size[0] if kind == mujoco.mjtGeom.mjGEOM_SPHERE else size[1] + cap
            parts.append((float(x), float(y), float(size[0]), float(z - half_height), float(z + half_height)))
            continue
        if kind in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE):  # lying along its own z
            cap = size[0] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            half_long, half_wide, axis = size[1] + cap, size[0], rotation[:2, 2]
            half_height = size[0] + abs(rotation[2, 2]) * (size[1] + cap)
        elif kind == mujoco.mjtGeom.mjGEOM_BOX and upright:
            long_side = 0 if size[0] >= size[1] else 1
            half_long, half_wide, axis = size[long_side], size[1 - long_side], rotation[:2, long_side]
            half_height = size[2]
        else:  # a tilted box, or a shape the catalog does not use: the bounding sphere
            radius = float(m.geom_rbound[g])
            parts.append((float(x), float(y), radius, float(z - radius), float(z + radius)))
            continue
        axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
        # cut the footprint into ``count`` pieces at most half_wide long along the axis; each piece (spacing by
        # 2 * half_wide) lies in the circle of radius hypot(spacing / 2, half_wide) around its centre
        count = max(1, int(math.ceil(2 * half_long / half_wide - 1e-9)))
        spacing = 2 * half_long / count
        radius = float(math.hypot(spacing / 2, half_wide))
        for k in range(count):
            t = -half_long + spacing * (k + 0.5)
            parts.append((float(x + t * axis[0]), float(y + t * axis[1]), radius,
                          float(z - half_height), float(z + half_height)))
    return parts


def hand_footprint(env, below: float) -> list[tuple[float, float, float, float, float, float]]:
    """Bounding boxes of the robot's bodies that reach lower than ``below`` (the hand and each finger, which
    hold the box rigidly at a fixed orientation), relative to the held box's centre: (x0, x1, y0, y1, z0,
    z1) each, z absolute. Only the end-effector's body and what hangs from it count: the links above move
    relative to the box and stay higher than the clutter."""
    m, d = env.model, env.data
    box_body = env.index.bottom_box_body
    box = d.xpos[box_body]
    wrist = int(m.site_bodyid[env.binding.ee_site])  # the body of the end-effector site: link 7, the hand

    def below_wrist(body: int) -> bool:
        while body > 0:
            if body == wrist:
                return True
            body = int(m.body_parentid[body])
        return False

    boxes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for g in range(m.ngeom):
        body = int(m.geom_bodyid[g])
        if body == box_body or not below_wrist(body) or not m.geom_contype[g] | m.geom_conaffinity[g]:
            continue
        aabb = m.geom_aabb[g].reshape(2, 3)
        rotation = d.geom_xmat[g].reshape(3, 3)
        centre, half = d.geom_xpos[g] + rotation @ aabb[0], np.abs(rotation) @ aabb[1]
        if centre[2] - half[2] >= below:
            continue
        lo, hi = boxes.get(body, (np.full(3, np.inf), np.full(3, -np.inf)))
        boxes[body] = (np.minimum(lo, centre - half), np.maximum(hi, centre + half))
    return [(lo[0] - box[0], hi[0] - box[0], lo[1] - box[1], hi[1] - box[1], lo[2], hi[2]) for lo, hi in boxes.values()]


def open_for_the_arm(env, parts=None) -> bool:
    """Whether the Panda can carry the box from the lane to the goal in this scene: the box, hand and fingers
    clear every object part by d4 on the 1 cm grid, and the box stays where the arm can hold it
    (``holding_reach``, "any" edge). ``parts``: the scene's ``part_extents``, if already computed."""
    sx, sy = env.geometry.path_start_xy
    return FreeSpace(env, 0.0, parts=parts, reach=holding_reach(env.geometry)).reachable_from(sx, sy)


class FreeSpace:
    """The held box centre's free space on a grid over the table, for one scene and one clearance.

    A grid point is free if the box there keeps every object part more than d4 + ``clearance`` away, and
    clears the top box. With ``hand``, the hand's and fingers' footprint (``hand_footprint``) must clear
    every part that reaches their height, too; without it, only parts lower than the box's top count.
    ``reach`` = (xs, ys, mask), a grid of box centres where the robot can hold the box (the Panda's
    ``scene.panda.holding_reach``): the box must also stay where ``reach_edge`` = "any" (a generous edge)
    or "all" (a safe one) of the reach grid's four points around it are held.
    """

    def __init__(self, env, clearance: float = 0.0, grid: float = GRID, hand: bool = True, parts=None,
                 reach: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, reach_edge: str = "any"):
        geo, d4 = env.geometry, env.thresholds.collision
        hx, hy, hz = geo.box_half_extents
        tx, ty = geo.table_half_extents
        inset = geo.workspace_inset
        self.grid = grid
        self.xs = np.arange(-tx + inset, tx - inset + 1e-9, grid)
        self.ys = np.arange(-ty + inset, ty - inset + 1e-9, grid)
        px, py = np.meshgrid(self.xs, self.ys, indexing="ij")
        parts = part_extents(env) if parts is None else parts
        rectangles = [(-hx, hx, -hy, hy, 0.0, 2 * hz)]
        if hand and parts:
            rectangles += hand_footprint(env, below=max(p[4] for p in parts) + d4 + clearance)
        free = np.ones(px.shape, dtype=bool)
        for cx, cy, r, z_low, z_high in parts:
            for x0, x1, y0, y1, r_low, r_high in rectangles:
                if z_low >= r_high or z_high <= r_low - d4 - clearance:
                    continue
                # distance from the part's centre to the footprint rectangle placed at each grid point
                dx = np.maximum(np.maximum(px + x0 - cx, cx - px - x1), 0.0)
                dy = np.maximum(np.maximum(py + y0 - cy, cy - py - y1), 0.0)
                free &= dx * dx + dy * dy > (r + d4 + clearance) ** 2
        top_x, top_y = geo.stack_xy  # the top box, left on the table: the held box may not pass through it
        free &= (np.abs(px - top_x) >= 2 * hx + d4) | (np.abs(py - top_y) >= 2 * hy + d4)
        if reach is not None:
            reach_xs, reach_ys, within = reach
            fx = (self.xs - reach_xs[0]) / (reach_xs[1] - reach_xs[0])
            fy = (self.ys - reach_ys[0]) / (reach_ys[1] - reach_ys[0])
            corners = [within[np.ix_(np.clip(i.astype(int), 0, len(reach_xs) - 1),
                                     np.clip(j.astype(int), 0, len(reach_ys) - 1))]
                       for i in (np.floor(fx), np.ceil(fx)) for j in (np.floor(fy), np.ceil(fy))]
            free &= np.logical_or.reduce(corners) if reach_edge == "any" else np.logical_and.reduce(corners)
        gx, gy = geo.goal_xy
        self.free = free
        self.goal = free & ((px - gx) ** 2 + (py - gy) ** 2 < env.thresholds.goal_radius ** 2)

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """The grid cell nearest to (x, y), clipped to the map."""
        i = int(round((x - self.xs[0]) / self.grid))
        j = int(round((y - self.ys[0]) / self.grid))
        return min(max(i, 0), len(self.xs) - 1), min(max(j, 0), len(self.ys) - 1)

    def reachable_from(self, x: float, y: float) -> bool:
        """Whether the box can slide from (x, y) to the goal region through free space (4-connected fill)."""
        filled = np.zeros_like(self.free)
        filled[self.cell(x, y)] = True
        filled &= self.free
        if not filled.any():
            return False
        while True:  # flood fill by shifts
            grown = filled.copy()
            grown[1:] |= filled[:-1]
            grown[:-1] |= filled[1:]
            grown[:, 1:] |= filled[:, :-1]
            grown[:, :-1] |= filled[:, 1:]
            grown &= self.free
            if (grown & self.goal).any():
                return True
            if np.array_equal(grown, filled):
                return False
            filled = grown

    def distance_to_goal(self, cost: np.ndarray | float = 1.0, goal: np.ndarray | None = None) -> np.ndarray:
        """Geodesic distance [m] from every free cell to the ``goal`` cells (default: the goal region),
        8-connected, each move weighted by ``cost`` of the cell it enters; inf where cut off."""
        dist = np.where(self.goal if goal is None else goal & self.free, 0.0, np.inf)
        weight = np.broadcast_to(np.asarray(cost, dtype=float), dist.shape)
        blocked = ~self.free
        rows, cols = dist.shape
        while True:  # wavefront relaxation by shifts: converges in about (longest path / grid) sweeps
            new = dist.copy()
            for dx, dy, step in _NEIGHBOURS:
                src = dist[max(dx, 0):rows + min(dx, 0), max(dy, 0):cols + min(dy, 0)]
                into = (slice(max(-dx, 0), rows + min(-dx, 0)), slice(max(-dy, 0), cols + min(-dy, 0)))
                dst = new[into]
                np.minimum(dst, src + (step * self.grid) * weight[into], out=dst)
            new[blocked] = np.inf
            if np.array_equal(new, dist):
                return dist
            dist = new


class GridPlanner:
    """Fast pull out from under the top box, then down a distance field through the clutter into the goal.

    The field is a geodesic distance to the goal centre over the cells where the box clears every object
    by d4, with each cell's cost raised the less room it leaves (``clearances``, widest first, with one
    ``penalties`` each): the path keeps to open space and squeezes through a gap only when it must. Each
    control step the box heads for the point ``lookahead`` down the field, at the top speed its room
    allows (``speeds``), braking at ``braking`` into the goal; close to the goal centre it settles. The
    pull heads straight out at ``pull_speed`` (at most ``pull_angle`` aside), no faster than lets it stop
    ``stop_margin`` short of what it avoids straight ahead at ``pull_braking``, or touch a soft object there at
    ``soft_speed``. Speeds are in m/s, commanded as actions through the env's action curve; the env's Cartesian
    speed and acceleration limits and the arm's joint limits apply on top, as for any policy.
    """

    def __init__(self, pull_speed: float = 1.3, clearances: tuple[float, ...] = (0.06, 0.04, 0.02, 0.0),
                 speeds: tuple[float, ...] = (0.8, 0.6, 0.4, 0.25), penalties: tuple[float, ...] = (0.0, 1.0, 3.0, 8.0),
                 braking: float = 2.0, lookahead: float = 0.08, settle_time: float = 0.2,
                 pull_angle: float = 0.0, avoid: str = "all", pull_braking: float = 2.0, stop_margin: float = 0.03,
                 soft_speed: float = 0.3):
        """``pull_speed``: the pull out from under the top box (>= 0.75 m/s leaves the top box in place on the
        Panda, ``benchmarks/tablecloth.py``); ``clearances``: extra room beyond d4 [m], widest first, with the top speed [m/s] and the
        extra cost per metre (``penalties``) of cells that leave only that much; ``braking``: the deceleration
        planned into the goal [m/s^2]; ``lookahead``: how far down the path the box heads [m];
        ``settle_time``: the time constant of the final approach to the goal centre [s]; ``pull_angle``: how
        far aside the pull may head [deg]: heading aside asks the shoulder and elbow, the joints that accelerate
        least, to move, which slows the whole pull, and at 10 deg the top box already comes along; ``avoid``: 'all'
        objects or only the 'fragile' (``no_contact``) ones (``PLANNER_AVOID``); ``pull_braking``: the deceleration
        [m/s^2] the pull plans with before an obstacle straight ahead, ``stop_margin`` [m] short of it;
        ``soft_speed``: the speed [m/s] at which the box may touch a soft object."""
        if not (len(speeds) == len(penalties) == len(clearances)) or list(clearances) != sorted(clearances, reverse=True):
            raise ValueError("clearances must be widest first, with one speed and one penalty each")
        if avoid not in PLANNER_AVOID:
            raise ValueError(f"avoid must be one of {PLANNER_AVOID}, got {avoid!r}")
        self.avoid = avoid
        self.pull_braking, self.stop_margin, self.soft_speed = pull_braking, stop_margin, soft_speed
        self.pull_speed, self.clearances, self.speeds, self.penalties = pull_speed, clearances, speeds, penalties
        self.braking, self.lookahead, self.settle_time = braking, lookahead, settle_time
        self.pull_slope = math.tan(math.radians(pull_angle))
        self._space = self._field = self._speed = None

    def reset(self, env=None) -> None:
        """Map the scene of the env's current episode (call after ``env.reset``)."""
        self._pulled_out = False
        self._space = self._field = self._speed = None
        if env is None:
            return
        avoided = None if self.avoid == "all" else [i for i, c in enumerate(env.constraints) if c == "no_contact"]
        parts = part_extents(env, avoided)
        reach = env.robot.holding_reach(env.geometry)
        # the safe edge of the reach map: on the generous one the arm can stall against a joint limit
        spaces = [FreeSpace(env, clearance, parts=parts, reach=reach, reach_edge="all") for clearance in self.clearances]
        space = spaces[-1]  # the narrowest: every cell the box may be in
        level = np.full(space.free.shape, len(spaces) - 1)  # the widest clearance each cell keeps
        for k in range(len(spaces) - 2, -1, -1):
            level[spaces[k].free] = k
        gx, gy = env.geometry.goal_xy
        px, py = np.meshgrid(space.xs, space.ys, indexing="ij")
        centre = (px - gx) ** 2 + (py - gy) ** 2 < (0.5 * env.thresholds.goal_radius) ** 2
        goal = centre if (centre & space.free).any() else space.goal
        self._space, self._speed = space, np.asarray(self.speeds)[level]
        soft = [i for i, c in enumerate(env.constraints) if c == "soft_contact"] if self.avoid == "fragile" else []
        self._touching = np.zeros(space.free.shape, dtype=bool)
        if soft:  # where the box would touch a soft object, it goes slowly enough to touch it gently
            self._touching = ~FreeSpace(env, 0.0, parts=part_extents(env, soft)).free
            self._speed = np.where(self._touching, np.minimum(self._speed, self.soft_speed), self._speed)
        self._field = space.distance_to_goal(1.0 + np.asarray(self.penalties)[level], goal)
        sx, sy = env.geometry.path_start_xy
        # the room the scene leaves (None: walled off): the widest clearance that reaches the goal, tried widest first
        self.clearance = next((c for c, sp in zip(self.clearances, spaces) if sp.reachable_from(sx, sy)), None)

    def act(self, info: dict, env) -> np.ndarray:
        """Action in [-1, 1]^3 for the env's current state."""
        state = env.scene_state()
        x, y = state.bottom_pos[:2]
        pulling = not self._pulled_out and info["margins"]["l1"] <= 0.0
        self._pulled_out = not pulling
        gx, gy = env.geometry.goal_xy
        to_goal = math.hypot(gx - x, gy - y)
        if not pulling and to_goal < 0.5 * env.thresholds.goal_radius:  # settle on the goal centre
            return self._action(np.array([gx - x, gy - y, 0.0]) / self.settle_time, env)
        # in the lane the box is under the top box, which the map keeps it away from: plan from the lane's end
        sx, _ = env.geometry.path_start_xy
        space, field = self._space, self._field
        i, j = space.cell(max(x, sx) if pulling else x, y)
        if field is None or not math.isfinite(field[i, j]):  # walled off (or no map)
            if pulling:  # the pull still has to be fast, or the top box comes along; it still brakes in time
                return self._action(np.array([self._pull_speed(space, i, j, x), 0.0, 0.0]), env)
            return np.zeros(3, dtype=np.float32)  # no way through what it avoids: it stays put (a timeout)
        ti, tj, top_speed = i, j, self._speed[i, j]
        for _ in range(int(self.lookahead / space.grid)):  # walk down the field
            best = (field[ti, tj], ti, tj)
            for dx, dy, _step in _NEIGHBOURS:
                a, b = ti + dx, tj + dy
                if 0 <= a < field.shape[0] and 0 <= b < field.shape[1] and field[a, b] < best[0]:
                    best = (field[a, b], a, b)
            if best[1:] == (ti, tj):
                break
            ti, tj = best[1:]
            top_speed = min(top_speed, self._speed[ti, tj])
        heading = np.array([space.xs[ti] - x, space.ys[tj] - y])
        norm = float(np.linalg.norm(heading))
        if norm < 1e-9:
            heading, norm = np.array([gx - x, gy - y]), max(to_goal, 1e-9)
        if pulling:
            heading[1] = min(max(heading[1], -self.pull_slope * heading[0]), self.pull_slope * heading[0])
            heading[0] = max(heading[0], 1e-3)  # keep pulling outwards, at most pull_angle aside
            speed = self._pull_speed(space, i, j, x)
            return self._action(np.array([*(heading / np.linalg.norm(heading) * speed), 0.0]), env)
        speed = min(top_speed, math.sqrt(2 * self.braking * to_goal) + 0.05)
        return self._action(np.array([*(heading / norm * speed), 0.0]), env)

    def _pull_speed(self, space: "FreeSpace", i: int, j: int, x: float) -> float:
        """The pull's speed: ``pull_speed``, but no faster than lets the box stop before what it avoids straight ahead
        of the lane (from cell (i, j) on), or slow down to a gentle touch before a soft object there."""
        speed = self.pull_speed
        for ahead_of, end_speed in ((~space.free[i:, j], 0.0), (self._touching[i:, j], self.soft_speed)):
            blocked = np.flatnonzero(ahead_of)
            if len(blocked):
                ahead = max(space.xs[i + blocked[0]] - x - self.stop_margin, 0.0)
                speed = min(speed, math.sqrt(end_speed ** 2 + 2 * self.pull_braking * ahead))
        return speed

    @staticmethod
    def _action(velocity: np.ndarray, env) -> np.ndarray:
        """The action that commands ``velocity`` [m/s] through the env's action curve (inverse of ``shape_action``)."""
        speed = float(np.linalg.norm(velocity))
        if speed == 0.0:
            return np.zeros(3, dtype=np.float32)
        fraction = min(speed / env.max_speed, 1.0)
        return (velocity / speed * fraction ** (1.0 / env.action_curve)).astype(np.float32)
