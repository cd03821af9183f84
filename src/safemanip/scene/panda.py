"""The Franka Emika Panda, 7-DoF, as the default embodiment.

The model is gymnasium-robotics' Panda (``envs/assets/kitchen_franka/franka_assets``: the kinematic
chain, collision and visual meshes, 18 kg), located in the installed package with importlib and
attached into the scene with MjSpec; no model file is copied into this project. At build time we
correct what that model gets wrong for a torque-controlled Panda:

* joint damping 100 (joints 1-4) / 10 (5-7), which capped joint speeds near 1 rad/s, becomes 1 with an
  armature of 0.1 (the values of MuJoCo Menagerie's Panda);
* gravity is compensated, as the Panda's own controller does (``gravcomp`` on every link);
* joints 6 and 7 get their zeros back where Franka defines them (the link frames carried extra turns of
  1.57 and 0.785 rad), and every joint range is Franka's published one (joint 4's and 6's differed);
* the fingers are opened to 7 cm and fixed (no finger joints), each with a spring-loaded pad at its tip
  (``scene/grasp.py``), and the colliding box geoms become convex meshes (MuJoCo's box-box collider misses
  some near pairs).

Servos: each joint has one velocity servo whose set-point is an integrator state, its torque limited to the
Panda's 87 / 12 Nm. The controller that ramps the set-points each control step (damped-least-squares
differential IK within Franka's joint limits) is ``control/cartesian.py``'s ``PandaController``. The home
configuration and the reach map are solved here by inverse kinematics of the bare arm (``scene/kinematics.py``).

The grasp (``scene/grasp.py``): the fingertip pads press on the lip of the bottom box that sticks out to
the right from under the top box, and drag it by friction; the box is a free body.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np

from safemanip.scene.config import GEOMETRY, TaskGeometry
from safemanip.scene.grasp import (COLLIDE_ROBOT, PAD_CLEARANCE, PAD_NOMINAL_QPOS, PAD_PRESS, PAD_RADIUS, add_pad,
                                   boxes_to_meshes)
from safemanip.scene.kinematics import dls_joint_velocity, orientation_error

_ASSET_SUBDIR = ("envs", "assets", "kitchen_franka", "franka_assets")
JOINTS = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
FRANKA_JOINT_RANGES = np.array([(-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
                                (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)])
"""Franka's published joint position limits [rad]."""
FRANKA_JOINT_SPEEDS = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
"""Franka's published joint velocity limits [rad/s]."""
FRANKA_JOINT_ACCELS = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
"""Franka's published joint acceleration limits [rad/s^2]."""
FRANKA_JOINT_JERKS = np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0])
"""Franka's published joint jerk limits [rad/s^3]."""
FRANKA_JOINT_TORQUES = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
"""Franka's published joint torque limits [Nm]."""
READY_POSTURE = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
"""Franka's 'ready' configuration: the IK's starting guess and the null-space posture."""

BASE_XY = (0.0, -0.60)
"""Robot base beside the table's near (-y) edge, facing the table (+y)."""
BASE_Z = 0.0
"""The base stands on a pedestal level with the table top."""
SERVO_GAIN = np.array([400.0, 400.0, 400.0, 400.0, 40.0, 40.0, 40.0])
"""Joint velocity servo gains [Nm s/rad]: time constants of a few ms against link inertia + armature; twice
these make the torque-limited servos chatter at the 2 ms timestep."""
LIMIT_MARGIN = 0.05
"""Joints are kept this far [rad] inside Franka's ranges."""
FINGER_OPENING = 0.035
"""Each finger is opened this far from closed [m] (the Panda opens 0.04): the pads stand 8.5 cm apart across
the lip, which lets them resist the box turning."""
FINGERTIP_Z = 0.0945
"""Where the fingertip ends along the finger's own z axis [m] in gymnasium-robotics' finger frame (the tip
capsule's centre, 0.0875, plus its 7 mm radius): the pads sit there."""
PANDA_PADS = ("panda/pad_left", "panda/pad_right")


class MissingRobotModel(RuntimeError):
    """The Panda model cannot be found; the message says how to install it."""


