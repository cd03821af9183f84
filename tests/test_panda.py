"""The Franka Panda embodiment: the model comes from the installed gymnasium-robotics package, carries the
corrections we make to it, starts with its fingertips on the box lip, and never exceeds Franka's limits."""

from __future__ import annotations

import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest

import safemanip  # noqa: F401
from safemanip.control.diff_ik import (MAX_EE_ACCEL, MAX_EE_SPEED, limit_ee_velocity, limit_joint_acceleration,
                                       limit_joint_velocity)
from safemanip.env.slide_out import SlideOutEnv
from safemanip.scene.config import GEOMETRY
from safemanip.scene.grasp import PAD_MASS
from safemanip.scene.panda import (FRANKA_JOINT_ACCELS, FRANKA_JOINT_JERKS, FRANKA_JOINT_RANGES, FRANKA_JOINT_SPEEDS,
                                   FRANKA_JOINT_TORQUES, JOINTS, load_panda_spec, panda_asset_dir)

REPO = Path(__file__).resolve().parents[1]


def test_the_model_loads_from_the_installed_package_and_is_not_copied_here():
    import gymnasium_robotics

    folder = panda_asset_dir()
    assert folder.is_relative_to(Path(gymnasium_robotics.__file__).parent)
    spec = load_panda_spec(visual=True)
    files = [m.file for m in spec.meshes if m.file]
    assert len(files) == 20  # 9 collision + 9 visual link meshes + 2 finger meshes, all from that folder
    assert all(Path(f).resolve().is_relative_to(folder.resolve()) for f in files)
    model = spec.compile()
    assert sum(model.body_mass) == pytest.approx(18.0 + 2 * PAD_MASS, abs=0.05)  # and the two pads
    # (the package may sit in a .venv inside the checkout: what matters is that git tracks none of it)
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True).stdout.split()
    assert not [f for f in tracked if (REPO / f).resolve().is_relative_to(folder.resolve())]
    assert not [f for f in tracked if f.lower().endswith((".stl", ".obj"))], "no robot mesh is copied into the repo"


def test_the_corrections_are_applied():
    model = load_panda_spec(visual=False).compile()
    for i, name in enumerate(JOINTS):
        joint = model.joint(name)
        assert joint.damping[0] == pytest.approx(1.0) and joint.armature[0] == pytest.approx(0.1)
        np.testing.assert_allclose(joint.range, FRANKA_JOINT_RANGES[i])
    assert np.all(model.body_gravcomp[1:] == 1.0)
    assert model.njnt == 9  # the fingers are fixed (opened); each pad slides on its spring
    assert [model.joint(i).name for i in range(7, 9)] == ["pad_left", "pad_right"]
    data = mujoco.MjData(model)
    data.qpos[:7] = 0.0
    mujoco.mj_kinematics(model, data)
    # Franka's zero configuration: the flange 0.926 m up and 0.088 m forward, the hand pointing down
    link7 = model.body("panda0_link7").id
    np.testing.assert_allclose(data.xpos[link7], [0.088, 0.0, 1.033], atol=1e-3)
    np.testing.assert_allclose(data.xmat[link7].reshape(3, 3)[:, 2], [0, 0, -1], atol=1e-3)


def test_each_load_is_independent_and_compiles_to_the_same_model():
    """Editing or attaching one loaded Panda must not leak into the next load (scenes reuse what they build),
    and a later load must compile to the same model as the first one did."""
    first = load_panda_spec(visual=False, gap=0.01)
    reference = first.compile()
    first.joint(JOINTS[0]).damping = [7.0, 0.0, 0.0]
    first.worldbody.add_body(name="stray").add_geom(size=[0.1, 0, 0])
    again = load_panda_spec(visual=False, gap=0.01).compile()
    assert again.joint(JOINTS[0]).damping[0] == pytest.approx(1.0)
    assert (again.nbody, again.ngeom, again.nmesh) == (reference.nbody, reference.ngeom, reference.nmesh)
    np.testing.assert_array_equal(again.geom_size, reference.geom_size)
    np.testing.assert_array_equal(again.body_mass, reference.body_mass)


def test_servos_are_torque_limited_like_a_panda():
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    forcerange = env.model.actuator_forcerange[env.binding.actuator_ids]
    np.testing.assert_allclose(forcerange[:, 1], FRANKA_JOINT_TORQUES)
    assert env.model.nu == 7


