"""The held box, the fingertip pads that drag it, and which geoms collide with which.

The grasp is a contact grasp a real Panda can make: the open fingers rest on the lip of the bottom box
that sticks out from under the top box, and their fingertip pads press down on it and drag it by friction.
Nothing holds the box but those contacts, so the hand cannot lift it, cannot press it into the table
with more than the pads' spring force, and loses it if it asks for more friction than the pads give.

* Each pad sits on a vertical slide at its fingertip with a soft spring preloaded far beyond its travel: a
  nearly constant force, 8-13 N per pad over its 25 mm travel, 10 N (20 N for the two) at the nominal press.
  It stands in for the Panda pressing down under Cartesian force/impedance control in z: the arm itself is
  velocity-servoed and as stiff as a vice, so without it every millimetre of height error would be tens of
  newtons (the welded box of earlier versions was pressed into the table with up to 205 N).
* Rubber on cardboard, friction ``PAD_FRICTION`` = 0.9: the pads can pull with up to ~18 N before they
  slip. Pulling the box out as fast as the arm's joints allow (about 7 m/s^2) needs ~11 N: its inertia, the
  table's friction under the pressed box and the top box's drag. Pressing harder would tip the box over when it
  is dragged from its top, the pads being near its front edge.

Judging: MuJoCo's box-box collider misses some edge-to-edge pairs closer than the contact gap (seen at
1.2 mm with a 1 cm gap; 47 of 3000 random box-box poses within the gap reported no contact), while its
convex-mesh collider found every one. So the held box carries two geoms of the same shape: a primitive
box for the table, the top box and the pads (stable multi-point resting contacts), and a convex mesh
box, the only one that meets the clutter. Robot geoms that are boxes become mesh boxes for the same
reason (``boxes_to_meshes``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from safemanip.scene.config import TaskGeometry

# contype/conaffinity bits: a pair collides if (type1 & affinity2) or (type2 & affinity1)
COLLIDE_TABLE = 1  # the table top
COLLIDE_OBJECTS = 2  # the clutter
COLLIDE_ROBOT = 4  # robot links, hand, fingers and pads: they hit the table, the clutter and the top box
COLLIDE_STACK = 8  # the two cereal boxes' primitive geoms: on each other and on the table
COLLIDE_PADS = 16  # fingertip pads: the only robot geoms that touch the held box
COLLIDE_HULL = 32  # the cereal boxes' mesh hulls: what the clutter (and the robot, for the top box) meets

PAD_FRICTION = 0.9
"""Sliding friction of the fingertip pads (rubber on cardboard)."""
PAD_STIFFNESS = 200.0
"""Spring stiffness of each pad's slide [N/m]: soft, so that the force hardly depends on the hand's height."""
PAD_PRELOAD = 0.040
"""Spring preload [m]: each fully extended pad already pushes with PAD_STIFFNESS * PAD_PRELOAD = 8 N."""
PAD_PRESS = 0.010
"""How far each pad is pushed in at the nominal press [m]: 10 N per pad, 20 N in all."""
PAD_TRAVEL = 0.025
"""Range of each pad's slide [m]; pushed in further, a pad bottoms out on its finger."""
PAD_CLEARANCE = 0.002
"""At the nominal press the fingertips stay this far above the lip [m]: only the pads touch it."""
PAD_DAMPING = 4.0
"""Damping of each pad's slide [N s/m]: about critical for the pad's 20 g on its spring."""
PAD_MASS = 0.02
PAD_RADIUS = 0.006
"""Pad capsule radius [m]; the capsule lies across the finger, 16 mm long."""
PAD_HALF_LENGTH = 0.008


def box_mesh_vertices(half: tuple[float, float, float] | np.ndarray) -> list[float]:
    """The 8 corners of a box of half-extents ``half``, flat, for an MjSpec mesh."""
    hx, hy, hz = (float(h) for h in half)
    return [c for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz) for c in (x, y, z)]


def add_box_mesh(spec: mujoco.MjSpec, name: str, half) -> str:
    """A convex mesh box asset named ``name`` (added once per spec); returns its name."""
    if not any(mesh.name == name for mesh in spec.meshes):
        spec.add_mesh(name=name, uservert=box_mesh_vertices(half))
    return name


