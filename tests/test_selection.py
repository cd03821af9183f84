"""Object and constraint selectors on hand-built views, and the reducer's ordering, encoding and padding."""

import numpy as np
import pytest

from safemanip.env.observation import ROBOT_DIM, SLOT_DIM, SceneState, observation_dim
from safemanip.rl.numpy_actor import NumpyActor
from safemanip.selection.reducer import DUMMY_POSITIONS, DUMMY_RADIUS, Reducer, order_by_distance
from safemanip.evaluation.registry import (CONSTRAINT_SELECTORS, OBJECT_SELECTORS, SelectorOptions,
                                           make_constraint_selector, make_object_selector)
from safemanip.selection.selectors import (ConservativeConstraints, DynamicKNN, FullSelector, GroundTruthConstraints,
                                           PrivilegedCriticality, PrivilegedSelector, StaticKNN, criticality_first)
from conftest import BOX, scene_view


# object 0 is far, 1 near, 2 middle, 3 nearest
POS = [[0.9, 0.0], [0.2, 0.0], [0.0, 0.5], [0.0, -0.1]]


def test_nearest_is_horizontal_distance_to_the_box_centre():
    sel = DynamicKNN()
    v = scene_view(0, [[0.3, 0.0, 0.0], [0.0, 0.25, 5.0]])  # object 1 is far above but horizontally nearer
    sel.reset(v, 1)
    assert sel.select(v, 1) == [1]
    moved = scene_view(4, [[0.3, 0.0, 0.0], [0.0, 0.25, 5.0]], box=np.array([0.3, 0.1, 0.035]))  # the box moved
    assert sel.select(moved, 1) == [0]


def test_static_knn_picks_at_t0_and_never_repicks():
    sel = StaticKNN()
    sel.reset(scene_view(0, POS), 2)
    assert sel.select(scene_view(0, POS), 2) == [3, 1]
    swapped = [[0.0, -0.1], [0.9, 0.0], [0.0, 0.05], [0.0, 0.9]]  # now 0 and 2 are nearest
    for t in range(1, 40):
        assert sel.select(scene_view(t, swapped), 2) == [3, 1]
    assert sel.picks == 1


def test_dynamic_knn_repicks_every_interval_steps():
    sel = DynamicKNN()  # default interval: 4 (paper)
    sel.reset(scene_view(0, POS), 2)
    assert sel.select(scene_view(0, POS), 2) == [3, 1]
    swapped = [[0.0, -0.1], [0.9, 0.0], [0.0, 0.05], [0.9, 0.9]]
    for t in (1, 2, 3):  # keeps the last pick between queries even though the scene changed
        assert sel.select(scene_view(t, swapped), 2) == [3, 1]
    assert sel.select(scene_view(4, swapped), 2) == [2, 0]
    assert sel.picks == 2
    sel2 = DynamicKNN(interval=2)
    sel2.reset(scene_view(0, POS), 1)
    picks = [tuple(sel2.select(scene_view(t, POS if t < 2 else swapped), 1)) for t in range(5)]
    assert picks == [(3,), (3,), (2,), (2,), (2,)] and sel2.picks == 3
    with pytest.raises(ValueError, match="interval"):
        DynamicKNN(interval=0)


def test_dynamic_knn_starts_over_on_a_new_episode_without_reset():
    sel = DynamicKNN()
    sel.reset(scene_view(0, POS), 1)
    sel.select(scene_view(0, POS), 1)
    sel.select(scene_view(9, POS), 1)
    other = [[0.0, -0.05], [0.9, 0.0], [0.0, 0.5], [0.9, 0.9]]
    assert sel.select(scene_view(0, other), 1) == [0]  # t went backwards: a new episode, pick now


def test_privileged_prefers_fragile_then_tops_up_with_nearest_others():
    classes = ["fragile", "durable", "fragile", "soft"]  # the nearest two (3, 1) are not fragile
    sel = PrivilegedSelector()
    sel.reset(scene_view(0, POS, classes), 2)
    assert sel.select(scene_view(0, POS, classes), 2) == [2, 0]
    sel3 = PrivilegedSelector()
    sel3.reset(scene_view(0, POS, classes), 3)
    assert sel3.select(scene_view(0, POS, classes), 3) == [2, 0, 3]  # two fragile, then the nearest other
    with pytest.raises(ValueError, match="privileged_classes"):
        PrivilegedSelector().select(scene_view(0, POS), 2)


