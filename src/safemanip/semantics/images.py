"""Frame annotation for the VLM: labelled bounding boxes, the past end-effector path, tiling, PNG.

The renderer (``SceneView.render``) returns ``{"image": HxWx3 uint8, "boxes": {id: (x0, y0, x1, y1)}}``
and may add ``"ee_path_px": (T, 2)`` pixel coordinates of the end-effector path; when present it is
drawn as the black arrow the prompt talks about.
"""

from __future__ import annotations

import io
from typing import Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw

_PALETTE = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
            (70, 240, 240), (240, 50, 230), (128, 128, 0), (0, 128, 128), (170, 110, 40)]


def annotate(image: np.ndarray, boxes: Mapping[int, Sequence[float]], labels: Mapping[int, str],
             ee_path_px: np.ndarray | None = None) -> np.ndarray:
    """Draw a box and label per object, and the past end-effector path as a black arrow."""
    img = Image.fromarray(np.ascontiguousarray(image[..., :3]).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    for obj_id, box in boxes.items():
        colour = _PALETTE[int(obj_id) % len(_PALETTE)]
        x0, y0, x1, y1 = (float(v) for v in box)
        draw.rectangle((x0, y0, x1, y1), outline=colour, width=2)
        text = labels.get(int(obj_id), str(obj_id))
        tx, ty = x0, max(0.0, y0 - 12)
        bbox = draw.textbbox((tx, ty), text)
        draw.rectangle(bbox, fill=(255, 255, 255))
        draw.text((tx, ty), text, fill=colour)
    if ee_path_px is not None and len(ee_path_px) >= 2:
        pts = [(float(x), float(y)) for x, y in np.asarray(ee_path_px)[:, :2]]
        draw.line(pts, fill=(0, 0, 0), width=3)
        _arrow_head(draw, pts)
    return np.asarray(img)


def _arrow_head(draw: ImageDraw.ImageDraw, pts: list[tuple[float, float]], size: float = 10.0) -> None:
    # direction from the last point that is far enough away to define one (paths often end with jitter)
    tip = np.array(pts[-1])
    for p in reversed(pts[:-1]):
        d = tip - np.array(p)
        if np.linalg.norm(d) > 1.0:
            break
    else:
        return
    d = d / np.linalg.norm(d)
    normal = np.array([-d[1], d[0]])
    base = tip - size * d
    left, right = base + 0.5 * size * normal, base - 0.5 * size * normal
    draw.polygon([tuple(tip), tuple(left), tuple(right)], fill=(0, 0, 0))


def tile(frames: Sequence[np.ndarray], gap: int = 4) -> np.ndarray:
    """Frames side by side, oldest left; heights are padded to the tallest frame."""
    if not frames:
        raise ValueError("tile() needs at least one frame")
    h = max(f.shape[0] for f in frames)
    w = sum(f.shape[1] for f in frames) + gap * (len(frames) - 1)
    out = np.full((h, w, 3), 255, dtype=np.uint8)
    x = 0
    for f in frames:
        out[: f.shape[0], x: x + f.shape[1]] = f[..., :3]
        x += f.shape[1] + gap
    return out


def to_png(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()
