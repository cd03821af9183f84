"""The env's arguments checked, before anything is built or stepped: every bad one refused by name with a
ValueError that says what it must be (rather than a KeyError or TypeError from deep inside)."""

from __future__ import annotations

import math

import numpy as np

from safemanip.env import margins as M
from safemanip.scene.catalog import CONSTRAINT_TYPES, load_catalog
from safemanip.scene.embodiment import EMBODIMENTS
from safemanip.scene.placement import LAYOUTS

CONSTRAINT_MODES = ("ground_truth", "conservative", "random")
"""How an episode's constraint types are chosen: from the catalog, all no_contact, or drawn at random."""


MAX_RENDER_SIZE = (960, 1280)
"""Largest (height, width) of a rendered frame: the offscreen buffer ``scene/builder.py`` allocates."""
RESET_OPTIONS = ("names", "constraints")


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _check_init_arguments(args: dict) -> None:
    """``SlideOutEnv.__init__``'s arguments, each refused with a ValueError that names it (rather than a KeyError
    or TypeError from deep inside)."""
    def refuse(name: str, want: str):
        raise ValueError(f"SlideOutEnv: {name} must be {want}, got {_short(args[name])}")

    def strings(value) -> bool:
        return isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)

    if args["names"] is not None and not strings(args["names"]):
        refuse("names", "a list of catalog names (or None)")
    if args["classes"] is not None and not (isinstance(args["classes"], str) or strings(args["classes"])):
        refuse("classes", "a list of semantic classes or a description such as '2 fragile, 1 soft' (or None)")
    if not (isinstance(args["constraints"], str) or strings(args["constraints"])):
        refuse("constraints", f"one of {CONSTRAINT_MODES} or a list of {CONSTRAINT_TYPES}")
    if args["near_path_fraction"] is not None and not (_is_real(args["near_path_fraction"])
                                                       and 0 <= args["near_path_fraction"] <= 1):
        refuse("near_path_fraction", "a number in [0, 1] (or None)")
    for name in ("sleep", "clear_route", "check_scenes"):
        if not isinstance(args[name], (bool, np.bool_)):
            refuse(name, "true or false")
    if args["visual"] is not None and not isinstance(args["visual"], (bool, np.bool_)):
        refuse("visual", "true, false or None")
    if not isinstance(args["layout"], str):  # which names: the scene config says
        refuse("layout", f"one of {', '.join(map(repr, LAYOUTS))}")
    for name, allowed in (("embodiment", EMBODIMENTS), ("slot_order", ("index", "nearest"))):
        if not isinstance(args[name], str) or args[name] not in allowed:
            refuse(name, f"one of {', '.join(map(repr, allowed))}")
    if args["render_mode"] is not None and not isinstance(args["render_mode"], str):
        refuse("render_mode", "None or 'rgb_array'")
    size = args["render_size"]
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(_is_int(v) for v in size)
            and 1 <= size[0] <= MAX_RENDER_SIZE[0] and 1 <= size[1] <= MAX_RENDER_SIZE[1]):
        refuse("render_size", f"(height, width) in pixels, at most {MAX_RENDER_SIZE}")
    if not (_is_real(args["action_curve"]) and math.isfinite(args["action_curve"])):
        refuse("action_curve", "a number from 1 (linear) to 4")
    if not isinstance(args["thresholds"], M.Thresholds):
        refuse("thresholds", "an env.margins.Thresholds")


def _check_reset_arguments(n_objects: int, seed, options) -> int | None:
    """``reset``'s seed and options: unknown option keys and values are refused, not ignored. Returns the seed as a
    Python int (Gymnasium refuses NumPy integers)."""
    if seed is not None and not (_is_int(seed) and 0 <= seed < 2**63):
        raise ValueError(f"reset: seed must be None or a non-negative integer, got {_short(seed)}")
    seed = None if seed is None else int(seed)
    if options is None:
        return seed
    if not isinstance(options, dict):
        raise ValueError(f"reset: options must be a dict with keys from {RESET_OPTIONS}, got {_short(options)}")
    unknown = [k for k in options if k not in RESET_OPTIONS]
    if unknown:
        raise ValueError(f"reset: unknown option(s) {_short(unknown)}; options takes {', '.join(RESET_OPTIONS)}")
    if "names" in options:
        names = options["names"]
        catalog = load_catalog()
        if not (isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names)):
            raise ValueError(f"reset: options['names'] must be a list of {n_objects} catalog names, got {_short(names)}")
        if len(names) != n_objects or len(set(names)) != len(names) or not all(n in catalog for n in names):
            unknown_names = [n for n in names if n not in catalog]
            raise ValueError(f"reset: options['names'] must hold {n_objects} names, distinct and from the catalog "
                             f"(`safemanip catalog` lists them), got {_short(list(names))}"
                             + (f"; unknown: {_short(unknown_names)}" if unknown_names else ""))
    if "constraints" in options:
        value = options["constraints"]
        ok = (value in CONSTRAINT_MODES) if isinstance(value, str) else (
            isinstance(value, (list, tuple)) and len(value) == n_objects
            and all(isinstance(c, str) and c in CONSTRAINT_TYPES for c in value))
        if not ok:
            raise ValueError(f"reset: options['constraints'] must be one of {CONSTRAINT_MODES} or a list of "
                             f"{n_objects} of {CONSTRAINT_TYPES}, got {_short(value)}")
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
                         f"{_short(action)} ({kind})")
    a = a.astype(np.float64).reshape(3)
    with np.errstate(over="ignore", invalid="ignore"):
        square = float(a @ a)
    if np.isfinite(a).all() and not math.isfinite(square):
        raise ValueError(f"step: action {a.tolist()} is too large to use (its length overflows); actions lie in the "
                         "unit ball, longer ones are scaled back onto it")
