"""The sim autopilot (edge.vehicle.mavsim) against ground-station software nobody here wrote.

- MAVSDK (the ``mavsdk`` wheel: the C++ library itself, through ctypes; no mavsdk_server and
  nothing downloaded at run time): discovery, health, every telemetry kind, parameters, mission,
  fence and rally upload/download round trips, an AUTO mission flown to completion, takeoff,
  DO_REPOSITION (goto_location), RTL, land, disarm.
- A MAVProxy-style pymavlink session (mavutil's own helpers, as MAVProxy's modules use them): mode
  changes by name, ``wp load`` of a QGC WPL 110 file through mavwp, ``param set``, legacy
  REQUEST_DATA_STREAM.
- Failsafes: FS_GCS and the fence; MAVLink 2 signing (a forged future-timestamp packet does not
  lock the real stream out).

Everything runs on loopback UDP; the vehicle flies at an accelerated speed factor. Waits have
generous limits (they bound a hang, they do not measure speed).
"""

from __future__ import annotations

import asyncio
import math
import socket
import time

import pymap3d
import pytest

pytest.importorskip("pymavlink", reason="the sim autopilot needs the 'mavlink' extra")

from edge.geometry import ardupilot_items as I  # noqa: E402
from edge.vehicle.apm.modes import CopterMode  # noqa: E402
from edge.vehicle.mavsim import DEFAULT_ORIGIN, MavlinkSimVehicle  # noqa: E402
from protocol.messages import Mode  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402

O = DEFAULT_ORIGIN


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def latlon(e: float, n: float) -> tuple[int, int]:
    lat, lon, _ = pymap3d.enu2geodetic(e, n, 0.0, *O)
    return round(lat * 1e7), round(lon * 1e7)


# ---------------------------------------------------------------------------------- MAVSDK
mavsdk = pytest.importorskip("mavsdk", reason="the MAVSDK tests need the 'mavsdk' wheel (test extra)")
from mavsdk import ComponentType  # noqa: E402
from mavsdk.asyncio import Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync  # noqa: E402
from mavsdk.asyncio.plugins.param import ParamAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync  # noqa: E402


async def first(gen, pred=lambda x: True, limit_s: float = 60.0):
    """The first item of an async generator that satisfies ``pred`` (TimeoutError past ``limit_s``)."""
    async def go():
        async for x in gen:
            if pred(x):
                return x
    return await asyncio.wait_for(go(), limit_s)


def run(coro, limit_s: float = 240.0):
    return asyncio.run(asyncio.wait_for(coro, limit_s))


RATES = ("position", "home", "gps_info", "raw_gps", "in_air", "landed_state", "battery", "attitude_euler",
         "velocity_ned", "position_velocity_ned", "health")


class Session:
    """One sim autopilot and a MAVSDK ground station listening for it.

    As against ArduCopter's firmware, which sends only HEARTBEAT until asked, the session asks for its
    telemetry with MAVSDK's ``set_rate_*`` (SET_MESSAGE_INTERVAL) unless ``ask_rates`` is False.
    """

    def __init__(self, speed: float = 4.0, ask_rates: bool = True, **opts):
        self.ask_rates = ask_rates
        self.port = free_udp_port()
        self.veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{self.port}", 1, speed=speed, **opts).start()
        self.sdk: Mavsdk | None = None

    async def __aenter__(self):
        self.sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        await self.sdk.add_any_connection(f"udpin://127.0.0.1:{self.port}")
        system = await self.sdk.first_autopilot(10.0)
        assert system is not None, "MAVSDK discovered no autopilot"
        self.system = system
        self.tel, self.act = TelemetryAsync(system), ActionAsync(system)
        self.mis, self.par = MissionRawAsync(system), ParamAsync(system)
        if self.ask_rates:
            for name in RATES:
                await getattr(self.tel, f"set_rate_{name}")(10.0)
        return self

    async def __aexit__(self, *exc):
        self.sdk.destroy()
        self.veh.close()


