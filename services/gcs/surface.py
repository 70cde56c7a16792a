"""The ground station's own look at each capture frame it receives: does it show a surface at all?

Apart from services/gcs/evidence.py so that what only counts reports (the launcher, the report) loads no OpenCV.
Design notes: docs/report.md (services/gcs/evidence.py).
"""

from __future__ import annotations

from protocol.imagecodec import decode_image
from protocol.messages import ImageMeta
from services.detector.exposure import exposure_problem, judged_reduction

__all__ = ["surface_problem"]


def surface_problem(meta: ImageMeta, image: bytes | memoryview) -> str | None:
    """The ground station's own look at a capture it received: why its image shows no surface
    (:func:`~services.detector.exposure.exposure_problem`, which judges every frame at one resolution, as the
    detector does whatever it decodes at; or why it does not decode), or None. A detector's ok report on such a
    frame does not count."""
    k = meta.intrinsics
    try:
        grey = decode_image(image, grey=True, reduce=judged_reduction(k.width, k.height), size=(k.width, k.height))
    except ValueError as exc:
        return f"does not decode: {exc}"
    return exposure_problem(grey)
