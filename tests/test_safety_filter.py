"""The braking safety filter (``safety/braking.py``): it stops the box before an object in its way at full speed in
every direction, leaves alone a policy that keeps its clearance, and keeps a random policy from hitting anything."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from safemanip.env.slide_out import SlideOutEnv
from safemanip.safety.braking import BrakingShield

D4 = 0.01


def _free_box(env) -> None:
    """The box pulled out from under the top box to the right, then at rest."""
    for _ in range(8):
        env.step(np.array([0.7, 0.0, 0.0], dtype=np.float32))
    for _ in range(15):
        env.step(np.zeros(3, dtype=np.float32))


def _place(env, i: int, xy) -> None:
    adr = int(env.index.object_qpos[i])
    env.data.qpos[adr:adr + 2] = xy
    env.data.qvel[int(env.index.object_qvel[i]):int(env.index.object_qvel[i]) + 6] = 0.0
    mujoco.mj_forward(env.model, env.data)


@pytest.mark.parametrize("angle", range(0, 360, 45))
def test_full_speed_towards_a_fragile_object_stops_short_of_it(angle):
    """A ceramic bowl straight ahead in each of eight directions, 25 cm beyond the box's footprint (12 cm towards
    the top box, 40 cm to the left, and towards the robot, whose table edge is 44 cm away), and the policy asks for
    full speed at it, every step: the box never comes within d4 of it (it stops, or slides past it)."""
    env = SlideOutEnv(n_objects=1, names=["ceramic bowl"], constraints="conservative")
    env.reset(seed=0)
    _free_box(env)
    direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    box = env.scene_state().bottom_pos[:2]
    gap = 0.12 if min(direction) < -0.5 else 0.25  # the top box to the left, the table's near edge 44 cm away
    _place(env, 0, box + direction * (0.165 + 0.075 + gap))  # the box's half-diagonal, the bowl's radius, the gap
    shield = BrakingShield()
    worst = np.inf
    for _ in range(40):
        action = shield.filter(env, np.r_[direction, 0.0].astype(np.float32), env.constraints)
        _, _, terminated, _, info = env.step(action)
        worst = min(worst, info["margins"]["g_hard:0:ceramic bowl"] + D4)
        assert info["event"] not in ("failure:hard", "failure:dyn", "failure:oob"), (angle, info["event"])
        if terminated:
            break
    assert shield.stats.overrides > 0  # it did have to brake
    assert worst > D4, f"came within {100 * worst:.1f} cm of the bowl"


def test_a_creeping_command_stops_at_the_floor():
    """A policy that asks for a few mm/s towards a fragile object for 15 s (below the speeds at which the box's own
    motion is checked): its commanded path is still checked, so the box stops outside d4. Before, the filter checked
    nothing below 1 cm/s and the box crept into the object (17 episodes of one policy on block 47)."""
    env = SlideOutEnv(n_objects=1, names=["ceramic bowl"], constraints="conservative")
    env.reset(seed=0)
    _free_box(env)
    box = env.scene_state().bottom_pos[:2]
    _place(env, 0, box + np.array([0.095 + 0.075 + 0.03, 0.0]))  # 3 cm beyond the box's short side, along +x
    shield = BrakingShield()
    creep = np.array([0.06, 0.0, 0.0], dtype=np.float32)  # with the benchmark's action curve 2: about 6 mm/s
    env.setpoint.curve = 2.0
    worst = np.inf
    for _ in range(300):
        _, _, terminated, _, info = env.step(shield.filter(env, creep, env.constraints))
        worst = min(worst, info["margins"]["g_hard:0:ceramic bowl"] + D4)
        assert info["event"] != "failure:hard"
        if terminated:
            break
    moved = env.scene_state().bottom_pos[0] - box[0]
    assert moved > 0.01, "the creep never started: the test checks nothing"
    assert shield.stats.overrides > 0 and worst > D4, f"came within {100 * worst:.1f} cm of the bowl"


def test_a_policy_that_keeps_its_clearance_is_never_overridden():
    env = SlideOutEnv(n_objects=2, names=["wine glass", "red mug"], constraints="conservative")
    env.reset(seed=0)
    _free_box(env)
    box = env.scene_state().bottom_pos[:2]
    _place(env, 0, box + np.array([0.0, 0.40]))  # well beside the path
    _place(env, 1, box + np.array([-0.35, 0.0]))  # behind the box
    shield = BrakingShield()
    rng = np.random.default_rng(0)
    for _ in range(20):  # slow moves along +x, away from the mug, past the glass
        action = np.array([0.35, rng.uniform(-0.05, 0.05), 0.0], dtype=np.float32)
        assert np.array_equal(shield.filter(env, action, env.constraints), action)
        env.step(action)
    assert shield.stats.overrides == 0 and shield.stats.steps == 20


def test_leaving_an_object_it_is_too_close_to_is_allowed_and_any_contact_objects_are_ignored():
    env = SlideOutEnv(n_objects=1, names=["toy sheep"], constraints="conservative")
    env.reset(seed=0)
    _free_box(env)
    box = env.scene_state().bottom_pos[:2]
    _place(env, 0, box + np.array([0.0, 0.135 + 0.05 + 0.012]))  # just outside the box's long side, inside clearance
    shield = BrakingShield()
    away = np.array([0.0, -0.5, 0.0], dtype=np.float32)
    assert np.array_equal(shield.filter(env, away, ["no_contact"]), away)
    towards = np.array([0.1, 0.5, 0.0], dtype=np.float32)
    kept = shield.filter(env, towards, ["no_contact"])
    assert kept[1] <= 0.0 and not np.array_equal(kept, towards)  # nothing of it towards the sheep is kept
    assert np.array_equal(shield.filter(env, towards, ["any_contact"]), towards)  # a durable object: no guard


@pytest.mark.slow
@pytest.mark.parametrize("layout, semantics, constraints", [
    ("exit", None, "conservative"), ("gate", "2 fragile, 2 soft, 1 durable", "ground_truth")])
def test_a_wrapped_random_policy_hits_nothing_in_200_episodes(layout, semantics, constraints):
    """Exit scenes (a fragile object past the pull lane) and gate scenes (soft and durable blockers, fragile objects
    beside them): with the filter, a random policy never collides with a protected object nor touches a soft one
    too fast. The top box is the task policy's job (docs/safety.md)."""
    env = SlideOutEnv(n_objects=5, classes=semantics, constraints=constraints, layout=layout,
                      **({"exit_share": 1.0} if layout == "exit" else {"gate_share": 1.0}))
    shield = BrakingShield()
    rng = np.random.default_rng(0)
    events = {}
    for episode in range(200):
        env.reset(seed=4_500_000 + episode)
        while True:
            action = shield.filter(env, rng.uniform(-1.0, 1.0, 3).astype(np.float32), env.constraints)
            _, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        events[info["event"]] = events.get(info["event"], 0) + 1
    assert not events.get("failure:hard") and not events.get("failure:soft"), events
    assert shield.stats.overrides > 0


