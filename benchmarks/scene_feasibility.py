"""How many scenes leave the box a way to the goal at all? A geometric upper bound on success, per N.

    python benchmarks/scene_feasibility.py [--objects 2 3 4 5 6] [--scenes 500] [--seed 9]
    python benchmarks/scene_feasibility.py --results EVAL_DIR [EVAL_DIR ...]

A learned policy's success rate means little without a ceiling: a scene whose clutter walls off the
goal fails whatever the learner does. This asks the most forgiving question about each scene: can the
held box, translating at its fixed orientation (the controller holds the hand's), slide from where it
leaves the lane under the top box (``path_start_xy``) to the goal region while every object stays more
than d4 (the collision threshold) away, and so does the top box, left where it stood? It ignores everything else that makes the task hard: the
arm's links and fingers, speed and acceleration limits, the top box, lifting. So the "reachable"
column is an upper bound on what any policy can achieve on these scenes (up to the object shapes:
each object part lower than the box's top counts as the circle around it, a few millimetres generous
for box-shaped parts).

With ``--results``, the same geometry explains an evaluation (``safemanip eval --out``): each episode's scene is
re-drawn from its seed, and the success rate is printed by the widest gap the scene leaves the box (the largest
extra clearance beyond d4 with which a path to the goal still exists), with what the failures hit (an object
placed in the corridor to the goal, or another).

Method: the box centre's free space on a 5 mm grid over the table (inside the workspace, every grid
point's box clear of every part circle grown by d4), flood-filled from the path start; a scene is
reachable if the fill touches the goal region (within d2 of the goal centre). Scenes: the env's
all-fragile scenes from seeds ``seed * 100000 + i``; one process, a few milliseconds per scene.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

GRID = 0.005  # m


def part_circles(env) -> list[tuple[float, float, float]]:
    """(x, y, radius) of every object geom that reaches below the box's top, at its placed pose."""
    m, d, idx = env.model, env.data, env.index
    box_top = 2 * env.geometry.box_half_extents[2]
    circles = []
    bodies = set(int(b) for b in idx.object_bodies)
    for g in range(m.ngeom):
        if int(m.geom_bodyid[g]) not in bodies:
            continue
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        axis_z = abs(d.geom_xmat[g].reshape(3, 3)[2, 2])  # 1: the geom's own z axis is upright
        if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            reach, half_height = size[0], size[0]
        elif kind in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE):
            upright = axis_z > 0.999
            cap = size[0] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            reach = size[0] if upright else size[0] + size[1] + cap
            half_height = size[1] + cap if upright else size[1] + size[0] + cap
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            upright = axis_z > 0.999
            reach = float(np.hypot(size[0], size[1])) if upright else float(np.linalg.norm(size))
            half_height = size[2] if upright else float(np.linalg.norm(size))
        else:  # not used by the catalog: the bounding sphere
            reach = half_height = m.geom_rbound[g]
        x, y, z = d.geom_xpos[g]
        if z - half_height < box_top:
            circles.append((float(x), float(y), float(reach)))
    return circles


def reachable(env, margin: float = 0.0, circles=None) -> bool:
    """Whether the box can slide from the lane to the goal with every object part more than d4 + ``margin``
    away (``circles``: the scene's ``part_circles``, if already computed)."""
    geo, d4 = env.geometry, env.thresholds.collision
    hx, hy = geo.box_half_extents[:2]
    tx, ty = geo.table_half_extents
    inset = geo.workspace_inset
    xs = np.arange(-tx + inset, tx - inset + 1e-9, GRID)
    ys = np.arange(-ty + inset, ty - inset + 1e-9, GRID)
    px, py = np.meshgrid(xs, ys, indexing="ij")
    free = np.ones(px.shape, dtype=bool)
    for cx, cy, r in part_circles(env) if circles is None else circles:
        dx = np.maximum(np.abs(cx - px) - hx, 0.0)
        dy = np.maximum(np.abs(cy - py) - hy, 0.0)
        free &= dx * dx + dy * dy > (r + d4 + margin) ** 2
    top_x, top_y = geo.stack_xy  # the top box, left on the table: the held box may not pass through it
    free &= (np.abs(px - top_x) >= 2 * hx + d4) | (np.abs(py - top_y) >= 2 * hy + d4)
    gx, gy = geo.goal_xy
    goal = (px - gx) ** 2 + (py - gy) ** 2 < env.thresholds.goal_radius ** 2
    sx, sy = geo.path_start_xy
    start = np.zeros_like(free)
    start[np.argmin(np.abs(xs - sx)), np.argmin(np.abs(ys - sy))] = True
    if not (start & free).any():
        return False
    filled = start
    while True:  # 4-connected flood fill by shifts
        grown = filled.copy()
        grown[1:] |= filled[:-1]
        grown[:-1] |= filled[1:]
        grown[:, 1:] |= filled[:, :-1]
        grown[:, :-1] |= filled[:, 1:]
        grown &= free
        if (grown & goal).any():
            return True
        if np.array_equal(grown, filled):
            return False
        filled = grown


