"""One formation error: the mission report (services.gcs.figures), the terminal line (services.gcs.progress) and
the web page (services.web.view) give the same number for the same states (edge.geometry.formation.ShapeErrorMeter);
the page's tracking error is another figure under its own name (edge.geometry.formation.tracking_error)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.geometry.formation import DEFAULT_OFFSETS, ShapeErrorMeter, rotation_of, tracking_error
from protocol.messages import Mode, VehicleState
from protocol.scenario import load_scenario
from services.gcs.figures import shape_errors
from services.gcs.progress import HeadingHold, formation_rms
from services.web.view import FleetView

OFFSETS = {u: tuple(map(float, DEFAULT_OFFSETS[u - 1])) for u in (1, 2, 3)}


def flight(n: int = 80, dt: float = 0.05) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Three UAVs on a turning path (1.5 m/s, 0.3 rad/s), each off its slot by its own wobble; a hover at the end."""
    t = np.arange(n) * dt
    s = np.minimum(t, 3.0)  # hovers after 3 s
    yaw = 0.3 * s
    c = np.stack([1.5 * np.sin(yaw) / 0.3, 1.5 * (1 - np.cos(yaw)) / 0.3, np.full(n, 20.0)], axis=1)
    pos = {}
    for u, o in OFFSETS.items():
        slot = np.array([rotation_of(0.0, 0.0, float(y)) @ np.array(o) for y in yaw])
        wobble = 0.2 * np.stack([np.sin(t + u), np.cos(t + 2 * u), 0.5 * np.sin(t + u)], axis=1)
        pos[u] = c + slot + wobble
    return t, pos


def states_at(t: np.ndarray, pos: dict[int, np.ndarray], k: int) -> dict[int, VehicleState]:
    return {u: VehicleState(uav=u, seq=k, t=float(t[k]), stamp=1e9 + float(t[k]), pos=tuple(pos[u][k]),
                            vel=(0.0, 0.0, 0.0), att=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), mode=Mode.MISSION,
                            wp_index=0, ref=tuple(pos[u][k] + np.array([0.0, 1.0, 0.0])), tau=float(t[k]))
            for u in OFFSETS}


def test_the_report_the_terminal_line_and_the_page_give_the_same_formation_error():
    t, pos = flight()
    report = shape_errors(t, pos, OFFSETS)
    heading = HeadingHold()
    view = FleetView(load_scenario(), fleet="f")
    terminal, page = [], []
    for k in range(t.size):
        sts = states_at(t, pos, k)
        terminal.append(formation_rms(sts, OFFSETS, heading))
        for s in sts.values():
            view.on_state(s)
        snap = view.snapshot()
        page.append(snap["formation_error_m"])
        assert snap["tracking_error_m"] == pytest.approx(1.0)  # each UAV 1 m from its own slot: another figure
    # live, the error of a time is known once half a heading window (0.5 s) of later states came
    known = [int(np.flatnonzero(t + 0.5 <= t[k])[-1]) if t[0] + 0.5 <= t[k] else None for k in range(t.size)]
    first = known.index(0)
    assert 9 <= first <= 11 and terminal[:first] == [None] * first and page[:first] == [None] * first
    for k in range(first, t.size):
        assert terminal[k] == pytest.approx(float(report[known[k]]), abs=1e-12), k
        assert page[k] == round(float(report[known[k]]), 3), k
    assert 0.1 < float(np.max(report)) < 1.0  # the wobble (0.2 m each), not the turn or the hover


def test_a_formation_lagging_its_plan_whole_has_no_formation_error_but_a_tracking_error():
    here = {u: np.array(o) for u, o in OFFSETS.items()}
    late = {u: p + np.array([0.0, -2.0, 0.0]) for u, p in here.items()}  # the whole formation 2 m behind
    assert tracking_error(late, here) == pytest.approx(2.0)
    assert ShapeErrorMeter.series([0.0, 1.0], {u: np.stack([p, p + (1.0, 0.0, 0.0)]) for u, p in late.items()},
                                  OFFSETS)[-1] == pytest.approx(0.0, abs=1e-12)
    assert tracking_error({}, here) is None
    with pytest.raises(ValueError):
        ShapeErrorMeter(OFFSETS).add(0.0, {1: (0.0, 0.0, math.nan), 2: (0.0, 0.0, 0.0)})
