"""Dynamic k: the dynamic-radius selector, the reducer's empty slots, and a set-network policy evaluated
with a varying number of objects by ``safemanip eval``'s harness."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from safemanip.env.observation import SceneState, observation_dim
from safemanip.evaluation.episode import parse_selections
from safemanip.selection.reducer import Reducer
from safemanip.evaluation.registry import SelectorOptions, make_object_selector
from safemanip.selection.selectors import DynamicRadius
from conftest import scene_view


def test_dynamic_radius_picks_the_objects_within_the_radius_nearest_first_at_most_k():
    sel = make_object_selector("dynamic-radius", SelectorOptions(interval=4, radius=0.3))
    assert isinstance(sel, DynamicRadius) and sel.variable_k
    xy = [[0.9, 0.0], [0.2, 0.0], [0.0, 0.29], [0.0, -0.1], [0.31, 0.0]]
    v0 = scene_view(0, xy)
    sel.reset(v0, 3)
    assert sel.select(v0, 3) == [3, 1, 2]  # within 0.3 m: 3 (0.1), 1 (0.2), 2 (0.29); 4 (0.31) and 0 are out
    two = DynamicRadius(4, 0.3)
    two.reset(v0, 2)
    assert two.select(v0, 2) == [3, 1]  # never more than k
    # re-picks on the dynamic-knn schedule only: objects that moved in are seen at t = 4, not t = 1
    moved = [[0.05, 0.0], [0.9, 0.9], [0.9, -0.9], [0.9, 0.5], [0.9, -0.5]]
    assert sel.select(scene_view(1, moved), 3) == [3, 1, 2]
    assert sel.select(scene_view(4, moved), 3) == [0]
    assert sel.select(scene_view(8, [[0.9, 0.9]]), 3) == []  # nothing near: no objects at all


def test_reducer_empty_slots_are_zero_and_the_real_slots_match_the_unpadded_observation():
    rng = np.random.default_rng(0)
    state = SceneState(*(rng.normal(size=3) for _ in range(6)), obj_pos=rng.normal(size=(5, 3)) * 0.3,
                       obj_vel=rng.normal(size=(5, 3)) * 0.1)
    types = ["no_contact"] * 5
    padded = Reducer(4, "all", empty_slots=True)(state, [2, 0], types)
    exact = Reducer(2, "all")(state, [2, 0], types)
    assert padded.shape == (observation_dim(4),)
    np.testing.assert_array_equal(padded[:observation_dim(2)], exact)
    assert not padded[observation_dim(2):].any()
    with pytest.raises(ValueError, match="allow padding"):
        Reducer(4, "all")(state, [2, 0], types)  # without empty slots (or dummies) fewer ids are an error


def test_set_policy_evaluates_with_dynamic_radius_in_a_larger_scene(tmp_path):
    from safemanip.evaluation.harness import EvalRequest, evaluate, prepare
    from safemanip.rl.checkpoint import save_policy
    from safemanip.rl.networks import SetActor, actor_arrays

    torch.manual_seed(0)
    meta = {"algorithm": "rarl", "k": 3, "constraints": "conservative", "network": "set",
            "env_kwargs": {"n_objects": 3, "constraints": "conservative", "near_path_fraction": 0.5,
                           "max_episode_steps": 20, "slot_order": "nearest", "embodiment": "panda"}}
    path = save_policy(tmp_path / "set.safetensors", actor_arrays(SetActor(3, (16, 16), 8)), meta)
    req = EvalRequest(policy=str(path), n_objects=5, selector="dynamic-radius", judge="conservative", episodes=3,
                      workers=1, out=str(tmp_path / "eval"))
    assert prepare(req).spec.k == 3
    result = evaluate(req)
    assert result["summary"]["episodes"] == 3 and result["summary"]["eval"]["selector"] == "dynamic-radius"
    for record in result["records"]:  # every selection held at most k = 3 objects of the 5
        for _, ids in parse_selections(record["selections"]):
            assert len(ids) <= 3 and all(0 <= i < 5 for i in ids)
    # a flat-MLP policy cannot take a varying number of objects without padding: refused before any episode
    from safemanip.evaluation.harness import EvalConfigError

    from safemanip.rl.networks import Actor

    flat = save_policy(tmp_path / "flat.safetensors", actor_arrays(Actor(observation_dim(2), 3, (16, 16))),
                       {**meta, "k": 2, "network": "mlp", "env_kwargs": {**meta["env_kwargs"], "n_objects": 2}})
    with pytest.raises(EvalConfigError, match="varying number of objects"):
        prepare(EvalRequest(policy=str(flat), n_objects=4, selector="dynamic-radius", episodes=1))
