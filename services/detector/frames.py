"""The captures the detector keeps (``--save-frames``): each analysed frame with its pose.

Design notes: docs/detector.md (services/detector/frames.py).
"""

from __future__ import annotations

from pathlib import Path

from protocol.messages import ImageMeta

__all__ = ["save_frame"]


def save_frame(folder: str | Path, meta: ImageMeta, image: bytes) -> Path:
    """Write one capture as ``uav<N>-<capture>.jpg|png`` with its pose file (the folder format above)."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    stem = f"uav{meta.uav}-{meta.capture_id:05d}"
    ext = ".png" if meta.encoding == "png" else ".jpg"
    (d / f"{stem}{ext}").write_bytes(bytes(image))
    (d / f"{stem}.json").write_text(meta.model_dump_json())
    return d / f"{stem}{ext}"