def test_discovery_health_and_every_telemetry_kind():
    async def go():
        async with Session() as s:
            assert await s.system.get_system_id() == 1
            assert int(await s.system.autopilot_type()) == int(mavsdk.Autopilot.ARDUPILOT)
            assert await first(s.tel.subscribe_health_all_ok(), lambda ok: ok)
            h = await first(s.tel.subscribe_health())
            assert h.is_global_position_ok and h.is_home_position_ok and h.is_armable and h.is_local_position_ok
            pos = await first(s.tel.subscribe_position())
            assert pos.latitude_deg == pytest.approx(O[0], abs=1e-6) and pos.longitude_deg == pytest.approx(O[1],
                                                                                                             abs=1e-6)
            home = await first(s.tel.subscribe_home())
            assert home.latitude_deg == pytest.approx(O[0], abs=1e-6)
            gps = await first(s.tel.subscribe_gps_info())
            assert gps.num_satellites >= 6 and int(gps.fix_type) >= 3
            raw = await first(s.tel.subscribe_raw_gps())
            assert raw.latitude_deg == pytest.approx(O[0], abs=1e-6)
            assert await first(s.tel.subscribe_in_air()) is False
            assert int(await first(s.tel.subscribe_landed_state())) == 1  # ON_GROUND
            assert await first(s.tel.subscribe_armed()) is False
            bat = await first(s.tel.subscribe_battery())
            assert bat.remaining_percent == pytest.approx(100, abs=1) and bat.voltage_v > 10
            att = await first(s.tel.subscribe_attitude_euler())
            assert att.yaw_deg == pytest.approx(90.0, abs=1.0)  # the sim faces east (ENU yaw 0)
            await first(s.tel.subscribe_velocity_ned())
            await first(s.tel.subscribe_heading())
            await first(s.tel.subscribe_position_velocity_ned())
            await first(s.tel.subscribe_flight_mode())
    run(go())


def test_mavsdk_without_rate_requests_gets_no_position_as_from_the_firmware():
    async def go():
        async with Session(ask_rates=False) as s:
            assert int(await s.system.autopilot_type()) == int(mavsdk.Autopilot.ARDUPILOT)
            with pytest.raises(asyncio.TimeoutError):
                await first(s.tel.subscribe_position(), limit_s=4.0)
            assert s.veh.streams.rate["GLOBAL_POSITION_INT"] == 0
    run(go())


def test_params_mission_fence_rally_round_trip_and_auto_flown_to_completion():
    async def go():
        async with Session(speed=6.0) as s:
            assert await s.par.get_param_float("WPNAV_SPEED") == pytest.approx(1000.0)
            await s.par.set_param_float("WPNAV_SPEED", 400.0)
            assert await s.par.get_param_float("WPNAV_SPEED") == pytest.approx(400.0)
            assert s.veh.params["WPNAV_SPEED"] == 400.0
            assert await s.par.get_param_int("SYSID_THISMAV") == 1

            def it(seq, cmd, e=0.0, n=0.0, z=0.0, p=(0, 0, 0, 0), frame=3, mission_type=0, pos=True):
                x, y = latlon(e, n) if pos else (0, 0)
                return MissionItem(seq, frame, cmd, 1 if seq == 0 else 0, 1, *p, x, y, z, mission_type)

            items = [it(0, 16, frame=0), it(1, 22, z=8), it(2, 178, p=I.speed_params(3.0)[:4], frame=2, pos=False),
                     it(3, 16, 15, 0, 8),
                     MissionItem(4, 2, 203, 0, 1, 0, 0, 0, 0, 0, 0, 0.0, 0),  # param5..7 live in x, y, z
                     it(5, 16, 15, 15, 10), it(6, 21, pos=False)]
            items[4] = MissionItem(4, 2, 203, 0, 1, 0, 0, 0, 0, 1, 42, 0.0, 0)  # shoot (x = param5), id 42 (param6)
            fence = [it(i, 5001, e, n, p=(4, 0, 0, 0), frame=0, mission_type=1)
                     for i, (e, n) in enumerate([(-50, -50), (60, -50), (60, 60), (-50, 60)])]
            await s.mis.upload_geofence(fence)
            gf = await s.mis.download_geofence()
            assert [(g.command, g.x, g.y) for g in gf] == [(f.command, f.x, f.y) for f in fence]
            rally = [it(0, 5100, 5, 5, 10, frame=3, mission_type=2)]
            await s.mis.upload_rally_points(rally)
            rp = await s.mis.download_rallypoints()
            assert [(r.command, r.x, r.y, r.z) for r in rp] == [(5100, *latlon(5, 5), 10.0)]

            # the mission last: MAVSDK's mission progress counts the items of its latest upload of any type
            await s.mis.upload_mission(items)
            back = await s.mis.download_mission()
            assert [(b.seq, b.command, b.x, b.y, b.z) for b in back[1:]] == \
                [(i.seq, i.command, i.x, i.y, pytest.approx(i.z)) for i in items[1:]]
            assert back[0].command == 16 and back[0].x == latlon(0, 0)[0]  # item 0 is home

            await s.act.arm()
            assert await first(s.tel.subscribe_armed(), lambda a: a)
            await s.mis.start_mission()
            done = await first(s.mis.subscribe_mission_progress(), lambda p: p.current == p.total, 180)
            assert done.total == len(items)
            assert int(await first(s.tel.subscribe_landed_state(), lambda st: int(st) == 1, 120)) == 1
            assert await first(s.tel.subscribe_armed(), lambda a: not a, 60) is False
            v = s.veh
            assert v.reached == [1, 3, 5, 6] and v.shots == [42]
            p = v.sim.state().pos
            assert math.hypot(p[0] - 15, p[1] - 15) < 2.0 and p[2] == pytest.approx(0.0, abs=0.05)
            assert v.custom_mode == CopterMode.AUTO and not v.errors
    run(go())


