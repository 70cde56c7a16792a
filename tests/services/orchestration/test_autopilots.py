"""services.orchestration.autopilots (``--autopilot uavN=ENDPOINT``, pure) and an edge's launch point taken from its
autopilot's HOME_POSITION (``--home-from-autopilot``: the MAVLink driver against a sim autopilot over loopback UDP)."""

from __future__ import annotations

import math
import socket
import time

import pytest

from services.orchestration.autopilots import autopilot_endpoints, normalise_endpoint, parse_autopilot


@pytest.mark.parametrize("text, expected", [
    ("udpin:0.0.0.0:14550", "udpin:0.0.0.0:14550"),
    ("udpout:192.168.1.20:14550", "udpout:192.168.1.20:14550"),
    ("udp:127.0.0.1:14551", "udp:127.0.0.1:14551"),
    ("tcp:127.0.0.1:5760", "tcp:127.0.0.1:5760"),
    ("tcp:sitl-host.local:05762", "tcp:sitl-host.local:5762"),
    ("tcpin:0.0.0.0:5760", "tcpin:0.0.0.0:5760"),
    ("udpin:[::1]:14550", "udpin:[::1]:14550"),
    ("/dev/ttyUSB0,57600", "/dev/ttyUSB0,57600"),
    ("/dev/serial/by-id/usb-ArduPilot_Pixhawk1_3A0038-if00", "/dev/serial/by-id/usb-ArduPilot_Pixhawk1_3A0038-if00"),
    ("serial:/dev/ttyACM0:921600", "/dev/ttyACM0,921600"),  # MAVSDK's form, written as pymavlink's
    ("serial:/dev/ttyAMA0", "/dev/ttyAMA0"),
])
def test_an_endpoint_is_written_as_pymavlink_opens_it(text, expected):
    assert normalise_endpoint(text) == expected


@pytest.mark.parametrize("text, needle", [
    ("", "expected udpin:HOST:PORT"),
    ("udpin:0.0.0.0", "expected udpin:HOST:PORT"),
    ("udpin:0.0.0.0:0", "port '0' is not in 1..65535"),
    ("udpin:0.0.0.0:70000", "port '70000' is not in 1..65535"),
    ("tcp:host name:5760", "expected tcp:HOST:PORT"),
    ("udpin:0.0.0.0:14550\n--insecure", "expected udpin:HOST:PORT"),  # hostile text: refused, shown escaped
    ("http://10.0.0.1:80", "expected udpin:HOST:PORT"),
    ("COM3", "expected udpin:HOST:PORT"),
    ("/dev/ttyUSB0,57601", "baud rate '57601' is not one of"),
    ("/dev/ttyUSB0,fast", "baud rate 'fast'"),
    ("serial:dev/ttyACM0:921600", "is not a device path"),
    ("/dev/../etc//passwd", "is not a device path"),
    ("udpin:0.0.0.0:" + "9" * 5000, "expected udpin:HOST:PORT"),
])
def test_a_bad_endpoint_is_a_one_line_error(text, needle):
    with pytest.raises(ValueError, match=needle) as err:
        normalise_endpoint(text)
    msg = str(err.value)
    assert "\n" not in msg and len(msg) < 300


def test_uav_numbers_are_checked_against_the_fleet():
    assert autopilot_endpoints(["uav3=tcp:127.0.0.1:5780", "uav1=udpin:0.0.0.0:14550"], 3) == {
        1: "udpin:0.0.0.0:14550", 3: "tcp:127.0.0.1:5780"}
    assert parse_autopilot(" uav12=serial:/dev/ttyACM1:115200") == (12, "/dev/ttyACM1,115200")
    for values, needle in ((["uav4=udpin:0.0.0.0:1"], "the fleet has UAVs 1..3"),
                           (["uav0=udpin:0.0.0.0:1"], "the fleet has UAVs 1..3"),
                           (["uav1=udpin:0.0.0.0:1", "uav1=udpin:0.0.0.0:2"], "uav1: given twice"),
                           (["uav1=/dev/ttyUSB0,57600", "uav2=/dev/ttyUSB0,115200"], "uav1's already"),
                           (["1=udpin:0.0.0.0:1"], "expected uavN=ENDPOINT"),
                           (["uav1"], "expected uavN=ENDPOINT"),
                           (["uav2=udpin:x:y"], "--autopilot uav2: endpoint")):
        with pytest.raises(ValueError, match=needle):
            autopilot_endpoints(values, 3)


