"""A MAVLink endpoint for the operator's ground station on the edge: the autopilot's traffic, forwarded.

Design notes: docs/hardware-mavlink.md (edge/vehicle/gcs_bridge.py).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.mav_camera import MavCamera, VideoStreamSpec

__all__ = ["GcsBridge"]


class GcsBridge:
    """Forward frames between the autopilot link (``to_autopilot`` writes one raw frame) and a ground-station
    ``endpoint`` (``udpout:HOST:PORT`` to reach a listening GCS, ``udpin:HOST:PORT`` to be dialled), with a
    camera component announcing ``video`` unless None."""

    def __init__(self, endpoint: str, to_autopilot: Callable[[bytes], None], video: VideoStreamSpec | None = None):
        from edge.vehicle.mavlink import open_connection  # the same codec (and signing) as the driver's link

        self.endpoint = endpoint
        self._conn = open_connection(endpoint, 0, 0)
        self._to_autopilot = to_autopilot
        self.to_gcs_count = 0
        self.from_gcs_count = 0
        self.dropped = 0
        self.video = video
        #: the camera component (created when the autopilot's system id is known)
        self.camera: MavCamera | None = None
        self._camera_beat = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="mavlink-gcs-bridge", daemon=True)
        self._thread.start()

    def to_gcs(self, msg: Any) -> None:
        """Forward one message received from the autopilot (its raw frame)."""
        buf = msg.get_msgbuf() if msg.get_type() != "BAD_DATA" else None
        if not buf:
            return
        if self.video is not None and self.camera is None and msg.get_type() == "HEARTBEAT" \
                and msg.autopilot != M.MAV_AUTOPILOT_INVALID and 1 <= msg.get_srcSystem() <= 255:
            self.camera = MavCamera(self.video, msg.get_srcSystem())
        try:
            self._conn.write(bytes(buf))
            self.to_gcs_count += 1
        except OSError:
            self.dropped += 1

    def _to_gcs_frames(self, frames: list[bytes]) -> None:
        for f in frames:
            try:
                self._conn.write(f)
            except OSError:
                self.dropped += 1

    def _loop(self) -> None:
        while not self._stop.is_set():
            cam = self.camera
            if cam is not None and time.monotonic() - self._camera_beat >= 1.0:
                self._camera_beat = time.monotonic()
                self._to_gcs_frames([cam.heartbeat()])
            try:
                msg = self._conn.recv_msg()
            except Exception:  # noqa: BLE001 - a bad datagram or a closed socket
                if self._stop.is_set():
                    break
                self.dropped += 1
                continue
            if msg is None:
                self._conn.select(0.02)
                continue
            if msg.get_type() == "BAD_DATA":
                self.dropped += 1
                continue
            if cam is not None:
                self._to_gcs_frames(cam.handle(msg))
                if getattr(msg, "target_component", None) == cam.component:
                    continue  # the camera's own business
            try:
                self._to_autopilot(bytes(msg.get_msgbuf()))
                self.from_gcs_count += 1
            except OSError:
                self.dropped += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        with contextlib.suppress(OSError):
            self._conn.close()
