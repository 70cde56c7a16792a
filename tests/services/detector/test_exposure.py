"""services.detector.exposure: a black, white or featureless frame is named as showing no surface; the frames
the mission and the photographs give are not."""

from __future__ import annotations

import numpy as np
import pytest

from edge.world.surface import textured_background
from services.detector.exposure import MAX_CLIPPED_SHARE, MIN_SPREAD, exposure_problem

RNG = np.random.default_rng(3)


def _noise(mean: float, sd: float, shape=(480, 640)) -> np.ndarray:
    return np.clip(np.round(mean + np.random.default_rng(1).normal(0, sd, shape)), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(("grey", "says"), [
    (np.zeros((480, 640), np.uint8), "under-exposed, 100% of the frame black"),
    (np.full((480, 640), 255, np.uint8), "over-exposed, 100% of the frame white"),
    (np.full((480, 640), 128, np.uint8), "blank, its grey levels within 0 over 98% of the frame"),
    (_noise(4, 1), "blank"),  # a covered lens: the sensor's own noise
    (_noise(230, 1.5), "blank"),  # a smooth sky
])
def test_a_frame_that_shows_nothing_is_named(grey, says):
    assert (exposure_problem(grey) or "").startswith(says)


def test_clipped_beyond_the_share_is_named_below_it_is_not():
    g = textured_background((480, 640), RNG, roughness=6.0)
    part = g.copy()
    part[: int(480 * (MAX_CLIPPED_SHARE - 0.1))] = 0  # a frame over the wall's edge: a band of nothing
    assert exposure_problem(part) is None
    part[: int(480 * (MAX_CLIPPED_SHARE + 0.1))] = 0
    assert exposure_problem(part).startswith("under-exposed, 6")
    white = g.copy()
    white[:, : int(640 * (MAX_CLIPPED_SHARE + 0.1))] = 255
    assert exposure_problem(white).startswith("over-exposed")


def test_faint_texture_is_a_surface():
    """The faintest photographs of the crack data sets span 35 grey levels (docs/detector.md); a wall whose grey
    levels vary by a standard deviation of half the spread's floor still counts."""
    assert exposure_problem(_noise(120, MIN_SPREAD / 2)) is None
    assert exposure_problem(textured_background((480, 640), RNG, roughness=2.0)) is None


def test_the_missions_captures_show_a_surface():
    from edge.world.wall import synthetic_surface
    from protocol.scenario import load_scenario
    from services.inspection.captures import decode, synthetic_captures

    sc = load_scenario()
    caps = synthetic_captures(sc, synthetic_surface(sc))
    assert [exposure_problem(decode(c)) for c in caps] == [None] * len(caps)


def test_a_large_frame_and_odd_input():
    big = np.zeros((3000, 4000), np.uint8)
    big[:, :1000] = _noise(128, 20, (3000, 1000))
    assert exposure_problem(big).startswith("under-exposed, 7")  # 3/4 of it black, measured on a subsample
    assert exposure_problem(np.zeros((0, 5), np.uint8)) == "not a grey image (shape (0, 5))"
    assert exposure_problem(np.zeros((4, 4, 3), np.uint8)).startswith("not a grey image")


@pytest.mark.parametrize("kind", ["wall", "grain", "low-light", "sky-band"])
def test_one_verdict_whatever_the_frame_was_decoded_at(kind):
    """The detector judges its reduced decode, the report the full frame, the ground station its own decode: the
    frame is judged at one resolution, so they agree (a frame of fine grain read blank at 1/4 and fine at 1/1)."""
    from protocol.imagecodec import decode_image, encode_jpeg
    from services.detector.exposure import judged_reduction

    rng = np.random.default_rng(5)
    shape = (1500, 2000)
    if kind == "wall":
        g = textured_background(shape, rng, roughness=6.0)
    elif kind == "grain":
        g = _noise(120, 4, shape)
    elif kind == "low-light":
        g = _noise(5, 4, shape)
    else:  # 40 % sky above a wall
        g = textured_background(shape, rng, roughness=6.0)
        g[: int(0.4 * shape[0])] = 255
    jpeg = encode_jpeg(g, 90)
    verdicts = {f: exposure_problem(decode_image(jpeg, grey=True, reduce=f)) for f in (1, 2, 4, 8)}
    assert len({v is None for v in verdicts.values()}) == 1, verdicts
    assert judged_reduction(2000, 1500) == 4 and judged_reduction(640, 480) == 1 and judged_reduction(4000, 3000) == 8