def panda_asset_dir() -> Path:
    """Folder of the Panda model inside the installed gymnasium-robotics package."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or spec.origin is None:
        raise MissingRobotModel("the Panda model comes from the gymnasium-robotics package, which is not installed: "
                                "run `pip install gymnasium-robotics` (or `pip install -e .` in this repository), "
                                "or use --embodiment hand")
    folder = Path(spec.origin).parent.joinpath(*_ASSET_SUBDIR)
    if not (folder / "chain.xml").is_file():
        raise MissingRobotModel(f"gymnasium-robotics is installed but has no Panda model at {folder}: "
                                "install gymnasium-robotics>=1.4 (`pip install -U gymnasium-robotics`)")
    return folder


def load_panda_spec(visual: bool = True, gap: float = 0.0) -> mujoco.MjSpec:
    """The corrected Panda as an MjSpec (root body ``panda0_link0``; not yet attached to anything), parsed
    afresh (~8 ms): scenes attach it once per embodiment and reuse that (``scene/builder.py: _scene_base``).

    ``visual=False`` drops the visual meshes (their mesh processing is ~95 % of a scene's compile time):
    the collision meshes are then shown instead. Physics is identical either way (visual geoms are
    massless and collide with nothing). ``gap``: robot geoms report contacts this far out without
    any force (MuJoCo >= 4 semantics: detection at margin + gap, force only within margin = 0).
    """
    folder = panda_asset_dir()
    wrapper = (f'<mujoco model="panda"><include file="{folder / "assets.xml"}"/>'
               f'<worldbody><include file="{folder / "chain.xml"}"/></worldbody></mujoco>')
    spec = mujoco.MjSpec.from_string(wrapper)
    spec.meshdir = ""
    spec.nuser_actuator = -1  # the model's actuator user fields are not attached; avoids an attach conflict
    for mesh in spec.meshes:  # include-relative paths resolve to the asset folder, the meshes live below it
        mesh.file = str(folder / "meshes" / Path(mesh.file).relative_to(folder))
    for i, name in enumerate(JOINTS):
        joint = spec.joint(name)
        joint.damping = [1.0, 0.0, 0.0]
        joint.armature = 0.1
        joint.range = FRANKA_JOINT_RANGES[i]
    for link in ("panda0_link6", "panda0_link7"):
        # Franka's frames (a quarter turn about x): the model's extra turns about z (1.57 rad at joint 6,
        # 0.785 at joint 7) shifted those joints' zeros away from Franka's, so published ranges did not apply
        body = spec.body(link)
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
        body.quat = [math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0]
    for body in spec.bodies:
        if body.name.startswith("panda0_"):
            body.gravcomp = 1.0
    for finger in ("panda0_leftfinger", "panda0_rightfinger"):
        for joint in list(spec.body(finger).joints):
            spec.delete(joint)
    for geom in list(spec.geoms):
        is_visual = geom.contype == 0 and geom.conaffinity == 0
        if is_visual:
            if not visual:
                spec.delete(geom)
            continue
        geom.contype, geom.conaffinity = COLLIDE_ROBOT, 0
        geom.name = geom.meshname or f"{geom.parent.name}_geom{geom.id}"
        geom.margin, geom.gap = 0.0, gap
        if not visual:
            geom.group = 0
            geom.rgba = [0.92, 0.92, 0.9, 1.0]
    boxes_to_meshes(spec, [g for g in spec.geoms if g.contype])
    for finger, side, pad in (("panda0_leftfinger", 1.0, "pad_left"), ("panda0_rightfinger", -1.0, "pad_right")):
        body = spec.body(finger)
        # open the finger along its own y axis (the closing direction), as seen in the hand's frame
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.asarray(body.quat, dtype=float))
        body.pos = np.asarray(body.pos, dtype=float) + side * FINGER_OPENING * rotation.reshape(3, 3)[:, 1]
        tip_y = side * 0.0075  # the tip capsules' offset across the finger
        # placed so that, pushed in by PAD_PRESS, the pad's lowest point is PAD_CLEARANCE past the fingertip
        add_pad(body, pad, pos=[0.0, tip_y, FINGERTIP_Z + PAD_CLEARANCE + PAD_PRESS - PAD_RADIUS], gap=gap)
    if not visual:
        for mesh in list(spec.meshes):
            if mesh.name.endswith("_viz"):
                spec.delete(mesh)
    return spec


@dataclass
class PandaBinding:
    """Ids and buffers resolved once per compiled model."""

    qpos_adr: np.ndarray  # (7,) arm joints
    dof_adr: np.ndarray  # (7,)
    actuator_ids: slice  # the 7 velocity servos (contiguous)
    act_adr: slice  # their set-points
    ee_site: int
    site_body: int
    pad_qpos: np.ndarray  # (2,) the pads' slides
    root_body: int
    home_qpos: np.ndarray
    target_rotation: np.ndarray  # (3, 3) hand orientation to hold
    site_jac: tuple[np.ndarray, np.ndarray]  # the end-effector site's Jacobian (translation, rotation): the two
    # (3, nv) halves of one (6, nv) buffer, which mj_jacSite fills
    site_jac_dot: tuple[np.ndarray, np.ndarray]  # the same for its time derivative (mj_jacDot)
    arm_jac: np.ndarray  # (6, 7) view of the arm's columns of the first buffer
    arm_jac_dot: np.ndarray  # (6, 7) view of the arm's columns of the second
    jac6: np.ndarray  # (6, 7) buffer: the two combined
    twist: np.ndarray  # (6,) buffer
    timestep: float  # the model's physics timestep [s]
    qpos: slice | np.ndarray  # qpos_adr as a slice when contiguous (it is, as compiled)
    dofs: slice  # dof_adr as a slice (the arm's dofs are contiguous)
    setpoint_rate: np.ndarray  # (7,) the servo set-points' rate (commanded joint acceleration) at the last substep
    ik_qdot: np.ndarray | None = None  # last step: the IK's joint velocities, and those the joint limits let through
    limited_qdot: np.ndarray | None = None

    @property
    def speed_scale(self) -> float:
        """Last step: share of the IK's joint speeds the joint limits let through (computed when asked: the
        controller never needs it)."""
        if self.ik_qdot is None:
            return 1.0
        unlimited = float(self.ik_qdot @ self.ik_qdot)
        return math.sqrt(float(self.limited_qdot @ self.limited_qdot) / unlimited) if unlimited > 0.0 else 1.0


class PandaArm:
    """The Franka Panda (see the module docstring); its controller is ``control.cartesian.PandaController``."""

    name = "panda"
    controller = "panda"
    root_body_name = "panda/panda0_link0"
    ee_site_name = "panda/end_effector"
    distance_geom_names = ("box_bottom", "panda/hand_col")

    def __init__(self, visual: bool = True, gap: float = 0.0):
        self.visual = visual
        self.gap = gap

    @property
    def cache_key(self) -> tuple:
        return (self.name, self.visual, self.gap)

    # ------------------------------------------------------------------ building
    def attach(self, spec: mujoco.MjSpec, geo: TaskGeometry) -> None:
        """The arm on its pedestal, its pads resting on the box lip in the home configuration, and its servos."""
        robot = load_panda_spec(self.visual, self.gap)
        base = spec.worldbody.add_frame(pos=[BASE_XY[0], BASE_XY[1], BASE_Z],
                                        quat=[math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])  # face +y
        base.attach_body(robot.body("panda0_link0"), "panda/", "")
        spec.worldbody.add_geom(name="pedestal", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.11, 0.4],
                                pos=[BASE_XY[0], BASE_XY[1], BASE_Z - 0.4], rgba=[0.25, 0.25, 0.28, 1],
                                contype=0, conaffinity=0)
        for i, joint in enumerate(JOINTS):
            servo = spec.add_actuator(name=f"servo{i + 1}", target=f"panda/{joint}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            servo.dyntype = mujoco.mjtDyn.mjDYN_INTEGRATOR  # set-point = integral of ctrl: a ramp within the step
            servo.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            servo.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            servo.gainprm[0] = SERVO_GAIN[i]
            servo.biasprm[:3] = [0.0, 0.0, -SERVO_GAIN[i]]
            servo.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            servo.forcerange = [-FRANKA_JOINT_TORQUES[i], FRANKA_JOINT_TORQUES[i]]
            servo.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE

    def bind(self, model: mujoco.MjModel) -> PandaBinding:
        joints = [model.joint(f"panda/{j}") for j in JOINTS]
        servos = [model.actuator(f"servo{i + 1}").id for i in range(7)]
        acts = [int(model.actuator_actadr[a]) for a in servos]
        if servos != list(range(servos[0], servos[0] + 7)) or acts != list(range(acts[0], acts[0] + 7)):
            raise RuntimeError("the Panda's servos must be contiguous in the compiled model")
        dofs = np.array([j.dofadr[0] for j in joints])
        arm = _as_slice(dofs)
        if not isinstance(arm, slice):  # the arm's Jacobian columns are then views (``arm_jac``)
            raise RuntimeError("the Panda's joints must have contiguous dofs in the compiled model")
        home, pose = home_configuration(GEOMETRY)  # the geometry every scene is built with
        nv = model.nv
        site_jac, site_jac_dot = np.zeros((6, nv)), np.zeros((6, nv))
        return PandaBinding(
            qpos_adr=np.array([j.qposadr[0] for j in joints]), dof_adr=dofs,
            actuator_ids=slice(servos[0], servos[0] + 7), act_adr=slice(acts[0], acts[0] + 7),
            ee_site=model.site(self.ee_site_name).id, site_body=int(model.site(self.ee_site_name).bodyid[0]),
            pad_qpos=np.array([model.joint(p).qposadr[0] for p in PANDA_PADS]),
            root_body=model.body(self.root_body_name).id, home_qpos=home, target_rotation=pose["site"][1],
            site_jac=(site_jac[:3], site_jac[3:]), site_jac_dot=(site_jac_dot[:3], site_jac_dot[3:]),
            arm_jac=site_jac[:, arm], arm_jac_dot=site_jac_dot[:, arm], jac6=np.zeros((6, 7)), twist=np.zeros(6),
            timestep=float(model.opt.timestep), qpos=_as_slice(np.array([j.qposadr[0] for j in joints])), dofs=arm,
            setpoint_rate=np.zeros(7))

    def holding_reach(self, geo: TaskGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where on the table the arm can hold the box (``holding_reach``, solved once per process)."""
        return holding_reach(geo)

    # ------------------------------------------------------------------ episode
    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, binding: PandaBinding) -> None:
        data.qpos[binding.qpos_adr] = binding.home_qpos
        data.qpos[binding.pad_qpos] = PAD_NOMINAL_QPOS  # pressed in, just touching the lip: no start-up jolt
        data.qvel[binding.dof_adr] = 0.0
        data.act[binding.act_adr] = 0.0
        binding.setpoint_rate = np.zeros(7)


