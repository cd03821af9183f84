"""Frame annotation for the VLM: labelled bounding boxes, the past end-effector path, tiling, PNG.

The renderer (``SceneView.render``) returns ``{"image": HxWx3 uint8, "boxes": {id: (x0, y0, x1, y1)}}``
and may add ``"ee_path_px": (T, 2)`` pixel coordinates of the end-effector path; when present it is
drawn as the black arrow the prompt talks about.
"""

from __future__ import annotations

import io
from typing import Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

_PALETTE = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
            (70, 240, 240), (240, 50, 230), (128, 128, 0), (0, 128, 128), (170, 110, 40)]


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)  # FreeType build of the bundled font (Pillow >= 10.1)
    except (TypeError, ValueError, OSError):  # pragma: no cover - Pillow without FreeType
        return ImageFont.load_default()


def _rect_gap(a: Sequence[float], b: Sequence[float]) -> float:
    """Distance between two axis-aligned rectangles (0 when they touch or overlap)."""
    dx = max(0.0, b[0] - a[2], a[0] - b[2])
    dy = max(0.0, b[1] - a[3], a[1] - b[3])
    return float(np.hypot(dx, dy))


def _overlap_area(a: Sequence[float], b: Sequence[float]) -> float:
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def _place_label(box: Sequence[float], tw: float, th: float, w: int, h: int,
                 placed: list[tuple[float, float, float, float]], others: list[Sequence[float]]
                 ) -> tuple[float, float, float, float]:
    """A label rectangle near ``box``: never over an already placed label if any spot allows it, preferably
    not over other objects' boxes, and as close to its own box as possible (just above it when free)."""
    x0, y0, x1, y1 = box
    xs = [x0, (x0 + x1 - tw) / 2, x1 - tw, x1 + 2, x0 - tw - 2]
    ys = [y0 - th - 1 - j * (th + 1) for j in range(6)] + [y1 + 1 + j * (th + 1) for j in range(6)] + [y0, y1 - th]
    best, best_cost = None, float("inf")
    for ty in ys:
        for tx in xs:
            cx, cy = min(max(0.0, tx), max(0.0, w - tw)), min(max(0.0, ty), max(0.0, h - th))
            rect = (cx, cy, cx + tw, cy + th)
            clash = sum(_overlap_area(rect, r) for r in placed)
            covers = sum(_overlap_area(rect, o) for o in others)
            cost = 1e6 * clash + 2.0 * covers + 40.0 * _rect_gap(rect, box) + 0.5 * abs(cy - (y0 - th - 1))
            if cost < best_cost:
                best, best_cost = rect, cost
    return best


def annotate(image: np.ndarray, boxes: Mapping[int, Sequence[float]], labels: Mapping[int, str],
             ee_path_px: np.ndarray | None = None, font_px: int | None = None) -> np.ndarray:
    """Draw a box and label per object, and the past end-effector path as a black arrow.

    Text and line sizes scale with the image (``font_px`` defaults to ~1/32 of its height, at least 11).
    Each label goes just above its box when that spot is free; otherwise to the nearest spot around the
    box that does not cover another label (and preferably no other object), with a thin leader line
    back to its box when it had to move away, so crowded scenes keep readable labels.
    """
    img = Image.fromarray(np.ascontiguousarray(image[..., :3]).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    w, h = img.size
    font_px = int(font_px or max(11, round(h / 32)))
    font = _font(font_px)
    line = max(2, round(h / 240))
    placed: list[tuple[float, float, float, float]] = []
    pending = []
    for obj_id, box in boxes.items():
        colour = _PALETTE[int(obj_id) % len(_PALETTE)]
        x0, y0, x1, y1 = (float(v) for v in box)
        draw.rectangle((x0, y0, x1, y1), outline=colour, width=line)
        pending.append((obj_id, colour, (x0, y0, x1, y1)))
    # labels after all boxes, so a later box's outline never cuts through an earlier label
    obstacles = [b for _, _, b in pending]
    for obj_id, colour, box in pending:
        text = labels.get(int(obj_id), str(obj_id))
        tb = draw.textbbox((0, 0), text, font=font)
        tw, th = tb[2] - tb[0] + 4, tb[3] - tb[1] + 4
        rect = _place_label(box, tw, th, w, h, placed, [b for b in obstacles if b is not box])
        placed.append(rect)
        gap = _rect_gap(rect, box)
        if gap > 3:  # a leader line when the label had to move away from its box
            lx = min(max((box[0] + box[2]) / 2, rect[0]), rect[2])
            ly = rect[3] if rect[3] <= box[1] else rect[1] if rect[1] >= box[3] else (rect[1] + rect[3]) / 2
            bx = min(max(lx, box[0]), box[2])
            by = min(max(ly, box[1]), box[3])
            draw.line((lx, ly, bx, by), fill=colour, width=1)
        # text on a patch of the box's colour, black or white by luminance, so pale colours stay legible
        ink = (0, 0, 0) if 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2] > 140 else (255, 255, 255)
        draw.rectangle(rect, fill=colour)
        draw.text((rect[0] + 2 - tb[0], rect[1] + 2 - tb[1]), text, fill=ink, font=font)
    if ee_path_px is not None and len(ee_path_px) >= 2:
        pts = [(float(x), float(y)) for x, y in np.asarray(ee_path_px)[:, :2]]
        draw.line(pts, fill=(0, 0, 0), width=line + 1, joint="curve")
        _arrow_head(draw, pts, size=max(10.0, h / 30))
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
