"""Geometry of the depth stage: range, pseudo-left, ground plane, search range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from pipeline.camera import Camera
from stages import geometry
from stages.geometry import (
    derive_max_disparity,
    derive_row_ceiling,
    derive_row_floor,
    disparity_from_range,
    fit_ground_plane,
    ground_disparity_at_row,
    height_above_plane,
    height_from_disparity,
    plane_disparity_coefficients,
    plane_from_disparity_coefficients,
    plane_from_pose,
    pseudo_left,
    range_from_disparity,
    residual,
)

CAMERA = Camera(focal_px=100.0, baseline_m=0.1, height_m=1.2, pitch_deg=38.0)
SHAPE = (80, 100)


def _ground_disparity(camera: Camera, shape=SHAPE) -> np.ndarray:
    """True disparity of the ground plane of ``camera``'s pose (NaN above the horizon)."""
    assert camera.height_m is not None and camera.pitch_deg is not None
    plane = plane_from_pose(height_m=camera.height_m, pitch_deg=camera.pitch_deg)
    a, b, c = plane_disparity_coefficients(plane, camera=camera, shape=shape)
    ys, xs = np.indices(shape, dtype=float)
    d = a * xs + b * ys + c
    return np.where(d > 0, d, np.nan).astype(np.float32)


def test_range_is_f_times_b_over_d():
    d = np.array([[1.0, 2.0, 4.0], [np.nan, 0.0, -1.0]], np.float32)
    z = range_from_disparity(d, focal_px=400.0, baseline_m=0.1)
    assert z.dtype == np.float32
    np.testing.assert_allclose(z[0], [40.0, 20.0, 10.0])
    assert np.all(np.isnan(z[1]))
    np.testing.assert_allclose(disparity_from_range(z, focal_px=400.0, baseline_m=0.1)[0], d[0])


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_range_rejects_bad_camera(bad):
    with pytest.raises(ValueError, match="focal_px"):
        range_from_disparity(np.ones((2, 2), np.float32), focal_px=bad, baseline_m=0.1)


def test_pseudo_left_of_true_disparity_reproduces_left_outside_occlusions():
    # background at 4 px, a nearer block at 11 px; the left view is built from the scene
    rng = np.random.default_rng(0)
    h, w = 40, 90
    back = rng.integers(0, 256, (h, w + 20)).astype(np.uint8)
    front = rng.integers(0, 256, (h, w + 20)).astype(np.uint8)
    block = np.zeros((h, w), bool)
    block[10:30, 30:50] = True
    right = np.where(block, front[:, :w], back[:, 4 : 4 + w])
    left = back[:, :w].copy()
    for y in range(10, 30):
        left[y, 41:61] = front[y, 30:50]
    truth = np.where(block, 11.0, 4.0).astype(np.float32)
    pseudo = pseudo_left(right, truth)
    defined = np.isfinite(pseudo)
    # undefined: left pixels the right camera does not see (beside the block, the image's
    # left edge seen only by the left camera)
    assert defined.mean() > 0.85
    np.testing.assert_array_equal(pseudo[defined], left[defined].astype(np.float32))
    assert not defined[15, 2]  # left image columns < 4 are not in the right view
    diff = residual(left, pseudo)
    assert np.all(diff[defined] == 0) and np.all(np.isnan(diff[~defined]))


def test_pseudo_left_interpolates_subpixel_disparity():
    world = ndimage.gaussian_filter(np.random.default_rng(1).normal(128, 40, (30, 140)), 2.0)
    shift = 6.4
    left = world[:, 10:110]
    right = ndimage.shift(world, (0, -shift), order=3)[:, 10:110]
    pseudo = pseudo_left(right, np.full(right.shape, shift, np.float32))
    inner = np.isfinite(pseudo)
    inner[:, :12] = inner[:, -4:] = False
    assert np.abs(pseudo[inner] - left[inner]).max() < 1.5
    assert np.sqrt(np.mean((pseudo[inner] - left[inner]) ** 2)) < 0.5