# -- the launch point from the autopilot's home


def test_home_in_frame_is_the_geodetic_inverse_of_the_sim_autopilots_home():
    pytest.importorskip("pymavlink", reason="the MAVLink driver needs the 'mavlink' extra")
    import pymap3d

    from edge.vehicle.mavlink.driver import home_in_frame

    origin = (-33.87601, 151.191182, 10.0)
    lla = pymap3d.enu2geodetic(37.5, -12.25, 3.0, *origin)
    assert home_in_frame(lla, origin) == pytest.approx((37.5, -12.25, 3.0), abs=2e-3)
    with pytest.raises(ValueError, match="km from the scenario's origin"):
        home_in_frame(pymap3d.enu2geodetic(30_000.0, 0.0, 0.0, *origin), origin)
    with pytest.raises(ValueError, match="not a geodetic point"):
        home_in_frame((91.0, 0.0, 0.0), origin)
    with pytest.raises(ValueError, match="not a geodetic point"):
        home_in_frame((0.0, 0.0, math.nan), origin)


def test_the_driver_takes_its_launch_point_from_the_autopilots_home():
    """A sim autopilot at (12, -7, 0) m of the scenario's frame; the driver told the scenario's slot (40, 8, 0):
    with ``home_origin`` it is not ready until it adopted the autopilot's home, then reports positions about it."""
    pytest.importorskip("pymavlink", reason="the MAVLink driver needs the 'mavlink' extra")
    from edge.vehicle.mavlink import MavlinkDriver
    from edge.vehicle.mavsim import DEFAULT_ORIGIN, MavlinkSimVehicle
    from services.orchestration.process import free_port

    port = free_port(socket.SOCK_DGRAM)
    real, told = (12.0, -7.0, 0.0), (40.0, 8.0, 0.0)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=told, home_origin=DEFAULT_ORIGIN)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=real, speed=8.0, boot_scale=0.0).start()
    try:
        t_end = time.monotonic() + 15.0
        while not drv.readiness().ready and time.monotonic() < t_end:
            time.sleep(0.05)
        assert drv.readiness().ready, drv.readiness()
        assert drv.home_adopted == pytest.approx(real, abs=0.01) and drv.home == drv.home_adopted
        t_end = time.monotonic() + 5.0
        while math.dist(drv.state().pos, real) > 0.2 and time.monotonic() < t_end:
            time.sleep(0.05)
        assert drv.state().pos == pytest.approx(real, abs=0.2)  # where the vehicle is, not the slot it was told
        drv.takeoff(4.0)
        t_end = time.monotonic() + 10.0
        while drv.state().pos[2] < 3.6 and time.monotonic() < t_end:
            drv.step(veh.clock.now())
            time.sleep(0.02)
        q = veh.sim.state().pos  # the simulated vehicle itself, in the scenario's frame
        assert math.dist(q[:2], real[:2]) < 0.5 and math.dist(drv.state().pos, q) < 0.6
    finally:
        drv.close()
        veh.close()


def test_without_an_origin_the_given_home_stays():
    pytest.importorskip("pymavlink", reason="the MAVLink driver needs the 'mavlink' extra")
    from edge.vehicle.mavlink import MavlinkDriver
    from edge.vehicle.mavsim import MavlinkSimVehicle
    from services.orchestration.process import free_port

    port = free_port(socket.SOCK_DGRAM)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=(40.0, 8.0, 0.0))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=(12.0, -7.0, 0.0), speed=8.0, boot_scale=0.0).start()
    try:
        t_end = time.monotonic() + 15.0
        while not drv.readiness().ready and time.monotonic() < t_end:
            time.sleep(0.05)
        assert drv.readiness().ready and drv.home_adopted is None and drv.home == (40.0, 8.0, 0.0)
    finally:
        drv.close()
        veh.close()
