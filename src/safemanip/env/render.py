"""Offscreen rendering helpers: a renderer with fast settings and 3D-box-to-image projection."""

from __future__ import annotations

import os

import mujoco
import numpy as np


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # no usable OpenGL: say how to get one
        raise RuntimeError(
            f"cannot create an offscreen renderer with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} ({err}). "
            "On a headless machine install Mesa's EGL (apt-get install libegl1 libgl1-mesa-dri) and set "
            "MUJOCO_GL=egl before Python starts, or use MUJOCO_GL=osmesa with libosmesa6; or pass --no-video.") from err


def _camera_projection(model, data, camera: str, height: int, width: int):
    cam = model.camera(camera).id
    pos = data.cam_xpos[cam]
    rot = data.cam_xmat[cam].reshape(3, 3)  # columns: camera x (right), y (up), z (backwards)
    focal = 0.5 * height / np.tan(np.deg2rad(model.cam_fovy[cam]) / 2)
    return pos, rot, focal


def project_points(model, data, camera: str, points: np.ndarray, height: int, width: int) -> np.ndarray:
    """Pixel coordinates (u right, v down) of world points as seen by ``camera``."""
    pos, rot, focal = _camera_projection(model, data, camera, height, width)
    local = (np.asarray(points) - pos) @ rot
    depth = np.maximum(-local[:, 2], 1e-6)
    u = width / 2 + focal * local[:, 0] / depth
    v = height / 2 - focal * local[:, 1] / depth
    return np.stack([u, v], axis=1)


def body_box_corners(model, data, body: int) -> np.ndarray:
    """World-space corners of the oriented bounding boxes of a body's geoms, (8 * n_geoms, 3)."""
    corners = []
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    for g in np.flatnonzero(model.geom_bodyid == body):
        center, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = center + signs * half
        corners.append(data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T)
    return np.concatenate(corners)


def project_body_boxes(model, data, camera: str, bodies: dict, height: int, width: int) -> dict:
    """{key: (x0, y0, x1, y1)} pixel boxes, clipped to the image, for each body id in ``bodies``."""
    out = {}
    for key, body in bodies.items():
        uv = project_points(model, data, camera, body_box_corners(model, data, body), height, width)
        x0, y0 = np.clip(uv.min(axis=0), 0, [width - 1, height - 1])
        x1, y1 = np.clip(uv.max(axis=0), 0, [width - 1, height - 1])
        out[key] = (float(x0), float(y0), float(x1), float(y1))
    return out
