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

from edge.vehicle.apm import items as I  # noqa: E402
from edge.vehicle.apm.modes import CopterMode  # noqa: E402
from edge.vehicle.mavsim import DEFAULT_ORIGIN, MavlinkSimVehicle  # noqa: E402
from protocol.messages import Mode  # noqa: E402

O = DEFAULT_ORIGIN


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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


class Session:
    """One sim autopilot and a MAVSDK ground station listening for it."""

    def __init__(self, speed: float = 4.0, **opts):
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
            await s.act.return_to_launch()
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
