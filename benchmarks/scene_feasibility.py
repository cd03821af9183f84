"""How many scenes leave the box a way to the goal at all? Geometric ceilings on success, per N.

    python benchmarks/scene_feasibility.py [--objects 2 3 4 5 6] [--scenes 500] [--seed 9] [--planner]
                                           [--layout route|straight]
    python benchmarks/scene_feasibility.py --results EVAL_DIR [EVAL_DIR ...]

A learned policy's success rate means little without a ceiling: a scene whose clutter walls off the
goal fails whatever the learner does, and one with nothing in the way asks little of it. Three
questions per scene:

- "straight way blocked": would the box and hand, carried straight from the lane to the goal, come
  within d4 of an object part? Those are the scenes where avoiding something is part of the task.

- "box alone": can the held box, translating at its fixed orientation (the controller holds the
  hand's), slide from where it leaves the lane under the top box (``path_start_xy``) to the goal
  region while every object part lower than its top stays more than d4 (the collision threshold)
  away, and so does the top box, left where it stood? This ignores the arm, the hand, speed and
  acceleration limits and lifting: the most forgiving question (5 mm grid).
- "open for the arm": the same, but the hand and fingers must clear every part that reaches their
  height, too, and the box must stay where the Panda can hold it (``scene.panda.holding_reach``: IK
  with the hand down, joints inside their ranges). On the 1 cm grid of the planner
  (``control/planner.py``), which drives through exactly these scenes. Not a strict bound: the reach
  map's edge is within a couple of centimetres, and a policy can lift the box 2 cm over flat parts.

Scenes come in the env's default layout, which keeps a route clear for the box and hand (``--layout route``;
every scene should be open for the arm), or in the straight-corridor layout of results before 2026-12-02
(``--layout straight``), in which most scenes with N >= 3 are not.

With ``--planner``, the privileged planner (``control/planner.py``: it sees every object) also drives each
scene, and its success is printed over all scenes and over those open for the arm: what a controller
that knows the geometry achieves within the arm's limits.

Object parts are covered by vertical cylinders (elongated ones by a row of them, ``part_extents``).

With ``--results``, the same geometry explains an evaluation (``safemanip eval --out``): each episode's
scene is re-drawn from its seed, and the success rate is printed by the widest gap the scene leaves the
box alone (the largest extra clearance beyond d4 with which a path to the goal still exists) and by
whether it is open for the arm, with what the failures hit (an object placed in the corridor to the
goal, or another).

Method: free space of the box centre on a grid over the table, flood-filled from the path start; a
scene passes if the fill touches the goal region (within d2 of the goal centre). Scenes: the env's
all-fragile scenes from seeds ``seed * 100000 + i``; one process, tens of milliseconds per scene (the
reach map, once per process, about ten seconds).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from safemanip.control.planner import FreeSpace, GridPlanner, open_for_the_arm, part_extents
from safemanip.scene.panda import holding_reach

GRID = 0.005  # m


def reachable(env, margin: float = 0.0, parts=None) -> bool:
    """Whether the box alone can slide from the lane to the goal with every object part lower than its top more
    than d4 + ``margin`` away (``parts``: the scene's ``part_extents``, if already computed)."""
    sx, sy = env.geometry.path_start_xy
    return FreeSpace(env, margin, grid=GRID, hand=False, parts=parts).reachable_from(sx, sy)


def straight_way_blocked(env, parts=None) -> bool:
    """Whether the box and hand, carried straight from the lane to the goal, would come within d4 of an object
    part: the scenes in which avoiding something is part of the task (1 cm steps on the planner's grid)."""
    space = FreeSpace(env, 0.0, parts=parts)
    start, goal = np.asarray(env.geometry.path_start_xy), np.asarray(env.geometry.goal_xy)
    steps = int(np.ceil(np.linalg.norm(goal - start) / 0.01)) + 1
    return not all(space.free[space.cell(*(start + t * (goal - start)))] for t in np.linspace(0.0, 1.0, steps))


GAP_MARGINS = (0.0, 0.02, 0.04, 0.06, 0.08, 0.10, 0.15)


def widest_gap(env, parts=None) -> float | None:
    """The largest of ``GAP_MARGINS`` by which every object part can be cleared beyond d4 on the way to the goal
    (None: the scene is unreachable even at d4): how much room the scene leaves the box alone."""
    parts, best = part_extents(env) if parts is None else parts, None
    for margin in GAP_MARGINS:
        if not reachable(env, margin, parts):
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
    env_kwargs = dict(summary["eval"]["env_kwargs"])
    env_kwargs.setdefault("clear_route", False)  # evaluations that do not record it ran on the straight layout
    env = SlideOutEnv(**env_kwargs)
    episodes = list(csv.DictReader((Path(folder) / "episodes.csv").open()))
    by_gap: dict = {}
    by_arm: dict = {True: [], False: []}
    hits = {"an object in the corridor": [], "another object": []}
    other: dict = {}
    for row in episodes:
        env.reset(seed=int(row["seed"]))
        parts = part_extents(env)
        by_gap.setdefault(widest_gap(env, parts), []).append(row["event"] == "success")
        by_arm[open_for_the_arm(env, parts)].append(row["event"] == "success")
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
    for is_open, label in ((True, "open for the arm"), (False, "walled off for the arm")):
        if by_arm[is_open]:
            print(f"{label:>22} {len(by_arm[is_open]):>6} {np.mean(by_arm[is_open]):>7.1%}")
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
    p.add_argument("--planner", action="store_true", help="also drive every scene with the privileged planner")
    p.add_argument("--layout", choices=("route", "narrow", "straight"), default="route",
                   help="a layout with a route kept clear (the default 'route', or 'narrow': every object beside "
                        "it, 1 cm to spare), or the old straight corridor")
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

    holding_reach(SlideOutEnv(n_objects=0).geometry)  # the reach map once, outside the timing
    columns = ["straight way blocked", "box alone", "open for the arm"] + (["planner", "planner, open scenes"] if args.planner else [])
    print(f"layout: {args.layout}")
    print(f"{'N':>2} {'scenes':>6} " + " ".join(f"{c:>22}" for c in columns) + f" {'ms/scene':>8}")
    for n in args.objects:
        env = SlideOutEnv(n_objects=n, classes=f"{n} fragile", constraints="conservative",
                          clear_route=args.layout != "straight",
                          layout="route" if args.layout == "straight" else args.layout)
        t0 = time.perf_counter()
        blocked = alone = arm = placed = placed_open = 0
        for i in range(args.scenes):
            _, info = env.reset(seed=args.seed * 100_000 + i)
            parts = part_extents(env)
            blocked += straight_way_blocked(env, parts)
            alone += reachable(env, parts=parts)
            is_open = open_for_the_arm(env, parts)
            arm += is_open
            if args.planner:
                success = drive(env, info)
                placed += success
                placed_open += success and is_open
        ms = (time.perf_counter() - t0) / args.scenes * 1e3
        cells = []
        for hits, total in ((blocked, args.scenes), (alone, args.scenes), (arm, args.scenes), (placed, args.scenes), (placed_open, arm)):
            if len(cells) < len(columns):
                lo, hi = wilson_interval(hits, max(total, 1))
                cells.append(f"{hits / max(total, 1):.1%} [{lo:.1%}, {hi:.1%}]")
        print(f"{n:>2} {args.scenes:>6} " + " ".join(f"{c:>22}" for c in cells) + f" {ms:>8.1f}")


def drive(env, info: dict) -> bool:
    """One episode of the privileged planner in the env's scene, just reset (``info``: what the reset returned);
    whether it placed the box."""
    planner = GridPlanner()
    planner.reset(env)
    for _ in range(env.max_episode_steps):
        _, _, terminated, truncated, info = env.step(planner.act(info, env))
        if terminated or truncated:
            break
    return info["event"] == "success"


if __name__ == "__main__":
    main()
