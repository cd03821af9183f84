"""Compose the scene with ``mujoco.MjSpec``: arena (table, goal, cameras, light) + robot + objects + the
sensors the judge reads.

The compiled model depends only on *which* objects are present and on the embodiment; poses are set per
episode through qpos, so ``build_model`` results are cached by (object names, embodiment).

Safety is judged at every physics substep without Python between substeps: robot and held-box geoms
report contacts within ``gap`` = d4 (no force: MuJoCo detects at margin + gap and pushes only within
margin = 0), and sensors with a 25-sample history (one sample per substep) record, per clutter object,
the nearest such contact and the object's velocity, plus the held box's position and velocity and the
top box's position and up-axis. The env reads the whole history once per control step.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from safemanip.scene.catalog import CatalogObject, load_catalog
from safemanip.scene.config import GEOMETRY, TaskGeometry
from safemanip.scene.embodiment import Embodiment, make_embodiment
from safemanip.scene.grasp import (COLLIDE_HULL, COLLIDE_OBJECTS, COLLIDE_ROBOT, COLLIDE_STACK, COLLIDE_TABLE,
                                   add_box_mesh, add_held_box)

TIMESTEP = 0.002
CONTROL_DT = 0.05  # 20 Hz control
SUBSTEPS = int(round(CONTROL_DT / TIMESTEP))
BOX_FRICTION = 0.2
IMPRATIO = 10.0
TABLE_FRICTION = 0.3
WHITE_BOX = (0.95, 0.95, 0.92, 1.0)
BLUE_BOX = (0.15, 0.30, 0.80, 1.0)

_GEOM_TYPES = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
               "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}


def _part_volume(part) -> float:
    s = part.size
    if part.type == "box":
        return 8 * s[0] * s[1] * s[2]
    if part.type == "cylinder":
        return np.pi * s[0] ** 2 * 2 * s[1]
    if part.type == "capsule":
        return np.pi * s[0] ** 2 * 2 * s[1] + 4 / 3 * np.pi * s[0] ** 3
    return 4 / 3 * np.pi * s[0] ** 3


def _add_arena(spec: mujoco.MjSpec, geo: TaskGeometry) -> None:
    tx, ty = geo.table_half_extents
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # elliptic friction cones, stiffened (impratio): with pyramidal ones the pads let the box slip and tip over
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = IMPRATIO
    spec.visual.quality.shadowsize = 0
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    spec.stat.center = [0, 0, 0]
    spec.stat.extent = 1.0
    world = spec.worldbody
    world.add_light(name="sun", pos=[0, -0.4, 2.0], dir=[0, 0.2, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, castshadow=0,
                    diffuse=[0.8, 0.8, 0.8], ambient=[0.35, 0.35, 0.35])
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[8, 8, 0.1], pos=[0, 0, -0.8],
                   rgba=[0.35, 0.35, 0.38, 1], contype=0, conaffinity=0)
    # table friction wins over every object's thanks to its higher priority
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[tx, ty, 0.025], pos=[0, 0, -0.025],
                   rgba=[0.55, 0.42, 0.30, 1], friction=[TABLE_FRICTION, 0.005, 0.0001], priority=1,
                   contype=COLLIDE_TABLE, conaffinity=COLLIDE_OBJECTS | COLLIDE_ROBOT | COLLIDE_STACK)
    for sx in (-1, 1):
        for sy in (-1, 1):
            world.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.025, 0.025, 0.385],
                           pos=[sx * (tx - 0.05), sy * (ty - 0.05), -0.435], rgba=[0.45, 0.33, 0.22, 1],
                           contype=0, conaffinity=0)
    gx, gy = geo.goal_xy
    world.add_geom(name="goal", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[geo.goal_radius, 0.0008],
                   pos=[gx, gy, 0.0008], rgba=[0.1, 0.8, 0.2, 0.45], contype=0, conaffinity=0)
    # high behind the robot, looking down at the table: the arm hides little of the clutter
    world.add_camera(name="front", pos=[0.0, -1.0, 1.8], xyaxes=[1, 0, 0, 0, 0.857, 0.514], fovy=44)
    world.add_camera(name="top", pos=[0.0, 0.0, 1.45], xyaxes=[1, 0, 0, 0, 1, 0], fovy=50)


def _add_top_box(spec: mujoco.MjSpec, geo: TaskGeometry) -> None:
    hx, hy, hz = geo.box_half_extents
    sx, sy = geo.stack_xy
    top = spec.worldbody.add_body(name="box_top", pos=[sx, sy, 3 * hz + 0.0005])
    top.add_freejoint(name="box_top")
    # a primitive box on the bottom box and the table (multi-point resting contacts), a mesh hull for the rest
    top.add_geom(name="box_top", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, hz], mass=geo.box_mass,
                 rgba=BLUE_BOX, friction=[BOX_FRICTION, 0.005, 0.0001],
                 contype=COLLIDE_STACK, conaffinity=COLLIDE_TABLE | COLLIDE_STACK)
    top.add_geom(name="box_top_hull", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=add_box_mesh(spec, "box_top_hull", (hx, hy, hz)),
                 mass=0.0, rgba=[0, 0, 0, 0], group=3, friction=[BOX_FRICTION, 0.005, 0.0001],
                 contype=COLLIDE_HULL, conaffinity=COLLIDE_OBJECTS | COLLIDE_ROBOT)


def _add_object(spec: mujoco.MjSpec, index: int, obj: CatalogObject) -> None:
    body = spec.worldbody.add_body(name=f"obj{index}", pos=[0, 0, 0])
    body.add_freejoint(name=f"obj{index}")
    total = sum(_part_volume(p) for p in obj.parts)
    for j, part in enumerate(obj.parts):
        _add_part(body, f"obj{index}_g{j}", part, obj, total)


def _add_part(body, name, part, obj: CatalogObject, total_volume: float):
    geom = body.add_geom(name=name, type=_GEOM_TYPES[part.type], size=list(part.size) + [0] * (3 - len(part.size)),
                         pos=part.pos, mass=obj.mass * _part_volume(part) / total_volume, rgba=obj.rgba,
                         friction=[0.5, 0.005, 0.0001],
                         contype=COLLIDE_OBJECTS, conaffinity=COLLIDE_OBJECTS | COLLIDE_ROBOT | COLLIDE_HULL)
    if any(part.euler):
        quat = np.zeros(4)
        mujoco.mju_euler2Quat(quat, np.asarray(part.euler, dtype=float), "xyz")
        geom.quat = quat
    return geom


def _add_judge_sensors(spec: mujoco.MjSpec, embodiment: Embodiment, n_objects: int) -> None:
    """Sensors with one history sample per substep (layout read by ``SceneIndex.history_index``)."""
    def sensor(name, kind, objtype, objname, **extra):
        spec.add_sensor(name=name, type=kind, objtype=objtype, objname=objname, nsample=SUBSTEPS, **extra)

    body, xbody = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_XBODY
    for i in range(n_objects):
        # nearest contact between object i and anything in the robot's subtree (links, hand, fingers, pads), and
        # between it and the held box
        for name, objtype, objname in ((f"judge_contact{i}", xbody, embodiment.root_body_name),
                                       (f"judge_box_contact{i}", body, "box_bottom")):
            sensor(name, mujoco.mjtSensor.mjSENS_CONTACT, objtype, objname, reftype=body, refname=f"obj{i}",
                   intprm=[1 | 8, 1, 1])  # data: found|dist; reduce: mindist; num 1
        sensor(f"judge_vel{i}", mujoco.mjtSensor.mjSENS_FRAMELINVEL, xbody, f"obj{i}")
    sensor("judge_box_vel", mujoco.mjtSensor.mjSENS_FRAMELINVEL, xbody, "box_bottom")
    sensor("judge_box_pos", mujoco.mjtSensor.mjSENS_FRAMEPOS, xbody, "box_bottom")
    sensor("judge_top_pos", mujoco.mjtSensor.mjSENS_FRAMEPOS, xbody, "box_top")
    sensor("judge_top_up", mujoco.mjtSensor.mjSENS_FRAMEZAXIS, xbody, "box_top")


_BASES: dict[tuple, mujoco.MjSpec] = {}


def _scene_base(embodiment: Embodiment, geometry: TaskGeometry) -> mujoco.MjSpec:
    """Table, robot with the held box, and top box: the part of every scene that does not depend on the
    clutter, built once per (embodiment, geometry) and copied (0.4 ms) for each new object set instead of
    rebuilt (~3 ms for the Panda). A copy plus the objects compiles to a byte-identical model (tested)."""
    key = (embodiment.cache_key, geometry)
    if key not in _BASES:
        if len(_BASES) >= 8:  # a few embodiments and geometries at most; never grow without bound
            _BASES.clear()
        spec = mujoco.MjSpec()
        spec.modelname = "slide_out"
        _add_arena(spec, geometry)
        add_held_box(spec, geometry, WHITE_BOX, BOX_FRICTION, embodiment.gap)
        embodiment.attach(spec, geometry)
        _add_top_box(spec, geometry)
        # the end-effector's velocity (the box's is the judge's ``judge_box_vel``): read once per control step
        spec.add_sensor(name="ee_vel", type=mujoco.mjtSensor.mjSENS_FRAMELINVEL, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname=embodiment.ee_site_name)
        _BASES[key] = spec
    return _BASES[key]


def build_spec(names: tuple[str, ...], embodiment: Embodiment | None = None, geometry: TaskGeometry = GEOMETRY,
               sleep: bool = True, judge: bool = True) -> mujoco.MjSpec:
    """The scene's spec. ``judge=False`` leaves out the per-substep judge sensors (benchmarks use it to
    price them; the env needs them)."""
    catalog = load_catalog()
    embodiment = embodiment if embodiment is not None else make_embodiment("panda")
    spec = _scene_base(embodiment, geometry).copy()
    for i, name in enumerate(names):
        _add_object(spec, i, catalog[name])
    if judge:
        _add_judge_sensors(spec, embodiment, len(names))
    if sleep:
        # resting clutter islands go to sleep and cost nothing until something touches them
        spec.option.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    return spec


MODEL_CACHE_SIZE = 384
"""Compiled scenes kept per process, shared by its envs. Building and compiling one is most of a reset that
draws a new object set (about 3 of 5.6 ms at N = 6 on the Panda). A Panda scene takes about 0.7 MB, about
0.3 MB of it resident: a full cache adds ~100 MB to a process. It holds every four-object draw of the 11
fragile objects (330), the scenes of the Fig. 5 cells, so evaluation there compiles each set once per
process. Training draws its objects from the whole catalog (52,360 four-object sets) and seldom meets a set
twice: there it saves little."""


@lru_cache(maxsize=MODEL_CACHE_SIZE)
def build_model(names: tuple[str, ...], sleep: bool = True, embodiment: str = "panda", visual: bool = False,
                gap: float = 0.01) -> mujoco.MjModel:
    """Compiled model for this set of clutter objects and embodiment (cached; treat it as read-only).

    ``visual``: include the robot's visual meshes (for rendering; compiling them costs ~70 ms, the rest
    ~3 ms). ``gap``: how far out robot and held-box contacts are reported (the collision threshold d4).
    """
    return build_spec(names, make_embodiment(embodiment, visual=visual, gap=gap), sleep=sleep).compile()


@lru_cache(maxsize=MODEL_CACHE_SIZE)
def scene_index(names: tuple[str, ...], sleep: bool = True, embodiment: str = "panda", visual: bool = False,
                gap: float = 0.01) -> "SceneIndex":
    """``SceneIndex`` of ``build_model``'s model for the same arguments (cached with it; read-only)."""
    model = build_model(names, sleep, embodiment, visual, gap)
    return SceneIndex.from_model(model, len(names), make_embodiment(embodiment, visual=visual, gap=gap))