def test_home_puts_the_pads_on_the_lip_with_the_hand_down():
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    d, b = env.data, env.binding
    gx, gy = GEOMETRY.grasp_xy
    np.testing.assert_allclose(d.site_xpos[b.ee_site][:2], [gx, gy], atol=1e-3)
    np.testing.assert_allclose(d.site_xmat[b.ee_site].reshape(3, 3)[:, 2], [0, 0, -1], atol=1e-3)
    q = d.qpos[b.qpos_adr]
    assert np.all(q > FRANKA_JOINT_RANGES[:, 0]) and np.all(q < FRANKA_JOINT_RANGES[:, 1])
    box = d.xpos[env.index.bottom_box_body]
    np.testing.assert_allclose(box[:2], GEOMETRY.bottom_xy, atol=1e-3)


def test_cartesian_limiter_caps_speed_by_norm_and_acceleration():
    dt = 0.05
    v = limit_ee_velocity(np.array([3.0, 3.0, 0.0]), np.zeros(3), dt)
    assert np.linalg.norm(v) == pytest.approx(MAX_EE_ACCEL * dt)
    assert v[0] == pytest.approx(v[1])  # direction kept, not clipped per axis
    previous = np.array([1.7, 0.0, 0.0])
    v = limit_ee_velocity(np.array([-1.7, 0.0, 0.0]), previous, dt)
    assert np.linalg.norm(v - previous) == pytest.approx(MAX_EE_ACCEL * dt)
    v = np.zeros(3)
    for _ in range(10):
        v = limit_ee_velocity(np.array([5.0, 5.0, 5.0]), v, dt)
    assert np.linalg.norm(v) == pytest.approx(MAX_EE_SPEED)


def test_joint_limiter_keeps_direction_and_brakes_before_the_range_ends():
    lower, upper = -np.ones(2), np.ones(2)
    speed, accel = np.full(2, 2.0), np.full(2, 10.0)
    qdot = limit_joint_velocity(np.array([4.0, 2.0]), np.zeros(2), lower, upper, speed, accel)
    np.testing.assert_allclose(qdot, [2.0, 1.0])  # scaled uniformly
    near = limit_joint_velocity(np.array([2.0, 0.0]), np.array([0.99, 0.0]), lower, upper, speed, accel)
    assert near[0] == pytest.approx(np.sqrt(2 * 10.0 * 0.01))  # can still stop within the 1 cm left
    away = limit_joint_velocity(np.array([-2.0, 0.0]), np.array([0.99, 0.0]), lower, upper, speed, accel)
    assert away[0] == pytest.approx(-2.0)  # moving away from a limit is never held back


def test_joint_acceleration_limiter_scales_the_change_and_keeps_its_direction():
    previous, wanted, cap = np.array([1.0, 0.0]), np.array([2.0, -2.0]), np.array([0.5, 0.5])
    qdot = limit_joint_acceleration(wanted, previous, cap)
    np.testing.assert_allclose(qdot, [1.25, -0.5])  # the change (1, -2) scaled by 1/4: joint 2 at its cap
    np.testing.assert_allclose(limit_joint_acceleration(np.array([1.2, 0.1]), previous, cap), [1.2, 0.1])


def test_speed_scale_is_the_share_of_the_ik_speed_the_limits_let_through():
    """``binding.speed_scale`` (read by benchmarks/tracking.py) is worked out when asked from the last step's joint
    velocities: 1 when nothing held the arm back, less once the acceleration limit does (a standing start at full
    speed), never more."""
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    assert env.binding.speed_scale == 1.0  # no step yet
    env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    b = env.binding
    assert b.speed_scale == pytest.approx(np.linalg.norm(b.limited_qdot) / np.linalg.norm(b.ik_qdot))
    assert 0.0 < b.speed_scale < 1.0
    for _ in range(3):
        env.step(np.zeros(3, dtype=np.float32))
    assert 0.0 < env.binding.speed_scale <= 1.0


def test_braking_leaves_room_for_one_more_control_step():
    """Discrete braking: hold v for dt, then stop at a: v dt + v^2 / 2a <= s."""
    s, a, dt = 0.05, 6.0, 0.05
    v = limit_joint_velocity(np.array([5.0]), np.array([1.0 - s]), -np.ones(1), np.ones(1), np.full(1, 9.0),
                             np.full(1, a), dt)[0]
    assert v * dt + v * v / (2 * a) == pytest.approx(s)
    assert v < np.sqrt(2 * a * s)  # stricter than the continuous curve


SUBSTEP = 0.002


def _watch_arm(env, samples):
    def watch(e):
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(e.model, e.data, mujoco.mjtObj.mjOBJ_SITE, e.binding.ee_site, velocity, 0)
        samples.append((velocity[3:].copy(), e.data.qvel[e.binding.dof_adr].copy(), e.data.qpos[e.binding.qpos_adr].copy(),
                        e.data.act[e.binding.act_adr].copy()))
    env.watch_substeps(1, watch)


