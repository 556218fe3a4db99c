"""Tests of the footprint measurements (hand-made arrays, known answers)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.camera import Camera
from stages._footprint import (
    _hinge_slope,
    bound_footprint_slope,
    face_rows,
    footprint_dimensions,
    footprint_disparity,
    ground_disparity_slope,
    ground_fringe_keep,
    too_dark_to_match,
    widest_row_width_m,
)
from stages._ground import GroundFrame, fit_disparity_surface, pixel_points

# the built-in archives' camera
CAMERA = Camera(focal_px=430.0, baseline_m=0.1, height_m=1.2, pitch_deg=40.0)
SHAPE = (500, 500)


def test_widest_row_width():
    mask = np.tri(9, 9, dtype=bool)  # row r spans r + 1 pixels
    rows, cols = np.nonzero(mask)
    depth = np.full(rows.shape, 2.0)
    assert widest_row_width_m(rows, cols, depth, focal_px=100.0, fallback_z=2.0) == pytest.approx(
        9 * 2.0 / 100.0
    )
    # a nearer widest row loses to a farther narrower row
    depth = np.where(rows == 8, 1.0, 2.0)
    expected = max(9 * 1.0, 8 * 2.0) / 100.0
    assert widest_row_width_m(rows, cols, depth, focal_px=100.0, fallback_z=2.0) == pytest.approx(
        expected
    )
    # rows without valid depth use the fallback depth
    depth = np.where(rows == 8, np.nan, 1.0)
    assert widest_row_width_m(rows, cols, depth, focal_px=100.0, fallback_z=3.0) == pytest.approx(
        9 * 3.0 / 100.0
    )


def test_footprint_dimensions_of_a_rotated_rectangle():
    # a filled 0.30 x 0.10 m rectangle of points, long side at 30 degrees
    u, v = np.meshgrid(np.linspace(-0.15, 0.15, 61), np.linspace(-0.05, 0.05, 21))
    angle = math.radians(30.0)
    x = 1.0 + u * math.cos(angle) - v * math.sin(angle)
    y = 2.0 + u * math.sin(angle) + v * math.cos(angle)
    width, length = footprint_dimensions(x.ravel(), y.ravel(), pixel_m=0.005)
    # the largest horizontal dimension of a rectangle is its diagonal (as in the synth truth);
    # across it, the rectangle spans 2 * area / diagonal
    diagonal = math.hypot(0.30, 0.10)
    assert width == pytest.approx(diagonal + 0.005, rel=0.01)
    assert length == pytest.approx(2 * 0.30 * 0.10 / diagonal + 0.005, rel=0.03)


def test_footprint_dimensions_drop_far_outliers():
    u, v = np.meshgrid(np.linspace(0, 0.1, 11), np.linspace(0, 0.1, 11))
    x, y = u.ravel(), v.ravel()
    clean = footprint_dimensions(x, y, pixel_m=0.01)
    x_out, y_out = np.r_[x, 0.05], np.r_[y, 3.0]  # a ground point far behind the rock
    assert footprint_dimensions(x_out, y_out, pixel_m=0.01) == pytest.approx(clean)
    assert all(math.isnan(v) for v in footprint_dimensions([1.0], [2.0], pixel_m=0.01))


def _flat_patch(rows: slice, cols: slice):
    """Pixels of a patch lying on the ground, with their exact disparities."""
    rr, cc = np.mgrid[rows, cols]
    rr, cc = rr.ravel(), cc.ravel()
    ground = GroundFrame.from_camera(CAMERA)
    rays = pixel_points(rr, cc, np.full(rr.shape, CAMERA.k_m_px), camera=CAMERA, shape=SHAPE)
    depth = float(ground.origin @ ground.up) / (rays @ ground.up)  # where the ray meets z = 0
    return rr, cc, CAMERA.k_m_px / depth, ground


def _footprint_width(rows, cols, surface, ground) -> float:
    points = ground.to_ground(pixel_points(rows, cols, surface, camera=CAMERA, shape=SHAPE))
    pixel_m = CAMERA.k_m_px / float(np.median(surface)) / CAMERA.focal_px
    return footprint_dimensions(points[:, 0], points[:, 1], pixel_m=pixel_m)[0]


def test_footprint_disparity_of_a_far_rock_tilted_across_columns():
    # regression (describe v5): a small rock 4 m away whose measured disparity tilts by 0.6 px
    # across its 12 columns (the matching windows take the ground's disparity on one side)
    # got a plane tilted across the view: a diagonal streak on the ground twice its width
    rows, cols, exact, ground = _flat_patch(slice(60, 66), slice(240, 252))
    true_width = _footprint_width(rows, cols, exact, ground)
    assert 0.12 < true_width < 0.25  # 12 pixels about 4 m away
    rng = np.random.default_rng(5)
    measured = exact + 0.05 * (cols - 246) + rng.normal(0, 0.05, exact.shape)
    tilted = fit_disparity_surface(rows, cols, measured, min_quadratic=500)
    assert _footprint_width(rows, cols, tilted, ground) > 2 * true_width
    along_rows = footprint_disparity(rows, cols, measured)
    assert _footprint_width(rows, cols, along_rows, ground) == pytest.approx(true_width, rel=0.15)


def test_footprint_disparity_is_constant_along_rows_and_follows_them():
    # a near patch: its disparity changes from row to row by far more than the noise
    rows, cols, exact, _ = _flat_patch(slice(400, 440), slice(200, 240))
    fitted = footprint_disparity(rows, cols, exact + 0.2 * np.sin(cols))
    per_row = fitted.reshape(40, 40)
    np.testing.assert_allclose(np.ptp(per_row, axis=1), 0.0, atol=1e-9)
    np.testing.assert_allclose(per_row[:, 0], exact.reshape(40, 40).mean(axis=1), atol=0.02)


def _rock_and_shadow(rock_h: float = 0.03):
    """A 10x30 object: a raised rock in columns 0-14, a ground-level shadow in 15-29."""
    mask = np.zeros((12, 32), dtype=bool)
    mask[1:11, 1:31] = True
    heights = np.zeros(mask.shape)
    heights[1:11, 1:16] = rock_h
    return mask, heights[mask]


def test_ground_fringe_keep_drops_a_shadow_but_not_the_rim():
    mask, heights = _rock_and_shadow()
    keep = ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=3)
    cols = np.nonzero(mask)[1]
    # the rock (columns 1-15) and 3 px of the shadow next to it stay: the rock's own low
    # rim would lie there; the far shadow goes
    assert keep[cols <= 18].all() and not keep[cols > 18].any()
    # unknown heights count as raised: nothing next to them is dropped
    heights[cols > 18] = np.nan
    assert ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=3).all()


def test_ground_fringe_keep_keeps_all_when_heights_cannot_tell():
    mask, heights = _rock_and_shadow(rock_h=0.002)  # nothing stands above 4 mm: flat
    assert ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=3).all()
    mask, heights = _rock_and_shadow()
    heights[np.nonzero(mask)[1] < 12] = 0.0  # a 4-column raised strip: most would go
    assert ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=0).all()
    assert ground_fringe_keep(mask, heights, min_height_m=0.0, reach_px=3).all()  # off


def test_ground_fringe_keep_validates():
    mask, heights = _rock_and_shadow()
    with pytest.raises(ValueError, match="one value per mask pixel"):
        ground_fringe_keep(mask, heights[:-1], min_height_m=0.004, reach_px=3)
    with pytest.raises(ValueError, match=">= 0"):
        ground_fringe_keep(mask, heights, min_height_m=-0.1, reach_px=3)


def test_ground_fringe_keep_smoothing_drops_a_noisy_shadow():
    # stereo heights scatter by ~8 mm on mojave's ground: one by one, about a third of a
    # flat shadow's pixels stand above 4 mm and keep the shadow within reach of them
    mask, heights = _rock_and_shadow()
    cols = np.nonzero(mask)[1]
    noisy = heights + np.random.default_rng(0).normal(0.0, 0.008, heights.size)
    alone = ground_fringe_keep(mask, noisy, min_height_m=0.004, reach_px=3)
    smoothed = ground_fringe_keep(mask, noisy, min_height_m=0.004, reach_px=3, smoothing_px=7)
    assert alone[cols > 22].mean() > 0.5  # pixel by pixel the far shadow mostly stays
    assert smoothed[cols <= 15].all()  # the rock stays
    # the far shadow goes; within half a box of the rock the mean is raised, so a noisy
    # pixel there may still stand (noise-free heights keep exactly reach_px, see below)
    assert not smoothed[cols > 15 + 3 + 7 // 2].any()
    assert np.array_equal(
        ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=3, smoothing_px=7),
        ground_fringe_keep(mask, heights, min_height_m=0.004, reach_px=3),
    )
    # unknown heights stay unknown (kept), and smoothing 1 is the pixel-by-pixel rule
    with_nan = noisy.copy()
    with_nan[cols > 27] = np.nan
    assert ground_fringe_keep(mask, with_nan, min_height_m=0.004, reach_px=3, smoothing_px=7)[
        cols > 27
    ].all()
    assert np.array_equal(
        ground_fringe_keep(mask, noisy, min_height_m=0.004, reach_px=3, smoothing_px=1), alone
    )
    with pytest.raises(ValueError, match="odd number"):
        ground_fringe_keep(mask, noisy, min_height_m=0.004, reach_px=3, smoothing_px=4)


def test_too_dark_to_match():
    gray = np.array([0, 10, 23, 24, 70, 200], dtype=np.uint8)
    assert too_dark_to_match(gray, ground_gray=160.0, dark_ratio=0.15).tolist() == [
        True, True, True, False, False, False,
    ]  # fmt: skip
    # no ground ring (NaN) or ratio 0: no pixel is too dark
    assert not too_dark_to_match(gray, ground_gray=math.nan, dark_ratio=0.15).any()
    assert not too_dark_to_match(gray, ground_gray=160.0, dark_ratio=0.0).any()
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        too_dark_to_match(gray, ground_gray=160.0, dark_ratio=1.0)


def test_black_rock_whose_lower_half_reads_ground_keeps_it_when_too_dark_to_match():
    # Regression (lab): a black rock gives the matcher no texture, its lower half takes the
    # floor's disparity and reads ground level, and the fringe rule cut it off as a shadow;
    # the widest rows of the rock went with it (widths ~5 % short, rocks of 0.10-0.12 m
    # classed as samples). A cast shadow (0.44 of the floor's gray) must still go.
    mask = np.zeros((20, 32), dtype=bool)
    mask[1:19, 1:31] = True
    heights = np.zeros(mask.shape)
    gray = np.full(mask.shape, 160.0)
    heights[1:11, 1:21] = 0.03  # the rock's upper part: measured
    gray[1:19, 1:21] = 20.0  # the whole rock is near-black: 0.125 of the floor's 160
    gray[1:19, 21:31] = 70.0  # its cast shadow beside it, at ground level
    h, g = heights[mask], gray[mask]
    cols, rows = np.nonzero(mask)[1], np.nonzero(mask)[0]
    rock_low = (cols < 21) & (rows > 13)  # farther than reach from the measured part
    plain = ground_fringe_keep(mask, h, min_height_m=0.004, reach_px=3, smoothing_px=7)
    assert not plain[rock_low].any()  # the bug: the rock's lower half is dropped
    dark = too_dark_to_match(g, ground_gray=160.0, dark_ratio=0.15)
    assert dark[cols < 21].all() and not dark[cols >= 21].any()
    fixed = ground_fringe_keep(
        mask, np.where(dark, np.nan, h), min_height_m=0.004, reach_px=3, smoothing_px=7
    )
    assert fixed[cols < 21].all()
    assert not fixed[cols >= 21 + 3 + 7 // 2].any()  # the shadow's far part still goes


def _project(ground: GroundFrame, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Row, column and disparity of the ground-frame point (x, y, z) in CAMERA's image."""
    point = ground.origin + x * ground.right + y * ground.forward + z * ground.up
    cx, cy = CAMERA.principal_point(SHAPE)
    return (
        CAMERA.focal_px * point[1] / point[2] + cy,
        CAMERA.focal_px * point[0] / point[2] + cx,
        CAMERA.k_m_px / point[2],
    )


