"""Scene sampling, the env's first part: which objects, which constraint types, which kind of scene, and where
everything stands at the start of an episode (``SlideOutEnv.reset`` calls these with itself as ``env``).

Names come from the scene config or the catalog, constraint types from the config's mode, the scene kind from the
layout's shares (``scene.placement.SCENE_KINDS``), and the placement from ``scene.placement``; a gate or exit scene is
checked on the planner's free-space map and redrawn until it is what it is meant to be.
"""

from __future__ import annotations

import mujoco
import numpy as np

from safemanip.control.planner import open_for_the_arm, part_extents
from safemanip.scene.catalog import CONSTRAINT_TYPES, load_catalog, names_of_class
from safemanip.scene.placement import LAYOUTS, sample_placement, sample_route

SCENE_TRIES = 20
"""Draws of a gate or exit scene before the episode falls back to an open one."""


def choose_names(env, rng: np.random.Generator) -> tuple[str, ...]:
    if env.scene_config.names is not None:
        return env.scene_config.names
    if env.scene_config.n_objects == 0:
        return ()
    if env.scene_config.classes is None:
        pool = sorted(load_catalog())
        return tuple(rng.choice(pool, size=env.scene_config.n_objects, replace=False).tolist())
    chosen: list[str] = []
    for c in env.scene_config.classes:
        pool = [n for n in names_of_class(c) if n not in chosen]
        chosen.append(str(rng.choice(pool)))
    return tuple(chosen)


def choose_constraints(env, mode, rng: np.random.Generator) -> tuple[str, ...]:
    n = len(env.names)
    if not isinstance(mode, str):
        return tuple(mode)
    if mode == "conservative":
        return ("no_contact",) * n
    if mode == "random":
        return tuple(CONSTRAINT_TYPES[i] for i in rng.integers(0, 3, size=n))
    catalog = load_catalog()
    return tuple(catalog[name].constraint for name in env.names)


def draw_kind(env, rng: np.random.Generator) -> str:
    """This episode's scene kind (``SCENE_KINDS``), by the config's shares; an open layout draws nothing."""
    gate, exit_ = env.scene_config.kind_shares
    if gate == 0.0 and exit_ == 0.0:
        return "open"
    u = float(rng.random())
    return "gate" if u < gate else "exit" if u < gate + exit_ else "open"


def place_scene(env, kind: str, rng: np.random.Generator):
    """Sample a placement of ``kind`` and set the scene to it. A gate or exit scene is redrawn until the planner's
    free-space map confirms what it is meant to be (``_is_its_kind``), at most ``SCENE_TRIES`` times; then it
    becomes an open scene, and ``placement.kind`` says so."""
    radii = env._footprint_radii(env.names)
    fragile = np.array([c == "no_contact" for c in env.constraints], dtype=bool)
    layout = LAYOUTS[env.scene_config.layout]
    for attempt in range(SCENE_TRIES if kind != "open" else 1):
        route = sample_route(rng, env.geometry, layout=layout) if env.scene_config.clear_route else None
        placement = sample_placement(radii, rng, env.scene_config.near_fraction, env.geometry, route=route, kind=kind,
                                     fragile=fragile)
        set_poses(env, placement)
        if placement.kind == "open" or not env.check_scenes or is_its_kind(env, placement, fragile):
            return placement
    return place_scene(env, "open", rng)


def set_poses(env, placement) -> None:
    m, d, idx = env.model, env.data, env.index
    mujoco.mj_resetData(m, d)
    env.robot.reset(m, d, env.binding)
    for i in range(len(env.names)):
        adr = idx.object_qpos[i]
        d.qpos[adr:adr + 3] = (*placement.xy[i], 0.0005)
        d.qpos[adr + 3:adr + 7] = (np.cos(placement.yaw[i] / 2), 0, 0, np.sin(placement.yaw[i] / 2))
    mujoco.mj_forward(m, d)


def is_its_kind(env, placement, fragile: np.ndarray) -> bool:
    """A gate is closed to the arm avoiding every object and open avoiding the fragile ones only; an exit is
    open (``control.planner.open_for_the_arm``, on the planner's 1 cm map of the scene as placed)."""
    parts = part_extents(env)
    if placement.kind == "exit":
        return open_for_the_arm(env, parts)
    breakable = part_extents(env, objects=np.flatnonzero(fragile))
    return not open_for_the_arm(env, parts) and open_for_the_arm(env, breakable)