GAP_MARGINS = (0.0, 0.02, 0.04, 0.06, 0.08, 0.10, 0.15)


def widest_gap(env) -> float | None:
    """The largest of ``GAP_MARGINS`` by which every object part can be cleared beyond d4 on the way to the goal
    (None: the scene is unreachable even at d4): how much room the scene leaves the box."""
    circles, best = part_circles(env), None
    for margin in GAP_MARGINS:
        if not reachable(env, margin, circles):
            break
        best = margin
    return best


def results_by_scene(folder: str) -> None:
    """Read an evaluation's episodes (``safemanip eval --out``), re-draw each scene from its seed and print the
    success rate by the room the scene leaves (``widest_gap``), and what the failed episodes hit."""
    import csv
    import json
    from pathlib import Path

    from safemanip.env.slide_out import SlideOutEnv

    summary = json.loads((Path(folder) / "summary.json").read_text())
    env_kwargs = summary["eval"]["env_kwargs"]
    env = SlideOutEnv(**env_kwargs)
    episodes = list(csv.DictReader((Path(folder) / "episodes.csv").open()))
    by_gap: dict = {}
    hits = {"an object in the corridor": [], "another object": []}
    other: dict = {}
    for row in episodes:
        env.reset(seed=int(row["seed"]))
        by_gap.setdefault(widest_gap(env), []).append(row["event"] == "success")
        if row["event"] in ("failure:hard", "failure:soft") and row["object_id"] not in ("", "None"):
            where = ("an object in the corridor" if env.placement.near_path[int(float(row["object_id"]))]
                     else "another object")
            hits[where].append(int(row["length"]))
        elif row["event"] != "success":
            other[row["event"]] = other.get(row["event"], 0) + 1
    print(f"\n{folder}: N = {env_kwargs['n_objects']}, {len(episodes)} episodes, "
          f"{summary['success']['rate']:.1%} success")
    print(f"{'widest gap beyond d4':>22} {'scenes':>6} {'success':>7}")
    for gap in sorted(by_gap, key=lambda g: -1.0 if g is None else g):
        label = "unreachable" if gap is None else f">= {100 * gap:.0f} cm"
        print(f"{label:>22} {len(by_gap[gap]):>6} {np.mean(by_gap[gap]):>7.1%}")
    for where, steps in hits.items():
        if steps:
            p10, p50, p90 = np.percentile(steps, [10, 50, 90])
            print(f"failures hitting {where}: {len(steps)} (control step median {p50:.0f}, 10th-90th {p10:.0f}-{p90:.0f})")
    for event, count in sorted(other.items()):
        print(f"failures {event}: {count}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", nargs="+", type=int, default=[2, 3, 4, 5, 6])
    p.add_argument("--scenes", type=int, default=500)
    p.add_argument("--seed", type=int, default=9, help="scene seeds are seed * 100000 + i")
    p.add_argument("--results", nargs="+", metavar="EVAL_DIR",
                   help="instead: success by the room each scene leaves, for these evaluations' episodes")
    args = p.parse_args()
    if args.results:
        for folder in args.results:
            results_by_scene(folder)
        return
    if args.scenes < 1 or any(not 1 <= n <= 8 for n in args.objects):
        p.error("--scenes must be >= 1 and every --objects value in 1..8")
    from safemanip.env.slide_out import SlideOutEnv
    from safemanip.evaluation.stats import wilson_interval

    print(f"{'N':>2} {'scenes':>6} {'reachable (upper bound on success)':>36} {'ms/scene':>8}")
    for n in args.objects:
        env = SlideOutEnv(n_objects=n, classes=f"{n} fragile", constraints="conservative")
        t0 = time.perf_counter()
        hits = 0
        for i in range(args.scenes):
            env.reset(seed=args.seed * 100_000 + i)
            hits += reachable(env)
        ms = (time.perf_counter() - t0) / args.scenes * 1e3
        lo, hi = wilson_interval(hits, args.scenes)
        print(f"{n:>2} {args.scenes:>6} {hits / args.scenes:>19.1%} [{lo:.1%}, {hi:.1%}] {ms:>8.1f}")


if __name__ == "__main__":
    main()