def test_takeoff_reposition_rtl_land_and_disarm():
    async def go():
        async with Session(speed=6.0) as s:
            await first(s.tel.subscribe_health_all_ok(), lambda ok: ok)
            await s.act.set_takeoff_altitude(6.0)
            await s.act.arm()
            await s.act.takeoff()
            assert await first(s.tel.subscribe_in_air(), lambda a: a)
            await first(s.tel.subscribe_position(), lambda p: p.relative_altitude_m > 5.6, 60)
            lat, lon, _ = pymap3d.enu2geodetic(20.0, 10.0, 0.0, *O)
            await s.act.goto_location(lat, lon, O[2] + 8.0, 0.0)  # COMMAND_INT DO_REPOSITION, AMSL altitude
            there = await first(s.tel.subscribe_position(), lambda p: abs(p.latitude_deg - lat) < 5e-6
                                and abs(p.longitude_deg - lon) < 5e-6 and abs(p.relative_altitude_m - 8.0) < 0.5, 120)
            assert there.relative_altitude_m == pytest.approx(8.0, abs=0.5)
            assert (192, 0) in s.veh.commands  # MAV_CMD_DO_REPOSITION accepted
            await s.act.set_return_to_launch_altitude(12.0)  # MAVSDK writes ArduPilot's RTL_ALT, in cm
            assert s.veh.params["RTL_ALT"] == 1200
            await s.act.return_to_launch()  # climbs to RTL_ALT above home first, as ArduCopter does
            await first(s.tel.subscribe_position(), lambda p: p.relative_altitude_m > 11.5, 60)
            assert int(await first(s.tel.subscribe_landed_state(), lambda st: int(st) == 1, 180)) == 1
            p = s.veh.sim.state().pos
            assert math.hypot(p[0], p[1]) < 1.0 and s.veh.custom_mode == CopterMode.RTL
            await first(s.tel.subscribe_armed(), lambda a: not a, 60)

            # again: take off, land on command, disarm (already disarmed by the landing: accepted)
            s.veh.pilot_mode(CopterMode.GUIDED)
            await first(s.tel.subscribe_flight_mode(), lambda m: s.veh.custom_mode == CopterMode.GUIDED, 10)
            await s.act.arm()
            await s.act.takeoff()
            await first(s.tel.subscribe_position(), lambda p: p.relative_altitude_m > 5.6, 60)
            await s.act.land()
            assert int(await first(s.tel.subscribe_landed_state(), lambda st: int(st) == 1, 120)) == 1
            await s.act.disarm()
            assert await first(s.tel.subscribe_armed(), lambda a: not a) is False
            assert s.veh.sim.mode == Mode.LANDED and not s.veh.errors
    run(go())


# ---------------------------------------------------------------------------------- pymavlink, MAVProxy style
from pymavlink import mavutil, mavwp  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.mavlink import MavlinkDriver, open_connection  # noqa: E402
from protocol.messages import Trajectory, Waypoint  # noqa: E402
from services.planner.export import qgc_wpl  # noqa: E402