def test_criticality_first_fills_the_slots_fragile_then_soft_then_durable():
    classes = ["fragile", "durable", "fragile", "soft"]  # 3 (soft) is the nearest, 1 (durable) the next
    box, positions = BOX, np.c_[np.array(POS), np.zeros(4)]
    assert criticality_first(box, positions, classes, 2, soft_reach=0.0) == [2, 0]
    assert criticality_first(box, positions, classes, 3, soft_reach=0.0) == [2, 0, 3]  # soft before durable
    assert criticality_first(box, positions, classes, 4, soft_reach=0.0) == [2, 0, 3, 1]
    sel = PrivilegedCriticality(soft_reach=0.0)
    sel.reset(scene_view(0, POS, classes), 3)
    assert sel.select(scene_view(0, POS, classes), 3) == [2, 0, 3]
    # where privileged tops up with the nearest object of any class, the durable one (1) can take a soft one's slot
    far_soft = ["fragile", "durable", "durable", "soft"]
    moved = [[0.9, 0.0], [0.2, 0.0], [0.0, 0.5], [0.0, 0.6]]
    assert PrivilegedSelector().select(scene_view(0, moved, far_soft), 2) == [0, 1]
    assert PrivilegedCriticality(soft_reach=0.0).select(scene_view(0, moved, far_soft), 2) == [0, 3]
    with pytest.raises(ValueError, match="privileged_classes"):
        PrivilegedCriticality().select(scene_view(0, POS), 2)


def test_a_soft_object_within_reach_ranks_with_the_fragile_ones():
    """soft_reach: the soft object 0.1 m from the box (3) is about to be met and takes a slot ahead of the fragile
    one 0.9 m away (0); beyond the reach it waits behind every fragile object; durable ones stay last."""
    classes = ["fragile", "durable", "fragile", "soft"]
    box, positions = BOX, np.c_[np.array(POS), np.zeros(4)]
    assert criticality_first(box, positions, classes, 2, soft_reach=0.15) == [3, 2]
    assert criticality_first(box, positions, classes, 2, soft_reach=0.05) == [2, 0]
    assert criticality_first(box, positions, classes, 4, soft_reach=0.15) == [3, 2, 0, 1]
    assert criticality_first(box, positions, ["soft", "durable", "soft", "durable"], 2, soft_reach=0.3) == [2, 0]
    assert PrivilegedCriticality(soft_reach=0.15).select(scene_view(0, POS, classes), 2) == [3, 2]
    assert make_object_selector("privileged-criticality", SelectorOptions(soft_reach=0.15)).soft_reach == 0.15
    with pytest.raises(ValueError, match="soft_reach"):
        criticality_first(box, positions, classes, 2, soft_reach=-0.1)
    with pytest.raises(ValueError, match="soft_reach"):
        PrivilegedCriticality(soft_reach=-1)


def test_display_names_never_call_the_offline_classifier_a_vlm():
    from safemanip.evaluation.registry import display_name
    for name in ("semantic", "dynamic-vlm", "vlm"):
        offline = display_name(name, "semantic:class_examples_v6.json")
        assert "VLM" not in offline and "offline names" in offline
        assert display_name(name, "openai:llava:13b").endswith("(openai: llava:13b)")
    assert display_name("dynamic-knn") == "dynamic-knn"


def test_privileged_repicks_on_the_dynamic_schedule():
    classes = ["fragile", "fragile", "durable", "durable"]
    sel = PrivilegedSelector(interval=4)
    sel.reset(scene_view(0, POS, classes), 1)
    assert sel.select(scene_view(0, POS, classes), 1) == [1]
    closer0 = [[0.05, 0.0], [0.2, 0.0], [0.0, 0.5], [0.0, -0.1]]
    assert sel.select(scene_view(3, closer0, classes), 1) == [1]
    assert sel.select(scene_view(4, closer0, classes), 1) == [0]