def test_ground_disparity_slope_is_the_ground_planes_change_per_row():
    rows, _, exact, ground = _flat_patch(slice(100, 400), slice(250, 251))
    slope = ground_disparity_slope(ground, CAMERA)
    assert slope > 0  # the ground comes nearer down the image
    np.testing.assert_allclose(np.diff(exact), slope, rtol=1e-9)


def test_face_rows_of_a_vertical_face():
    ground = GroundFrame.from_camera(CAMERA)
    foot_row, foot_col, foot_d = _project(ground, 0.2, 3.0, 0.0)
    top_row, _, _ = _project(ground, 0.2, 3.0, 0.15)
    mid_row, mid_col, mid_d = _project(ground, 0.2, 3.0, 0.075)
    # from any point of the face: it stands on the ground under that point
    for row, col, d in ((foot_row, foot_col, foot_d), (mid_row, mid_col, mid_d)):
        got = face_rows(row, col, d, 0.15, camera=CAMERA, ground=ground, shape=SHAPE)
        assert got == pytest.approx(foot_row - top_row, rel=1e-6)
    for height, d in ((0.0, mid_d), (0.1, math.nan)):
        got = face_rows(mid_row, mid_col, d, height, camera=CAMERA, ground=ground, shape=SHAPE)
        assert got == 0.0


