"""Cartesian velocity control of a redundant arm: the Cartesian and joint limits and the jerk-limited ramp.

Pure NumPy functions, called once per 20 Hz control step (never between physics substeps), so the
arm costs the env a few microseconds of Python per step. Limits are the Franka Panda's published
ones (Franka's control-parameter documentation): what a real Panda would refuse, the policy cannot
command either. The controllers that use them are in ``control/cartesian.py``; the damped-least-squares
solve they share with the scene's inverse kinematics is ``scene/kinematics.py``.
"""

from __future__ import annotations

import math

import numpy as np

MAX_EE_SPEED = 1.7
"""Panda Cartesian translational velocity limit [m/s]."""
MAX_EE_ACCEL = 13.0
"""Panda Cartesian translational acceleration limit [m/s^2]."""


def limit_norm(vector: np.ndarray, max_norm: float) -> np.ndarray:
    """Scale ``vector`` down (never up) so that its Euclidean norm is at most ``max_norm``; keeps direction."""
    n = math.sqrt(float(vector @ vector))
    if n > max_norm:
        return vector * (max_norm / n)
    return vector


def shape_action(action: np.ndarray, exponent: float) -> np.ndarray:
    """An action in the unit ball -> a fraction of the top speed: the action's direction, with its norm (capped
    at 1) raised to ``exponent``. 1 is linear; 2 gives the policy a finer hand near rest (5 cm/s of 1.7 m/s is
    |a| < 0.17 instead of |a| < 0.03) and still reaches full speed at |a| = 1."""
    n = math.sqrt(float(action @ action))
    if n == 0.0:
        return action * 0.0
    return action * (min(n, 1.0) ** exponent / n)


def limit_ee_velocity(requested: np.ndarray, previous: np.ndarray, dt: float,
                      max_speed: float = MAX_EE_SPEED, max_accel: float = MAX_EE_ACCEL) -> np.ndarray:
    """The Cartesian velocity to command for the next control step.

    The speed is capped by norm at ``max_speed`` and the change from ``previous`` (the velocity commanded
    for the step before) by norm at ``max_accel * dt``. The embodiment's controller ramps linearly from the old to
    the new set-point over the step, so the commanded acceleration never exceeds ``max_accel``.
    """
    requested = limit_norm(requested, max_speed)
    return previous + limit_norm(requested - previous, max_accel * dt)


def limit_joint_velocity(qdot: np.ndarray, q: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                         max_speed: np.ndarray, max_accel: np.ndarray, dt: float = 0.0) -> np.ndarray:
    """Scale ``qdot`` down uniformly (its direction, and so the end-effector's, is kept) so that every joint
    stays under its speed limit and can still brake to a stop before its position limit at ``max_accel``.

    Moving towards a limit at distance s, a joint may go at most the speed v from which it can hold v for
    one more control step of ``dt`` and then brake: v dt + v^2 / (2 max_accel) <= s (with dt = 0, the
    continuous sqrt(2 max_accel s)). The arm slows down smoothly as a joint nears its limit instead of
    hitting it, and a joint at its limit only stops motions that would push it further.
    """
    ratio = 0.0
    # scalar maths on 7 joints: a fraction of the cost of a dozen small NumPy calls, the same numbers
    for v, qi, lo, hi, v_max, a_max in zip(qdot.tolist(), q.tolist(), lower.tolist(), upper.tolist(),
                                          max_speed.tolist(), max_accel.tolist()):
        towards = hi - qi if v > 0.0 else qi - lo
        step = a_max * dt
        braking = math.sqrt(step * step + 2.0 * a_max * max(towards, 0.0)) - step
        allowed = max(min(v_max, braking), 1e-12)  # a joint at its limit: only 0 is allowed
        ratio = max(ratio, abs(v) / allowed)
    if ratio > 1.0:
        qdot = qdot / ratio
    return qdot


def jerk_limited_ramp(start: np.ndarray, end: np.ndarray, previous_rate: np.ndarray, substeps: int,
                      timestep: float) -> tuple[np.ndarray, np.ndarray]:
    """The rates at which a set-point moves from ``start`` to ``end`` over one control step of ``substeps``
    physics steps: (the first substep's rate, the other substeps' rate).

    A set-point that ramped at ``previous_rate`` over the last step and at a new constant rate over this one would
    change its rate (for a joint velocity: its acceleration) in a single 2 ms substep, by up to twice the
    acceleration cap when the arm reverses: up to 1.4x Franka's jerk limit, which a real Panda's 1 kHz interface
    checks. Here the first substep takes the mean of the old and the new rate, which halves every such jump, and
    the new rate is chosen so that the step still ends at ``end`` exactly:
    timestep * (first + (substeps - 1) * rest) = end - start. With the rates capped at c, rest stays within
    c (substeps + 1/2) / (substeps - 1/2), 4 % over c at 25 substeps.
    """
    rest = ((end - start) / timestep - 0.5 * previous_rate) / (substeps - 0.5)
    return 0.5 * (previous_rate + rest), rest


def limit_joint_acceleration(qdot: np.ndarray, previous: np.ndarray, max_change: np.ndarray) -> np.ndarray:
    """Move from the ``previous`` joint velocities towards ``qdot`` only as far as ``max_change`` (per joint, the
    acceleration limit times the step) allows, by one factor for all joints: the change keeps its direction.

    Both end points lie within the joint speed limits (a box), so every point between them does too.
    """
    change = qdot - previous
    ratio = 0.0
    for c, limit in zip(change.tolist(), max_change.tolist()):
        ratio = max(ratio, abs(c) / limit)
    if ratio > 1.0:
        return previous + change / ratio
    return qdot
