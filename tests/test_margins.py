"""The pure margin functions on hand-placed values: sign and exact value of every term.

Conventions (paper Sec. V): l > 0 inside the target set, g < 0 inside the failure set.
"""

from __future__ import annotations

import math

import pytest

from safemanip.env import margins as M

HALF = (0.135, 0.095)  # the cereal box footprint half-extents (x, y)


# ------------------------------------------------------------------ thresholds


def test_default_thresholds_match_paper_table_v():
    th = M.DEFAULT_THRESHOLDS
    assert th.collision == 0.01  # "Collision threshold 0.01 m"
    assert th.relative_speed == 1.0  # "Relative velocity threshold 1.0 m/s"
    assert th.top_box_min_up == pytest.approx(math.cos(math.radians(60)))
    assert th.goal_radius > 0 and th.out_clearance > 0 and th.top_box_displacement > 0


# ------------------------------------------------------------------ l1: out from under


def test_l1_overlapping_stack_is_negative():
    # the initial stack: bottom box 4 cm towards the robot from the top box
    l1 = M.margin_out_from_under((-0.45, 0.03), (-0.45, 0.07), HALF, HALF, 0.04)
    # gap_x = 0 - 0.27 = -0.27, gap_y = 0.04 - 0.19 = -0.15 -> max = -0.15, minus clearance
    assert l1 == pytest.approx(-0.19)


def test_l1_separated_along_x():
    l1 = M.margin_out_from_under((0.0, 0.0), (0.5, 0.01), (0.1, 0.05), (0.1, 0.05), 0.04)
    # gap_x = 0.5 - 0.2 = 0.3, gap_y = 0.01 - 0.1 = -0.09 -> 0.3 - 0.04
    assert l1 == pytest.approx(0.26)


def test_l1_separated_along_y():
    l1 = M.margin_out_from_under((0.02, -0.3), (0.0, 0.0), (0.1, 0.05), (0.1, 0.05), 0.04)
    # gap_x = 0.02 - 0.2 = -0.18, gap_y = 0.3 - 0.1 = 0.2 -> 0.2 - 0.04
    assert l1 == pytest.approx(0.16)


def test_l1_uses_both_boxes_half_extents_and_is_symmetric():
    bottom_half, top_half = (0.1, 0.05), (0.2, 0.1)
    l1 = M.margin_out_from_under((0.0, 0.0), (0.0, 0.3), bottom_half, top_half, 0.04)
    assert l1 == pytest.approx(0.3 - 0.15 - 0.04)
    # swapping the boxes or mirroring the offset changes nothing
    assert M.margin_out_from_under((0.0, 0.3), (0.0, 0.0), top_half, bottom_half, 0.04) == pytest.approx(l1)
    assert M.margin_out_from_under((0.0, 0.0), (0.0, -0.3), bottom_half, top_half, 0.04) == pytest.approx(l1)


def test_l1_sign_flips_at_the_clearance():
    # footprints 0.19 deep in y: centres 0.19 + 0.04 apart -> exactly on the boundary
    just_in = M.margin_out_from_under((0.0, 0.0), (0.0, 0.19 + 0.039), HALF, HALF, 0.04)
    just_out = M.margin_out_from_under((0.0, 0.0), (0.0, 0.19 + 0.041), HALF, HALF, 0.04)
    assert just_in == pytest.approx(-0.001) and just_in < 0
    assert just_out == pytest.approx(0.001) and just_out > 0


def test_l1_diagonal_separation_uses_the_larger_axis_gap():
    # separated along both axes: the separating-axis margin is the larger gap, not the Euclidean one
    l1 = M.margin_out_from_under((0.0, 0.0), (0.3, 0.2), (0.1, 0.05), (0.1, 0.05), 0.0)
    assert l1 == pytest.approx(max(0.3 - 0.2, 0.2 - 0.1))


# ------------------------------------------------------------------ l2: in goal


def test_l2_goal_margin_exact_values():
    goal = (0.5, -0.15)
    assert M.margin_in_goal(goal, goal, 0.08) == pytest.approx(0.08)
    assert M.margin_in_goal((0.53, -0.11), goal, 0.08) == pytest.approx(0.08 - 0.05)  # 3-4-5
    assert M.margin_in_goal((0.5, -0.25), goal, 0.08) == pytest.approx(-0.02)
    assert M.margin_in_goal((0.5 - 0.08, -0.15), goal, 0.08) == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------ g_dyn: top box


def test_g_dyn_small_displacement_is_safe():
    g = M.margin_top_box((0.03, 0.04), (0.0, 0.0), 1.0, 0.10, 0.5)
    assert g == pytest.approx(0.05)


def test_g_dyn_large_displacement_fails():
    g = M.margin_top_box((-0.45 + 0.2, 0.07), (-0.45, 0.07), 1.0, 0.10, 0.5)
    assert g == pytest.approx(-0.10)
    assert M.is_failure(g)


