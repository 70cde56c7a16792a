"""Hostile input on the autopilot link's mission-progress and mode paths: MISSION_CURRENT / MISSION_ITEM_REACHED
out of range, total 0, going backwards, jumping ahead, in a flood, NaN positions, HEARTBEAT custom modes that map to
nothing, and a hostile mode name. Real pymavlink messages, encoded and decoded; the driver on a real UDP socket."""

from __future__ import annotations

import math
import random
import time

import pytest

pytest.importorskip("pymavlink", reason="the MAVLink driver needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.mavlink import MavlinkDriver, open_connection  # noqa: E402
from edge.vehicle.mavlink.dialect import PX4, Px4  # noqa: E402
from edge.vehicle.mavlink.driver import safe_mode_name  # noqa: E402
from edge.vehicle.mavlink.handlers import Telemetry, dispatch  # noqa: E402
from edge.vehicle.px4 import modes as PX  # noqa: E402
from protocol.messages import AutopilotReadiness, Mode  # noqa: E402
from tests.edge.vehicle.mavlink.test_seams import wire  # noqa: E402
from tests.edge.vehicle.test_mavlink import free_udp_port  # noqa: E402

HOME = (0.0, 0.0, 0.0)


def px4_heartbeat(mode: int, armed: bool = True):
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return wire(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, mode & 0xFFFFFFFF,
                                            M.MAV_STATE_ACTIVE, 3))


def current(seq: int, total: int = 10):
    return wire(M.MAVLink_mission_current_message(seq, total, 0, 0))


def reached(seq: int):
    return wire(M.MAVLink_mission_item_reached_message(seq))


@pytest.fixture
def tel() -> Telemetry:
    t = Telemetry(1, HOME, our_system=255)
    dispatch(t, px4_heartbeat(PX.MISSION), 0.0)
    t.mission_count = 10  # the driver uploaded 10 items
    return t


def test_progress_outside_the_mission_backwards_or_ahead_is_counted_and_ignored(tel):
    t = tel
    dispatch(t, current(3), 1.0)
    assert t.current_seq == 3 and t.mission_total == 10
    for bad in (10, 50, 65535):  # out of range
        dispatch(t, current(bad), 1.0)
        dispatch(t, reached(bad), 1.0)
    assert (t.current_seq, t.reached_seq, t.progress_rejected) == (3, -1, 6)
    dispatch(t, reached(9), 1.0)  # the last item "reached" while flying to item 3: a jump, refused
    assert t.reached_seq == -1 and t.progress_rejected == 7
    dispatch(t, reached(3), 1.0)
    dispatch(t, reached(4), 1.0)  # the item after the current one: accepted (MISSION_CURRENT may come later)
    assert (t.current_seq, t.reached_seq) == (4, 4)
    dispatch(t, reached(2), 1.0)  # an older item, or PX4's ~1 Hz repeat: nothing changes, nothing counted
    dispatch(t, reached(4), 1.0)
    assert (t.reached_seq, t.progress_rejected) == (4, 7)
    dispatch(t, current(1), 1.0)  # back before an item already reached: refused
    assert t.current_seq == 4 and t.progress_rejected == 8
    dispatch(t, current(5, total=0), 1.0)  # total 0 ("not supported"): the item still counts, the total is kept
    assert t.current_seq == 5 and t.mission_total == 0


def test_a_flood_of_forged_progress_never_leaves_the_mission_nor_goes_back(tel):
    t, rng = tel, random.Random(7)
    last = (-1, -1)
    for _ in range(20_000):
        seq = rng.choice([rng.randrange(0, 12), rng.randrange(0, 65536)])
        dispatch(t, current(seq) if rng.random() < 0.5 else reached(seq), 1.0)
        assert -1 <= t.reached_seq <= t.current_seq < 10  # within the uploaded mission
        assert t.reached_seq >= last[1]  # never backwards
        if t.reached_seq > last[1]:
            assert t.reached_seq <= max(last[0], last[1]) + 1  # one item at a time: never a jump
        last = (t.current_seq, t.reached_seq)
    assert t.progress_rejected > 5_000


def test_nan_positions_are_counted_not_taken(tel):
    t = tel
    dispatch(t, wire(M.MAVLink_local_position_ned_message(0, 1.0, 2.0, -3.0, 0, 0, 0)), 1.0)
    assert t.pos == pytest.approx((2.0, 1.0, 3.0))
    errors = t.errors
    for v in (math.nan, math.inf):
        dispatch(t, wire(M.MAVLink_local_position_ned_message(0, v, 2.0, -3.0, 0, 0, 0)), 1.0)
        dispatch(t, wire(M.MAVLink_attitude_message(0, v, 0, 0, 0, 0, 0)), 1.0)
    assert t.errors == errors + 4 and t.pos == pytest.approx((2.0, 1.0, 3.0))


