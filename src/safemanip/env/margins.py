"""Target and failure margins of the slide-out task as small pure functions.

Sign conventions follow the paper: l(s) > 0 inside the target set, g(s) < 0 inside the failure set.
All distances are in metres; the soft-contact margin mixes in a speed margin (m/s) exactly as the
paper's g_soft does.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np


@dataclass(frozen=True)
class Thresholds:
    """Margin thresholds. Paper values (Table V) where the paper gives them."""

    out_clearance: float = 0.04
    """d1: gap required between the footprints of the two boxes for the bottom one to count as out."""
    goal_radius: float = 0.08
    """d2: the bottom box centre must be within this distance of the goal centre."""
    top_box_displacement: float = 0.12
    """d3: the top box may move at most this far (horizontally) from where it started. The paper gives no value; a
    Panda within its joint accelerations pulls the box out fast enough to leave the top box 9-11 cm from its start
    (``benchmarks/tablecloth.py``), a pull at 0.5 m/s drags it 14 cm and more."""
    top_box_min_up: float = 0.5
    """The top box's up-axis must keep a z-component above this (cos 60 deg); lower means it flipped."""
    collision: float = 0.01
    """d4: collision threshold (paper Table V: 0.01 m)."""
    relative_speed: float = 1.0
    """Soft-contact relative velocity threshold (paper Table V: 1.0 m/s)."""
    place_horizon: float = 0.1
    """l3's scale above v_place [s]: excess speed becomes the distance travelled in this time (see
    ``margin_at_rest``)."""
    rest_horizon: float = 1.0
    """l3's scale below v_place [s]: a box at rest scores v_place x 1 s = 5 cm, the size of l2's margin."""
    place_speed: float = 0.05
    """v_place: the box counts as placed only when slower than this [m/s]. 5 cm/s is 3 % of the Panda's
    1.7 m/s and a Panda stops from it in 4 ms at 13 m/s^2, so the box is at rest in the goal for any
    practical purpose, yet a policy need not wait for the last vibration to die out."""


DEFAULT_THRESHOLDS = Thresholds()


def margin_out_from_under(bottom_xy, top_xy, bottom_half_xy, top_half_xy, clearance: float) -> float:
    """l1 > 0 once the two boxes' footprints are separated by more than ``clearance``.

    A separating-axis test on the axis-aligned footprints (the held box does not rotate; the top
    box's small yaw is ignored), i.e. the paper's ||x_bot - x_top|| - d1 made exact for boxes.
    """
    gap_x = abs(bottom_xy[0] - top_xy[0]) - (bottom_half_xy[0] + top_half_xy[0])
    gap_y = abs(bottom_xy[1] - top_xy[1]) - (bottom_half_xy[1] + top_half_xy[1])
    return float(max(gap_x, gap_y) - clearance)


def margin_in_goal(bottom_xy, goal_xy, goal_radius: float) -> float:
    """l2 = d2 - ||x_bot - x_goal|| (horizontal)."""
    return float(goal_radius - math.hypot(bottom_xy[0] - goal_xy[0], bottom_xy[1] - goal_xy[1]))


def margin_top_box(top_xy, top_xy_start, top_up_z: float, max_displacement: float, min_up: float) -> float:
    """g_dyn: the top box stays within d3 of its start (horizontally) and is not flipped."""
    displaced = max_displacement - math.hypot(top_xy[0] - top_xy_start[0], top_xy[1] - top_xy_start[1])
    return min(displaced, float(top_up_z) - min_up)


def margin_at_rest(speed: float, place_speed: float, horizon: float, rest_horizon: float) -> float:
    """l3: the box is placed, not passing through. Positive below v_place, in metres like l1 and l2.

    Above v_place: ``horizon * (v_place - speed)``, the distance the box would travel in ``horizon``
    seconds beyond what a placed box may. In m/s the term dwarfed the distance to the goal while the box
    moved fast, so l = min(l1, l2, l3) ranked a fast pull (which the tablecloth trick needs) as far from
    success as it could be; with a short horizon it matters only close to the goal.
    Below v_place: ``rest_horizon * (v_place - speed)``. With the short horizon here too, a placed box
    was worth at most 5 mm, under the critic's noise and half the collision threshold, so reaching the
    target barely showed in the value. The longer horizon lets a box at rest score as much as l2 does.
    Continuous and piecewise linear (Lipschitz, as the backup needs); its sign, and so the target set,
    is v < v_place either way.
    """
    excess = place_speed - speed
    return float((rest_horizon if excess > 0.0 else horizon) * excess)


def worst_top_box(top_xy_path: np.ndarray, top_xy_start, top_up_z_path: np.ndarray, max_displacement: float,
                  min_up: float) -> float:
    """min over a path (rows = physics substeps) of ``margin_top_box``."""
    dx = top_xy_path[:, 0] - top_xy_start[0]
    dy = top_xy_path[:, 1] - top_xy_start[1]
    dx *= dx  # in place: this runs every control step, and a temporary costs about as much as the arithmetic
    dy *= dy
    dx += dy
    displaced = max_displacement - math.sqrt(float(dx.max()))
    return min(displaced, float(top_up_z_path.min()) - min_up)


def worst_in_workspace(xy_path: np.ndarray, half_extents, inset: float) -> float:
    """min over a path (rows = physics substeps) of ``margin_in_workspace``."""
    return margin_in_workspace(np.abs(xy_path).max(axis=0).tolist(), half_extents, inset)


def margin_no_contact(distance: float, collision: float) -> float:
    """g_hard = signed geom distance - collision threshold."""
    return float(distance - collision)


def margin_soft_contact(distance: float, relative_speed: float, collision: float, speed_limit: float) -> float:
    """g_soft: safe when far away or when moving gently, i.e. max(distance margin, speed margin)."""
    return float(max(distance - collision, speed_limit - relative_speed))


def margin_in_workspace(xy, half_extents, inset: float) -> float:
    """g_oob: how far the point is inside the table top shrunk by ``inset`` (negative outside)."""
    hx, hy = half_extents
    x, y = xy
    return float(min(hx - inset - abs(x), hy - inset - abs(y)))


def is_success(l: float, g: float) -> bool:
    return l > 0.0 and g >= 0.0


def is_failure(g: float) -> bool:
    return g < 0.0
