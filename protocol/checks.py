"""Argument checks shared by every layer: one wording of "must be finite and positive" and of 3-vectors."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["positive", "finite_array", "finite_vec3"]


def positive(name: str, value: Any) -> float:
    """``value`` as a float that is finite and > 0; ValueError naming ``name`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def finite_array(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """``value`` as a float array with no NaN or inf; ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, got {value!r}"[:300]) from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (got NaN or inf)")
    return a


def finite_vec3(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """``value`` as a finite float array of shape (3,); ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return a
