"""The judge, the env's second part: every margin of the paper (``env/margins.py``, pure) evaluated on the state
just read, and g over the control step's 25 physics substeps from the judge sensors' history
(``scene/builder.py``). ``SlideOutEnv`` calls these with itself as ``env``.

g_hard and g_soft between contacts use the exact geom distance of the held box and the hand (capped at
``DISTANCE_CAP``); at the substeps, every contact within d4 of the robot's subtree or the held box's hull counts.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from safemanip.env import margins as M
from safemanip.env.observation import SceneState

DISTANCE_CAP = 0.3
"""Geom distances saturate here: far objects do not need an exact value."""
SPHERE_SLACK = 1e-4
"""A geom pair whose bounding spheres are farther apart than the nearest distance found so far plus this [m] is not
queried: its distance cannot be the smaller one. 0.1 mm lies far above the error of MuJoCo's distance solvers (their
tolerance, ``opt.ccd_tolerance``, is 1e-6), so the judge's distances are exactly those of querying every pair."""
_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False


def geom_distances(env, ids) -> list[float]:
    """Capped geom distances of objects ``ids``, from the positions of the last state read.

    Only pairs that could come nearer than the best distance found so far are queried (bounding spheres with
    ``SPHERE_SLACK``): the same minimum as querying every pair, for a third of the queries in a cluttered scene."""
    m, d, gather, v = env.model, env.data, env.gather, env._values
    bx, by, bz = v[gather.bottom_pos.start:gather.bottom_pos.start + 3]
    base = gather.obj_pos.start
    centres = None
    out = []
    for i in ids:
        j = base + 3 * i
        dx, dy, dz = v[j] - bx, v[j + 1] - by, v[j + 2] - bz
        best = DISTANCE_CAP
        if math.sqrt(dx * dx + dy * dy + dz * dz) - gather.reach[i] < DISTANCE_CAP:
            if centres is None:  # the geoms' centres, once per call
                centres = gather.geom_xpos[gather.distance_geoms].tolist()
            for g1, g2, row1, row2, radii in gather.geom_pairs[i]:
                if math.dist(centres[row1], centres[row2]) - radii > best + SPHERE_SLACK:
                    continue  # the spheres around the two geoms are apart by more than the best distance so far
                dist = mujoco.mj_geomDistance(m, d, g1, g2, DISTANCE_CAP, None)
                if dist < best:
                    best = dist
        out.append(best)
    return out


def margins(env, state: SceneState | None = None, substeps: bool = False) -> dict[str, Any]:
    """Every margin term of the last state read (``state``, if given, must be that state).

    With ``substeps``, each g term is also the minimum over the physics substeps of the control step
    just taken, read from the judge sensors' history (``scene/builder.py``).
    """
    if state is not None and state is not env._state:
        raise ValueError("_margins works on the state of the last read; pass env.scene_state() or nothing")
    th, geo, v, gather = env.thresholds, env.geometry, env._values, env.gather
    half = geo.box_half_extents
    b0 = gather.bottom_pos.start
    bottom = v[b0:b0 + 2]
    top = v[b0 + 3:b0 + 5]
    bvx, bvy, bvz = v[gather.box_vel]
    terms: dict[str, Any] = {
        "l1": M.margin_out_from_under(bottom, top, half, half, th.out_clearance),
        "l2": M.margin_in_goal(bottom, geo.goal_xy, th.goal_radius),
        "g_dyn": M.margin_top_box(top, env._top_start, float(gather.xmat[gather.top_up_z]),
                                  th.top_box_displacement, th.top_box_min_up),
        "g_oob": M.margin_in_workspace(bottom, geo.table_half_extents, geo.workspace_inset),
        "l3": M.margin_at_rest(math.sqrt(bvx * bvx + bvy * bvy + bvz * bvz), th.place_speed,
                               th.place_horizon, th.rest_horizon),
    }
    if substeps:  # the boxes' paths over the substeps: views of their sensors' samples
        terms["g_dyn"] = min(terms["g_dyn"], M.worst_top_box(
            gather.top_xy_path, env._top_start, gather.top_up_z_path, th.top_box_displacement, th.top_box_min_up))
        terms["g_oob"] = min(terms["g_oob"], M.worst_in_workspace(
            gather.box_xy_path, geo.table_half_extents, geo.workspace_inset))
    n = len(env.names)
    object_terms = [math.inf] * n
    distances = [DISTANCE_CAP] * n
    g_objects = math.inf
    checked = env._checked_list
    if checked:
        v0 = gather.obj_vel.start
        for i, dist in zip(checked, geom_distances(env, checked)):
            distances[i] = dist
            if env._soft_flags[i]:
                j = v0 + 3 * i
                speed = math.sqrt((v[j] - bvx) ** 2 + (v[j + 1] - bvy) ** 2 + (v[j + 2] - bvz) ** 2)
                term = M.margin_soft_contact(dist, speed, th.collision, th.relative_speed)
            else:
                term = dist - th.collision  # = margin_no_contact
            object_terms[i] = term
        # the contact sensors' found flags at every substep: only when one of them is set is the whole history read
        if substeps and gather.history[gather.found_index].max() > 0.5:
            history = gather.history[gather.history_index]  # (substeps, columns): one gather
            # (substeps, N, 2): a contact within d4 of the robot / of the held box at that substep
            found = history[:, gather.h_found] > 0.5
            for i in checked:
                hit = found[:, i]
                if hit.any():
                    object_terms[i] = min(object_terms[i], substep_contact_margin(env, history, hit, i))
        g_objects = min(object_terms[i] for i in checked)
    terms["objects"] = np.array(object_terms) if n else _EMPTY
    terms["distances"] = np.array(distances) if n else _EMPTY
    terms["l"] = min(terms["l1"], terms["l2"], terms["l3"])
    terms["g"] = float(min(terms["g_dyn"], terms["g_oob"], g_objects))
    env._last_terms = terms
    return terms


def substep_contact_margin(env, history: np.ndarray, hit: np.ndarray, i: int) -> float:
    """Worst g of object i over the substeps where the robot or the held box came within d4 of it (``hit``:
    (substeps, 2), which of the two contact sensors found one)."""
    th, gather = env.thresholds, env.gather
    substeps = hit.any(axis=1)
    rows = history[substeps]
    distance = np.where(hit[substeps], rows[:, gather.h_dist[i]], np.inf).min(axis=1)
    if not env._soft_flags[i]:
        return float(np.min(distance)) - th.collision  # = margin_no_contact
    # the held box's velocity stands for the robot's: it is the fastest-moving part near the table
    relative = rows[:, gather.h_box_vel] - rows[:, gather.h_obj_vel[i]]
    speed = np.sqrt(np.einsum("ij,ij->i", relative, relative))
    return min(M.margin_soft_contact(float(dd), float(sp), th.collision, th.relative_speed)
               for dd, sp in zip(distance, speed))


def failure_cause(env, terms) -> tuple[str, int | None]:
    candidates = {"failure:dyn": terms["g_dyn"], "failure:oob": terms["g_oob"]}
    worst_obj = None
    if len(env.names) and np.isfinite(terms["objects"]).any():
        worst_obj = int(np.argmin(terms["objects"]))
        kind = "failure:soft" if env._soft_flags[worst_obj] else "failure:hard"
        candidates[kind] = terms["objects"][worst_obj]
    event = min(candidates, key=candidates.get)
    return event, (worst_obj if event in ("failure:hard", "failure:soft") else None)
