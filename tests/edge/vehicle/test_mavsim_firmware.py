"""The sim autopilot behaves as ArduCopter's own firmware where the edge and common clients depend on it.

Each test is a row of the sim-versus-firmware comparison (ArduCopter 4.8.0-dev software in the
loop, seen side by side with the same client): telemetry only when asked, HEARTBEAT flags and
system status, PARAM_ERROR for an unknown name, the start-up (BOOT, EKF origin and home, pre-arm,
"requires position"), and the MAVLink driver's readiness built from what the autopilot says.
Real pymavlink sessions on loopback UDP; waits bound a hang, they do not measure speed.
"""

from __future__ import annotations

import socket
import time

import pytest

pytest.importorskip("pymavlink", reason="the sim autopilot needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.apm.boot import EKF_HEALTHY, GPS_TEXT, ORIGIN_TEXT, BootTimeline, position_ok  # noqa: E402
from edge.vehicle.mavlink import MavlinkDriver, MavlinkParams, open_connection  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402

QUIET = {"HEARTBEAT", "STATUSTEXT"}


class Gcs:
    """A plain pymavlink ground station on a udpin link (no stream requests unless a test sends them)."""

    def __init__(self, port: int):
        self.m = open_connection(f"udpin:127.0.0.1:{port}", 255, M.MAV_COMP_ID_MISSIONPLANNER)
        self.texts: list[str] = []
        self.seen: dict[str, int] = {}

    def beat(self) -> None:
        self.m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def recv(self, timeout: float = 0.1):
        msg = self.m.recv_match(blocking=True, timeout=timeout)
        if msg is not None:
            kind = msg.get_type()
            self.seen[kind] = self.seen.get(kind, 0) + 1
            if kind == "STATUSTEXT":
                self.texts.append(msg.text)
        return msg

    def wait(self, kind: str, cond=lambda m: True, limit_s: float = 30.0):
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            msg = self.recv()
            if msg is not None and msg.get_type() == kind and cond(msg):
                return msg
        raise TimeoutError(f"no {kind} within {limit_s} s (seen: {self.seen}, texts: {self.texts[-5:]})")

    def said(self, cond, limit_s: float = 30.0) -> str:
        """A STATUSTEXT (already received or the next ones) whose text satisfies ``cond``."""
        for t in self.texts:
            if cond(t):
                return t
        return self.wait("STATUSTEXT", lambda m: cond(m.text), limit_s).text

    def drain(self, seconds: float) -> dict[str, int]:
        """Message counts by type received during ``seconds``."""
        before = dict(self.seen)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.recv()
        return {k: v - before.get(k, 0) for k, v in self.seen.items() if v > before.get(k, 0)}

    def command(self, command: int, *params: float) -> int:
        p = tuple(params) + (0.0,) * (7 - len(params))
        self.m.mav.command_long_send(1, 1, command, 0, *p)
        return self.wait("COMMAND_ACK", lambda a: a.command == command).result

    def mode(self, mode: int) -> int:
        return self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)

    def close(self) -> None:
        self.m.close()


@pytest.fixture
def session(request):
    """A sim autopilot sending to a plain ground station; ``request.param``: the vehicle's options."""
    opts = dict(getattr(request, "param", {}))
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, **{"speed": 4.0, **opts}).start()
    try:
        gcs.first_heartbeat = gcs.wait("HEARTBEAT", limit_s=10)
        gcs.beat()  # the link has carried a packet: the autopilot's STATUSTEXTs come to it
        yield gcs, veh
    finally:
        gcs.close()
        veh.close()


# ---------------------------------------------------------------------------------- telemetry on request
def test_only_heartbeat_until_a_ground_station_asks_then_each_kind_of_request_is_served(session):
    gcs, veh = session
    unasked = gcs.drain(2.5)
    assert set(unasked) <= QUIET and unasked.get("HEARTBEAT", 0) >= 1, unasked
    # SET_MESSAGE_INTERVAL: one message at the asked rate
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1e5) == \
        M.MAV_RESULT_ACCEPTED
    got = gcs.drain(1.5)
    assert got.get("GLOBAL_POSITION_INT", 0) >= 5 and "ATTITUDE" not in got, got
    # REQUEST_DATA_STREAM: ArduCopter's EXTRA1 group is ATTITUDE
    gcs.m.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_EXTRA1, 10, 1)
    gcs.wait("ATTITUDE")
    # REQUEST_MESSAGE: one SYS_STATUS, once
    assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_SYS_STATUS) == M.MAV_RESULT_ACCEPTED
    assert gcs.drain(1.5).get("SYS_STATUS", 0) <= 1
    assert "SYS_STATUS" in gcs.seen


