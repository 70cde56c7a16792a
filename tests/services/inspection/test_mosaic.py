"""services/inspection/mosaic.py: frames placed by their poses, and aligned to each other when a pose is off."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edge.world.wall import synthetic_surface
from protocol.scenario import load_scenario
from services.inspection.captures import decode, synthetic_captures
from services.inspection.mosaic import Plane, PosedFrame, alignment, build_mosaic, moved_camera, solve_shifts


def texture(seed: int = 0, shape: tuple[int, int] = (300, 400)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.normal(128, 40, shape).astype(np.float32), (0, 0), 2).clip(0, 255).astype(np.uint8)


def test_alignment_finds_how_far_a_frames_content_sits_from_the_mosaics():
    tex = texture()
    fixed = tex[50:250, 50:350]
    moving = tex[52:252, 47:347]  # what fixed shows at q, moving shows at q + (3, -2)
    both = np.ones(fixed.shape, bool)
    assert alignment(moving, both, fixed, both, 20)[:2] == pytest.approx((3.0, -2.0), abs=0.1)
    # only where both have pixels: the rest of each side does not pull
    part = both.copy()
    part[:, :150] = False
    assert alignment(moving, part, np.where(part, fixed, 0).astype(np.uint8), part, 20)[:2] == pytest.approx(
        (3.0, -2.0), abs=0.1)


def test_a_large_overlap_is_aligned_at_a_reduced_size(monkeypatch):
    import services.inspection.mosaic as mosaic

    tex = cv2.resize(texture(1), (1600, 1200), interpolation=cv2.INTER_CUBIC)
    fixed, moving = tex[100:1100, 100:1500], tex[108:1108, 88:1488]  # content 12 px right, 8 px up
    both = np.ones(fixed.shape, bool)
    monkeypatch.setattr(mosaic, "ALIGN_MAX_PX", 200_000)  # 1.4 MP: reduced by 3
    assert alignment(moving, both, fixed, both, 40)[:2] == pytest.approx((12.0, -8.0), abs=1.0)


def test_alignment_refuses_a_thin_overlap_a_blank_wall_and_a_shift_beyond_its_limit():
    tex = texture()
    fixed, moving = tex[50:250, 50:350], tex[52:252, 47:347]
    both = np.ones(fixed.shape, bool)
    thin = np.zeros(fixed.shape, bool)
    thin[:, :10] = True
    assert alignment(moving, thin, fixed, thin, 20) is None
    flat = np.full(fixed.shape, 128, np.uint8)
    assert alignment(flat, both, flat, both, 20) is None
    assert alignment(moving, both, fixed, both, 2.0) is None


def test_the_moves_are_solved_together_and_a_pair_that_disagrees_is_dropped():
    truth = np.array([[0.0, 0.0], [4.0, -2.0], [-3.0, 1.0], [1.0, 5.0]])  # each frame's content off by this
    truth -= truth.mean(0)
    pairs = [(a, b, *(truth[b] - truth[a]), 1.0) for a, b in ((0, 1), (1, 2), (2, 3), (0, 2), (1, 3))]
    pairs.append((0, 3, 30.0, -20.0, 1.0))  # a false peak
    c = solve_shifts(4, pairs)
    assert c == pytest.approx(-truth, abs=0.05)  # each moved back by its own error, not the first frame's
    alone = solve_shifts(5, pairs)  # frame 4 is in no pair: it stays put
    assert alone[4] == pytest.approx((0.0, 0.0), abs=1e-6) and alone[:4] == pytest.approx(-truth, abs=0.05)


@pytest.fixture(scope="module")
def wall():
    sc = load_scenario("monorail")
    surf = synthetic_surface(sc)
    frames = [PosedFrame(c.meta, decode(c)) for c in synthetic_captures(sc, surf)]
    return Plane.from_corners(surf.corners), frames


def test_a_frame_off_its_pose_is_put_back_where_the_others_see_its_content(wall):
    plane, frames = wall
    k = len(frames) // 2
    moved = [*frames[:k], PosedFrame(moved_camera(frames[k].meta, plane, 0.05, -0.03), frames[k].grey),  # 5 cm along
             *frames[k + 1:]]                                                                              # 3 cm down
    exact = build_mosaic(frames, plane)
    placed = build_mosaic(moved, plane)
    aligned = build_mosaic(moved, plane, align_m=0.6)
    assert not exact.moved_m and not placed.moved_m and len(aligned.moved_m) == len(frames)
    # the frame moves back by about its error (the others by the mean correction, under a centimetre)
    assert aligned.moved_m[k] == pytest.approx(np.hypot(0.05, 0.03), abs=0.01)
    assert max(m for i, m in enumerate(aligned.moved_m) if i != k) < 0.01
    # its camera, moved as the frame was, is back where it was (what the report's "seen by" uses)
    back = moved_camera(moved[k].meta, plane, *aligned.shifts_m[k]).cam_pos
    assert np.asarray(back) == pytest.approx(np.asarray(frames[k].meta.cam_pos), abs=0.01)
    seen = (exact.owner == k) & (aligned.owner == k)

    def err(m):
        return float(np.mean(np.abs(m.image[seen].astype(int) - exact.image[seen].astype(int))))

    assert err(aligned) < 0.25 * err(placed), (err(aligned), err(placed))


def test_frames_at_their_exact_poses_stay_put(wall):
    plane, frames = wall
    aligned = build_mosaic(frames, plane, align_m=0.6)
    assert max(aligned.moved_m) < 0.002  # under a quarter of a canvas pixel (7.8 mm)
