"""The capture frames the ground station received itself: what a detector's report is checked against.

Design notes: docs/recording.md (services/recording/witness.py).
"""

from __future__ import annotations

import hashlib
import threading
from collections import Counter
from collections.abc import Callable
from enum import StrEnum

from protocol.binding import frame_source
from protocol.imagery import unpack_image
from protocol.messages import FrameEvidence, ImageMeta

__all__ = ["CAPTURE_CAMERA", "MAX_FRAMES_PER_CAMERA", "FrameWitness", "Seen", "SurfaceCheck"]

#: the camera whose frames are captures (edge.camera_service: previews use camera 1)
CAPTURE_CAMERA = 0
#: frames witnessed per camera at most (~200 bytes each; a mission takes dozens of captures a UAV); beyond,
#: that camera's further frames are counted, not kept, so one camera's flood cannot crowd out another's
MAX_FRAMES_PER_CAMERA = 4096


class Seen(StrEnum):
    """What the ground station holds of the frame a report names."""

    HELD = "held"  # that frame, those image bytes, that capture
    NOT_RECEIVED = "not-received"  # no frame of that camera with that sequence number
    DIFFERENT = "different"  # a frame with that sequence number, but other image bytes or another capture
    NO_SURFACE = "no-surface"  # that frame, but the ground station's own look at it finds no surface in it


#: what a frame's image shows no surface for (black, white, blank), or None: the ground station's own check of
#: a frame a detector may call fine (services.gcs.surface.surface_problem)
SurfaceCheck = Callable[[ImageMeta, bytes | memoryview], str | None]


class FrameWitness:
    """Capture frames by RTP SSRC and sequence number (RFC 3550 5.1), with the SHA-256 of their image bytes and
    their capture id, as :class:`~protocol.messages.FrameEvidence` names them, and with ``surface_check`` whether
    each shows a surface at all. Thread-safe; bounded per camera."""

    def __init__(self, max_per_camera: int = MAX_FRAMES_PER_CAMERA, surface_check: SurfaceCheck | None = None) -> None:
        self.max_per_camera = max_per_camera
        self.surface_check = surface_check
        #: the frames kept that show no surface: (SSRC, sequence, digest, capture id) -> why
        self.no_surface: dict[tuple[int, int, str, int], str] = {}
        self.not_kept: Counter[int] = Counter()  # SSRC -> frames over its bound (a report naming one: not received)
        self._frames: dict[tuple[int, int], set[tuple[str, int]]] = {}
        self._held: Counter[int] = Counter()  # SSRC -> frames kept
        self._lock = threading.Lock()

    def add_sample(self, key: str, data: bytes | memoryview) -> bool:
        """Witness one sample of a camera key; False (nothing kept) unless it is an image frame of the capture
        camera of the UAV whose key carried it (:func:`protocol.binding.frame_source`)."""
        try:
            header, meta, image = unpack_image(data)
        except ValueError:
            return False
        src = frame_source(key, header.ssrc)
        if src is None or src != (meta.uav, CAPTURE_CAMERA) or not len(image):
            return False
        digest = hashlib.sha256(image).hexdigest()
        with self._lock:  # kept already, or its camera at its bound: not looked at (add counts the latter)
            if (digest, meta.capture_id) in self._frames.get((header.ssrc, header.sequence), ()):
                return False
            full = self._held[header.ssrc] >= self.max_per_camera
        problem = None if self.surface_check is None or full else self.surface_check(meta, image)
        return self.add(header.ssrc, header.sequence, digest, meta.capture_id, problem)

    def add(self, ssrc: int, sequence: int, digest: str, capture_id: int, no_surface: str | None = None) -> bool:
        """Keep one frame (``no_surface``: why it shows none); False when it was kept already or its camera is at
        its bound (counted)."""
        with self._lock:
            if (digest, capture_id) in self._frames.get((ssrc, sequence), ()):
                return False
            if self._held[ssrc] >= self.max_per_camera:
                self.not_kept[ssrc] += 1
                return False
            self._frames.setdefault((ssrc, sequence), set()).add((digest, capture_id))
            self._held[ssrc] += 1
            if no_surface is not None:
                self.no_surface[(ssrc, sequence, digest, capture_id)] = no_surface
            return True

    def __len__(self) -> int:
        return sum(self._held.values())

    def no_surface_reason(self, frame: FrameEvidence, capture_id: int) -> str | None:
        """Why the frame ``frame`` names shows no surface, when the ground station's own check found so."""
        with self._lock:
            return self.no_surface.get((frame.ssrc, frame.seq, frame.digest, capture_id))

    def seen(self, frame: FrameEvidence, capture_id: int) -> Seen:
        """Whether ``frame``, named as the one of ``capture_id``, is one this ground station received as named."""
        with self._lock:  # (the set may grow while another thread adds to it)
            held = self._frames.get((frame.ssrc, frame.seq))
            if not held:
                return Seen.NOT_RECEIVED
            if (frame.digest, capture_id) not in held:
                return Seen.DIFFERENT
            return Seen.NO_SURFACE if (frame.ssrc, frame.seq, frame.digest, capture_id) in self.no_surface else Seen.HELD
