"""ArduCopter's two parameter naming schemes (stable 4.5/4.6 vs 4.7+): the table, the simulated
autopilot answering in either over real UDP, and the MAVLink driver learning the scheme and
setting parameters in the autopilot's own names and units."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from edge.vehicle.apm.params import (
    COPTER_PARAMS,
    DEFAULT_SCHEME,
    RENAMED,
    ParamTable,
    copter_params,
    flight_sw_version,
    from_raw,
    param_name,
    scheme_of_version,
    to_raw,
)
from services.orchestration.process import free_port

pytest.importorskip("pymavlink", reason="the MAVLink tests need pymavlink (the mavlink extra)")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.mavlink import MavlinkDriver, MavlinkParams, open_connection  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402

GCS = (255, 190)
OLD = {"SYSID_THISMAV", "WPNAV_SPEED", "RTL_ALT", "LAND_SPEED", "ARMING_CHECK", "SYSID_MYGCS", "WPNAV_RADIUS",
       "WPNAV_SPEED_UP", "WPNAV_SPEED_DN"}
NEW = {"MAV_SYSID", "WP_SPD", "RTL_ALT_M", "LAND_SPD_MS", "ARMING_SKIPCHK", "MAV_GCS_SYSID", "WP_RADIUS_M",
       "WP_SPD_UP", "WP_SPD_DN"}


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


# ---------------------------------------------------------------------------------- the table (pure)
def test_each_scheme_has_its_names_and_units_and_the_same_si_values():
    assert DEFAULT_SCHEME == "4.6" and copter_params("4.6") == COPTER_PARAMS
    old, new = ParamTable(scheme="4.6"), ParamTable(scheme="4.7")
    assert OLD <= set(old.values) and not NEW & set(old.values)
    assert NEW <= set(new.values) and not OLD & set(new.values)
    assert len(old.specs) == len(new.specs)
    # the raw values in each scheme's unit: cm/s and cm in 4.6, m/s and m in 4.7
    assert (old["WPNAV_SPEED"], old["RTL_ALT"], old["LAND_SPEED"]) == (1000.0, 1500.0, 50.0)
    assert (new["WP_SPD"], new["RTL_ALT_M"], new["LAND_SPD_MS"]) == (10.0, 15.0, 0.5)
    assert (old["WPNAV_RADIUS"], new["WP_RADIUS_M"], old["SYSID_MYGCS"], new["MAV_GCS_SYSID"]) == (200, 2, 255, 255)
    for key in ("wp_speed", "rtl_alt", "land_speed", "wp_radius", "wp_speed_up", "wp_speed_dn"):
        assert old.si(key) == pytest.approx(new.si(key))
    # ARMING_CHECK enables checks (1: all), ARMING_SKIPCHK names checks to skip (0: none): both "all checks"
    assert old["ARMING_CHECK"] == 1 and new["ARMING_SKIPCHK"] == 0
    assert to_raw("wp_speed", 3.5, "4.6") == pytest.approx(350.0) and to_raw("wp_speed", 3.5, "4.7") == 3.5
    assert from_raw("rtl_alt", 2000, "4.6") == pytest.approx(20.0) and from_raw("rtl_alt", 20, "4.7") == 20.0
    with pytest.raises(ValueError):
        to_raw("arming_skip", 1, "4.7")  # re-meant, not converted
    assert [param_name(r.key, "4.7") for r in RENAMED] == [r.new.name for r in RENAMED]


def test_the_other_schemes_names_get_param_error_and_bad_values_are_refused():
    new = ParamTable(scheme="4.7", MAV_SYSID=3)
    assert new.name("sysid") == "MAV_SYSID" and new["MAV_SYSID"] == 3
    for name in OLD:
        (err,) = new.request_read(name, -1, GCS)
        assert err[0] == "param_error" and err[1]["param_id"] == name.encode()
        (err,) = new.param_set(name, 1.0, GCS)
        assert err[0] == "param_error"
    assert new.param_set("WP_SPD", 3.5)[0][1]["param_value"] == 3.5
    for bad in (math.nan, 350.0, 0.0):  # 350 (a 4.6 value in cm/s) is out of WP_SPD's m/s range
        assert new.param_set("WP_SPD", bad)[0][1]["param_value"] == 3.5
    assert new.rejected == len(OLD) + 3
    with pytest.raises(ValueError):
        ParamTable(scheme="4.7", SYSID_THISMAV=2)
    with pytest.raises(ValueError, match="scheme"):
        ParamTable(scheme="5.0")


def test_flight_sw_version_maps_to_its_scheme():
    assert scheme_of_version(flight_sw_version("4.7")) == "4.7"
    assert scheme_of_version(flight_sw_version("4.6")) == "4.6"
    assert scheme_of_version((4 << 24) | (5 << 16) | (7 << 8) | 255) == "4.6"
    assert scheme_of_version((4 << 24) | (8 << 16) | 0) == "4.7"  # 4.8.0-dev keeps 4.7's names


# ---------------------------------------------------------------------------------- the sim over UDP
class Gcs:
    """A bare pymavlink ground station on a udpin link."""

    def __init__(self, port: int):
        self.m = open_connection(f"udpin:127.0.0.1:{port}", *GCS)

    def wait(self, types, cond=lambda m: True, limit_s: float = 20.0):
        end, beat = time.monotonic() + limit_s, 0.0
        while time.monotonic() < end:
            if time.monotonic() >= beat:
                self.m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                beat = time.monotonic() + 1.0
            msg = self.m.recv_match(type=types, blocking=True, timeout=0.1)
            if msg is not None and cond(msg):
                return msg
        raise TimeoutError(f"no {types} within {limit_s} s")

    def read(self, name: str):
        self.m.mav.param_request_read_send(1, 1, name.encode(), -1)
        return self.wait(["PARAM_VALUE", "PARAM_ERROR"], lambda p: p.param_id == name)


@pytest.mark.parametrize("scheme", ["4.6", "4.7"])
def test_sim_autopilot_answers_in_its_schemes_names_and_units(scheme):
    port = free_udp_port()
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0, firmware=scheme).start()
    try:
        assert gcs.m.wait_heartbeat(timeout=10) is not None
        mine, other = (OLD, NEW) if scheme == "4.6" else (NEW, OLD)
        expect = {"4.6": {"SYSID_THISMAV": 1, "WPNAV_SPEED": 1000, "RTL_ALT": 1500, "LAND_SPEED": 50,
                          "ARMING_CHECK": 1},
                  "4.7": {"MAV_SYSID": 1, "WP_SPD": 10, "RTL_ALT_M": 15, "LAND_SPD_MS": 0.5,
                          "ARMING_SKIPCHK": 0}}[scheme]
        for name, value in expect.items():
            pv = gcs.read(name)
            assert pv.get_type() == "PARAM_VALUE" and pv.param_value == pytest.approx(value), name
        for name in other:
            err = gcs.read(name)
            assert err.get_type() == "PARAM_ERROR" and err.error == M.MAV_PARAM_ERROR_DOES_NOT_EXIST, name
        wp = "WPNAV_SPEED" if scheme == "4.6" else "WP_SPD"
        new_speed = 350.0 if scheme == "4.6" else 3.5
        gcs.m.mav.param_set_send(1, 1, wp.encode(), new_speed, M.MAV_PARAM_TYPE_REAL32)
        assert gcs.wait("PARAM_VALUE", lambda p: p.param_id == wp).param_value == pytest.approx(new_speed)
        assert veh.params.si("wp_speed") == pytest.approx(3.5)
        gcs.m.mav.param_request_list_send(1, 1)
        names = {gcs.wait("PARAM_VALUE").param_id for _ in range(len(veh.params.specs))}
        assert mine <= names and not other & names
        gcs.m.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                    0, 0, 0, 0, 0, 0)
        av = gcs.wait("AUTOPILOT_VERSION")
        assert scheme_of_version(av.flight_sw_version) == scheme
    finally:
        gcs.m.close()
        veh.close()


def test_skynet_sim_autopilot_firmware_version_option():
    port = free_udp_port()
    gcs = Gcs(port)
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", "2", "--port-base",
                             str(port - 1), "--firmware-version", "4.7", "--boot-scale", "0"], cwd=root,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert gcs.m.wait_heartbeat(timeout=30) is not None
        gcs.m.mav.param_request_read_send(2, 1, b"MAV_SYSID", -1)
        assert gcs.wait("PARAM_VALUE", lambda p: p.param_id == "MAV_SYSID").param_value == 2
    finally:
        proc.terminate()
        proc.communicate(timeout=20)
        gcs.m.close()
    bad = subprocess.run([sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", "1",
                          "--firmware-version", "9.9"], cwd=root, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--firmware-version" in bad.stderr and "Traceback" not in bad.stderr


# ---------------------------------------------------------------------------------- the driver
@pytest.fixture
def link(request):
    scheme = request.param
    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", params=MavlinkParams(heartbeat_timeout_s=3.0))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0, firmware=scheme).start()
    try:
        drv.wait_heartbeat(10.0)
        yield scheme, drv, veh
    finally:
        drv.close()
        veh.close()


@pytest.mark.parametrize("link", ["4.6", "4.7"], indirect=True)
def test_driver_learns_the_scheme_and_sets_parameters_in_the_autopilots_units(link):
    scheme, drv, veh = link
    assert drv.learn_param_scheme() == scheme and drv.param_scheme == scheme
    assert drv.read_param_si("wp_speed") == pytest.approx(10.0)
    assert drv.read_param_si("rtl_alt") == pytest.approx(15.0)
    assert drv.set_waypoint_speed(3.5) == pytest.approx(3.5)
    # read back in the sim's own units
    if scheme == "4.6":
        assert veh.params["WPNAV_SPEED"] == pytest.approx(350.0)
    else:
        assert veh.params["WP_SPD"] == pytest.approx(3.5)
    assert drv.set_param_si("rtl_alt", 20.0) == pytest.approx(20.0)
    assert veh.params[param_name("rtl_alt", scheme)] == pytest.approx(2000.0 if scheme == "4.6" else 20.0)
    assert drv.set_param_si("land_speed", 0.7) == pytest.approx(0.7)
    assert veh.params.si("land_speed") == pytest.approx(0.7)
    # the other scheme's name does not exist; an out-of-range value is kept out
    other = "SYSID_THISMAV" if scheme == "4.7" else "MAV_SYSID"
    assert drv.read_param(other) is None
    with pytest.raises(ValueError, match="does not exist"):
        drv.set_param(other, 3, M.MAV_PARAM_TYPE_INT16)
    with pytest.raises(ValueError, match="kept"):
        drv.set_waypoint_speed(50.0)  # above the range of either scheme (20 m/s)
    assert veh.params.si("wp_speed") == pytest.approx(3.5)
    for bad in (math.nan, -1.0, 0.0):
        with pytest.raises(ValueError):
            drv.set_waypoint_speed(bad)
    with pytest.raises(ValueError):
        drv.read_param("X" * 17)


def test_driver_finds_a_parameter_in_the_other_spelling():
    """Firmware part-way through the renames (ArduPilot's rename page: 4.7.0 has WP_SPD but kept SYSID_THISMAV)."""
    from edge.vehicle.apm.params import ParamSpec

    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", params=MavlinkParams(heartbeat_timeout_s=3.0))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0, firmware="4.7")
    specs = tuple(ParamSpec("SYSID_THISMAV", 1, 1, 255, s.type) if s.name == "MAV_SYSID" else s
                  for s in copter_params("4.7"))
    veh.params = ParamTable(specs, scheme="4.7", SYSID_THISMAV=1)
    veh.start()
    try:
        drv.wait_heartbeat(10.0)
        assert drv.learn_param_scheme() == "4.7"
        assert drv.read_param_si("sysid") == 1 and drv.read_param("MAV_SYSID") is None
        assert drv.set_waypoint_speed(2.0) == pytest.approx(2.0) and veh.params["WP_SPD"] == pytest.approx(2.0)
    finally:
        drv.close()
        veh.close()


def test_driver_survives_hostile_param_messages():
    """A peer posing as the autopilot sends NaN values, junk names and PARAM_ERRORs for others: counted, ignored."""
    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", params=MavlinkParams(heartbeat_timeout_s=3.0))
    ap = open_connection(f"udpout:127.0.0.1:{port}", 1, M.MAV_COMP_ID_AUTOPILOT1)
    try:
        def beat():
            ap.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, M.MAV_STATE_STANDBY)
        beat()
        drv.wait_heartbeat(10.0)
        errors0 = drv.link_errors
        ap.mav.param_value_send(b"WP_SPD", math.nan, M.MAV_PARAM_TYPE_REAL32, 1, 0)
        ap.mav.param_error_send(7, 1, b"MAV_SYSID", -1, M.MAV_PARAM_ERROR_DOES_NOT_EXIST)  # addressed elsewhere
        end = time.monotonic() + 10
        while drv.link_errors == errors0 and time.monotonic() < end:
            beat()
            time.sleep(0.1)
        assert drv.link_errors > errors0
        # no answer at all: a clear error, not a hang
        with pytest.raises(ValueError, match="no answer"):
            drv.read_param("WP_SPD", timeout_s=0.3, retries=0)
    finally:
        drv.close()
        ap.close()


# ---------------------------------------------------------------------------------- through the launcher
@pytest.mark.mission
def test_auto_mission_through_the_launcher_on_4_7_autopilots(tmp_path):
    """``skynet mission --vehicle mavlink --flight auto --sim-firmware-version 4.7``: the edges set the plan's
    speed as WP_SPD (m/s) on every autopilot and fly the mission to success."""
    import json

    out = tmp_path / "report"
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--vehicle", "mavlink", "--speed", "8",
                           "--flight", "auto", "--sim-boot-scale", "0.1", "--sim-firmware-version", "4.7",
                           "--quiet", "--out", str(out)], cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and not report["failures"]
    log = (out / "services.log").read_text()
    for i in (1, 2, 3):
        assert f"UAV {i}: autopilot parameters in ArduCopter 4.7's naming scheme" in log
        assert f"UAV {i}: waypoint speed" in log
    assert "set as WP_SPD (ArduCopter 4.7 parameter names)" in log and "WPNAV_SPEED" not in log
    assert "waypoint speed was not set" not in log