def _as_slice(ids: np.ndarray):
    """A slice for contiguous ids: slicing MjData costs a fraction of a fancy-index gather."""
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


class _BareArm:
    """The Panda alone at its base, for inverse kinematics of the hand pointing down (no scene, no box)."""

    # hand pointing down, fingers closing along world y (the hand is then thin along x, towards the top box)
    HAND_DOWN = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])

    def __init__(self):
        spec = load_panda_spec(visual=False)
        base = mujoco.MjSpec()
        frame = base.worldbody.add_frame(pos=[BASE_XY[0], BASE_XY[1], BASE_Z],
                                         quat=[math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
        frame.attach_body(spec.body("panda0_link0"), "panda/", "")
        self.model = model = base.compile()
        self.data = mujoco.MjData(model)
        self.site = model.site("panda/end_effector").id
        joints = [model.joint(f"panda/{j}") for j in JOINTS]
        self.qadr = np.array([j.qposadr[0] for j in joints])
        self.dadr = np.array([j.dofadr[0] for j in joints])
        self.jacp, self.jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))

    def solve(self, target_pos: np.ndarray, start: np.ndarray, posture: np.ndarray, iterations: int = 1000,
              tolerance: float = 1e-6) -> tuple[np.ndarray, float, float]:
        """DLS IK from ``start`` for the site at ``target_pos`` with the hand down, every joint kept LIMIT_MARGIN
        inside Franka's ranges and pulled gently towards ``posture``. Returns the angles and the position [m]
        and orientation [rad] residuals."""
        model, data, site = self.model, self.data, self.site
        lo, hi = FRANKA_JOINT_RANGES[:, 0] + LIMIT_MARGIN, FRANKA_JOINT_RANGES[:, 1] - LIMIT_MARGIN
        data.qpos[self.qadr] = start
        for _ in range(iterations):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            err = np.concatenate((target_pos - data.site_xpos[site],
                                  orientation_error(data.site_xmat[site].reshape(3, 3), self.HAND_DOWN)))
            if np.linalg.norm(err) < tolerance:
                break
            mujoco.mj_jacSite(model, data, self.jacp, self.jacr, site)
            jac = np.vstack((self.jacp[:, self.dadr], self.jacr[:, self.dadr]))
            step = dls_joint_velocity(jac, err, 0.01, 0.02 * (posture - data.qpos[self.qadr]))
            data.qpos[self.qadr] = np.clip(data.qpos[self.qadr] + 0.5 * step, lo, hi)
        return data.qpos[self.qadr].copy(), float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))