@pytest.mark.parametrize("session", [{"stream_all": True}], indirect=True)
def test_stream_all_keeps_the_old_unasked_telemetry_as_an_option(session):
    gcs, _ = session
    got = gcs.drain(2.0)
    assert {"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "SYS_STATUS"} <= set(got), got


# ---------------------------------------------------------------------------------- HEARTBEAT
@pytest.mark.parametrize("session", [{"boot_scale": 0.5, "speed": 1.0}], indirect=True)
def test_heartbeat_status_boot_standby_active_and_base_mode_flags_follow_the_mode(session):
    gcs, veh = session
    first = gcs.first_heartbeat
    assert first.system_status == M.MAV_STATE_BOOT  # the first second of a 0.5-scaled boot
    hb = gcs.wait("HEARTBEAT", lambda h: h.system_status != M.MAV_STATE_BOOT)
    assert (hb.system_status, hb.base_mode, hb.custom_mode) == (M.MAV_STATE_STANDBY, 81, 0)  # disarmed STABILIZE
    gcs.said(lambda t: t == GPS_TEXT, limit_s=60)
    assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED
    assert gcs.wait("HEARTBEAT", lambda h: h.custom_mode == 4).base_mode == 81  # GUIDED, disarmed: no GUIDED flag
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    hb = gcs.wait("HEARTBEAT", lambda h: h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert (hb.base_mode, hb.system_status) == (209, M.MAV_STATE_STANDBY)  # armed on the ground
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5) == M.MAV_RESULT_ACCEPTED
    hb = gcs.wait("HEARTBEAT", lambda h: h.system_status == M.MAV_STATE_ACTIVE)
    assert hb.base_mode == 217  # flying in GUIDED
    assert gcs.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
    hb = gcs.wait("HEARTBEAT", lambda h: not h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, limit_s=60)
    assert (hb.base_mode, hb.system_status, hb.custom_mode) == (81, M.MAV_STATE_STANDBY, 9)


# ---------------------------------------------------------------------------------- parameters
def test_an_unknown_parameter_gets_param_error_at_once_and_a_known_one_its_value(session):
    gcs, _ = session
    gcs.m.mav.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    err = gcs.wait("PARAM_ERROR", limit_s=5)
    assert (err.param_id, err.error, err.target_system) == ("NO_SUCH_PARAM", M.MAV_PARAM_ERROR_DOES_NOT_EXIST, 255)
    gcs.m.mav.param_set_send(1, 1, b"NOPE", 1.0, M.MAV_PARAM_TYPE_REAL32)
    assert gcs.wait("PARAM_ERROR", lambda e: e.param_id == "NOPE", limit_s=5).error == \
        M.MAV_PARAM_ERROR_DOES_NOT_EXIST
    gcs.m.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
    assert gcs.wait("PARAM_VALUE", limit_s=5).param_value == 1000.0


# ---------------------------------------------------------------------------------- start-up
@pytest.mark.parametrize("session", [{"boot_scale": 0.1, "speed": 1.0}], indirect=True)
def test_boot_home_after_origin_arming_and_guided_refused_until_the_ekf_uses_gps(session):
    gcs, veh = session
    assert veh.boot.position_s * veh.boot.scale > 1.0  # the checks below run before the EKF uses GPS
    assert gcs.command(M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_FAILED  # no home yet
    assert gcs.mode(4) == M.MAV_RESULT_FAILED
    assert gcs.said(lambda t: "Mode change to GUIDED failed: requires position" in t)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_FAILED
    assert gcs.said(lambda t: t.startswith("Arm: "))
    gcs.m.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_EXTRA3, 4, 1)
    early = gcs.wait("EKF_STATUS_REPORT")
    if not early.flags & 1024:  # past BOOT: attitude only, constant-position mode
        assert not position_ok(early.flags)
    gcs.said(lambda t: t == ORIGIN_TEXT)
    assert "HOME_POSITION" not in gcs.seen
    assert gcs.command(M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
    assert "HOME_POSITION" in gcs.seen or gcs.wait("HOME_POSITION")  # sent before its COMMAND_ACK
    gcs.said(lambda t: t == GPS_TEXT)
    assert gcs.wait("EKF_STATUS_REPORT").flags == EKF_HEALTHY
    assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.texts.index(ORIGIN_TEXT) < gcs.texts.index(GPS_TEXT)


def test_boot_timeline_scales_and_orders_its_steps():
    b = BootTimeline(scale=0.5)
    assert b.booting(0.5) and not b.booting(1.0)
    assert not b.home_known(9.9) and b.home_known(10.0)
    assert b.prearm_failure(11.9) and b.prearm_failure(12.0) is None
    assert not b.position(20.9) and b.position(21.0)
    assert b.texts_between(-1, 30) == [ORIGIN_TEXT, GPS_TEXT] and b.texts_between(10, 30) == [GPS_TEXT]
    assert position_ok(b.ekf_flags(21.0)) and not position_ok(b.ekf_flags(15.0))
    assert BootTimeline(scale=0).prearm_failure(0.0) is None and not BootTimeline(scale=0).booting(0.0)
    for bad in (-1.0, float("nan"), 1e9):
        with pytest.raises(ValueError, match="boot scale"):
            BootTimeline(scale=bad)


# ---------------------------------------------------------------------------------- the driver
def test_the_driver_asks_for_its_telemetry_and_reports_readiness_with_the_autopilots_reason():
    port = free_port(socket.SOCK_DGRAM)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", params=MavlinkParams(heartbeat_timeout_s=2.0))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=1.0, boot_scale=0.15).start()
    try:
        drv.wait_heartbeat(10.0)
        early = drv.readiness()
        assert not early.ready and early.heartbeat and early.reason
        seen: list[str] = []
        end = time.monotonic() + 40
        r = early
        while time.monotonic() < end and not r.ready:
            r = drv.readiness()
            seen.append(r.reason)
            time.sleep(0.05)
        assert r.ready and r.home and r.position and r.armable and r.status == "standby", r
        assert any("waiting for home" in s for s in seen), seen[-3:]  # the autopilot's own pre-arm text
        assert veh.streams.rate["LOCAL_POSITION_NED"] > 0 and veh.streams.rate["EKF_STATUS_REPORT"] > 0
        drv.takeoff(3.0)
    finally:
        drv.close()
        veh.close()


def test_the_driver_falls_back_to_request_data_stream_when_set_message_interval_is_refused():
    """A stand-in autopilot (plain pymavlink) that answers SET_MESSAGE_INTERVAL with UNSUPPORTED."""
    port = free_port(socket.SOCK_DGRAM)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}")
    ap = open_connection(f"udpout:127.0.0.1:{port}", 1, 1)
    groups: set[int] = set()
    try:
        end = time.monotonic() + 20
        next_hb = 0.0
        while time.monotonic() < end and not {M.MAV_DATA_STREAM_POSITION, M.MAV_DATA_STREAM_EXTRA1} <= groups:
            if time.monotonic() >= next_hb:
                ap.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 81, 0, 3)
                next_hb = time.monotonic() + 0.5
            msg = ap.recv_match(blocking=True, timeout=0.1)
            if msg is None:
                continue
            if msg.get_type() == "COMMAND_LONG" and msg.command == M.MAV_CMD_SET_MESSAGE_INTERVAL:
                ap.mav.command_ack_send(msg.command, M.MAV_RESULT_UNSUPPORTED, 0, 0, 255, msg.get_srcComponent())
            elif msg.get_type() == "REQUEST_DATA_STREAM" and msg.start_stop == 1:
                groups.add(msg.req_stream_id)
        assert {M.MAV_DATA_STREAM_POSITION, M.MAV_DATA_STREAM_EXTRA1} <= groups, groups
    finally:
        drv.close()
        ap.close()


def test_no_mission_upload_while_booting():
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=1.0, boot_scale=1.0).start()
    try:
        assert gcs.wait("HEARTBEAT", limit_s=10).system_status == M.MAV_STATE_BOOT
        gcs.m.mav.mission_count_send(1, 1, 2, M.MAV_MISSION_TYPE_MISSION)
        assert gcs.wait("MISSION_ACK", limit_s=5).type == M.MAV_MISSION_NO_SPACE
    finally:
        gcs.close()
        veh.close()


def test_statustext_goes_only_to_a_link_that_carried_a_packet():
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=1.0, boot_scale=0.02).start()
    try:
        assert "STATUSTEXT" not in gcs.drain(2.5)  # a silent listener: HEARTBEATs only
        assert ORIGIN_TEXT in veh.statustexts and GPS_TEXT in veh.statustexts  # said, but to no link
        gcs.beat()
        assert gcs.mode(3) == M.MAV_RESULT_FAILED  # AUTO without a mission
        assert gcs.said(lambda t: t.startswith("Mode change to AUTO failed"), limit_s=5)
    finally:
        gcs.close()
        veh.close()