def boxes_to_meshes(spec: mujoco.MjSpec, geoms) -> None:
    """Turn the colliding box ``geoms`` of a robot into convex mesh boxes of the same size and pose, so that
    their contacts with the clutter's boxes are not missed (see the module docstring)."""
    for geom in geoms:
        if geom.type != mujoco.mjtGeom.mjGEOM_BOX:
            continue
        half = np.asarray(geom.size, dtype=float)
        geom.meshname = add_box_mesh(spec, f"hull_{half[0]:.4f}_{half[1]:.4f}_{half[2]:.4f}", half)
        geom.type = mujoco.mjtGeom.mjGEOM_MESH


def add_held_box(spec: mujoco.MjSpec, geo: TaskGeometry, rgba, friction: float, gap: float) -> None:
    """The bottom cereal box: a free body resting on the table where the task starts, with its primitive box
    (table, top box, pads) and its mesh hull (clutter, judged at ``gap`` = d4 without any force)."""
    hx, hy, hz = geo.box_half_extents
    bx, by = geo.bottom_xy
    body = spec.worldbody.add_body(name="box_bottom", pos=[bx, by, hz])
    body.add_freejoint(name="box_bottom")
    body.add_geom(name="box_bottom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, hz], mass=geo.box_mass,
                  rgba=rgba, friction=[friction, 0.005, 0.0001],
                  contype=COLLIDE_STACK, conaffinity=COLLIDE_TABLE | COLLIDE_STACK | COLLIDE_PADS)
    body.add_geom(name="box_bottom_hull", type=mujoco.mjtGeom.mjGEOM_MESH,
                  meshname=add_box_mesh(spec, "box_bottom_hull", (hx, hy, hz)), mass=0.0, rgba=[0, 0, 0, 0],
                  friction=[friction, 0.005, 0.0001], gap=gap, group=3,
                  contype=COLLIDE_HULL, conaffinity=COLLIDE_OBJECTS)


def add_pad(parent: mujoco.MjsBody, name: str, pos, quat=(1.0, 0.0, 0.0, 0.0), gap: float = 0.0) -> None:
    """A fingertip pad below ``parent``: a body at ``pos`` (parent frame) on a slide along its own +z (pointing
    out of the fingertip, down onto the box), preloaded by a spring against the end of its range, carrying a
    capsule across its x axis whose lowest point is ``PAD_RADIUS`` past ``pos`` along +z."""
    # Every physical property is set here, none inherited: a pad added below a robot model's body takes that
    # model's default class otherwise (gymnasium-robotics' Panda gave the slide an armature of 5, a 5 kg pad on
    # a 200 N/m spring, and the capsule a 1 mm contact margin: the box rattled between the pads with up to 84 N
    # at 2 ms and shook the arm's joints to twice Franka's acceleration limits).
    pad = parent.add_body(name=name, pos=list(pos), quat=list(quat), gravcomp=1.0)
    pad.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1], range=[-PAD_TRAVEL, 0.0],
                  limited=mujoco.mjtLimited.mjLIMITED_TRUE, stiffness=[PAD_STIFFNESS, 0.0, 0.0],
                  springref=PAD_PRELOAD, damping=[PAD_DAMPING, 0.0, 0.0], armature=0.0, frictionloss=0.0,
                  solref_limit=list(_SOLREF), solimp_limit=list(_SOLIMP))
    pad.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[PAD_RADIUS, PAD_HALF_LENGTH, 0.0],
                 quat=[np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0],  # the capsule's axis along the pad's x
                 mass=PAD_MASS, rgba=[0.15, 0.15, 0.15, 1.0], friction=[PAD_FRICTION, 0.005, 0.0001],
                 margin=0.0, gap=gap, solref=list(_SOLREF), solimp=list(_SOLIMP), solmix=1.0, priority=0,
                 condim=3, contype=COLLIDE_ROBOT | COLLIDE_PADS, conaffinity=0)


_SOLREF = (0.02, 1.0)
"""MuJoCo's default contact and limit softness, stated: the pads must not take a robot model's default class."""
_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)


PAD_NOMINAL_QPOS = -PAD_PRESS
"""Each pad's slide position at the nominal press (pushed in by PAD_PRESS): where resets put it."""
