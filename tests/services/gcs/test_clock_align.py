"""services.gcs.clock_align: each UAV's sim clock recovered from its states and put on one clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.gcs.clock_align import estimate_epoch, sim_time_shifts

SPEED = 4.0


def states(epoch: float, n: int = 200, start: float = 1000.0, rate: float = 20.0):
    """States published at ``rate`` Hz from wall time ``start`` by a clock whose epoch is ``epoch``."""
    stamp = start + np.arange(n) / rate
    return list((stamp - epoch) * SPEED), list(stamp)


def test_epoch_is_recovered_from_the_states():
    t, s = states(epoch=995.3)
    assert estimate_epoch(t, s, SPEED) == pytest.approx(995.3, abs=1e-9)


def test_a_stray_state_and_clamped_states_do_not_move_the_estimate():
    t, s = states(epoch=995.3)
    t[10] += 50.0                      # one state from elsewhere
    t[:5] = [0.0] * 5                   # published before the epoch: the driver clamps t to 0
    s[20] = float("nan")
    assert estimate_epoch(t, s, SPEED) == pytest.approx(995.3, abs=1e-9)


def test_no_usable_state_gives_none_and_bad_input_a_clear_error():
    assert estimate_epoch([0.0, 0.0], [1000.0, 1000.1], SPEED) is None
    assert estimate_epoch([], [], SPEED) is None
    with pytest.raises(ValueError, match="speed"):
        estimate_epoch([1.0], [1000.0], 0.0)
    with pytest.raises(ValueError, match="speed"):
        estimate_epoch([1.0], [1000.0], math.inf)
    with pytest.raises(ValueError, match="same length"):
        estimate_epoch([1.0, 2.0], [1000.0], SPEED)


def test_shifts_put_every_uav_on_the_lowest_ids_clock():
    # UAV 2 started 0.31 s of wall time after UAV 1 (compose), UAV 3 0.62 s; UAV 4 sent nothing usable
    tracks = {2: states(995.31), 1: states(995.0), 3: states(995.62), 4: ([0.0], [1000.0])}
    shift = sim_time_shifts(tracks, SPEED)
    assert shift[1] == 0.0 and shift[4] == 0.0
    assert shift[2] == pytest.approx(0.31 * SPEED, abs=1e-9)
    assert shift[3] == pytest.approx(0.62 * SPEED, abs=1e-9)
    # after the shift the same wall instant reads the same sim time on every UAV
    for u in (2, 3):
        t, s = tracks[u]
        t1 = (np.asarray(s) - 995.0) * SPEED
        assert np.allclose(np.asarray(t) + shift[u], t1)


def test_a_shared_epoch_needs_no_shift():
    assert sim_time_shifts({1: states(995.0), 2: states(995.0)}, SPEED) == {1: 0.0, 2: 0.0}
    assert sim_time_shifts({1: ([0.0], [0.0])}, SPEED) == {1: 0.0}
