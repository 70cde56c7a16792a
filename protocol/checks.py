"""Argument checks shared by every layer: one wording of "must be finite and positive", of rates and of 3-vectors."""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["positive", "rate", "rate_arg", "finite_array", "finite_vec3"]


def positive(name: str, value: Any) -> float:
    """``value`` as a float that is finite and > 0; ValueError naming ``name`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def rate(name: str, value: Any) -> float:
    """``value`` as a float rate in Hz, a number (not a bool or a string) finite and >= 0 (0: off);
    ValueError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite rate >= 0 Hz, got {value!r}")
    return float(value)


def rate_arg(text: str) -> float:
    """argparse type of a rate option (``--preview-hz``, ``--gcs-state-hz``, ``--state-ingress-hz``): a finite
    rate >= 0 Hz, 0 meaning off."""
    try:
        return rate("rate", float(text))
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a rate in Hz >= 0, got {text!r}") from None


def xyz(value: Any) -> tuple[float, float, float]:
    """Three numbers as a typed triple of floats (a position, an offset, a corner); ValueError when there
    are not three.

    >>> xyz([1, 2.5, 3])
    (1.0, 2.5, 3.0)
    """
    x, y, z = value
    return float(x), float(y), float(z)


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
