import numpy as np
import pytest

from edge.surface import SyntheticSurface, crack_image, draw_cracks, textured_background

CORNERS = [[60, 85, 25.5], [60, 35, 25.5], [60, 35, 31.5], [60, 85, 31.5]]


def test_generators_are_deterministic_and_cracks_are_darker():
    a = crack_image((120, 160), rng=4)
    b = crack_image((120, 160), rng=4)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    grey, mask = a
    assert grey.dtype == np.uint8 and mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
    assert grey[mask > 0].mean() < grey[mask == 0].mean() - 20
    assert textured_background((30, 40), rng=1).shape == (30, 40)
    assert not draw_cracks((50, 50), rng=1, n_cracks=0).any()


@pytest.mark.parametrize("bad", [(0, 10), (10, -1), "x", (1.5, 3)])
def test_bad_shapes_are_refused(bad):
    with pytest.raises(ValueError):
        textured_background(bad, rng=0)


def test_surface_geometry_round_trips():
    s = SyntheticSurface.from_corners(CORNERS, px_per_m=50, seed=1)
    assert s.texture.shape == (300, 2500)
    assert np.allclose(s.normal, [-1, 0, 0])  # faces west, where the formation flies
    uv = np.array([[0.0, 0.0], [50.0, 6.0], [12.5, 3.0]])
    world = s.surface_to_world(uv)
    assert np.allclose(world[0], CORNERS[0]) and np.allclose(world[1], CORNERS[2])
    assert np.allclose(s.world_to_surface(world), uv)
    # a point off the plane projects onto it
    assert np.allclose(s.world_to_surface([[55.0, 60.0, 28.0]]), [[25.0, 2.5]])
    A = s.pixel_to_world_matrix()
    for col, row in [(0, 0), (2499, 299), (1250, 150)]:
        px = s.surface_to_pixel(s.world_to_surface((A @ [col, row, 1.0])[None]))[0]
        assert np.allclose(px, [col, row])


def test_ground_truth_defects_match_the_mask():
    s = SyntheticSurface.from_corners(CORNERS, px_per_m=50, seed=3)
    defects = s.defects()
    assert defects and all(0 <= d.centroid_uv[0] <= 50 and 0 <= d.centroid_uv[1] <= 6 for d in defects)
    for d in defects:
        u0, v0, u1, v1 = d.bbox_uv
        assert u0 <= d.centroid_uv[0] <= u1 and v0 <= d.centroid_uv[1] <= v1
        c, r = s.surface_to_pixel([d.centroid_uv])[0]
        assert np.isclose(d.centroid_world[0], 60.0)
    assert sum(d.area_px for d in defects) <= int((s.mask > 0).sum())


def test_bad_corners_are_refused():
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0], [1, 0, 0], [1, 1, 1]])
    with pytest.raises(ValueError):
        SyntheticSurface.from_corners([[0, 0, 0], [10, 0, 0], [11, 0, 3], [1, 0, 3]])  # not a rectangle
