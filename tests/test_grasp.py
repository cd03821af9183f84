"""The contact grasp (``scene/grasp.py``): spring-loaded fingertip pads press on the box lip and drag it by
friction. The hand cannot lift the box, cannot press it into the table with more than the pads' spring, and
drags it along as long as friction allows."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from safemanip.control.setpoint import LIFT_BAND
from safemanip.env.slide_out import SlideOutEnv
from safemanip.scene.grasp import PAD_PRELOAD, PAD_PRESS, PAD_STIFFNESS, PAD_TRAVEL

NOMINAL = 2 * PAD_STIFFNESS * (PAD_PRELOAD + PAD_PRESS)  # both pads at the nominal press [N]
MOST = 2 * PAD_STIFFNESS * (PAD_PRELOAD + PAD_TRAVEL)  # both pads pushed in all the way
LEAST = 2 * PAD_STIFFNESS * (PAD_PRELOAD + PAD_PRESS - LIFT_BAND)  # the hand at the top of its lift band


def _pad_force(env) -> float:
    """Total normal force of the pads on the held box now [N]."""
    m, d = env.model, env.data
    box = m.geom("box_bottom").id
    force, total = np.zeros(6), 0.0
    for i in range(d.ncon):
        c = d.contact[i]
        if box in (c.geom1, c.geom2) and "pad" in m.geom(c.geom1 if c.geom2 == box else c.geom2).name:
            mujoco.mj_contactForce(m, d, i, force)
            total += force[0]
    return total


def _run(env, action, steps):
    """Step with ``action``; per step the mean pad force over its substeps and the box's height at its end."""
    forces, heights, per_step = [], [], []
    env.watch_substeps(1, lambda e: per_step.append(_pad_force(e)))
    for _ in range(steps):
        per_step.clear()
        env.step(np.asarray(action, dtype=np.float32))
        forces.append(float(np.mean(per_step)))
        heights.append(float(env.data.xpos[env.index.bottom_box_body][2]))
    env.watch_substeps(None)
    return np.array(forces), np.array(heights)


@pytest.mark.parametrize("embodiment", ["panda", "hand"])
def test_the_pads_press_with_their_spring_force_and_no_more(embodiment):
    env = SlideOutEnv(n_objects=0, embodiment=embodiment)
    env.reset(seed=0)
    forces, heights = _run(env, [0.0, 0.0, -1.0], 10)  # pushing down as hard as the action allows
    assert np.all(forces[2:] > 0.8 * NOMINAL) and np.all(forces <= MOST), forces
    hz = env.geometry.box_half_extents[2]
    assert np.all(np.abs(heights - hz) < 0.001)  # flat on the table


@pytest.mark.parametrize("embodiment", ["panda", "hand"])
def test_the_hand_cannot_lift_the_box_nor_let_go_of_it(embodiment):
    env = SlideOutEnv(n_objects=0, embodiment=embodiment)
    env.reset(seed=0)
    forces, heights = _run(env, [0.0, 0.0, 1.0], 10)  # up to the top of the lift band
    hz = env.geometry.box_half_extents[2]
    assert np.all(heights < hz + 0.001), heights
    assert np.all(forces[3:] > 0.8 * LEAST) and np.all(forces <= MOST), forces  # still pressing


def test_the_pads_drag_the_box_along():
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=0)
    state = env.scene_state()
    offset = state.ee_pos[:2] - state.bottom_pos[:2]
    for _ in range(6):
        env.step(np.array([0.5, 0.0, -1.0], dtype=np.float32))  # 0.85 m/s along the pull
    state = env.scene_state()
    assert state.bottom_pos[0] - env.geometry.bottom_xy[0] > 0.15  # the box came along
    np.testing.assert_allclose(state.ee_pos[:2] - state.bottom_pos[:2], offset, atol=0.01)  # hardly slipping


@pytest.mark.parametrize("embodiment", ["panda", "hand"])
def test_the_pads_push_no_harder_than_their_springs_at_any_substep(embodiment):
    """During the fastest pulls and stops the arm can make, the pads' force on the box at every 2 ms substep stays
    within what their springs can push (both at the end of their travel; 5 % for the pads' damping). Forces
    averaged over a control step hid 4 ms spikes of up to 84 N while the pad slides inherited a 5 kg armature
    from the robot model's default class (``add_pad``)."""
    env = SlideOutEnv(n_objects=0, embodiment=embodiment)
    env.reset(seed=0)
    forces = []
    env.watch_substeps(1, lambda e: forces.append(_pad_force(e)))
    for action in [[1.0, 0.0, 0.0]] * 8 + [[-1.0, 0.0, 0.0]] * 3 + [[0.0, 1.0, -1.0]] * 4 + [[0.0, 0.0, 0.0]] * 5:
        env.step(np.asarray(action, dtype=np.float32))
    assert len(forces) == 20 * 25 and max(forces[50:]) > 0.8 * NOMINAL  # the pads pressed throughout
    assert max(forces) <= 1.05 * MOST, f"the pads pushed with up to {max(forces):.1f} N; their springs give {MOST:.0f}"


def test_the_pad_slides_take_nothing_from_the_robot_models_default_class():
    from safemanip.scene.builder import build_model
    from safemanip.scene.grasp import PAD_MASS

    model = build_model((), embodiment="panda")
    for pad in ("panda/pad_left", "panda/pad_right"):
        joint, geom = model.joint(pad), model.geom(pad)
        assert model.dof_armature[joint.dofadr[0]] == 0.0 and model.dof_frictionloss[joint.dofadr[0]] == 0.0
        assert model.body_mass[joint.bodyid[0]] == pytest.approx(PAD_MASS)
        assert geom.margin[0] == 0.0 and tuple(geom.solref) == (0.02, 1.0)