def _far_face(distance_m: float = 3.8, width_m: float = 0.35, height_m: float = 0.17):
    """Pixels of a vertical face ``width_m`` x ``height_m`` standing ``distance_m`` ahead,
    their exact disparities and the ground's disparities at the same pixels."""
    ground = GroundFrame.from_camera(CAMERA)
    top, left, _ = _project(ground, -width_m / 2, distance_m, height_m)
    foot, right, _ = _project(ground, width_m / 2, distance_m, 0.0)
    rr, cc = np.mgrid[
        math.ceil(top) : math.floor(foot) + 1, math.ceil(left) : math.floor(right) + 1
    ]
    rows, cols = rr.ravel(), cc.ravel()
    rays = pixel_points(rows, cols, np.full(rows.shape, CAMERA.k_m_px), camera=CAMERA, shape=SHAPE)
    # the face: the plane forward . (X - origin) = distance_m; the ground: up . X = up . origin
    on_face = (distance_m + ground.forward @ ground.origin) / (rays @ ground.forward)
    on_ground = float(ground.origin @ ground.up) / (rays @ ground.up)
    return rows, cols, CAMERA.k_m_px / on_face, CAMERA.k_m_px / on_ground, ground


def test_a_far_face_read_as_ground_keeps_its_width():
    # regression (lab_0000 object 2, a black rock 3.8 m away, 0.535 m wide against the
    # truth's 0.368): the matching windows give a face at one depth the floor's disparity
    # around it, the row fit follows the ground's slope, the upper rows land far behind
    # and the footprint's largest spread runs along the line of sight
    rows, cols, exact, floor, ground = _far_face()
    true_width = _footprint_width(rows, cols, exact, ground)
    assert true_width == pytest.approx(0.35, rel=0.1)
    fitted = footprint_disparity(rows, cols, floor)
    assert _footprint_width(rows, cols, fitted, ground) > 1.3 * true_width
    face_px = face_rows(
        float(np.median(rows)),
        float(np.median(cols)),
        float(np.median(fitted)),
        0.17,
        camera=CAMERA,
        ground=ground,
        shape=SHAPE,
    )
    assert face_px / (np.ptp(rows) + 1) > 0.7  # seen from the side: nearly all face
    bounded = bound_footprint_slope(
        rows,
        cols,
        fitted,
        ground_slope_px=ground_disparity_slope(ground, CAMERA),
        face_px=face_px,
        focal_px=CAMERA.focal_px,
    )
    # twice as wide -> a little wider (the middle row's level is the floor's, behind the face)
    assert _footprint_width(rows, cols, bounded, ground) == pytest.approx(true_width, rel=0.15)
    # the level at the middle row stays
    middle = rows == (rows.min() + rows.max()) // 2
    np.testing.assert_allclose(bounded[middle], fitted[middle], atol=0.05)


