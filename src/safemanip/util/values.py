"""The type checks every validator shares (env settings, sweep specs, policy metadata, semantic answers), and the
short form of a bad value its message quotes."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np


def is_int(value: Any) -> bool:
    """An integer, a NumPy one included, and not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def is_real(value: Any) -> bool:
    """A real number (an integer or a float, NumPy's included), and not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def is_strings(value: Any) -> bool:
    """A list or tuple of strings."""
    return isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)


def brief(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters: a huge bad value does not flood the message that quotes it."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."