@lru_cache(maxsize=4)
def press_site_height(geo: TaskGeometry) -> float:
    """Height of the ``end_effector`` site when the pads press on the box lip, each pushed in by PAD_PRESS.

    The site, the fingers' bases and their z axes all lie along link 7's z axis, which points down here."""
    spec = load_panda_spec(visual=False)
    finger_base = float(spec.body("panda0_leftfinger").pos[2])
    site = float(spec.site("end_effector").pos[2])
    return 2 * geo.box_half_extents[2] + finger_base + FINGERTIP_Z + PAD_CLEARANCE - site


def _facing(target_xy) -> np.ndarray:
    """The ready posture turned to face ``target_xy`` from the base, the hand's yaw kept."""
    q = READY_POSTURE.copy()
    q[0] = math.atan2(-(target_xy[0] - BASE_XY[0]), target_xy[1] - BASE_XY[1])
    q[6] -= q[0]
    return q


@lru_cache(maxsize=4)
def home_configuration(geo: TaskGeometry) -> tuple[np.ndarray, dict]:
    """Joint angles that put the pads on the box lip, pressed in by PAD_PRESS, with the hand pointing down.

    Solved once by DLS IK on the bare arm from the ready posture; returns the angles and the world poses
    of the ``end_effector`` site and of link 7 in that configuration.
    """
    arm = _BareArm()
    gx, gy = geo.grasp_xy
    start = _facing((gx, gy))
    q, position_error, rotation_error = arm.solve(np.array([gx, gy, press_site_height(geo)]), start, start)
    residual = math.hypot(position_error, rotation_error)
    if residual > 1e-4:
        raise RuntimeError(f"no home configuration reaches the box grasp (residual {residual:.2e} m): "
                           "the task geometry is out of the Panda's reach")
    model, data, site = arm.model, arm.data, arm.site
    link7 = model.body("panda/panda0_link7").id
    poses = {"site": (data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy()),
             "link7": (data.xpos[link7].copy(), data.xmat[link7].reshape(3, 3).copy())}
    return q, poses


