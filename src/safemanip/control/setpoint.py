"""The end-effector's Cartesian set-point: what one action asks the arm's controller for.

An action (a velocity request in the unit ball) becomes the end-effector velocity the controller
(``control/cartesian.py``) tracks over the next control step, in three parts:

- **the action curve**: by norm, not per axis (no faster diagonals), through ``shape_action``;
- **the lift band**: the action's z moves a commanded height within a band above the nominal press, and the hand is
  sent there (the pads' push makes the velocity-servoed arm drift up by a few mm otherwise);
- **the horizontal hold**: the velocity-servoed arm lags its set-points under load (gravity, the pads, the table's
  friction on the box), so a zero command alone let the hand creep by about 1 cm/s. As a real arm's Cartesian
  velocity interface integrates its command into a pose it holds, a hold point moves with the command sent and the
  hand is pulled towards it;

then the result is limited to the arm's Cartesian speed and acceleration (``limit_ee_velocity``).

``plan`` is pure (it changes nothing, so a caller may ask what an action would command); ``commit`` makes a plan the
new state. The safety filter (``safety/braking.py``) predicts from the same curve, limits and last command, without
the hold point's pull (docs/safety.md).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from safemanip.control.diff_ik import MAX_EE_ACCEL, MAX_EE_SPEED, limit_ee_velocity, shape_action
from safemanip.scene.grasp import PAD_PRESS

LIFT_BAND = 0.5 * PAD_PRESS
"""The hand may rise this far above the nominal press [m]: the pads, half out, still press with 18 N (20 N at the
nominal press), so the action's z only trims the pressing force and never lets go."""
HEIGHT_GAIN = 0.5
"""Share of the hand's height error corrected per step: a full correction overshoots and rings."""
HOLD_GAIN = 0.5
"""Share of the hand's horizontal error from its hold point corrected per step (as for the height)."""
HOLD_RADIUS = 0.005
"""The hold point stays this close to the hand [m]: when the arm's limits or a contact hold the hand back, the hold
point does not run ahead of it (no wind-up); the correction is at most 5 cm/s."""


class SetpointPlan(NamedTuple):
    """One step's command and the set-point state it leaves."""

    command: np.ndarray
    """(3,) end-effector velocity [m/s] the controller tracks over the step."""
    height: float
    """The commanded height after the step [m]."""
    hold: list[float]
    """The hold point (x, y) after the step [m]."""


class CartesianSetpoint:
    """The set-point state of one episode (module docstring): the last command, the commanded height and its band,
    the hold point."""

    def __init__(self, dt: float, curve: float = 1.0, max_speed: float = MAX_EE_SPEED,
                 max_accel: float = MAX_EE_ACCEL):
        self.dt, self.curve, self.max_speed, self.max_accel = dt, float(curve), max_speed, max_accel
        self.command = np.zeros(3)
        self.band = (0.0, 0.0)
        self.height = 0.0
        self.hold: list[float] = [0.0, 0.0]

    def reset(self, position: Sequence[float]) -> None:
        """At rest at the end-effector's ``position`` (x, y, z), holding it."""
        self.command = np.zeros(3)
        self.band = (position[2], position[2] + LIFT_BAND)
        self.height = position[2]
        self.hold = list(position[:2])

    def plan(self, action: np.ndarray, position: Sequence[float]) -> SetpointPlan:
        """The command for ``action`` (a checked (3,) float array) with the end-effector at ``position`` (x, y, z),
        and the state it leaves; changes nothing."""
        dt = self.dt
        shaped = shape_action(action, self.curve).tolist()
        request_x, request_y, request_z = (a * self.max_speed for a in shaped)
        z_low, z_high = self.band
        height = min(max(self.height + request_z * dt, z_low), z_high)
        request_z = HEIGHT_GAIN * (height - position[2]) / dt
        x, y = position[0], position[1]
        hold_x, hold_y = self.hold
        error_x, error_y = hold_x - x, hold_y - y
        error = math.hypot(error_x, error_y)
        if error > HOLD_RADIUS:
            error_x, error_y = error_x * HOLD_RADIUS / error, error_y * HOLD_RADIUS / error
        correction_x, correction_y = HOLD_GAIN * error_x / dt, HOLD_GAIN * error_y / dt
        request = np.array((request_x + correction_x, request_y + correction_y, request_z))
        command = limit_ee_velocity(request, self.command, dt, self.max_speed, self.max_accel)
        command_x, command_y, _ = command.tolist()
        hold = [x + error_x + (command_x - correction_x) * dt, y + error_y + (command_y - correction_y) * dt]
        return SetpointPlan(command, height, hold)

    def commit(self, plan: SetpointPlan) -> np.ndarray:
        """Make ``plan`` the state; returns its command."""
        self.command, self.height, self.hold = plan.command, plan.height, plan.hold
        return plan.command
