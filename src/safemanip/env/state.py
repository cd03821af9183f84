"""The state the env reads, the env's third part: one flat array per control step, gathered from MjData in a few
vectorised reads, with named blocks (``StateGather``) from which an observation is one more gather and the judge
reads its history columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from safemanip.env.observation import slot_dim
from safemanip.scene.builder import SceneIndex

MANIPULATED_REACH = 0.25
"""Bounding radius [m] of the held box and the hand around the box centre."""


class _Blocks:
    """Consecutive named blocks of a flat array: ``take(n)`` returns the next n entries' slice."""

    def __init__(self):
        self.size = 0

    def take(self, n: int) -> slice:
        block = slice(self.size, self.size + n)
        self.size += n
        return block


@dataclass(frozen=True)
class StateGather:
    """Index arrays and MjData views, built once per compiled scene, that read the state in a few gathers.

    The flat state is ``[ee_pos(3), ee_vel(3), box_vel(3), top_vel(3), obj_vel(3N), bottom_pos(3), top_pos(3),
    obj_pos(3N), constraint one-hots(3N), footprint radii(N, with object_size)]``: the order ``_read_state``
    concatenates its sources in (the site's position, the end-effector's velocity sensor, the free joints' linear
    velocities, the bodies' positions, the episode's constants); the slices below name each block. An observation is one
    gather from it.

    The judge sensors' history (one ring buffer of ``substeps`` samples per sensor, each overwritten once per control
    step) is read where the judge needs it: the held box's and the top box's paths as views of their sensors' samples,
    the contact sensors' found flags in one gather (``found_index``); only a step with a contact near an object reads
    everything, as one (substeps, columns) gather through ``history_index`` whose columns the ``h_*`` fields name.
    """

    xpos: np.ndarray  # views into this scene's MjData (its buffers never move)
    geom_xpos: np.ndarray
    qvel: np.ndarray
    site_xpos: np.ndarray
    xmat: np.ndarray  # flat
    sensordata: np.ndarray
    history: np.ndarray
    sensor_index: slice  # in sensordata: the end-effector's linear velocity
    ee_site: int
    top_up_z: int  # index in ``xmat`` of the top box's up-axis z component
    body_rows: np.ndarray
    qvel_index: np.ndarray
    ee_pos: slice  # the blocks of the flat state
    ee_vel: slice
    box_vel: slice
    top_vel: slice
    obj_vel: slice
    bottom_pos: slice
    top_pos: slice
    obj_pos: slice
    reach: list[float]  # per object: bounding radius of its geoms plus the held box's
    distance_geoms: np.ndarray  # the manipulated geoms, then every object geom: the rows of one geom_xpos gather
    geom_pairs: list[list[tuple[int, int, int, int, float]]]  # per object, the (manipulated geom, object geom) pairs
    # to query: (geom 1, geom 2, their rows in ``distance_geoms``, the sum of their bounding radii)
    index_order: np.ndarray
    robot_sources: np.ndarray  # (18,): flat-state indices of the robot and box part of the observation
    slot_sources: np.ndarray  # (N, 9 or 10): flat-state indices of each slot entry (observation.py layout)
    index_sources: np.ndarray  # observation_sources(index_order), the common case, precomputed
    history_index: np.ndarray  # (substeps, columns) indices into MjData.history
    h_found: np.ndarray  # (N, 2) columns: contact found between object i and the robot's subtree / the held box
    h_dist: np.ndarray  # (N, 2) columns: those contacts' distances
    h_obj_vel: np.ndarray  # (N, 3) columns: object i's linear velocity
    h_box_vel: np.ndarray  # (3,) the held box's linear velocity
    h_box_xy: np.ndarray  # (2,) the held box's position
    h_top_pos: np.ndarray  # (2,) the top box's horizontal position
    h_top_up_z: int  # the z component of the top box's up axis
    found_index: np.ndarray  # indices into MjData.history of the h_found columns at every substep, flat
    box_xy_path: np.ndarray  # (substeps, 2) view of MjData.history: the held box's position
    top_xy_path: np.ndarray  # (substeps, 2) view: the top box's horizontal position
    top_up_z_path: np.ndarray  # (substeps,) view: the z component of the top box's up axis

    @classmethod
    def build(cls, model: mujoco.MjModel, index: SceneIndex, binding, data: mujoco.MjData,
              object_size: bool = False) -> "StateGather":
        n = len(index.object_bodies)
        blocks = _Blocks()
        ee_pos, ee_vel, box_vel, top_vel, obj_vel = (blocks.take(3), blocks.take(3), blocks.take(3), blocks.take(3),
                                                     blocks.take(3 * n))
        bottom_pos, top_pos, obj_pos = blocks.take(3), blocks.take(3), blocks.take(3 * n)
        onehot, radius = blocks.take(3 * n), blocks.take(n if object_size else 0)
        robot = np.r_[ee_pos, ee_vel, bottom_pos, box_vel, top_pos, top_vel].astype(np.intp)
        slots = np.array([np.r_[obj_pos.start + 3 * i:obj_pos.start + 3 * i + 3,
                                obj_vel.start + 3 * i:obj_vel.start + 3 * i + 3,
                                onehot.start + 3 * i:onehot.start + 3 * i + 3,
                                radius.start + i:radius.start + i + (1 if object_size else 0)]
                          for i in range(n)], dtype=np.intp).reshape(n, slot_dim(object_size))
        manipulated = [int(g) for g in index.manipulated_geoms]
        columns: list[np.ndarray] = []  # per column, its (substeps,) indices into MjData.history

        def history_layout(sensor_name: str) -> tuple[int, int, int]:
            """(address of the first sample, samples, dim): per sensor, MjData.history holds 2 header values, the
            sample times, then the samples (dim values each)."""
            sensor = model.sensor(sensor_name)
            samples, dim = int(model.sensor_history[sensor.id, 0]), int(sensor.dim[0])
            return int(model.sensor_historyadr[sensor.id]) + 2 + samples, samples, dim

        def history_columns(sensor_name: str) -> list[int]:
            values, samples, dim = history_layout(sensor_name)
            first = len(columns)
            for c in range(dim):
                columns.append(values + c + dim * np.arange(samples))
            return list(range(first, first + dim))

        def history_samples(sensor_name: str) -> np.ndarray:
            """(samples, dim) read-only view of a sensor's samples in MjData.history (its buffer never moves)."""
            values, samples, dim = history_layout(sensor_name)
            view = data.history[values:values + samples * dim].reshape(samples, dim)
            view.flags.writeable = False
            return view

        found, dist, object_vel = [], [], []
        for i in range(n):
            (f_robot, d_robot), (f_box, d_box) = (history_columns(f"judge_contact{i}"),
                                                  history_columns(f"judge_box_contact{i}"))
            found.append((f_robot, f_box))
            dist.append((d_robot, d_box))
            object_vel.append(history_columns(f"judge_vel{i}"))
        h_box_vel = history_columns("judge_box_vel")
        box_xy = history_columns("judge_box_pos")[:2]
        top_xy = history_columns("judge_top_pos")[:2]
        top_up_z = history_columns("judge_top_up")[2]
        history_index = np.stack(columns, axis=1).astype(np.intp)
        h_found = np.array(found, dtype=np.intp).reshape(n, 2)

        distance_geoms = np.r_[manipulated, [int(g) for geoms in index.object_geoms for g in geoms]].astype(np.intp)
        row = {int(g): r for r, g in enumerate(distance_geoms)}  # an object geom is listed once, after the manipulated
        radius = model.geom_rbound

        def sensor_values(name: str) -> slice:
            adr = int(model.sensor_adr[model.sensor(name).id])
            return slice(adr, adr + 3)

        return cls(
            xpos=data.xpos, geom_xpos=data.geom_xpos, qvel=data.qvel, site_xpos=data.site_xpos,
            xmat=data.xmat.reshape(-1), sensordata=data.sensordata, history=data.history,
            sensor_index=sensor_values("ee_vel"),
            ee_site=int(binding.ee_site), top_up_z=9 * int(index.top_box_body) + 8,
            body_rows=np.r_[index.bottom_box_body, index.top_box_body, index.object_bodies].astype(np.intp),
            # the boxes' and objects' free joints: linear velocities after the last substep (a sensor's value is
            # computed before that substep's integration, 2 ms old; the held box's at-rest test must not be)
            qvel_index=np.r_[np.arange(index.bottom_box_qvel, index.bottom_box_qvel + 3),
                             np.arange(index.top_box_qvel, index.top_box_qvel + 3),
                             index.object_qvel_flat].astype(np.intp),
            ee_pos=ee_pos, ee_vel=ee_vel, box_vel=box_vel, top_vel=top_vel, obj_vel=obj_vel,
            bottom_pos=bottom_pos, top_pos=top_pos, obj_pos=obj_pos,
            reach=[float(r) + MANIPULATED_REACH for r in index.object_reach], distance_geoms=distance_geoms,
            geom_pairs=[[(g1, int(g2), row[g1], row[int(g2)], float(radius[g1] + radius[g2])) for g1 in manipulated
                         for g2 in geoms] for geoms in index.object_geoms],
            index_order=np.arange(n), robot_sources=robot, slot_sources=slots,
            index_sources=np.concatenate((robot, slots.ravel())),
            history_index=history_index,
            h_found=h_found, h_dist=np.array(dist, dtype=np.intp).reshape(n, 2),
            h_obj_vel=np.array(object_vel, dtype=np.intp).reshape(n, 3), h_box_vel=np.array(h_box_vel, dtype=np.intp),
            h_box_xy=np.array(box_xy, dtype=np.intp), h_top_pos=np.array(top_xy, dtype=np.intp), h_top_up_z=top_up_z,
            found_index=history_index[:, h_found].ravel(), box_xy_path=history_samples("judge_box_pos")[:, :2],
            top_xy_path=history_samples("judge_top_pos")[:, :2], top_up_z_path=history_samples("judge_top_up")[:, 2])

    def observation_sources(self, ids: np.ndarray) -> np.ndarray:
        if ids is self.index_order:
            return self.index_sources
        return np.concatenate((self.robot_sources, self.slot_sources[ids].ravel()))
