"""Rates with 95% Wilson score intervals."""

from __future__ import annotations

import math


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95% Wilson score interval for a binomial proportion, as fractions in [0, 1]."""
    if trials == 0:
        return (0.0, 1.0)
    p = successes / trials
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def rate_line(label: str, count: int, total: int, width: int = 28) -> str:
    lo, hi = wilson_interval(count, total)
    pct = 100.0 * count / total if total else 0.0
    return f"{label:<{width}} {pct:5.1f}% [{100 * lo:5.1f}, {100 * hi:5.1f}]  ({count}/{total})"
