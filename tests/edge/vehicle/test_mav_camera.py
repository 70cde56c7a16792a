"""The UAV's camera on the edge's ground-station endpoint (edge.vehicle.mav_camera) with a real pymavlink GCS.

sim autopilot <-> MavlinkDriver (edge) <-> bridge + camera component <-> a ground station doing what
QGroundControl's camera manager does: hear the camera's HEARTBEAT, ask for CAMERA_INFORMATION, then
VIDEO_STREAM_INFORMATION (MAV_CMD_REQUEST_MESSAGE and the legacy commands) and VIDEO_STREAM_STATUS.
"""

from __future__ import annotations

import math
import socket
import time

import pytest

pytest.importorskip("pymavlink", reason="needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.mav_camera import CAMERA_COMPONENT, MavCamera, VideoStreamSpec, stream_port  # noqa: E402
from edge.vehicle.mavlink import MavlinkDriver, open_connection  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def test_stream_port_follows_skynet_video_and_the_spec_checks_its_fields():
    assert [stream_port(5600, n) for n in (1, 2, 3)] == [5600, 5602, 5604]
    with pytest.raises(ValueError):
        stream_port(65534, 3)
    assert VideoStreamSpec(5602).uri == "udp://0.0.0.0:5602"
    for bad in (dict(port=0), dict(port=5600, framerate=math.nan), dict(port=5600, codec="vp8"),
                dict(port=5600, name="x" * 33)):
        with pytest.raises(ValueError):
            VideoStreamSpec(**bad)


def _parse(frames: list[bytes]) -> list:
    mav = M.MAVLink(None)
    return [mav.decode(bytearray(f)) for f in frames]


def test_camera_answers_requests_and_refuses_what_it_does_not_do():
    cam = MavCamera(VideoStreamSpec(5600, codec="mjpeg"), sysid=3)
    req = M.MAVLink(None, srcSystem=255, srcComponent=190)
    ask = lambda *p, comp=CAMERA_COMPONENT, cmd=M.MAV_CMD_REQUEST_MESSAGE: _parse(cam.handle(  # noqa: E731
        req.decode(bytearray(req.command_long_encode(3, comp, cmd, 0, *p, *(0,) * (7 - len(p))).pack(req)))))
    ack, info = ask(M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 0)
    assert ack.result == M.MAV_RESULT_ACCEPTED and ack.target_system == 255 and ack.target_component == 190
    assert info.encoding == M.VIDEO_STREAM_ENCODING_UNKNOWN and info.get_srcComponent() == CAMERA_COMPONENT
    (denied,) = ask(M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 7)  # no stream 7
    assert denied.result == M.MAV_RESULT_DENIED
    (unsup,) = ask(math.nan)
    assert unsup.result == M.MAV_RESULT_UNSUPPORTED
    (unsup,) = ask(0, cmd=M.MAV_CMD_IMAGE_START_CAPTURE)
    assert unsup.result == M.MAV_RESULT_UNSUPPORTED
    assert ask(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, comp=1) == []  # for the autopilot, not for us
    assert ask(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, comp=0) == []  # broadcast: the autopilot answers
    assert (cam.answered, cam.refused) == (1, 3)


def _request(gcs, cmd, params, want, limit_s=10.0):
    """Send a COMMAND_LONG to the camera; its COMMAND_ACK and (if ``want``) the message it asked for."""
    gcs.mav.command_long_send(2, CAMERA_COMPONENT, cmd, 0, *params, *(0,) * (7 - len(params)))
    ack = got = None
    end = time.monotonic() + limit_s
    while time.monotonic() < end and (ack is None or (want and got is None)):
        m = gcs.recv_match(type=["COMMAND_ACK", want or "COMMAND_ACK"], blocking=True, timeout=0.1)
        if m is None or m.get_srcComponent() != CAMERA_COMPONENT:
            continue
        if m.get_type() == "COMMAND_ACK" and m.command == cmd:
            ack = m
        elif want and m.get_type() == want:
            got = m
    assert ack is not None, f"no COMMAND_ACK to {cmd} from the camera"
    return ack, got


def test_ground_station_finds_the_video_stream_the_qgc_way():
    ap_port, gcs_port = free_udp_port(), free_udp_port()
    gcs = open_connection(f"udpin:127.0.0.1:{gcs_port}", 255, M.MAV_COMP_ID_MISSIONPLANNER)
    video = VideoStreamSpec(stream_port(5600, 2), framerate=2.0)
    drv = MavlinkDriver(2, f"udpin:127.0.0.1:{ap_port}", gcs_endpoint=f"udpout:127.0.0.1:{gcs_port}",
                        gcs_video=video)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{ap_port}", 2, speed=8.0).start()
    try:
        drv.wait_heartbeat(10)
        end = time.monotonic() + 15
        while True:  # the camera's heartbeat: the vehicle's system id, a camera component
            assert time.monotonic() < end, "no camera HEARTBEAT"
            gcs.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if hb is not None and hb.get_srcComponent() == CAMERA_COMPONENT:
                break
        assert hb.get_srcSystem() == 2 and hb.type == M.MAV_TYPE_CAMERA
        assert hb.autopilot == M.MAV_AUTOPILOT_INVALID
        ack, info = _request(gcs, M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_CAMERA_INFORMATION,),
                             "CAMERA_INFORMATION")
        assert ack.result == M.MAV_RESULT_ACCEPTED and info.flags & M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        ack, vsi = _request(gcs, M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 0),
                            "VIDEO_STREAM_INFORMATION")
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert vsi.uri == "udp://0.0.0.0:5602" and vsi.type == M.VIDEO_STREAM_TYPE_RTPUDP
        assert vsi.encoding == M.VIDEO_STREAM_ENCODING_H264 and vsi.stream_id == 1 and vsi.count == 1
        assert (vsi.resolution_h, vsi.resolution_v) == (320, 240) and vsi.framerate == 2.0
        assert vsi.flags & M.VIDEO_STREAM_STATUS_FLAGS_RUNNING
        ack, legacy = _request(gcs, M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, (1,), "VIDEO_STREAM_INFORMATION")
        assert ack.result == M.MAV_RESULT_ACCEPTED and legacy.uri == vsi.uri
        ack, status = _request(gcs, M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS, 1),
                               "VIDEO_STREAM_STATUS")
        assert ack.result == M.MAV_RESULT_ACCEPTED and status.resolution_h == 320
        ack, _ = _request(gcs, M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 9), None)
        assert ack.result == M.MAV_RESULT_DENIED
        # the autopilot is still the autopilot: a request for it is forwarded and answered by it
        gcs.mav.command_long_send(2, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                  0, 0, 0, 0, 0, 0)
        av = gcs.recv_match(type="AUTOPILOT_VERSION", blocking=True, timeout=10)
        assert av is not None and av.get_srcComponent() == 1
        assert drv.bridge.camera.answered == 4 and drv.bridge.camera.refused == 1
    finally:
        drv.close()
        veh.close()
        gcs.close()
