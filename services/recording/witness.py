"""The capture frames the ground station received itself: what a detector's report is checked against.

Design notes: docs/recording.md (services/recording/witness.py).
"""

from __future__ import annotations

import hashlib
import threading
from enum import StrEnum

from protocol import keys
from protocol.imagery import unpack_image
from protocol.messages import DefectReport
from protocol.rtp import parse_ssrc

__all__ = ["CAPTURE_CAMERA", "MAX_FRAMES", "FrameWitness", "Seen"]

#: the camera whose frames are captures (edge.camera_service: previews use camera 1)
CAPTURE_CAMERA = 0
#: frames witnessed at most (~200 bytes each); beyond, further frames are counted, not kept
MAX_FRAMES = 65_536


class Seen(StrEnum):
    """What the ground station holds of the frame a report names."""

    HELD = "held"  # that frame, those image bytes, that capture
    NOT_RECEIVED = "not-received"  # no frame of that camera with that sequence number
    DIFFERENT = "different"  # a frame with that sequence number, but other image bytes or another capture
    NO_EVIDENCE = "no-evidence"  # the report names no frame of its UAV's capture camera


class FrameWitness:
    """Capture frames by RTP SSRC and sequence number (RFC 3550 5.1), with the SHA-256 of their image bytes and
    their capture id, as :class:`~protocol.messages.FrameEvidence` names them. Thread-safe; bounded."""

    def __init__(self, max_frames: int = MAX_FRAMES) -> None:
        self.max_frames = max_frames
        self.not_kept = 0  # frames over the bound: a report naming one reads as not received
        self._frames: dict[tuple[int, int], set[tuple[str, int]]] = {}
        self._held = 0
        self._lock = threading.Lock()

    def add_sample(self, key: str, data: bytes | memoryview) -> bool:
        """Witness one sample of a camera key; False (nothing kept) unless it is an image frame of the capture
        camera of the UAV whose key carried it (a UAV writes only its own keys)."""
        try:
            header, meta, image = unpack_image(data)
            uav, camera = parse_ssrc(header.ssrc)
            key_uav = keys.parse(key).uav
        except ValueError:
            return False
        if uav != key_uav or meta.uav != uav or camera != CAPTURE_CAMERA or not len(image):
            return False
        self.add(header.ssrc, header.sequence, hashlib.sha256(image).hexdigest(), meta.capture_id)
        return True

    def add(self, ssrc: int, sequence: int, digest: str, capture_id: int) -> None:
        with self._lock:
            held = self._frames.get((ssrc, sequence))
            if held is not None and (digest, capture_id) in held:
                return
            if self._held >= self.max_frames:
                self.not_kept += 1
                return
            self._frames.setdefault((ssrc, sequence), set()).add((digest, capture_id))
            self._held += 1

    def __len__(self) -> int:
        return self._held

    def seen(self, report: DefectReport) -> Seen:
        """Whether the frame ``report`` names is one this ground station received, as named."""
        ev = report.frame
        try:
            if ev is None or parse_ssrc(ev.ssrc) != (report.uav, CAPTURE_CAMERA):
                return Seen.NO_EVIDENCE
        except ValueError:
            return Seen.NO_EVIDENCE
        with self._lock:
            held = self._frames.get((ev.ssrc, ev.seq))
            if held is None:
                return Seen.NOT_RECEIVED
            return Seen.HELD if (ev.digest, report.capture_id) in held else Seen.DIFFERENT
