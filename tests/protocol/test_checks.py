"""protocol.checks: the shared argument checks (one wording of each)."""

import argparse
import math

import numpy as np
import pytest

from protocol.checks import finite_vec3, positive, rate, rate_arg


def test_rate_takes_finite_numbers_from_zero_and_refuses_the_rest():
    assert rate("r", 0) == 0.0 and rate("r", 2.5) == 2.5 and isinstance(rate("r", 3), float)
    for bad in (-1, math.nan, math.inf, True, "2", None):
        with pytest.raises(ValueError, match="r must be a finite rate >= 0 Hz"):
            rate("r", bad)


def test_rate_arg_is_the_argparse_form():
    assert rate_arg("0") == 0.0 and rate_arg("250") == 250.0
    for bad in ("-1", "nan", "inf", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="expected a rate in Hz >= 0"):
            rate_arg(bad)


def test_positive_and_vec3():
    assert positive("p", "2") == 2.0
    with pytest.raises(ValueError):
        positive("p", 0)
    assert np.array_equal(finite_vec3("v", (1, 2, 3)), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        finite_vec3("v", (1, 2, math.nan))