@dataclass
class SceneIndex:
    """Name -> id lookups done once per compiled model."""

    top_box_body: int
    top_box_qpos: int
    top_box_qvel: int
    bottom_box_body: int
    bottom_box_qpos: int  # start of the held box's free joint in qpos (x, y, z, quaternion)
    bottom_box_qvel: int
    manipulated_geoms: np.ndarray  # geoms whose exact distance to the clutter is measured (held box, hand)
    object_bodies: np.ndarray  # (N,)
    object_qpos: np.ndarray  # (N,) start of each free joint's qpos
    object_qvel: np.ndarray
    object_geoms: list[np.ndarray]  # per object, its geom ids
    geom_to_object: dict[int, int]
    object_qvel_flat: np.ndarray  # (3N,) qvel indices of the objects' linear velocities, for one gather
    object_reach: np.ndarray  # (N,) radius around the body origin that contains all of the object's geoms

    @classmethod
    def from_model(cls, model: mujoco.MjModel, n_objects: int, embodiment: Embodiment) -> "SceneIndex":
        bodies = np.array([model.body(f"obj{i}").id for i in range(n_objects)], dtype=int)
        geoms = [np.flatnonzero(model.geom_bodyid == b) for b in bodies]
        top = model.joint("box_top")
        return cls(
            top_box_body=model.body("box_top").id,
            top_box_qpos=int(top.qposadr[0]),
            top_box_qvel=int(top.dofadr[0]),
            bottom_box_body=model.body("box_bottom").id,
            bottom_box_qpos=int(model.joint("box_bottom").qposadr[0]),
            bottom_box_qvel=int(model.joint("box_bottom").dofadr[0]),
            manipulated_geoms=np.array([model.geom(g).id for g in embodiment.distance_geom_names]),
            object_bodies=bodies,
            object_qpos=np.array([model.joint(f"obj{i}").qposadr[0] for i in range(n_objects)], dtype=int),
            object_qvel=np.array([model.joint(f"obj{i}").dofadr[0] for i in range(n_objects)], dtype=int),
            object_geoms=geoms,
            geom_to_object={int(g): i for i, gs in enumerate(geoms) for g in gs},
            object_qvel_flat=np.array([model.joint(f"obj{i}").dofadr[0] + j for i in range(n_objects) for j in range(3)],
                                      dtype=int),
            object_reach=np.array([max((np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g] for g in gs), default=0.0)
                                   for gs in geoms]),
        )
