"""The one definition of "nearest" in the package: horizontal (x-y) distance between object centres and a
reference point, nearest first, ties broken by id (or by the order of the candidates given).

The metric selectors and the reducer pass the manipulated (bottom) box's centre as the reference; the
semantic selectors order their candidate list by distance to the end-effector.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def nearest_ids(reference: np.ndarray, positions: np.ndarray, k: int, candidates: Sequence[int] | None = None) -> list[int]:
    """Ids of the k objects whose centres are nearest (horizontal distance) to ``reference``, nearest first.

    Ties keep id order (the order of ``candidates`` when given).
    """
    ids = np.arange(len(positions)) if candidates is None else np.asarray(list(candidates), dtype=int)
    if len(ids) == 0:
        return []
    d = np.linalg.norm(positions[ids, :2] - reference[:2], axis=1)
    order = np.argsort(d, kind="stable")
    return [int(i) for i in ids[order][:k]]