def test_which_objects_it_protects_comes_from_the_cells_best_semantic_source():
    """Constraint selector's types when semantic or ground truth; else the object selector's classes (privileged:
    true, semantic: decided); else every object no_contact (a kNN cell with conservative types stops at a blocker)."""
    from types import SimpleNamespace

    from safemanip.evaluation.episode import shield_constraints

    view = SimpleNamespace(names=("red mug", "toy sheep"), privileged_classes=("fragile", "durable"))
    named = lambda name, **kw: SimpleNamespace(name=name, **kw)  # noqa: E731
    assigned = ["no_contact", "soft_contact"]
    assert shield_constraints(named("dynamic-knn"), named("ground-truth"), assigned, view) == assigned
    assert shield_constraints(named("dynamic-knn"), named("vlm"), assigned, view) == assigned
    assert shield_constraints(named("privileged"), named("conservative"), ["no_contact"] * 2, view) == \
        ["no_contact", "any_contact"]
    classifier = SimpleNamespace(classify=lambda names: ["fragile", "soft"])
    assert shield_constraints(named("semantic", backend=classifier), named("conservative"), [], view) == \
        ["no_contact", "soft_contact"]
    assert shield_constraints(named("dynamic-knn"), named("conservative"), [], view) == ["no_contact"] * 2


