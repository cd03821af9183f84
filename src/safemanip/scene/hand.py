"""The idealised floating-hand ablation: the Panda hand on three world-aligned slide joints.

It tracks the commanded end-effector velocity with one velocity servo per axis (``control.cartesian.HandController``
ramps their set-points) and has no joints to limit, so it measures what the 7-DoF arm costs a policy. The env
applies the same Cartesian speed and acceleration limits to it as to the arm, and it grasps the same way
(``scene/grasp.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from safemanip.scene.config import TaskGeometry
from safemanip.scene.grasp import COLLIDE_ROBOT, PAD_NOMINAL_QPOS, PAD_PRESS, PAD_RADIUS, add_pad, boxes_to_meshes
from safemanip.scene.panda import FINGER_OPENING


@dataclass
class HandBinding:
    """Ids resolved once after compilation."""

    qpos_adr: np.ndarray  # (3,) x, y, z slide joints
    qvel_adr: np.ndarray
    actuator_ids: slice  # the three velocity servos (contiguous)
    act_adr: slice  # their set-points
    ee_site: int
    pad_qpos: np.ndarray  # (2,) the pads' slides


class CartesianHand:
    """The idealised ablation: a Panda hand on three world-aligned slide joints (see the module docstring)."""

    name = "hand"
    controller = "hand"
    root_body_name = "hand"
    ee_site_name = "ee"
    distance_geom_names = ("box_bottom", "hand_palm")
    servo_gain = 1000.0
    """Velocity servo gain [N s/m]: a 1 ms time constant against the hand (0.77 kg), stiff enough that the pads' push
    (up to 20 N) leaves the hand 2 cm/s short of its commanded velocity."""
    mass = 0.73
    """Panda hand mass."""
    lift_range = (0.0, 0.02)
    """How far the box may be lifted above resting on the table [m]: sliding, not carrying over clutter."""

    def __init__(self, visual: bool = True, gap: float = 0.0):
        self.visual = visual  # the hand has no meshes: nothing to drop
        self.gap = gap

    @property
    def cache_key(self) -> tuple:
        return (self.name, self.gap)

    def attach(self, spec: mujoco.MjSpec, geo: TaskGeometry) -> None:
        hx, hy, hz = geo.box_half_extents
        gx, gy = geo.grasp_xy
        grasp = np.array([gx, gy, 2 * hz])  # on top of the lip, where the Panda's pads press
        hand = spec.worldbody.add_body(name="hand", pos=grasp, gravcomp=1.0)
        tx, ty = geo.table_half_extents
        ranges = {"x": (-tx - gx, tx - gx), "y": (-ty - gy, ty - gy), "z": self.lift_range}
        for axis, vec in zip("xyz", np.eye(3)):
            hand.add_joint(name=f"hand_{axis}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=vec,
                           range=ranges[axis], limited=mujoco.mjtLimited.mjLIMITED_TRUE, armature=0.01)
            # the same servo as each Panda joint's: the set-point is an integrator state that the controller
            # ramps linearly over each control step, so the commanded acceleration limit holds within the step
            servo = spec.add_actuator(name=f"hand_{axis}", target=f"hand_{axis}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            servo.dyntype = mujoco.mjtDyn.mjDYN_INTEGRATOR
            servo.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            servo.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            servo.gainprm[0] = self.servo_gain
            servo.biasprm[:3] = [0.0, 0.0, -self.servo_gain]
            servo.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        # palm above the lip, two fingers reaching down to it, a pad at each fingertip
        palm = hand.add_geom(name="hand_palm", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.10, 0.025],
                             pos=[0, 0, 0.09], mass=self.mass, rgba=[0.9, 0.9, 0.9, 1],
                             contype=COLLIDE_ROBOT, conaffinity=0, gap=self.gap)
        boxes_to_meshes(spec, [palm])
        spread = 0.0075 + FINGER_OPENING  # the Panda's pad offset across the hand
        for side in (-1, 1):
            hand.add_geom(name=f"hand_finger_{'lr'[side > 0]}", type=mujoco.mjtGeom.mjGEOM_BOX,
                          size=[0.01, 0.008, 0.03], pos=[0, side * spread, 0.04],
                          rgba=[0.3, 0.3, 0.3, 1], contype=0, conaffinity=0, mass=0)
            # the pad's +z points down; fully out, its lowest point is PAD_PRESS below the lip's top
            add_pad(hand, f"hand_pad_{'lr'[side > 0]}", pos=[0, side * spread, PAD_RADIUS - PAD_PRESS],
                    quat=[0.0, 1.0, 0.0, 0.0], gap=self.gap)
        hand.add_site(name="ee", pos=[0, 0, 0], size=[0.01, 0, 0])

    def bind(self, model: mujoco.MjModel) -> HandBinding:
        joints = [model.joint(f"hand_{a}") for a in "xyz"]
        servos = [model.actuator(f"hand_{a}").id for a in "xyz"]
        acts = [int(model.actuator_actadr[a]) for a in servos]
        if servos != list(range(servos[0], servos[0] + 3)) or acts != list(range(acts[0], acts[0] + 3)):
            raise RuntimeError("the hand's servos must be contiguous in the compiled model")
        return HandBinding(qpos_adr=np.array([j.qposadr[0] for j in joints]),
                           qvel_adr=np.array([j.dofadr[0] for j in joints]),
                           actuator_ids=slice(servos[0], servos[0] + 3), act_adr=slice(acts[0], acts[0] + 3),
                           ee_site=model.site("ee").id,
                           pad_qpos=np.array([model.joint(f"hand_pad_{s}").qposadr[0] for s in "lr"]))

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, binding: HandBinding) -> None:
        """Joint zero is the grasp pose; the pads start pressed in, just touching the lip."""
        data.qpos[binding.pad_qpos] = PAD_NOMINAL_QPOS

    def holding_reach(self, geo: TaskGeometry):
        """The hand holds the box anywhere on the table: no reach map."""
        return None