def test_full_selector_and_constraint_selectors():
    assert FullSelector().select(scene_view(0, POS), 4) == [0, 1, 2, 3]
    classes = ["fragile", "soft", "durable", "fragile"]
    assert ConservativeConstraints().assign(scene_view(0, POS, classes)) == ["no_contact"] * 4
    assert GroundTruthConstraints().assign(scene_view(0, POS, classes)) == ["no_contact", "soft_contact", "any_contact",
                                                                      "no_contact"]


def test_registry_names_and_errors(tmp_path):
    assert {"static-knn", "dynamic-knn", "privileged", "dynamic-vlm"} <= set(OBJECT_SELECTORS)
    assert {"conservative", "ground-truth", "vlm"} <= set(CONSTRAINT_SELECTORS)
    assert make_object_selector("dynamic-knn", SelectorOptions(interval=7)).interval == 7
    with pytest.raises(ValueError, match="unknown object selector 'nearest'"):
        make_object_selector("nearest")
    with pytest.raises(ValueError, match="unknown constraint selector"):
        make_constraint_selector("gt")
    # the VLM seam: built from the semantics package with the backend options (no network at construction)
    opts = SelectorOptions(interval=3, vlm_backend="openai", vlm_model="m", vlm_cache=str(tmp_path), vlm_cache_only=True)
    vlm = make_object_selector("dynamic-vlm", opts)
    assert vlm.query_interval == 3 and vlm.backend.model == "m" and vlm.backend.cache.mode == "cache_only"
    assert make_constraint_selector("vlm", opts).name == "vlm"


# ------------------------------------------------------------------------------------------ reducer
def state(obj_xy, box=(0.0, 0.0)):
    n = len(obj_xy)
    obj = np.c_[np.asarray(obj_xy, dtype=float), np.full(n, 0.0005)]
    return SceneState(ee_pos=np.array([box[0], box[1] - 0.095, 0.035]), ee_vel=np.array([0.1, 0.0, 0.0]),
                      bottom_pos=np.array([box[0], box[1], 0.035]), bottom_vel=np.array([0.1, 0.0, 0.0]),
                      top_pos=np.array([0.0, 0.04, 0.105]), top_vel=np.zeros(3), obj_pos=obj,
                      obj_vel=np.arange(3 * n, dtype=float).reshape(n, 3) / 100)


def slots(obs, k):
    return obs[ROBOT_DIM:].reshape(k, SLOT_DIM)


def test_reducer_orders_slots_nearest_first_and_encodes_constraints():
    s = state([[0.5, 0.0], [0.1, 0.0], [0.0, 0.3], [0.2, 0.2]])
    assert order_by_distance(s, [0, 1, 2]) == [1, 2, 0]
    constraints = ["no_contact", "any_contact", "soft_contact", "no_contact"]
    red = Reducer(3, "all")
    obs = red(s, [0, 2, 1], constraints)  # the selector's order does not matter
    assert obs.shape == (observation_dim(3),) and obs.dtype == np.float32
    sl = slots(obs, 3)
    np.testing.assert_allclose(sl[:, :3], s.obj_pos[[1, 2, 0]], atol=1e-7)
    np.testing.assert_allclose(sl[:, 3:6], s.obj_vel[[1, 2, 0]], atol=1e-7)
    np.testing.assert_array_equal(sl[:, 6:], [[0, 0, 1], [0, 1, 0], [1, 0, 0]])  # any, soft, no
    np.testing.assert_allclose(obs[6:9], s.bottom_pos, atol=1e-7)
    np.testing.assert_array_equal(obs, red(s, [1, 0, 2], constraints))


def test_reducer_equal_distances_break_ties_by_id():
    s = state([[0.2, 0.0], [-0.2, 0.0], [0.0, 0.2]])
    assert order_by_distance(s, [2, 1, 0]) == [0, 1, 2]


