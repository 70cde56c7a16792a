"""The operator's ground-station endpoint on the edge (edge.vehicle.gcs_bridge) with real pymavlink peers.

sim autopilot <-> MavlinkDriver (edge) <-> bridge <-> a ground station (pymavlink, MAVProxy style).
The ground station sees the autopilot and takes over; the driver reports the change it did not
make; and because the edge speaks as the companion computer, not as a GCS, the autopilot's GCS
failsafe fires when the operator's ground station falls silent.
"""

from __future__ import annotations

import socket
import time

import pytest

pytest.importorskip("pymavlink", reason="needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.apm.modes import CopterMode  # noqa: E402
from edge.vehicle.mavlink import MavlinkDriver, Phase, open_connection  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from protocol.messages import Mode  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def wait_for(gcs, type, cond, limit_s=30.0, beat=True):
    end, nxt = time.monotonic() + limit_s, 0.0
    while time.monotonic() < end:
        if beat and time.monotonic() >= nxt:
            gcs.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            nxt = time.monotonic() + 1.0
        m = gcs.recv_match(type=type, blocking=True, timeout=0.1)
        if m is not None and cond(m):
            return m
    raise TimeoutError(f"no {type} within {limit_s} s")


def test_ground_station_watches_takes_over_and_keeps_the_gcs_failsafe_meaningful():
    ap_port, gcs_port = free_udp_port(), free_udp_port()
    gcs = open_connection(f"udpin:127.0.0.1:{gcs_port}", 255, M.MAV_COMP_ID_MISSIONPLANNER)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{ap_port}", gcs_endpoint=f"udpout:127.0.0.1:{gcs_port}")
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{ap_port}", 1, speed=8.0, rc_centred=True,  # the pilot's RC on
                            param_overrides={"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 2}).start()
    try:
        drv.wait_heartbeat(10)
        hb = wait_for(gcs, "HEARTBEAT", lambda h: h.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA)
        assert hb.get_srcSystem() == 1  # the autopilot itself, forwarded
        # the operator's ground station asks for its own telemetry (ArduCopter sends only HEARTBEAT unasked)
        gcs.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                  250000, 0, 0, 0, 0, 0)
        drv.takeoff(5.0)
        wait_for(gcs, "GLOBAL_POSITION_INT", lambda g: drv.step(veh.clock.now()) is not None
                 and drv.state().mode == Mode.HOLD, 60)  # the board steps the driver on its clock
        # the edge is not a GCS: only the operator's heartbeats (system 255) count for FS_GCS
        assert veh.gcs_heartbeats >= 1 and drv.bridge.from_gcs_count >= 1
        # the operator takes over: LOITER, acknowledged through the bridge
        gcs.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, CopterMode.LOITER, 0, 0, 0, 0, 0)
        ack = wait_for(gcs, "COMMAND_ACK", lambda a: a.command == M.MAV_CMD_DO_SET_MODE)
        assert ack.result == M.MAV_RESULT_ACCEPTED and ack.target_system == 255
        end = time.monotonic() + 20
        while drv.state().mode != Mode.PILOT or drv.phase is not Phase.EXTERNAL:  # the pilot's mode, not "hold"
            assert time.monotonic() < end, drv.phase
            drv.step(veh.clock.now())
            time.sleep(0.05)
        with pytest.raises(ValueError):
            drv.start()  # the driver stops commanding while the pilot flies (start needs its own HOLD)
        # the operator's ground station falls silent: the autopilot's failsafe returns to launch
        wait_for(gcs, "HEARTBEAT", lambda h: h.get_srcSystem() == 1 and h.custom_mode == CopterMode.RTL, 30,
                 beat=False)
        assert "GCS Failsafe" in veh.statustexts
        assert drv.bridge.to_gcs_count > 50
    finally:
        drv.close()
        veh.close()
        gcs.close()