def test_a_rock_seen_from_above_keeps_its_fitted_slope():
    # the top shows over most of the rows and the footprint is no longer than wide: the
    # fit measures the rock's depth
    rows, cols, exact, ground = _flat_patch(slice(400, 440), slice(200, 240))
    slope = ground_disparity_slope(ground, CAMERA)
    kw = {"ground_slope_px": slope, "focal_px": CAMERA.focal_px}
    kept = bound_footprint_slope(rows, cols, exact, face_px=10.0, **kw)
    np.testing.assert_array_equal(kept, exact)
    # all face: the slope goes, the level at the middle row stays
    flat = bound_footprint_slope(rows, cols, exact, face_px=40.0, **kw)
    np.testing.assert_allclose(np.ptp(flat), 0.0, atol=1e-9)
    # the same rows on 2 columns read far longer along the line of sight than across:
    # bounded by a profile a quarter face, three quarters top
    narrow = cols < 202
    along = bound_footprint_slope(rows[narrow], cols[narrow], exact[narrow], face_px=10.0, **kw)
    per_row = np.diff(along.reshape(40, 2)[:, 0])
    np.testing.assert_allclose(per_row, slope * _hinge_slope(0.25), rtol=1e-6)
    assert 0.7 * slope < per_row[0] < 0.9 * slope
    with pytest.raises(ValueError, match="min_face_share"):
        bound_footprint_slope(rows, cols, exact, face_px=1.0, min_face_share=2, **kw)


def test_dilate_diamond_reaches_city_block_distance_with_its_cached_kernel():
    from scipy import ndimage

    from stages._footprint import _dilate_diamond

    mask = np.zeros((15, 17), dtype=bool)
    mask[7, 8] = mask[2, 3] = True
    distance = ndimage.distance_transform_cdt(~mask, metric="taxicab")
    for radius in (1, 3, 1, 3):  # the second call of a radius reads the cached kernel
        assert np.array_equal(_dilate_diamond(mask, radius), distance <= radius)
