"""A sweep's stored cell results: ``cells/<cell id>.json`` in its output folder, each ``{"cell": the cell's record,
"summary": the evaluation's summary}``, written last (its presence means the cell is done), read back with their
structure checked (a damaged file is left out and its cell redone)."""

from __future__ import annotations

import json
import math
import sys
from dataclasses import MISSING, fields
from pathlib import Path

from safemanip.evaluation.sweep.grid import RECORD_FIELDS, Cell, PlannerCell
from safemanip.util.files import atomic_write_text, read_json_file
from safemanip.util.values import is_int

MAX_RESULT_BYTES = 10_000_000
REQUIRED_FIELDS = {f.name for f in fields(Cell) if f.default is MISSING}
"""A stored record's fields that were there from the start; the others may be missing from older results."""


def result_path(root: Path, cell: Cell | PlannerCell) -> Path:
    return Path(root) / "cells" / f"{cell.id}.json"


def write_result(root: Path, cell: Cell | PlannerCell, summary: dict) -> None:
    atomic_write_text(result_path(root, cell), json.dumps({"cell": cell.record(), "summary": summary}, indent=1))


def is_done(path: Path, cell: Cell | PlannerCell) -> bool:
    """Whether ``path`` holds this very cell's result (a damaged file, or one of other settings, is redone)."""
    if not path.exists():
        return False
    stored = _read_result(path)
    return stored is not None and _with_defaults(stored["cell"]) == cell.record()


def load_results(root: Path) -> list[dict]:
    """The stored cell results; a file that is not one (unreadable, too large or deep, wrong structure) is left out
    with a warning, and its cell is redone by the next run."""
    out = []
    for path in sorted((Path(root) / "cells").glob("*.json")):
        result = _read_result(path)
        if result is None:
            print(f"warning: ignoring unreadable result {path} (its cell is redone by the next run)", file=sys.stderr)
            continue
        out.append({**result, "cell": _with_defaults(result["cell"])})
    return out


def _with_defaults(cell: dict) -> dict:
    """A stored cell's fields, with the defaults of fields added since it was stored ('vlm', 'shield')."""
    return {"vlm": None, "shield": None, **cell}


def _read_result(path: Path) -> dict | None:
    """A stored cell result read with the bounded reader and its structure checked (the fields rendering reads are
    there, of their types); None if it cannot be used."""
    try:
        result = read_json_file(path, max_bytes=MAX_RESULT_BYTES)
    except (OSError, ValueError):
        return None
    return result if _result_ok(result) else None


def _rate_ok(entry) -> bool:
    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    return (isinstance(entry, dict) and num(entry.get("rate")) and isinstance(entry.get("ci95"), list)
            and len(entry["ci95"]) == 2 and all(num(v) for v in entry["ci95"]))


def _result_ok(result) -> bool:
    from safemanip.evaluation.episode import CATEGORIES

    if not isinstance(result, dict) or not isinstance(result.get("cell"), dict) or not isinstance(result.get("summary"), dict):
        return False
    cell, summary = result["cell"], result["summary"]
    if not REQUIRED_FIELDS <= set(cell) <= set(RECORD_FIELDS):
        return False
    types_ok = (all(isinstance(cell[k], str) for k in ("policy", "algorithm", "policy_constraints", "selector",
                                                         "constraints", "judge"))
                and all(is_int(cell[k]) for k in ("k", "n_objects", "episodes", "seed"))
                and (cell["semantics"] is None or isinstance(cell["semantics"], str))
                and (cell.get("vlm") is None or isinstance(cell["vlm"], str)))
    categories = summary.get("categories")
    return bool(types_ok and _rate_ok(summary.get("success")) and _rate_ok(summary.get("safety_violation"))
                and isinstance(categories, dict) and all(_rate_ok(categories.get(c)) for c in CATEGORIES)
                and is_int(summary.get("episodes")) and isinstance(summary.get("mean_length"), (int, float)))