def test_nearer_surface_wins_in_pseudo_left():
    right = np.zeros((1, 20), np.float32)
    right[0, 5] = 100.0  # near pixel at d = 6 lands on column 11
    right[0, 9] = 50.0  # far pixel at d = 2 lands on column 11 as well
    d = np.full((1, 20), np.nan, np.float32)
    d[0, 5], d[0, 9] = 6.0, 2.0
    assert pseudo_left(right, d)[0, 11] == 100.0


@settings(max_examples=20, deadline=None)
@given(height=st.floats(0.3, 3.0), pitch=st.floats(5.0, 80.0))
def test_plane_round_trips_through_disparity_coefficients(height, pitch):
    camera = Camera(focal_px=200.0, baseline_m=0.2, height_m=height, pitch_deg=pitch)
    plane = plane_from_pose(height_m=height, pitch_deg=pitch)
    coef = plane_disparity_coefficients(plane, camera=camera, shape=SHAPE)
    np.testing.assert_allclose(
        plane_from_disparity_coefficients(coef, camera=camera, shape=SHAPE), plane, atol=1e-9
    )


def test_pose_plane_agrees_with_camera_to_ground():
    d = _ground_disparity(CAMERA)
    points = CAMERA.camera_points(d)
    up = CAMERA.camera_to_ground(points)[..., 2]
    ok = np.isfinite(up)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(up[ok], 0.0, atol=1e-6)
    plane = plane_from_pose(height_m=1.2, pitch_deg=38.0)
    np.testing.assert_allclose(height_above_plane(points, plane)[ok], 0.0, atol=1e-5)
    assert height_above_plane(np.zeros(3), plane) == pytest.approx(1.2)  # the camera


@pytest.mark.parametrize("seed", [0, 1])
def test_height_from_disparity_is_height_above_plane_of_the_points_bit_for_bit(seed):
    # the depth stage's height product: computing it without the (M, N, 3) points must
    # not change a bit of it
    camera = Camera(focal_px=100.0, baseline_m=0.1, height_m=1.2, pitch_deg=38.0, cx=40.5)
    rng = np.random.default_rng(seed)
    d = (_ground_disparity(camera) + rng.normal(0.0, 0.5, SHAPE)).astype(np.float32)
    d[rng.random(SHAPE) < 0.1] = np.nan
    d[0, :4] = (0.0, -1.0, np.inf, 1e-30)
    plane = fit_ground_plane(d, camera=camera).plane
    assert np.isfinite(plane).all()
    expected = height_above_plane(camera.camera_points(d), plane)
    got = height_from_disparity(d, plane, camera=camera)
    assert got.dtype == np.float32 and got.shape == SHAPE
    np.testing.assert_array_equal(got.view(np.uint32), expected.view(np.uint32))
    with pytest.raises(ValueError, match="2-D"):
        height_from_disparity(d[None], plane, camera=camera)


def _ground_with_rocks(camera: Camera, seed=0):
    d = _ground_disparity(camera).astype(np.float64)
    rng = np.random.default_rng(seed)
    d += rng.normal(0, 0.15, d.shape)
    d[50:70, 20:40] += 6.0  # a rock: nearer than the ground
    d[5:15, 60:90] = np.nan  # no match
    return d.astype(np.float32)


def test_ground_fit_from_pose_refines_and_ignores_rocks():
    d = _ground_with_rocks(CAMERA)
    fit = fit_ground_plane(d, camera=CAMERA)
    assert fit.source == "pose"
    np.testing.assert_allclose(fit.plane, plane_from_pose(height_m=1.2, pitch_deg=38.0), atol=0.02)
    assert not fit.inliers[55, 30]
    assert 0.85 < fit.inlier_fraction < 0.99


