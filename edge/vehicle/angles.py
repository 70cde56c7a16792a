"""Angles: the one wrap to (−π, π] that the controllers, the MAVLink conversions and the sim share."""

from __future__ import annotations

import math

__all__ = ["wrap_angle"]


def wrap_angle(a: float) -> float:
    """``a`` wrapped to (−π, π] (IEEE remainder by 2π, with −π sent to π).

    >>> wrap_angle(3 * math.pi / 2), wrap_angle(-math.pi)
    (-1.5707963267948966, 3.141592653589793)
    """
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w