class Gcs:
    """A ground station as MAVProxy is one: mavutil's helpers on a udpin link, HEARTBEAT as MAV_TYPE_GCS."""

    def __init__(self, port: int, key: str | None = None):
        self.m = open_connection(f"udpin:127.0.0.1:{port}", 255, M.MAV_COMP_ID_MISSIONPLANNER)
        if key is not None:
            from edge.vehicle.apm.signing import enable_signing, parse_key
            enable_signing(self.m, parse_key(key))

    def beat(self) -> None:
        self.m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def wait(self, type, cond=lambda m: True, limit_s: float = 30.0, beat: bool = True):
        """The next message of ``type`` satisfying ``cond`` (heartbeats go out meanwhile, as MAVProxy's do)."""
        end, next_beat = time.monotonic() + limit_s, 0.0
        while time.monotonic() < end:
            if beat and time.monotonic() >= next_beat:
                self.beat()
                next_beat = time.monotonic() + 1.0
            msg = self.m.recv_match(type=type, blocking=True, timeout=0.1)
            if msg is not None and cond(msg):
                return msg
        raise TimeoutError(f"no {type} within {limit_s} s")

    def ack(self, command: int) -> int:
        return self.wait("COMMAND_ACK", lambda a: a.command == command).result

    def mode(self, name: str) -> int:
        self.m.set_mode_apm(name)  # what MAVProxy's "mode NAME" sends: DO_SET_MODE with ArduCopter's number
        return self.ack(M.MAV_CMD_DO_SET_MODE)

    def close(self) -> None:
        self.m.close()


@pytest.fixture
def gcs_link(request):
    opts = getattr(request, "param", {})
    port = free_udp_port()
    gcs = Gcs(port, opts.get("mavlink_key"))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=8.0, **opts).start()
    try:
        hb = gcs.m.wait_heartbeat(timeout=10)
        assert hb is not None and gcs.m.target_system == 1
        # what MAVProxy asks on connecting (its default "streamrate 4"): ArduCopter sends nothing else unasked
        gcs.m.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_ALL, 4, 1)
        yield gcs, veh
    finally:
        gcs.close()
        veh.close()


