"""edge/vehicle/driver.py: where a capture's shutter is, from a position report of some age."""

from __future__ import annotations

import math

import pytest

from edge.vehicle.driver import shutter_position


def test_a_report_is_carried_forward_at_its_own_velocity():
    assert shutter_position((0.0, 0.0, 10.0), (2.0, -1.0, 0.5), 0.05) == pytest.approx((0.1, -0.05, 10.025))
    assert shutter_position((1.0, 2.0, 3.0), (2.0, 0.0, 0.0), 0.0) == (1.0, 2.0, 3.0)


@pytest.mark.parametrize("age", [-0.1, math.nan, math.inf, -math.inf])
def test_a_bad_age_leaves_the_report_where_it_was(age):
    assert shutter_position((1.0, 2.0, 3.0), (5.0, 5.0, 5.0), age) == (1.0, 2.0, 3.0)