def test_conservative_policy_gets_no_contact_whatever_the_selector_says():
    s = state([[0.5, 0.0], [0.1, 0.0], [0.0, 0.3]])
    obs = Reducer(2, "conservative")(s, [0, 1], ["any_contact", "soft_contact", "any_contact"])
    np.testing.assert_array_equal(slots(obs, 2)[:, 6:], [[1, 0, 0], [1, 0, 0]])


def test_reducer_pads_missing_slots_with_far_dummies_only_when_allowed():
    s = state([[0.1, 0.0]])
    with pytest.raises(ValueError, match="--pad"):
        Reducer(3, "all")(s, [0], ["no_contact"])
    obs = Reducer(3, "all", pad=True)(s, [0], ["soft_contact"])
    sl = slots(obs, 3)
    np.testing.assert_allclose(sl[0, :3], s.obj_pos[0], atol=1e-7)
    np.testing.assert_allclose(sl[1:, :3], DUMMY_POSITIONS[:2], atol=1e-6)
    np.testing.assert_array_equal(sl[1:, 3:6], 0.0)  # dummies stand still
    np.testing.assert_array_equal(sl[:, 6:], [[0, 1, 0], [0, 0, 1], [0, 0, 1]])  # dummies: any_contact
    cons = slots(Reducer(3, "conservative", pad=True)(s, [0], ["soft_contact"]), 3)
    np.testing.assert_array_equal(cons[:, 6:], [[1, 0, 0]] * 3)  # a conservative policy knows only no_contact
    # dummies are far from the box's path to the goal (y about -0.15) and on the table
    assert np.all(DUMMY_POSITIONS[:, 1] > 0.2) and np.all(np.abs(DUMMY_POSITIONS[:, 0]) < 0.75)
    empty = Reducer(2, "all", pad=True)(state(np.zeros((0, 2))), [], [])
    assert empty.shape == (observation_dim(2),)


def test_reducer_gives_a_sized_policy_each_slots_radius_and_dummies_a_mid_size():
    s = state([[0.5, 0.0], [0.1, 0.0], [0.0, 0.3]])._replace(obj_radius=np.array([0.03, 0.1, 0.06]))
    red = Reducer(4, "conservative", pad=True, object_size=True)
    obs = red(s, [2, 0, 1], ["no_contact"] * 3)
    assert obs.shape == (observation_dim(4, object_size=True),) == (red.obs_dim,)
    sl = obs[ROBOT_DIM:].reshape(4, SLOT_DIM + 1)
    np.testing.assert_allclose(sl[:, 9], [0.1, 0.06, 0.03, DUMMY_RADIUS], atol=1e-7)  # nearest first, then the dummy
    np.testing.assert_array_equal(sl[:3, :9], slots(Reducer(3, "conservative")(s, [2, 0, 1], ["no_contact"] * 3), 3))
    empty = Reducer(3, "all", empty_slots=True, object_size=True)(s, [1], ["no_contact"] * 3)
    np.testing.assert_array_equal(empty[ROBOT_DIM + 10:], 0.0)  # absent slots stay all zeros, size included
    with pytest.raises(ValueError, match="obj_radius"):
        Reducer(2, "conservative", object_size=True)(state([[0.1, 0.0], [0.2, 0.0]]), [0, 1], ["no_contact"] * 2)


def test_reducer_rejects_bad_input():
    s = state([[0.1, 0.0], [0.2, 0.0]])
    with pytest.raises(ValueError, match="distinct"):
        Reducer(2, "all")(s, [0, 0], ["no_contact"] * 2)
    with pytest.raises(ValueError, match="k=1"):
        Reducer(1, "all")(s, [0, 1], ["no_contact"] * 2)
    with pytest.raises(ValueError, match="policy_constraints"):
        Reducer(1, "some")


def test_numpy_policy_matches_the_torch_actor():
    import torch

    from safemanip.rl.networks import Actor, actor_arrays

    torch.manual_seed(0)
    actor = Actor(observation_dim(2), 3, (64, 64))
    obs = np.random.default_rng(0).normal(size=(5, observation_dim(2))).astype(np.float32)
    with torch.no_grad():
        expected = actor(torch.from_numpy(obs)).numpy()
    np.testing.assert_allclose(NumpyActor(actor_arrays(actor))(obs), expected, atol=1e-5)
