"""Inverse-kinematics building blocks: the hand's orientation error and a damped-least-squares solve.

The scene solves the Panda's home configuration and its reach map with them (``scene/panda.py``), and the
controller the arm's joint velocities every control step (``control/cartesian.py``). They live in ``scene``, the
lower of the two layers, so that ``scene`` imports nothing from ``control``.
"""

from __future__ import annotations

import mujoco
import numpy as np


def orientation_error(rotation: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Small-angle rotation vector (world frame) that turns ``rotation`` towards ``target`` (3x3 each).

    Equals 0.5 * sum_i cross(rotation[:, i], target[:, i]), read off the skew part of target @ rotation.T
    (one small matrix product instead of three cross products: this runs every control step).
    """
    (_, m01, m02), (m10, _, m12), (m20, m21, _) = (target @ rotation.T).tolist()
    return np.array((0.5 * (m21 - m12), 0.5 * (m02 - m20), 0.5 * (m10 - m01)))


def dls_joint_velocity(jacobian: np.ndarray, twist: np.ndarray, damping: float,
                       nullspace_velocity: np.ndarray | None = None) -> np.ndarray:
    """Damped least squares: qdot = J^T (J J^T + damping^2 I)^-1 twist, plus a null-space term.

    ``jacobian`` is (6, n) (translation rows first), ``twist`` (6,). The null-space term (e.g. a pull
    towards a comfortable posture) is projected so that it does not disturb the end-effector twist:
    qdot = z + J^+ (twist - J z), with J^+ the damped pseudo-inverse. The 6x6 system is solved by
    MuJoCo's Cholesky routines (a microsecond, where numpy's solve costs tens in call overhead).
    """
    jjt = jacobian @ jacobian.T
    diagonal = jjt.reshape(-1)[::jjt.shape[0] + 1]  # a view (``flat`` indexing would copy out and back)
    diagonal += damping * damping
    rhs = twist if nullspace_velocity is None else twist - jacobian @ nullspace_velocity
    if mujoco.mju_cholFactor(jjt, 1e-12) < jjt.shape[0]:  # singular without damping: fall back to lstsq
        solution = np.linalg.lstsq(jacobian @ jacobian.T, rhs, rcond=None)[0]
    else:
        solution = np.empty(jjt.shape[0])
        mujoco.mju_cholSolve(solution, jjt, np.ascontiguousarray(rhs))
    qdot = jacobian.T @ solution
    return qdot if nullspace_velocity is None else qdot + nullspace_velocity
