"""The UAV's camera as a MAVLink camera component on the edge's ground-station endpoint.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mav_camera.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Literal

from pymavlink.dialects.v20 import ardupilotmega as M

__all__ = ["VideoStreamSpec", "MavCamera", "stream_port", "CAMERA_COMPONENT"]

#: MAVLink component id of the (first) camera (MAV_COMPONENT: MAV_COMP_ID_CAMERA)
CAMERA_COMPONENT = M.MAV_COMP_ID_CAMERA
_STREAM_ID = 1


def stream_port(base: int, uav: int) -> int:
    """UDP port of UAV ``uav``'s stream when UAV 1's is ``base``: ``base + 2 (uav - 1)`` (services.video)."""
    if not (isinstance(uav, int) and uav >= 1):
        raise ValueError("uav must be an int >= 1")
    port = int(base) + 2 * (uav - 1)
    if not 0 < port < 65536:
        raise ValueError(f"UAV {uav}'s video port {port} is out of range")
    return port


@dataclass(frozen=True)
class VideoStreamSpec:
    """One RTP/UDP stream as VIDEO_STREAM_INFORMATION describes it."""

    port: int
    width: int = 320
    height: int = 240
    framerate: float = 2.0
    codec: Literal["h264", "mjpeg"] = "h264"
    hfov_deg: float = 0.0
    bitrate: int = 0
    name: str = "preview"

    def __post_init__(self) -> None:
        if not (isinstance(self.port, int) and 0 < self.port < 65536):
            raise ValueError("port must be an int in 1..65535")
        if not (0 < self.width < 65536 and 0 < self.height < 65536):
            raise ValueError("width and height must be in 1..65535")
        if not (math.isfinite(self.framerate) and self.framerate >= 0):
            raise ValueError("framerate must be finite and >= 0")
        if self.codec not in ("h264", "mjpeg"):
            raise ValueError("codec must be 'h264' or 'mjpeg'")
        if not (math.isfinite(self.hfov_deg) and 0 <= self.hfov_deg < 360):
            raise ValueError("hfov_deg must be in [0, 360)")
        if len(self.name.encode()) > 32:
            raise ValueError("name must fit MAVLink's 32 bytes")

    @property
    def uri(self) -> str:
        """The URI QGroundControl listens on for this stream: ``udp://0.0.0.0:<port>``."""
        return f"udp://0.0.0.0:{self.port}"


class MavCamera:
    """The camera component's side of the MAVLink Camera Protocol (no I/O): announces ``stream`` as a
    component of the vehicle ``sysid``."""

    def __init__(self, stream: VideoStreamSpec, sysid: int, component: int = CAMERA_COMPONENT):
        if not (isinstance(sysid, int) and 1 <= sysid <= 255):
            raise ValueError("sysid must be an int in 1..255")
        self.stream = stream
        self.mav = M.MAVLink(None, srcSystem=sysid, srcComponent=component)
        self.sysid, self.component = sysid, component
        self._boot = time.monotonic()
        #: requests answered, and refused (unsupported command, unknown stream)
        self.answered = 0
        self.refused = 0

    def addressed(self, msg: Any) -> bool:
        """Whether a message from the ground station is for this camera (its component, or broadcast)."""
        ts = getattr(msg, "target_system", None)
        tc = getattr(msg, "target_component", None)
        return ts in (0, self.sysid) and tc in (0, self.component)

    def heartbeat(self) -> bytes:
        return self.mav.heartbeat_encode(M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                         M.MAV_STATE_ACTIVE).pack(self.mav)

    def information(self) -> Any:
        s = self.stream
        return self.mav.camera_information_encode(
            int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF, b"SkyNet".ljust(32, b"\0"),
            b"edge camera".ljust(32, b"\0"), 0, 0.0, 0.0, 0.0,
            s.width, s.height, 0, M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM, 0, b"")

    def stream_information(self) -> Any:
        s = self.stream
        enc = M.VIDEO_STREAM_ENCODING_H264 if s.codec == "h264" else M.VIDEO_STREAM_ENCODING_UNKNOWN
        return self.mav.video_stream_information_encode(
            _STREAM_ID, 1, M.VIDEO_STREAM_TYPE_RTPUDP, M.VIDEO_STREAM_STATUS_FLAGS_RUNNING, s.framerate,
            s.width, s.height, s.bitrate, 0, int(round(s.hfov_deg)), s.name.encode(), s.uri.encode(), enc)

    def stream_status(self) -> Any:
        s = self.stream
        return self.mav.video_stream_status_encode(
            _STREAM_ID, M.VIDEO_STREAM_STATUS_FLAGS_RUNNING, s.framerate, s.width, s.height, s.bitrate, 0,
            int(round(s.hfov_deg)))

    def _ack(self, msg: Any, result: int) -> Any:
        return self.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def handle(self, msg: Any) -> list[bytes]:
        """The frames answering one ground-station message (empty: not a request for this camera)."""
        if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT") or not self.addressed(msg):
            return []
        cmd = int(msg.command)
        wanted: Any = None
        stream_arg = None
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            what = int(msg.param1) if math.isfinite(msg.param1) else -1
            if what == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
                wanted = self.information
            elif what == M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION:
                wanted, stream_arg = self.stream_information, msg.param2
            elif what == M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS:
                wanted, stream_arg = self.stream_status, msg.param2
        elif cmd == M.MAV_CMD_REQUEST_CAMERA_INFORMATION:
            wanted = self.information
        elif cmd == M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION:
            wanted, stream_arg = self.stream_information, msg.param1
        elif cmd == M.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS:
            wanted, stream_arg = self.stream_status, msg.param1
        if wanted is None:
            if msg.target_component == self.component:
                self.refused += 1
                return [self._ack(msg, M.MAV_RESULT_UNSUPPORTED).pack(self.mav)]
            return []  # a broadcast command for someone else (the autopilot answers it)
        if stream_arg is not None and not (math.isfinite(stream_arg) and int(stream_arg) in (0, _STREAM_ID)):
            self.refused += 1
            return [self._ack(msg, M.MAV_RESULT_DENIED).pack(self.mav)]
        self.answered += 1
        return [self._ack(msg, M.MAV_RESULT_ACCEPTED).pack(self.mav), wanted().pack(self.mav)]
