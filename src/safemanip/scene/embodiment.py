"""Robot embodiments. The policy acts on end-effector displacements, so any embodiment that can
track a Cartesian end-effector target can stand behind the same observation and action spaces.

``CartesianHand`` models the Franka Panda hand as a gravity-compensated body on three world-aligned
slide joints, each driven by a position actuator (PD). The grasped (bottom) cereal box is rigidly
attached to the hand, i.e. a perfect grasp. A 7-DoF Panda with operational-space control can
replace it by implementing the same three methods.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from safemanip.scene.config import TaskGeometry

COLLIDE_TABLE = 1  # contype/conaffinity bit shared with the table
COLLIDE_OBJECTS = 2  # bit shared by everything that is not the table


@dataclass
class HandBinding:
    """Ids resolved once after compilation."""

    qpos_adr: np.ndarray  # (3,) x, y, z slide joints
    qvel_adr: np.ndarray
    actuator_ids: np.ndarray  # integrated-velocity (ramped set-point) actuators
    velocity_actuator_ids: np.ndarray
    act_adr: np.ndarray  # activation (set-point) addresses of the ramp actuators
    ee_site: int
    home: np.ndarray  # (3,) world position of the ee site at joint zero

    def __post_init__(self):
        # the per-step writes use slices where the ids are contiguous (they are, as compiled): a slice
        # write costs a fraction of a fancy-index write, and this runs every control step
        self._act = _as_slice(self.act_adr)
        self._qpos = _as_slice(self.qpos_adr)
        self._ctrl = _as_slice(self.actuator_ids)
        self._ctrl_velocity = _as_slice(self.velocity_actuator_ids)


def _as_slice(ids: np.ndarray):
    ids = np.asarray(ids)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


class CartesianHand:
    name = "cartesian-hand"
    kp = 3000.0
    """Position gain [N/m] (critically damped with the velocity actuators' kv)."""
    mass = 0.73
    """Panda hand mass."""
    lift_range = (0.0, 0.02)
    """How far the box may be lifted above resting on the table [m]: sliding, not carrying over clutter."""

    def attach(self, spec: mujoco.MjSpec, geo: TaskGeometry, box_rgba, box_friction: float) -> None:
        hx, hy, hz = geo.box_half_extents
        bx, by = geo.bottom_xy
        grasp = np.array([bx, by - hy, hz])  # middle of the near edge of the bottom box
        hand = spec.worldbody.add_body(name="hand", pos=grasp, gravcomp=1.0)
        tx, ty = geo.table_half_extents
        ranges = {"x": (-tx - bx, tx - bx), "y": (-ty - by + hy, ty - by), "z": self.lift_range}
        for axis, vec in zip("xyz", np.eye(3)):
            hand.add_joint(name=f"hand_{axis}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=vec,
                           range=ranges[axis], limited=mujoco.mjtLimited.mjLIMITED_TRUE, armature=0.01)
            kv = 2.0 * np.sqrt(self.kp * (self.mass + geo.box_mass))  # critically damped
            # The set-point is the actuator's activation: it integrates the commanded velocity, so within a
            # control step the target ramps smoothly inside MuJoCo (no per-substep Python).
            ramp = spec.add_actuator(name=f"hand_{axis}", target=f"hand_{axis}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            ramp.set_to_intvelocity(kp=self.kp)
            ramp.actrange = ranges[axis]
            ramp.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
            # velocity feed-forward: damping pulls towards the commanded velocity, not towards rest, so the
            # ramp is tracked without lag
            vel = spec.add_actuator(name=f"hand_v{axis}", target=f"hand_{axis}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            vel.set_to_velocity(kv=kv)
        # palm above the box edge and two fingers pinching it; palm collides with clutter, not the table
        hand.add_geom(name="hand_palm", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.10, 0.03, 0.025],
                      pos=[0, -0.03, hz + 0.045], mass=self.mass, rgba=[0.9, 0.9, 0.9, 1],
                      contype=COLLIDE_OBJECTS, conaffinity=COLLIDE_OBJECTS)
        for side in (-1, 1):
            hand.add_geom(name=f"hand_finger_{'lr'[side > 0]}", type=mujoco.mjtGeom.mjGEOM_BOX,
                          size=[0.01, 0.02, 0.03], pos=[side * 0.04, 0.005, 0.035 + 0.0],
                          rgba=[0.3, 0.3, 0.3, 1], contype=0, conaffinity=0, mass=0)
        hand.add_site(name="ee", pos=[0, 0, 0], size=[0.01, 0, 0])
        box = hand.add_body(name="box_bottom", pos=[0, hy, 0])
        box.add_geom(name="box_bottom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, hz],
                     mass=geo.box_mass, rgba=box_rgba, friction=[box_friction, 0.005, 0.0001],
                     contype=COLLIDE_TABLE | COLLIDE_OBJECTS, conaffinity=COLLIDE_TABLE | COLLIDE_OBJECTS)

    def bind(self, model: mujoco.MjModel) -> HandBinding:
        joints = [model.joint(f"hand_{a}") for a in "xyz"]
        home = model.body("hand").pos.copy()
        return HandBinding(
            qpos_adr=np.array([j.qposadr[0] for j in joints]),
            qvel_adr=np.array([j.dofadr[0] for j in joints]),
            actuator_ids=np.array([model.actuator(f"hand_{a}").id for a in "xyz"]),
            velocity_actuator_ids=np.array([model.actuator(f"hand_v{a}").id for a in "xyz"]),
            act_adr=np.array([model.actuator_actadr[model.actuator(f"hand_{a}").id] for a in "xyz"]),
            ee_site=model.site("ee").id,
            home=home,
        )

    @staticmethod
    def command_velocity(data, binding: HandBinding, velocity: np.ndarray) -> None:
        """Move the end-effector at ``velocity`` (m/s) from where it is now, for the coming control step.

        The set-point restarts at the measured position each call, so a blocked hand never winds up.
        """
        data.act[binding._act] = data.qpos[binding._qpos]
        ctrl = data.ctrl
        ctrl[binding._ctrl] = velocity
        ctrl[binding._ctrl_velocity] = velocity

    @staticmethod
    def ee_position(data, binding: HandBinding) -> np.ndarray:
        return data.site_xpos[binding.ee_site]

    @staticmethod
    def ee_velocity(data, binding: HandBinding) -> np.ndarray:
        return data.qvel[binding.qvel_adr]  # slide axes are world-aligned
