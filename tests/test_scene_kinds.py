"""Gate and exit scenes (``scene.placement.SCENE_KINDS``): what each kind places where, that the env confirms each
one with the planner's free-space map, records the kind per episode, and mixes kinds by the config's shares."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from safemanip.control.planner import open_for_the_arm, part_extents
from safemanip.env.slide_out import SlideOutEnv
from safemanip.scene.config import SceneConfig, SceneConfigError
from safemanip.scene.placement import EXIT_CLEARANCE, LAYOUTS, _route_gap_squared


def test_layouts_mix_kinds_by_their_shares():
    assert LAYOUTS["route"].gate_share == LAYOUTS["route"].exit_share == 0.0
    assert LAYOUTS["gate"].gate_share == 0.5 and LAYOUTS["exit"].exit_share == 0.5
    assert SceneConfig(layout="gate").kind_shares == (0.5, 0.0)
    assert SceneConfig(layout="route", exit_share=1.0).kind_shares == (0.0, 1.0)


@pytest.mark.parametrize("shares", [dict(gate_share=0.7, exit_share=0.5), dict(gate_share=-0.1), dict(exit_share=True),
                                    dict(gate_share="half")])
def test_bad_shares_are_refused(shares):
    with pytest.raises(SceneConfigError, match="share"):
        SceneConfig(**shares)


def test_every_episode_records_its_kind_in_the_layouts_proportions():
    env = SlideOutEnv(n_objects=4, layout="exit", constraints="conservative")
    kinds = Counter(env.reset(seed=seed)[1]["scene_kind"] for seed in range(40))
    assert set(kinds) == {"open", "exit"} and 10 <= kinds["exit"] <= 30


@pytest.mark.slow
def test_gate_scenes_are_closed_avoiding_everything_and_open_avoiding_the_fragile_objects():
    env = SlideOutEnv(n_objects=5, classes="2 fragile, 3 durable", gate_share=1.0)
    gates = 0
    for seed in range(12):
        _, info = env.reset(seed=seed)
        placement = env.placement
        if info["scene_kind"] != "gate":
            continue
        gates += 1
        fragile = [c == "no_contact" for c in env.constraints]
        roles = placement.roles
        assert 1 <= roles.count("blocker") <= 2
        assert all(not fragile[i] for i, r in enumerate(roles) if r == "blocker")
        assert all(fragile[i] for i, r in enumerate(roles) if r == "flank")
        # a blocker stands on the route's band, a flank beside it
        for i, r in enumerate(roles):
            on_band = _route_gap_squared(placement.xy[i:i + 1, 0], placement.xy[i:i + 1, 1], placement.route)[0] == 0
            assert on_band == (r == "blocker"), (seed, i, r)
        assert not open_for_the_arm(env)
        assert open_for_the_arm(env, part_extents(env, np.flatnonzero(fragile)))
    assert gates >= 10  # nearly every draw finds a gate within the env's tries


def test_a_gate_needs_a_touchable_object_and_falls_back_to_an_open_scene():
    env = SlideOutEnv(n_objects=3, constraints="conservative", gate_share=1.0)  # every object no_contact
    for seed in range(5):
        _, info = env.reset(seed=seed)
        assert info["scene_kind"] == "open" and env.placement.roles == ()


@pytest.mark.slow
def test_exit_scenes_put_one_fragile_object_just_past_the_pull_lane_and_stay_open():
    env = SlideOutEnv(n_objects=4, constraints="conservative", exit_share=1.0)
    geo, gap = env.geometry, LAYOUTS["route"].exit.gap
    lane_end = geo.path_start_xy[0] + geo.box_half_extents[0]
    exits = 0
    for seed in range(12):
        _, info = env.reset(seed=seed)
        if info["scene_kind"] != "exit":
            continue
        exits += 1
        (probe,) = [i for i, r in enumerate(env.placement.roles) if r == "probe"]
        near_edge = env.placement.xy[probe, 0] - env._footprint_radii(env.names)[probe]
        assert lane_end + EXIT_CLEARANCE + gap[0] - 1e-9 <= near_edge <= lane_end + EXIT_CLEARANCE + gap[1] + 1e-9
        assert abs(env.placement.xy[probe, 1] - geo.path_start_xy[1]) <= geo.box_half_extents[1]
        assert open_for_the_arm(env)
    assert exits >= 10


def test_scene_kinds_are_deterministic_for_a_seed():
    a = SlideOutEnv(n_objects=5, classes="2 fragile, 2 soft, 1 durable", layout="gate")
    b = SlideOutEnv(n_objects=5, classes="2 fragile, 2 soft, 1 durable", layout="gate")
    for seed in range(4):
        oa, ia = a.reset(seed=seed)
        ob, ib = b.reset(seed=seed)
        assert ia["scene_kind"] == ib["scene_kind"]
        np.testing.assert_array_equal(oa, ob)