def _arm_limits_hold(samples) -> None:
    assert_within_franka_joint_limits(np.array([s[1] for s in samples]), np.array([s[2] for s in samples]),
                                      np.array([s[3] for s in samples]))


def assert_within_franka_joint_limits(qdot: np.ndarray, q: np.ndarray, setpoints: np.ndarray | None = None) -> None:
    """Joint speeds and positions at every substep, within Franka's published limits. Joint accelerations and
    jerks at every 2 ms substep (a real Panda checks its commands at 1 kHz), by finite differences of the
    achieved joint velocities: within the limits with 10 % for the differencing, and over every 50 ms window (a
    sliding one, starting at every substep) within them exactly. The commanded motion (``setpoints``, the
    servos' velocity set-points at every substep) within them exactly."""
    assert np.all(np.abs(qdot) <= FRANKA_JOINT_SPEEDS)
    assert np.all(q >= FRANKA_JOINT_RANGES[:, 0]) and np.all(q <= FRANKA_JOINT_RANGES[:, 1])
    for name, velocity, tolerance in (("achieved", qdot, 1.1), ("commanded", setpoints, 1.0)):
        if velocity is None:
            continue
        accel = np.diff(velocity, axis=0) / SUBSTEP
        worst = np.abs(accel).max(axis=0) / FRANKA_JOINT_ACCELS
        assert np.all(worst <= tolerance), f"{name} joint accelerations reach {np.round(worst, 3)} of Franka's limits"
        worst = np.abs(np.diff(accel, axis=0) / SUBSTEP).max(axis=0) / FRANKA_JOINT_JERKS
        assert np.all(worst <= tolerance), f"{name} joint jerks reach {np.round(worst, 3)} of Franka's limits"
    window = 25  # substeps in 50 ms
    accel = (qdot[window:] - qdot[:-window]) / 0.05
    worst = np.abs(accel).max(axis=0) / FRANKA_JOINT_ACCELS
    assert np.all(worst <= 1.0), f"joint accelerations over 50 ms reach {np.round(worst, 3)} of Franka's limits"


@pytest.mark.slow
@pytest.mark.parametrize("actions", ["random", "full-scale"])
def test_franka_limits_are_never_exceeded(actions):
    """Watching every 2 ms physics step over random and full-scale (corner of the action cube) actions, among
    clutter: commanded speed <= 1.7 m/s and commanded acceleration <= 13 m/s^2 exactly; achieved end-effector
    speed, joint speeds, positions, accelerations and jerks within Franka's limits (``assert_within_franka_joint_
    limits``); achieved Cartesian acceleration, averaged over each control step, within 13 m/s^2 (+5 %)."""
    env = SlideOutEnv(n_objects=4)
    rng = np.random.default_rng(0)
    samples = []
    _watch_arm(env, samples)
    for episode in range(12):
        env.reset(seed=episode)
        samples.clear()
        _watch_arm(env, samples)
        env._substep_hook[1](env)  # the state at the start of the episode
        previous_command = np.zeros(3)
        step_end_velocities = [np.zeros(3)]
        for _ in range(40):
            a = rng.uniform(-1, 1, 3) if actions == "random" else np.sign(rng.uniform(-1, 1, 3))
            *_, terminated, _, _ = env.step(a.astype(np.float32))
            command = env.setpoint.command
            assert np.linalg.norm(command) <= MAX_EE_SPEED + 1e-9
            assert np.linalg.norm(command - previous_command) <= MAX_EE_ACCEL * 0.05 + 1e-9
            previous_command = command.copy()
            step_end_velocities.append(samples[-1][0])
            if terminated:
                break
        ee_velocity = np.array([s[0] for s in samples])
        assert np.linalg.norm(ee_velocity, axis=1).max() <= MAX_EE_SPEED
        _arm_limits_hold(samples)
        per_step = np.linalg.norm(np.diff(np.array(step_end_velocities), axis=0), axis=1) / 0.05
        assert per_step.max() <= 1.05 * MAX_EE_ACCEL, per_step.max()