def test_ground_fit_without_pose_uses_ransac_and_finds_the_same_plane():
    d = _ground_with_rocks(CAMERA)
    no_pose = Camera(focal_px=CAMERA.focal_px, baseline_m=CAMERA.baseline_m)
    fit = fit_ground_plane(d, camera=no_pose)
    assert fit.source == "ransac"
    np.testing.assert_allclose(fit.plane, plane_from_pose(height_m=1.2, pitch_deg=38.0), atol=0.02)


@pytest.mark.parametrize(("height", "pitch"), [(1.5, 30.0), (3.0, 10.0), (0.3, 80.0)])
def test_wrong_pose_still_finds_the_ground(height, pitch):
    # a roughly right pose is refined; a badly wrong one explains too little -> RANSAC
    d = _ground_with_rocks(CAMERA)
    wrong = Camera(focal_px=100.0, baseline_m=0.1, height_m=height, pitch_deg=pitch)
    fit = fit_ground_plane(d, camera=wrong)
    assert fit.source in ("pose", "ransac")
    np.testing.assert_allclose(fit.plane, plane_from_pose(height_m=1.2, pitch_deg=38.0), atol=0.02)


def test_ground_fit_without_data_is_nan():
    fit = fit_ground_plane(np.full(SHAPE, np.nan, np.float32), camera=CAMERA)
    assert fit.source == "none" and np.all(np.isnan(fit.plane))
    assert math.isnan(fit.inlier_fraction)


def test_max_disparity_from_pose_nearest_range_and_fallback():
    bottom = ground_disparity_at_row(CAMERA, row=SHAPE[0] - 1, shape=SHAPE)
    assert bottom == pytest.approx(float(np.nanmax(_ground_disparity(CAMERA))), rel=1e-6)
    assert derive_max_disparity(CAMERA, shape=SHAPE) == math.ceil(bottom * 1.25) + 2
    assert derive_max_disparity(CAMERA, shape=SHAPE, nearest_range_m=0.5) == 20
    bare = Camera(focal_px=100.0, baseline_m=0.1)
    assert derive_max_disparity(bare, shape=SHAPE) == 64
    assert derive_max_disparity(bare, shape=(20, 30)) == 29  # never beyond the image


def test_row_floor_lies_below_the_ground_by_the_margins():
    floor = derive_row_floor(CAMERA, shape=SHAPE)
    ground = np.array(
        [ground_disparity_at_row(CAMERA, row=y, shape=SHAPE) for y in range(SHAPE[0])]
    )
    np.testing.assert_array_equal(floor, np.floor(0.75 * ground - 2.0).astype(np.int64))
    assert np.all(np.diff(floor) >= 0)  # the ground is nearer lower in the image
    assert np.all(np.nan_to_num(_ground_disparity(CAMERA), nan=np.inf) > floor[:, None])
    assert derive_row_floor(CAMERA, shape=SHAPE, margin=1.0).max() <= -2  # no floor
    assert derive_row_floor(Camera(focal_px=100.0, baseline_m=0.1), shape=SHAPE) is None
    with pytest.raises(ValueError, match="margin"):
        derive_row_floor(CAMERA, shape=SHAPE, margin=1.5)


def test_row_ceiling_admits_objects_up_to_the_ratio_height():
    # a point z above the ground on a row's ray has g / (1 - z / h) disparity: ratio 2 admits
    # up to half the camera height
    ceiling = derive_row_ceiling(CAMERA, shape=SHAPE, ratio=2.0, slack_px=0.0)
    ground = np.array(
        [ground_disparity_at_row(CAMERA, row=y, shape=SHAPE) for y in range(SHAPE[0])]
    )
    np.testing.assert_array_equal(ceiling, np.ceil(2.0 * np.maximum(ground, 0)).astype(np.int64))
    assert np.all(derive_row_ceiling(CAMERA, shape=SHAPE) >= ceiling + 2)
    assert derive_row_ceiling(Camera(focal_px=100.0, baseline_m=0.1), shape=SHAPE) is None
    with pytest.raises(ValueError, match="ratio"):
        derive_row_ceiling(CAMERA, shape=SHAPE, ratio=0.5)