REACH_GRID = 0.02
"""Spacing [m] of the map of where the Panda can hold the box (``holding_reach``)."""
REACH_TOLERANCE = (0.01, 0.1)
"""Position [m] and hand-orientation [rad] residuals within which a box centre counts as held: half a
grid cell, and a tilt the orientation hold recovers from (a policy was seen to carry the box ~1 cm past
the exact-pose boundary near the base)."""


@lru_cache(maxsize=4)
def holding_reach(geo: TaskGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where on the table the Panda can hold the box: (xs, ys, mask) on a ``REACH_GRID`` grid of box centres.

    A cell is within reach if DLS IK, every joint at least ``LIMIT_MARGIN`` inside its range, puts the
    fingertips on the box lip there with the hand pointing down, within ``REACH_TOLERANCE`` (the
    controller, too, lets the hand tilt a little where a joint limit blocks the way). Solved once per
    process by continuation: along each column of the grid from the lane's row outwards, each cell
    starting from its neighbour's solution, up to the first cell out of reach (so the map holds the
    cells the box can be carried to from the lane). It ignores the links' clearance from the table and
    the clutter; the env judges those.
    """
    arm = _BareArm()
    tx, ty = geo.table_half_extents
    lip = geo.grasp_xy[0] - geo.bottom_xy[0], geo.grasp_xy[1] - geo.bottom_xy[1]  # fingertips from the box centre
    z = press_site_height(geo)
    xs = np.arange(-tx, tx + 1e-9, REACH_GRID)
    ys = np.arange(-ty, ty + 1e-9, REACH_GRID)
    mask = np.zeros((len(xs), len(ys)), dtype=bool)
    home, _ = home_configuration(geo)
    lane = int(np.argmin(np.abs(ys - geo.bottom_xy[1])))
    for i, x in enumerate(xs):
        for rows in (range(lane, len(ys)), range(lane - 1, -1, -1)):
            q = None
            for j in rows:
                target = (x + lip[0], ys[j] + lip[1])
                for start in ([_facing(target)] if q is None else [q, _facing(target)]):
                    solution, position_error, rotation_error = arm.solve(np.array([*target, z]), start, home,
                                                                         iterations=400, tolerance=1e-4)
                    if position_error < REACH_TOLERANCE[0] and rotation_error < REACH_TOLERANCE[1]:
                        mask[i, j], q = True, solution
                        break
                if not mask[i, j]:
                    break
    return xs, ys, mask