def test_g_dyn_flip_fails_even_without_displacement():
    flipped = M.margin_top_box((0.0, 0.0), (0.0, 0.0), -1.0, 0.10, 0.5)
    assert flipped == pytest.approx(-1.5)
    tipped = M.margin_top_box((0.0, 0.0), (0.0, 0.0), 0.4, 0.10, 0.5)  # tilted ~66 deg
    assert tipped == pytest.approx(-0.1)
    tilted = M.margin_top_box((0.0, 0.0), (0.0, 0.0), 0.7, 0.10, 0.5)  # ~45 deg: tilt margin 0.2 > 0.1
    assert tilted == pytest.approx(0.1)


# ------------------------------------------------------------------ g_hard, g_soft


def test_g_hard_exact_values():
    assert M.margin_no_contact(0.05, 0.01) == pytest.approx(0.04)
    assert M.margin_no_contact(0.005, 0.01) == pytest.approx(-0.005)  # within the threshold: failure
    assert M.margin_no_contact(-0.002, 0.01) == pytest.approx(-0.012)  # penetrating
    assert M.is_failure(M.margin_no_contact(0.005, 0.01))
    assert not M.is_failure(M.margin_no_contact(0.011, 0.01))


def test_g_soft_far_and_fast_is_safe():
    g = M.margin_soft_contact(0.2, 3.0, 0.01, 1.0)
    assert g == pytest.approx(0.19)  # the distance margin wins


def test_g_soft_near_and_slow_is_safe():
    g = M.margin_soft_contact(0.0, 0.4, 0.01, 1.0)
    assert g == pytest.approx(0.6)  # the speed margin wins


def test_g_soft_near_and_fast_fails():
    g = M.margin_soft_contact(0.005, 1.5, 0.01, 1.0)
    assert g == pytest.approx(-0.005)
    assert M.is_failure(g)
    deep = M.margin_soft_contact(-0.01, 2.0, 0.01, 1.0)
    assert deep == pytest.approx(-0.02)


def test_g_soft_at_exactly_the_speed_limit_is_not_a_failure():
    g = M.margin_soft_contact(0.0, 1.0, 0.01, 1.0)
    assert g == pytest.approx(0.0)
    assert not M.is_failure(g)


# ------------------------------------------------------------------ g_oob


def test_g_oob_inside_and_outside():
    half = (0.8, 0.45)
    assert M.margin_in_workspace((0.0, 0.0), half, 0.03) == pytest.approx(0.42)
    assert M.margin_in_workspace((0.7, 0.3), half, 0.03) == pytest.approx(0.07)
    assert M.margin_in_workspace((-0.79, 0.0), half, 0.03) == pytest.approx(-0.02)
    assert M.margin_in_workspace((0.0, -0.5), half, 0.03) == pytest.approx(-0.08)
    assert M.margin_in_workspace((0.9, 0.9), half, 0.03) == pytest.approx(-0.48)


# ------------------------------------------------------------------ success / failure


def test_is_success_needs_l_positive_and_g_nonnegative():
    assert M.is_success(0.01, 0.0)
    assert M.is_success(0.01, 0.5)
    assert not M.is_success(0.0, 0.5)  # on the boundary of the target set: not yet
    assert not M.is_success(-0.01, 0.5)
    assert not M.is_success(0.3, -0.001)  # in the failure set: never a success


def test_is_failure_is_strictly_negative_g():
    assert M.is_failure(-1e-9)
    assert not M.is_failure(0.0)
    assert not M.is_failure(0.2)


def test_margins_return_python_floats():
    values = [M.margin_out_from_under((0, 0), (1, 1), HALF, HALF, 0.04), M.margin_in_goal((0, 0), (1, 1), 0.08),
              M.margin_top_box((0, 0), (0, 0), 1.0, 0.1, 0.5), M.margin_no_contact(0.1, 0.01),
              M.margin_soft_contact(0.1, 0.1, 0.01, 1.0), M.margin_in_workspace((0, 0), (0.8, 0.45), 0.03)]
    assert all(type(v) is float for v in values)


def test_at_rest_margin_is_a_distance_and_positive_only_below_v_place():
    from safemanip.env.margins import margin_at_rest

    assert margin_at_rest(0.0, 0.05, 0.1, 1.0) == pytest.approx(0.05)  # at rest: the size of l2 (at most 0.08)
    assert margin_at_rest(0.05, 0.05, 0.1, 1.0) == pytest.approx(0.0)
    assert margin_at_rest(1.45, 0.05, 0.1, 1.0) == pytest.approx(-0.14)  # metres: comparable with l1 and l2
    assert (margin_at_rest(0.049, 0.05, 0.1, 1.0) > 0) and (margin_at_rest(0.051, 0.05, 0.1, 1.0) < 0)
    # continuous at v_place from both sides (the backup needs a Lipschitz l)
    assert abs(margin_at_rest(0.05 - 1e-9, 0.05, 0.1, 1.0) - margin_at_rest(0.05 + 1e-9, 0.05, 0.1, 1.0)) < 1e-8
