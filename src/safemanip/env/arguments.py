"""The env's arguments checked, before anything is built or stepped: every bad one refused by name with a
ValueError that says what it must be (rather than a KeyError or TypeError from deep inside)."""

from __future__ import annotations

import math

import numpy as np

from safemanip.env import margins as M
from safemanip.env.config import CONSTRAINT_MODES
from safemanip.scene.catalog import CONSTRAINT_TYPES, load_catalog
from safemanip.util.values import brief, is_int

MAX_RENDER_SIZE = (960, 1280)
"""Largest (height, width) of a rendered frame: the offscreen buffer ``scene/builder.py`` allocates."""
RESET_OPTIONS = ("names", "constraints")


def _check_runtime_arguments(args: dict) -> None:
    """``SlideOutEnv.__init__``'s options beside its settings (those are ``EnvConfig``'s to check): how it renders,
    sleeps, checks scenes and judges. Each refused with a ValueError that names it (rather than a KeyError or
    TypeError from deep inside)."""
    def refuse(name: str, want: str):
        raise ValueError(f"SlideOutEnv: {name} must be {want}, got {brief(args[name])}")

    for name in ("sleep", "check_scenes"):
        if not isinstance(args[name], (bool, np.bool_)):
            refuse(name, "true or false")
    if args["visual"] is not None and not isinstance(args["visual"], (bool, np.bool_)):
        refuse("visual", "true, false or None")
    if args["render_mode"] not in (None, "rgb_array"):
        refuse("render_mode", "None or 'rgb_array'")
    size = args["render_size"]
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(is_int(v) for v in size)
            and 1 <= size[0] <= MAX_RENDER_SIZE[0] and 1 <= size[1] <= MAX_RENDER_SIZE[1]):
        refuse("render_size", f"(height, width) in pixels, at most {MAX_RENDER_SIZE}")
    if not isinstance(args["thresholds"], M.Thresholds):
        refuse("thresholds", "an env.margins.Thresholds")


def _check_reset_arguments(n_objects: int, seed, options) -> int | None:
    """``reset``'s seed and options: unknown option keys and values are refused, not ignored. Returns the seed as a
    Python int (Gymnasium refuses NumPy integers)."""
    if seed is not None and not (is_int(seed) and 0 <= seed < 2**63):
        raise ValueError(f"reset: seed must be None or a non-negative integer, got {brief(seed)}")
    seed = None if seed is None else int(seed)
    if options is None:
        return seed
    if not isinstance(options, dict):
        raise ValueError(f"reset: options must be a dict with keys from {RESET_OPTIONS}, got {brief(options)}")
    unknown = [k for k in options if k not in RESET_OPTIONS]
    if unknown:
        raise ValueError(f"reset: unknown option(s) {brief(unknown)}; options takes {', '.join(RESET_OPTIONS)}")
    if "names" in options:
        names = options["names"]
        catalog = load_catalog()
        if not (isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names)):
            raise ValueError(f"reset: options['names'] must be a list of {n_objects} catalog names, got {brief(names)}")
        if len(names) != n_objects or len(set(names)) != len(names) or not all(n in catalog for n in names):
            unknown_names = [n for n in names if n not in catalog]
            raise ValueError(f"reset: options['names'] must hold {n_objects} names, distinct and from the catalog "
                             f"(`safemanip catalog` lists them), got {brief(list(names))}"
                             + (f"; unknown: {brief(unknown_names)}" if unknown_names else ""))
    if "constraints" in options:
        value = options["constraints"]
        ok = (value in CONSTRAINT_MODES) if isinstance(value, str) else (
            isinstance(value, (list, tuple)) and len(value) == n_objects
            and all(isinstance(c, str) and c in CONSTRAINT_TYPES for c in value))
        if not ok:
            raise ValueError(f"reset: options['constraints'] must be one of {CONSTRAINT_MODES} or a list of "
                             f"{n_objects} of {CONSTRAINT_TYPES}, got {brief(value)}")
    return seed


_SMALL_ACTION = 1e150
"""Entries below this in magnitude are finite, and the squared norm of three of them cannot overflow."""


def _action_vector(action) -> np.ndarray:
    """``action`` as a finite float64 (3,) array: what ``_check_action`` refuses, and a NaN or infinite entry, raise a
    ValueError. A float vector of three entries well inside the float range (what every policy sends) is accepted
    without the general checks: this runs every step."""
    if type(action) is np.ndarray and action.shape == (3,) and action.dtype.kind == "f":
        request = action.astype(np.float64)
        x, y, z = request.tolist()
        if abs(x) < _SMALL_ACTION and abs(y) < _SMALL_ACTION and abs(z) < _SMALL_ACTION:
            return request
    _check_action(action)
    request = np.asarray(action, dtype=np.float64).reshape(3)
    if not all(map(math.isfinite, request.tolist())):
        raise ValueError(f"action must be finite, got {request.tolist()}: a NaN action usually means the "
                         "policy's weights or its observation hold NaN")
    return request


def _check_action(action) -> None:
    """An action ``step`` can use: three finite real numbers whose squared norm is finite too (1e200 is finite, but
    the speed it asks for is not), not complex, text, booleans or objects."""
    try:
        a = np.asarray(action)
    except Exception:
        a = None
    if a is None or a.dtype.kind not in "iuf" or a.size != 3 or a.ndim > 2:
        kind = "no array" if a is None else f"dtype {a.dtype}, shape {a.shape}"
        raise ValueError(f"step: action must be 3 real numbers (the end-effector displacement in the unit ball), got "
                         f"{brief(action)} ({kind})")
    a = a.astype(np.float64).reshape(3)
    with np.errstate(over="ignore", invalid="ignore"):
        square = float(a @ a)
    if np.isfinite(a).all() and not math.isfinite(square):
        raise ValueError(f"step: action {a.tolist()} is too large to use (its length overflows); actions lie in the "
                         "unit ball, longer ones are scaled back onto it")
