"""Each embodiment's Cartesian velocity controller: what turns the end-effector velocity the env commands into the
robot's servo commands over one control step.

An embodiment (``scene/embodiment.py``) names its controller (``controller``, a key of ``CONTROLLERS``); the env
takes it from ``make_controller`` and runs the phases it returns, so no Python runs between physics substeps.

The Panda (``PandaController``): once per 20 Hz step, damped-least-squares differential IK turns the commanded
end-effector velocity (and a correction that holds the hand's orientation, and a null-space pull to a comfortable
posture) into joint velocities within the Panda's joint position and speed limits. Each joint has one velocity
servo whose set-point is an integrator state (``scene/panda.py``): the controller sets its rate so that the
set-point ramps linearly from the last command to the new one over the step. MuJoCo runs the 25 substeps with no
Python in between. Each step's change of joint velocity is scaled down so that no joint accelerates faster than
``ACCEL_MARGIN`` of Franka's limit, and the set-points' acceleration changes from one step's to the next over a
substep (``jerk_limited_ramp``): within Franka's jerk limits at every 2 ms substep, as a real Panda's 1 kHz
interface checks.

The hand ablation (``HandController``): its slide joints are world-aligned, so the velocity is its servos'
set-point, ramped linearly over the step.
"""

from __future__ import annotations

import mujoco
import numpy as np

from safemanip.control.diff_ik import jerk_limited_ramp, limit_joint_acceleration, limit_joint_velocity
from safemanip.scene.hand import HandBinding
from safemanip.scene.kinematics import dls_joint_velocity, orientation_error
from safemanip.scene.panda import (FRANKA_JOINT_ACCELS, FRANKA_JOINT_RANGES, FRANKA_JOINT_SPEEDS, LIMIT_MARGIN,
                                   PandaBinding)

SPEED_MARGIN = 0.85
"""Joint velocities are commanded up to this share of Franka's limits: the servos track with small
overshoots (inertial coupling between joints, contacts), and the achieved speed must stay within the limit."""
ACCEL_MARGIN = 0.7
"""Joint accelerations are commanded up to this share of Franka's limits: the servos lag the ramped set-points by
a few ms and the joints pull on each other, which lets the achieved change over a 50 ms window overshoot the
commanded one by up to ~25 % (measured: 0.99 of joint 2's limit with 0.8)."""


class PandaController:
    """The Franka Panda's Cartesian velocity controller (see the module docstring)."""

    ik_damping = 0.02
    orientation_gain = 0.5
    """Fraction of the orientation error removed per control step."""
    posture_gain = 0.5
    """Null-space pull towards the home posture [1/s] (keeps the elbow where it started)."""

    def command_velocity(self, model, data, binding: PandaBinding, velocity: np.ndarray, dt: float) -> tuple:
        """Track end-effector ``velocity`` (world frame, m/s) over the coming control step of ``dt`` s.

        Returns the step's servo commands as phases, ((substeps, ctrl), ...), for the env to run."""
        jac = binding.jac6
        mujoco.mj_jacSite(model, data, *binding.site_jac, binding.ee_site)
        # The joint velocities hold for the whole step while the arm moves (at 1.5 m/s the first joint turns
        # ~0.13 rad), so solve with the Jacobian expected half-way through the step: J + (dt/2) dJ/dt.
        mujoco.mj_jacDot(model, data, *binding.site_jac_dot, data.site_xpos[binding.ee_site], binding.site_body)
        np.multiply(binding.arm_jac_dot, 0.5 * dt, out=jac)
        jac += binding.arm_jac
        twist = binding.twist
        twist[:3] = velocity
        np.multiply(orientation_error(data.site_xmat[binding.ee_site].reshape(3, 3), binding.target_rotation),
                    self.orientation_gain / dt, out=twist[3:])
        q = data.qpos[binding.qpos]
        binding.ik_qdot = qdot = dls_joint_velocity(jac, twist, self.ik_damping,
                                                    self.posture_gain * (binding.home_qpos - q))
        # brake at half Franka's joint accelerations: the servos lag a little behind their set-points
        qdot = limit_joint_velocity(qdot, q, _LOWER, _UPPER, _SPEED_CAP, _BRAKING, dt)
        previous = data.act[binding.act_adr]  # the set-points the last ramp ended at
        binding.limited_qdot = qdot = limit_joint_acceleration(qdot, previous, _ACCEL_CAP * dt)
        # ramp the servo set-points from where they are to qdot over the step, the joint accelerations blended
        # from the last step's over the first substep (within Franka's jerk limits at 1 kHz)
        substeps = int(round(dt / binding.timestep))
        first, rest = jerk_limited_ramp(previous, qdot, binding.setpoint_rate, substeps, binding.timestep)
        binding.setpoint_rate = rest
        return (1, first), (substeps - 1, rest)


_LOWER = FRANKA_JOINT_RANGES[:, 0] + LIMIT_MARGIN
_UPPER = FRANKA_JOINT_RANGES[:, 1] - LIMIT_MARGIN
_SPEED_CAP = SPEED_MARGIN * FRANKA_JOINT_SPEEDS
_BRAKING = 0.5 * FRANKA_JOINT_ACCELS
_ACCEL_CAP = ACCEL_MARGIN * FRANKA_JOINT_ACCELS


class HandController:
    """The hand ablation's controller (see the module docstring)."""

    @staticmethod
    def command_velocity(model, data, binding: HandBinding, velocity: np.ndarray, dt: float) -> tuple:
        """Track end-effector ``velocity`` (m/s; the slide axes are world-aligned) over the coming step: one phase,
        a linear ramp of the set-points (the ablation has no joints, so no joint jerk to limit)."""
        return ((int(round(dt / model.opt.timestep)), (velocity - data.act[binding.act_adr]) / dt),)


CONTROLLERS = {"panda": PandaController, "hand": HandController}
"""Controllers by name: an embodiment's ``controller`` names one."""


def make_controller(robot):
    """The controller of the embodiment ``robot`` (``scene.embodiment.Embodiment``)."""
    if robot.controller not in CONTROLLERS:
        raise ValueError(f"embodiment {robot.name!r} names controller {robot.controller!r}; controllers: "
                         f"{sorted(CONTROLLERS)}")
    return CONTROLLERS[robot.controller]()