# ------------------------------------------------------------ numba passes against numpy
# The depth stage's per-pixel products are numba passes; each must give the bits of the
# numpy expression (or plain-Python loop) it replaced.


def _odd_disparities(seed, shape=(7, 23)):
    rng = np.random.default_rng(seed)
    d = rng.uniform(-1.0, 9.0, shape).astype(np.float32)
    d[rng.random(shape) < 0.2] = np.nan
    d[0, :5] = (0.0, -0.0, np.inf, 1e-30, -np.inf)
    return d


def test_range_kernel_equals_the_numpy_expression():
    d = _odd_disparities(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        expected = np.where(d > 0, 430.0 * 0.07 / d.astype(np.float64), np.nan)
    got = range_from_disparity(d, focal_px=430.0, baseline_m=0.07)
    assert got.dtype == np.float32
    assert got.tobytes() == expected.astype(np.float32).tobytes()


def test_plane_inliers_equal_the_broadcast_numpy_test():
    d = _odd_disparities(1)
    alpha, beta, gamma = 0.013, 0.31, 1.7
    xx = np.arange(d.shape[1], dtype=np.float64)[None, :]
    yy = np.arange(d.shape[0], dtype=np.float64)[:, None]
    d64 = d.astype(np.float64)
    with np.errstate(invalid="ignore"):
        expected = (np.isfinite(d64) & (d64 > 0)) & (
            np.abs(alpha * xx + beta * yy + gamma - d64) <= 2.0
        )
    inliers, count = geometry._plane_inliers(d, alpha, beta, gamma, 2.0)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(inliers, expected)
    assert count == np.count_nonzero(expected)


def _python_forward_warp(image, disparity):
    """The pseudo-left warp as plain Python loops over float64 copies, with a full-frame
    z-buffer (the layout the kernel had before it kept one row)."""
    image = image.astype(np.float32).astype(np.float64)
    disparity = disparity.astype(np.float64)
    h, w = image.shape
    out = np.full((h, w), np.nan, np.float32)
    zbuf = np.full((h, w), -np.inf)
    for y in range(h):
        for x in range(w):
            d0 = disparity[y, x]
            if not np.isfinite(d0):
                continue
            u0 = x + d0
            joined = False
            if x + 1 < w and np.isfinite(disparity[y, x + 1]):
                d1 = disparity[y, x + 1]
                if abs(d1 - d0) <= 1.0:
                    joined = True
                    u1 = x + 1 + d1
                    lo, hi = min(u0, u1), max(u0, u1)
                    for c in range(max(0, math.ceil(lo)), min(w - 1, math.floor(hi)) + 1):
                        t = 0.0 if u1 == u0 else (c - u0) / (u1 - u0)
                        key = d0 + t * (d1 - d0)
                        if key > zbuf[y, c]:
                            zbuf[y, c] = key
                            out[y, c] = image[y, x] + t * (image[y, x + 1] - image[y, x])
            if not joined:
                c = math.floor(u0 + 0.5)
                if 0 <= c < w and abs(c - u0) < 0.5 and d0 > zbuf[y, c]:
                    zbuf[y, c] = d0
                    out[y, c] = image[y, x]
    return out


@pytest.mark.parametrize("image_dtype", [np.uint8, np.float32, np.float64])
def test_forward_warp_equals_python_loops(image_dtype):
    # uint8 and float32 images and float32 disparities are read without converted copies
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (6, 30)).astype(image_dtype)
    d = np.round(rng.uniform(0, 5, (6, 30)) * 8).astype(np.float32) / 8
    d[:, 10:14] += 3.0  # a nearer patch: occludes, z-buffer decides
    d[rng.random(d.shape) < 0.15] = np.nan
    expected = _python_forward_warp(image, d)
    for disparity in (d, d.astype(np.float64)):
        assert pseudo_left(image, disparity).tobytes() == expected.tobytes()
