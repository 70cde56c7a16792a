"""services.gcs.surface: the ground station's own look at a capture frame, judged as the detector judges it."""

from __future__ import annotations


def test_the_ground_stations_look_decodes_as_the_detector_does():
    import numpy as np

    from services.gcs.surface import surface_problem
    from services.inspection.captures import capture_meta

    meta = capture_meta(1, 0, np.zeros(3), np.eye(3), (640, 480), 500.0, 500.0, 320.0, 240.0, 5.0)
    assert surface_problem(meta, b"\xff\xd8 nothing") == "does not decode: cannot decode a truncated JPEG: no end-of-image marker"
    from protocol.imagecodec import encode_jpeg

    assert surface_problem(meta, encode_jpeg(np.full((480, 640), 255, np.uint8))).startswith("over-exposed")
    assert surface_problem(meta, encode_jpeg(np.zeros((240, 320), np.uint8))) == (
        "does not decode: the JPEG is 320 x 240 px, its metadata says 640 x 480")