def test_eval_refuses_an_unknown_filter_and_a_filter_around_the_planner():
    from safemanip.evaluation.harness import EvalConfigError, EvalRequest, prepare

    with pytest.raises(EvalConfigError, match="unknown --shield 'airbag'"):
        prepare(EvalRequest(policy="rarl-k2-conservative-s0", shield="airbag", episodes=1))
    with pytest.raises(EvalConfigError, match="--shield wraps a policy"):
        prepare(EvalRequest(policy=None, planner="all", n_objects=2, shield="brake", episodes=1))
    prep = prepare(EvalRequest(policy="rarl-k2-conservative-s0", shield="brake", episodes=1))
    assert prep.spec.shield == "brake"


def test_rectangle_distances_match_their_sampled_boundaries():
    """The oriented-rectangle footprints: apart, the distance equals the least distance between densely sampled edges;
    overlapping, it is negative."""
    from safemanip.safety.braking import _corners, _rect_distances

    def edge_points(c, yaw, half):
        corners = _corners(np.asarray(c), yaw, np.asarray(half))
        t = np.linspace(0.0, 1.0, 200)[:, None]  # at most 1.5 mm apart
        return np.concatenate([corners[i] + t * (corners[(i + 1) % 4] - corners[i]) for i in range(4)])

    rng = np.random.default_rng(3)
    apart = overlapping = 0
    for _ in range(120):
        c1, c2 = rng.uniform(-0.3, 0.3, (2, 2))
        y1, y2 = rng.uniform(-np.pi, np.pi, 2)
        h1, h2 = rng.uniform(0.01, 0.15, (2, 2))
        d = float(_rect_distances(c1, y1, h1, c2[None], np.array([y2]), h2[None])[0])
        a, b = edge_points(c1, y1, h1), edge_points(c2, y2, h2)
        sampled = float(np.min(np.linalg.norm(a[:, None] - b[None], axis=-1)))
        if sampled < 1e-3 or d < 0:  # touching or overlapping (then the sampled edges cross or nest)
            overlapping += d <= 1e-9
            continue
        apart += 1
        assert abs(d - sampled) < 2e-3, (d, sampled)
    assert apart > 30 and overlapping > 10


def test_a_footprint_rectangle_holds_the_object_and_beats_the_circle_on_long_objects():
    """``footprint_rect`` contains every part's box; on a long object it is far tighter than the radius sideways."""
    from safemanip.scene.catalog import _part_corners, load_catalog

    for obj in load_catalog().values():
        cx, cy, hx, hy = obj.footprint_rect
        for part in obj.parts:
            xy = _part_corners(part)[:, :2]
            assert (np.abs(xy - (cx, cy)) <= np.array([hx, hy]) + 1e-9).all(), obj.name
    phone = load_catalog()["smartphone"]
    assert min(phone.footprint_rect[2:]) < phone.footprint_radius - 0.04


def test_the_hand_above_the_box_is_swept_too():
    """The hand above the held box reaches past the box's footprint once the box has turned in the grip, and meets
    the bowl of a tall wine glass the box itself passes. Development block 45, seed 4500258 (``rarl-k2-conservative-s1``,
    static kNN, a gate scene): with only the box swept, the hand hit the glass at step 106 while the filter's model put
    the box 10.8 cm from it. With the hand's footprint swept too (for the objects tall enough to reach it), nothing
    is hit."""
    from safemanip.evaluation.episode import run_episode
    from safemanip.evaluation.harness import EvalRequest, prepare
    from safemanip.evaluation.parallel import make_numpy_actor
    from safemanip.evaluation.registry import make_constraint_selector, make_object_selector
    from safemanip.selection.reducer import Reducer

    spec = prepare(EvalRequest(policy="rarl-k2-conservative-s1", n_objects=5, semantics="2 fragile, 3 durable",
                               selector="static-knn", constraint_selector="conservative", shield="brake", episodes=1,
                               env={"layout": "gate", "gate_share": 1.0})).spec
    env = SlideOutEnv(**spec.env_kwargs)
    shield = BrakingShield()
    hand_beside = []

    def on_step(env, info, ids):
        glass = env.names.index("wine glass")
        hand_beside.append(env._last_terms["distances"][glass])

    record = run_episode(env, make_numpy_actor(spec.actor_arrays), Reducer(2, "conservative", object_size=True),
                         make_object_selector("static-knn", spec.options),
                         make_constraint_selector("conservative", spec.options), 4500258, shield=shield,
                         on_step=on_step)
    assert "wine glass" in env.names and min(hand_beside) < 0.05  # the hand did come near the glass
    assert record["category"] not in ("collision_selected", "collision_unselected"), record