def test_a_mavproxy_style_session_modes_param_set_wp_load_and_auto(gcs_link, tmp_path):
    gcs, veh = gcs_link
    m = gcs.m
    assert mavutil.mode_string_v10(gcs.wait("HEARTBEAT")) == "STABILIZE"
    # legacy stream request (MAVProxy, Mission Planner): POSITION group at 4 Hz
    m.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_POSITION, 4, 1)
    g = gcs.wait("GLOBAL_POSITION_INT")
    assert g.lat == round(O[0] * 1e7) and g.relative_alt == 0
    st = gcs.wait("SYS_STATUS")
    fence = M.MAV_SYS_STATUS_GEOFENCE
    assert st.onboard_control_sensors_present & fence and st.onboard_control_sensors_health & fence  # no "fence breach"
    # param set / fetch
    m.param_set_send("WPNAV_SPEED", 600.0)
    pv = gcs.wait("PARAM_VALUE", lambda p: p.param_id == "WPNAV_SPEED")
    assert pv.param_value == 600.0 and veh.params["WPNAV_SPEED"] == 600.0
    m.param_set_send("WPNAV_SPEED", 1e9)  # out of range: refused, the old value answered
    assert gcs.wait("PARAM_VALUE", lambda p: p.param_id == "WPNAV_SPEED").param_value == 600.0
    m.mav.param_request_list_send(1, 1)
    names = {gcs.wait("PARAM_VALUE").param_id for _ in range(len(veh.params.specs))}
    assert {"FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "RTL_ALT", "SYSID_THISMAV", "FENCE_ENABLE"} <= names
    # modes: AUTO without a mission and RTL on the ground are refused, as ArduCopter does
    assert gcs.mode("AUTO") == M.MAV_RESULT_FAILED and gcs.mode("RTL") == M.MAV_RESULT_FAILED
    assert gcs.mode("LOITER") == M.MAV_RESULT_ACCEPTED

    # wp load: a file from the planner's exporter, uploaded as MAVProxy's wp module does
    tr = Trajectory(uav=1, waypoints=[Waypoint(t=0, pos=(0, 0, 5), capture_id=3),
                                      Waypoint(t=4, pos=(12, 0, 5)),
                                      Waypoint(t=8, pos=(12, 12, 6), capture_id=4)])
    path = tmp_path / "uav1.waypoints"
    path.write_text(qgc_wpl(tr, O))
    wp = mavwp.MAVWPLoader(target_system=1, target_component=1)
    assert wp.load(str(path)) == wp.count()
    m.waypoint_count_send(wp.count())
    while True:
        msg = gcs.wait(["MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"])
        if msg.get_type() == "MISSION_ACK":
            break
        w = wp.wp(msg.seq)
        if msg.get_type() == "MISSION_REQUEST_INT":
            global_ = w.frame in (0, 3)
            m.mav.mission_item_int_send(1, 1, w.seq, w.frame, w.command, w.current, w.autocontinue, w.param1,
                                        w.param2, w.param3, w.param4, round(w.x * 1e7) if global_ else int(w.x),
                                        round(w.y * 1e7) if global_ else int(w.y), w.z)
        else:
            m.mav.send(w)
    assert msg.type == M.MAV_MISSION_ACCEPTED and len(veh.missions.mission()) == wp.count()

    assert gcs.mode("GUIDED") == M.MAV_RESULT_ACCEPTED
    m.arducopter_arm()
    assert gcs.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED
    assert gcs.mode("AUTO") == M.MAV_RESULT_ACCEPTED  # armed on the ground: the mission takes off
    last_nav = wp.count() - 1  # RTL
    gcs.wait("MISSION_ITEM_REACHED", lambda r: r.seq == last_nav, 120)
    gcs.wait("HEARTBEAT", lambda h: not h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 60)
    assert veh.shots == [3, 4] and not veh.errors
    p = veh.sim.state().pos
    assert math.hypot(p[0], p[1]) < 1.0  # RTL came home
    fb = [t for t in veh.statustexts if "failed" in t]
    assert len(fb) == 2  # the two refused mode changes said why


@pytest.mark.parametrize("gcs_link", [{"param_overrides": {"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 2}}],
                         indirect=True)
def test_gcs_failsafe_returns_to_launch_when_the_ground_station_falls_silent(gcs_link):
    gcs, veh = gcs_link
    assert gcs.mode("GUIDED") == M.MAV_RESULT_ACCEPTED
    gcs.m.arducopter_arm()
    assert gcs.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED
    gcs.m.mav.command_long_send(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, 0, 0, 6)
    assert gcs.ack(M.MAV_CMD_NAV_TAKEOFF) == M.MAV_RESULT_ACCEPTED
    gcs.wait("GLOBAL_POSITION_INT", lambda g: g.relative_alt > 5500, 60)
    assert not veh.gcs_failsafe
    # silence: no more HEARTBEATs from the ground station
    hb = gcs.wait("HEARTBEAT", lambda h: h.custom_mode == CopterMode.RTL, 30, beat=False)
    assert hb.system_status == M.MAV_STATE_CRITICAL and "GCS Failsafe" in veh.statustexts
    gcs.wait("STATUSTEXT", lambda t: "Failsafe Cleared" in t.text, 30)  # heartbeats again


@pytest.mark.parametrize("gcs_link", [{"param_overrides": {"FENCE_ENABLE": 1, "FENCE_ALT_MAX": 10,
                                                           "FENCE_ACTION": 1}}], indirect=True)
def test_fence_breach_reports_and_returns_to_launch(gcs_link):
    gcs, veh = gcs_link
    assert gcs.mode("GUIDED") == M.MAV_RESULT_ACCEPTED
    gcs.m.arducopter_arm()
    assert gcs.ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == M.MAV_RESULT_ACCEPTED
    gcs.m.mav.command_long_send(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, 0, 0, 5)
    assert gcs.ack(M.MAV_CMD_NAV_TAKEOFF) == M.MAV_RESULT_ACCEPTED
    gcs.wait("GLOBAL_POSITION_INT", lambda g: g.relative_alt > 4500, 60)
    mask = 0b110111111000  # position only (ignore velocity, acceleration, yaw rate... and yaw)
    for _ in range(3):
        gcs.m.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask | 1024, 0, 0, -14,
                                                     0, 0, 0, 0, 0, 0, 0, 0)
    gcs.wait("STATUSTEXT", lambda t: t.text == "Fence Breached", 60)
    gcs.wait("HEARTBEAT", lambda h: h.custom_mode == CopterMode.RTL, 10)
    gcs.wait("HEARTBEAT", lambda h: not h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 120)
    assert veh.fence_breaches == 1  # the geofence health bit was clear meanwhile (a breach may last < 1 SYS_STATUS)
    st = gcs.wait("SYS_STATUS")
    assert st.onboard_control_sensors_enabled & st.onboard_control_sensors_health & M.MAV_SYS_STATUS_GEOFENCE


# ---------------------------------------------------------------------------------- signing end to end
KEY = "a signing passphrase for the tests"


def test_signed_link_survives_a_forged_future_timestamp_and_ignores_unsigned_commands():
    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", signing_key=KEY)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=8.0, mavlink_key=KEY).start()
    try:
        drv.wait_heartbeat(10.0)
        # the attacker: the autopilot's address and link id, a timestamp a year ahead, a wrong signature
        liar = M.MAVLink(None, srcSystem=1, srcComponent=1)
        liar.signing.secret_key = b"\x00" * 32
        liar.signing.sign_outgoing = True
        liar.signing.timestamp = veh._conn.mav.signing.timestamp + 365 * 86400 * 100_000
        forged = bytes(liar.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4, 0).pack(liar))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(3):
                s.sendto(forged, ("127.0.0.1", port))
        drv.takeoff(4.0)  # needs the autopilot's genuine COMMAND_ACKs after the forgery
        assert veh.armed and drv.link.conn.mav.signing.badsig_count >= 3
        # an unsigned ground station is not obeyed: a LAND sent straight to the vehicle's socket
        n = len(veh.commands)
        sig = veh._conn.mav.signing
        refused = sig.reject_count + sig.unsigned_count
        plain = M.MAVLink(None, srcSystem=250, srcComponent=190)
        land = bytes(plain.command_long_encode(1, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(plain))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(land, veh._conn.port.getsockname())
        # one more signed round trip (a command after the datagram): the vehicle has read it by then
        drv.command(M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_HOME_POSITION,), "request HOME_POSITION")
        assert all(c != M.MAV_CMD_NAV_LAND for c, _ in veh.commands[n:]) and veh.custom_mode == CopterMode.GUIDED
        assert sig.reject_count + sig.unsigned_count > refused
    finally:
        drv.close()
        veh.close()


# ---------------------------------------------------------------------------------- skynet sim-autopilot
def test_skynet_sim_autopilot_runs_several_instances_with_distinct_system_ids():
    import subprocess
    import sys
    from pathlib import Path

    from edge.vehicle.sim_autopilot import connection_for

    assert connection_for("udpout:127.0.0.1:{port}", 3, 14550) == "udpout:127.0.0.1:14552"
    with pytest.raises(ValueError):
        connection_for("udpout:127.0.0.1:{port}", 3, 65535)
    base = free_udp_port()
    listeners = [mavutil.mavlink_connection(f"udpin:127.0.0.1:{base + k}") for k in range(2)]
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", "1", "--uav", "2",
                             "--port-base", str(base), "--speed", "2"], cwd=root, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        ids = []
        for m in listeners:
            hb = m.wait_heartbeat(timeout=30)
            assert hb is not None and hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
            ids.append(hb.get_srcSystem())
        assert ids == [1, 2]
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
        for m in listeners:
            m.close()
    assert proc.returncode == 0 and "uav 2 (system id 2)" in out and "sim-autopilot stopped" in out
    bad = subprocess.run([sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", "1", "--uav", "1"],
                         cwd=root, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "distinct" in bad.stderr


def test_one_command_line_for_the_sim_autopilot():
    """``skynet sim-autopilot`` and ``python -m edge.vehicle.mavsim`` parse the same arguments with the same
    defaults (one parser): their help texts differ only in the program's name."""
    import subprocess
    import sys
    from pathlib import Path

    from edge.vehicle import sim_autopilot
    from edge.vehicle.mavsim import cli

    assert sim_autopilot.main is cli.main and sim_autopilot.build_parser is cli.build_parser
    defaults = vars(cli.build_parser().parse_args(["--uav", "1"]))
    assert defaults["wind"] == "calm" and defaults["boot_scale"] == 1.0 and defaults["firmware_version"] == "4.6"
    root = Path(__file__).resolve().parents[3]
    texts = [subprocess.run([sys.executable, "-m", *entry, "--help"], cwd=root, capture_output=True, text=True,
                            timeout=60, env={"COLUMNS": "100", "PATH": "/usr/bin:/bin"}).stdout
             for entry in (["services.cli", "sim-autopilot"], ["edge.vehicle.mavsim"])]
    assert "--wind" in texts[0] and "--refuse-arming" in texts[0] and "--port-base" in texts[0]
    same = [t.replace("skynet sim-autopilot", "PROG").replace("python -m edge.vehicle.mavsim", "PROG").split()
            for t in texts]
    assert same[0] == same[1]