@pytest.mark.parametrize("embodiment, pull", [("panda", True), ("hand", True), ("panda", False)])
def test_a_zero_action_holds_the_hand_in_place(embodiment, pull):
    """After a pull (or from reset), zero actions keep the held box where it stopped: the velocity-servoed arm lags its
    set-points under load, and without the env's horizontal hold it crept about 1 cm/s (into a fragile object beside
    the lane within 8 s). Over 10 s of zero actions the box moves less than 2 mm."""
    env = SlideOutEnv(n_objects=0, embodiment=embodiment)
    env.reset(seed=3)
    if pull:
        for _ in range(8):
            env.step(np.array([0.6, 0.0, 0.0], dtype=np.float32))
        for _ in range(20):  # come to rest
            env.step(np.zeros(3, dtype=np.float32))
    start = env.scene_state().bottom_pos[:2].copy()
    for _ in range(200):
        env.step(np.zeros(3, dtype=np.float32))
    moved = np.linalg.norm(env.scene_state().bottom_pos[:2] - start)
    assert moved < 0.002, f"the box crept {1000 * moved:.2f} mm in 10 s of zero actions"


def test_the_held_box_velocity_is_read_after_the_last_substep():
    """The at-rest test of a placement (l3) reads the held box's velocity from its free joint after the step's last
    substep; a velocity sensor's value dates from before that substep's integration."""
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    for _ in range(6):
        env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    dof = env.index.bottom_box_qvel
    np.testing.assert_array_equal(env.scene_state().bottom_vel, env.data.qvel[dof:dof + 3])
    sensor = env.data.sensor("judge_box_vel").data
    assert not np.allclose(sensor, env.data.qvel[dof:dof + 3], atol=1e-4)  # the stale one differs while accelerating


def test_the_jerk_limited_ramp_ends_where_asked_and_halves_the_jump_in_acceleration():
    from safemanip.control.diff_ik import jerk_limited_ramp

    start, end, previous_rate, h = np.array([0.5, -0.2]), np.array([-0.1, 0.3]), np.array([10.0, -6.0]), 0.002
    first, rest = jerk_limited_ramp(start, end, previous_rate, 25, h)
    np.testing.assert_allclose(start + h * (first + 24 * rest), end)
    np.testing.assert_allclose(first - previous_rate, rest - first)  # two equal jumps instead of one


def test_the_hand_ablation_has_the_same_cartesian_limits():
    env = SlideOutEnv(n_objects=0, embodiment="hand")
    env.reset(seed=0)
    speeds = []
    for _ in range(8):
        obs, *_ = env.step(np.array([1.0, 1.0, 0.0], dtype=np.float32))
        speeds.append(np.linalg.norm(env.setpoint.command))
    assert speeds[0] == pytest.approx(MAX_EE_ACCEL * 0.05) and max(speeds) == pytest.approx(MAX_EE_SPEED)


def test_nan_actions_are_refused_with_a_message():
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be finite"):
        env.step(np.array([np.nan, 0.0, 0.0], dtype=np.float32))


def test_ik_building_blocks_match_their_textbook_forms():
    from safemanip.scene.kinematics import dls_joint_velocity, orientation_error

    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b = (np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(2))
        a, b = a * np.sign(np.linalg.det(a)), b * np.sign(np.linalg.det(b))
        expected = 0.5 * sum(np.cross(a[:, i], b[:, i]) for i in range(3))
        np.testing.assert_allclose(orientation_error(a, b), expected, atol=1e-12)
    jac, twist, posture, damping = rng.normal(size=(6, 7)), rng.normal(size=6), rng.normal(size=7), 0.02
    pinv = jac.T @ np.linalg.inv(jac @ jac.T + damping ** 2 * np.eye(6))
    np.testing.assert_allclose(dls_joint_velocity(jac, twist, damping, posture),
                               pinv @ twist + posture - pinv @ jac @ posture, atol=1e-10)
    # with no damping and a full-rank J, the twist is tracked exactly whatever the null-space term
    np.testing.assert_allclose(jac @ dls_joint_velocity(jac, twist, 0.0, posture), twist, atol=1e-9)


@pytest.mark.slow
def test_a_shipped_policy_stays_within_franka_limits():
    """100 rollouts of the shipped pi_2 in its own scenes (half of them exit scenes, where it pulls hard and brakes),
    watched at every 2 ms substep: joint speeds, positions, accelerations and jerks, achieved and commanded, stay
    within Franka's limits at every substep (``assert_within_franka_joint_limits``)."""
    from safemanip.rl.checkpoint import load_policy

    actor, meta = load_policy("rarl-k2-conservative-s0")
    env = SlideOutEnv(**meta["env_kwargs"])
    samples = []
    _watch_arm(env, samples)
    steps = 0
    for episode in range(100):
        obs, _ = env.reset(seed=900_000 + episode)
        samples.clear()
        env._substep_hook[1](env)
        while True:
            obs, _, terminated, truncated, _ = env.step(actor(obs[None])[0])
            steps += 1
            if terminated or truncated:
                break
        _arm_limits_hold(samples)
    assert steps > 1000  # the rollouts did move the arm
