"""Every fuzz target of bench/fuzz.py under hypothesis: any bytes give a result or a typed error.

Fast and bounded (a few hundred examples per target, mutations of the same valid seeds as the script
plus hypothesis's own bytes); the script runs >= 100,000 inputs per target."""

from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

_spec = importlib.util.spec_from_file_location("bench_fuzz", Path(__file__).resolve().parents[2] / "bench" / "fuzz.py")
fuzz = importlib.util.module_from_spec(_spec)
sys.modules["bench_fuzz"] = fuzz  # dataclasses look their module up
_spec.loader.exec_module(fuzz)
TARGETS = {t.name: t for t in fuzz.targets()}


@pytest.mark.parametrize("name", sorted(TARGETS))
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.one_of(st.binary(max_size=512), st.integers(0, 2**32)))
def test_only_typed_errors(name, data):
    t = TARGETS[name]
    if isinstance(data, int):  # a havoc mutation of a valid seed, drawn by hypothesis
        data = fuzz.mutate(random.Random(data), t.seeds)
    try:
        t.run(data)
    except t.allowed:
        pass


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_the_valid_seeds_are_accepted(name):
    """The seeds are valid inputs (else the mutations would explore only the error paths)."""
    t = TARGETS[name]
    for s in t.seeds[:3]:
        t.run(s)


def test_the_script_finds_no_crash_in_a_short_run(tmp_path):
    assert fuzz.main(["--n", "300", "--out", str(tmp_path / "f.json")]) == 0
    assert (tmp_path / "f.json").stat().st_size > 0