def test_a_rejected_position_does_not_make_the_last_one_look_fresh(tel):
    # the capture's pose carries the last position forward over its age: a report that was not taken must not
    # reset that age (edge.vehicle.mavlink.driver: the shutter)
    t = tel
    dispatch(t, wire(M.MAVLink_local_position_ned_message(0, 1.0, 2.0, -3.0, 0.5, 0, 0)), 100.0)
    assert t.pos_mono == 100.0
    dispatch(t, wire(M.MAVLink_local_position_ned_message(0, math.nan, 2.0, -3.0, 0.5, 0, 0)), 200.0)
    assert t.pos_mono == 100.0


def test_a_position_or_velocity_beyond_any_flight_is_counted_not_taken(tel):
    # finite but absurd (float32's range): taken, it would carry a capture's pose kilometres ahead and make every
    # state the board publishes invalid on the wire (its speeds and coordinates are bounded)
    t = tel
    dispatch(t, wire(M.MAVLink_local_position_ned_message(0, 1.0, 2.0, -3.0, 0.5, 0, 0)), 100.0)
    errors = t.errors
    for x, vx in ((1.0, 3e38), (1.0, 150.0), (1e9, 0.5), (-3e38, 0.5)):
        dispatch(t, wire(M.MAVLink_local_position_ned_message(0, x, 2.0, -3.0, vx, 0, 0)), 200.0)
    assert t.errors == errors + 4 and t.pos_mono == 100.0
    assert t.pos == pytest.approx((2.0, 1.0, 3.0)) and t.vel == pytest.approx((0.0, 0.5, 0.0))


@pytest.fixture
def heartbeats():
    """A driver listening on loopback and a raw pymavlink "autopilot" (system 1) that sends what the test says."""
    made = []

    def make(**kw):
        port = free_udp_port()
        drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", **kw)
        ap = open_connection(f"udpout:127.0.0.1:{port}", 1, 1)
        made.append((drv, ap))
        return drv, ap

    yield make
    for drv, ap in made:
        drv.close()
        ap.close()


def beat_until(drv, ap, mode: int, armed: bool = True, timeout_s: float = 5.0) -> None:
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        ap.mav.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, mode, 3, 3))
        hb = drv.tel.hb
        if hb is not None and hb.custom_mode == mode:
            return
        time.sleep(0.05)
    raise AssertionError("the driver did not hear the heartbeat")


def test_custom_modes_that_map_to_nothing_read_as_the_pilots_with_a_bounded_name(heartbeats):
    drv, ap = heartbeats()
    for odd in (0x12345678, PX.custom_mode(4, 200), PX.custom_mode(250), 0xFFFFFFFF):
        beat_until(drv, ap, odd)
        assert drv.dialect is PX4
        st, ready = drv.state(), drv.readiness()
        assert st.mode == Mode.PILOT  # armed in a mode the edge did not command: the pilot's, never "hold"
        assert ready.mode == f"MODE_0x{odd:08X}" and ready.external
        AutopilotReadiness.model_validate(ready.model_dump())  # publishable as is


def test_a_hostile_mode_name_is_sanitised_and_bounded(heartbeats):
    hostile = "\x1b[2J<script>alert('x')</script>\n\u202eLOITER\x00" * 20

    class Hostile(Px4):
        mode_name = staticmethod(lambda custom: hostile)

    drv, ap = heartbeats(dialect=Hostile())
    beat_until(drv, ap, PX.LOITER)
    name = drv.readiness().mode
    assert name == "??2J?script?alert??x????script??"  # control characters, markup, bidi marks: '?'
    assert all(c.isascii() and (c.isalnum() or c in "_.-?") for c in name)
    assert safe_mode_name("AUTO.MISSION") == "AUTO.MISSION" and safe_mode_name(None) == "None"
    assert safe_mode_name("x" * 10_000) == "x" * 32


def test_a_px4_parameter_value_that_cannot_be_one_is_counted_not_stored(tel):
    """PX4 sends an integer parameter's bytes in PARAM_VALUE's float field (decoded by its type); a REAL32 that is
    NaN or infinite is an error counted, never a stored value."""
    t = tel
    ok = M.MAVLink_param_value_message(b"NAV_DLL_ACT", 2.8e-45, M.MAV_PARAM_TYPE_INT32, 20, 1)  # the bytes of 2
    dispatch(t, wire(ok), 1.0)
    assert t.param_rx["NAV_DLL_ACT"][0] == 2.0
    errors = t.errors
    for value, kind in ((math.nan, M.MAV_PARAM_TYPE_REAL32), (math.inf, M.MAV_PARAM_TYPE_REAL32),
                        (-math.inf, M.MAV_PARAM_TYPE_REAL32)):
        dispatch(t, wire(M.MAVLink_param_value_message(b"MPC_XY_CRUISE", value, kind, 20, 2)), 1.0)
    assert "MPC_XY_CRUISE" not in t.param_rx and t.errors == errors + 3
