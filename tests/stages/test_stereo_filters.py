"""Filters around stereo matching (stages._stereo_filters): the prefilter, speckle removal
and OpenCV's StereoSGBM."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage
from stereo_scenes import shifted_pair, texture, u8

from stages._stereo import match_disparity
from stages._stereo_filters import (
    prefilter_image,
    remove_speckles,
    sgbm_disparity,
    speckle_mask,
)


def _shaded_pair(seed=5, shape=(80, 160), d=6):
    """(right, left): faint fine texture (std ~1.5) under a strong lamp-like shading."""
    h, w = shape
    rng = np.random.default_rng(seed)
    fine = ndimage.gaussian_filter(rng.normal(0.0, 3.0, (h, w + d)), 1.0)
    ys, xs = np.indices((h, w + d))
    shade = 60 + 120 * np.exp(-(((xs - 80) / 60.0) ** 2 + ((ys - 20) / 50.0) ** 2))
    world = u8(shade + fine)
    return world[:, d : d + w], world[:, :w]


def test_prefilter_finds_faint_texture_under_shading():
    # the lab floor's failure: a window's ZNCC is dominated by the lamp's brightness gradient,
    # its curve is a broad hump and the peak is not distinct; the high-pass exposes the texture
    right, left = _shaded_pair()
    args = {"min_disparity": 0, "max_disparity": 20, "windows": "5,9,15x41"}
    raw = match_disparity(right, left, prefilter=0, **args)
    high = match_disparity(right, left, prefilter=15, **args)
    assert high.valid_fraction > 0.8 > 0.2 > raw.valid_fraction
    assert np.nanmax(np.abs(high.disparity - 6)) < 1.0


def test_prefilter_image_is_the_rounded_high_pass():
    image = u8(texture((40, 50), seed=2, blur=2.0))
    out = prefilter_image(image, size=9)
    f = image.astype(np.float64)
    mean = ndimage.uniform_filter(f, 9, mode="reflect")  # scipy 'reflect' = cv2 BORDER_REFLECT
    expected = np.clip(np.floor(2 * (f - mean) + 0.5) + 128, 0, 255)
    assert out.dtype == np.uint8
    # the float box mean may land a hair off a .5 tie; the integer one does not
    assert np.mean(out == expected) > 0.99 and np.abs(out - expected).max() <= 1
    # a linear ramp has no high-pass content away from the border
    ramp = np.add.outer(np.arange(40) * 3, np.arange(50)).astype(np.uint8)
    assert np.all(prefilter_image(ramp, size=9)[4:-4, 4:-4] == 128)


def test_prefilter_tiles_equal_the_whole_image():
    image = u8(texture((70, 90), seed=4))
    whole = prefilter_image(image, size=15)
    part = prefilter_image(image[10:60, 20:80], size=15)
    np.testing.assert_array_equal(part[7:-7, 7:-7], whole[17:53, 27:73])


def test_sgbm_gives_right_reference_disparity():
    right, left = shifted_pair((64, 128), 9, seed=4)
    d = sgbm_disparity(left, right, min_disparity=0, max_disparity=30)
    values = d[np.isfinite(d)]
    assert values.size > 0.5 * d.size
    assert np.median(values) == pytest.approx(9, abs=0.1)
    # right-reference: the right image's last columns have no partner in the left image
    assert np.all(np.isnan(d[:, -8:]))


def test_opencv_method_matches_sgbm_function():
    right, left = shifted_pair((48, 96), 5, seed=5)
    m = match_disparity(
        right, left, min_disparity=0, max_disparity=20, method="opencv-sgbm", speckle_size=0
    )
    np.testing.assert_array_equal(
        m.disparity, sgbm_disparity(left, right, min_disparity=0, max_disparity=20)
    )


def test_speckles_are_removed_and_large_regions_kept():
    d = np.full((30, 30), 10.0, np.float32)
    d[5:8, 5:8] = 20.0  # 9-pixel island
    d[15:30, 15:30] = 3.0  # 225-pixel region
    cleaned, removed = remove_speckles(d, max_size=20, max_diff=1.0)
    assert removed.sum() == 9 and np.all(removed[5:8, 5:8])
    assert np.all(np.isnan(cleaned[5:8, 5:8]))
    assert np.all(cleaned[15:30, 15:30] == 3.0)


def _numpy_speckles(disparity, max_size, max_diff):
    """Reference: the speckle filter's numpy input and output passes (before the kernels)."""
    valid = np.isfinite(disparity)
    fixed = np.full(disparity.shape, -32768, np.int16)
    fixed[valid] = np.round(disparity[valid] * 16).astype(np.int16)
    cv2.filterSpeckles(fixed, -32768, max_size, max(1, round(max_diff * 16)))
    return valid & (fixed == -32768)


def test_speckle_mask_equals_the_numpy_passes():
    # half-sixteenths round to even, as np.round; NaN and +-inf are all invalid input
    rng = np.random.default_rng(7)
    d = (np.round(rng.uniform(0, 4, (40, 50)) * 32) / 32).astype(np.float32)
    d[rng.random(d.shape) < 0.2] = np.nan
    d[rng.random(d.shape) < 0.05] = np.inf
    d[rng.random(d.shape) < 0.05] = -np.inf
    expected = _numpy_speckles(d, 8, 0.25)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(speckle_mask(d, max_size=8, max_diff=0.25), expected)
    cleaned, removed = remove_speckles(d, max_size=8, max_diff=0.25)
    np.testing.assert_array_equal(removed, expected)
    np.testing.assert_array_equal(cleaned, np.where(expected, np.nan, d))


@pytest.mark.parametrize(("shape", "size"), [((40, 50), 15), ((5, 7), 9), ((12, 11), 3)])
def test_prefilter_kernel_equals_the_integer_numpy_passes(shape, size):
    # the integer formula with numpy's integral image (the passes the kernel replaced):
    # same bits, also for images smaller than the box and for saturated highs
    rng = np.random.default_rng(size)
    image = rng.integers(0, 256, shape).astype(np.uint8)
    image[: shape[0] // 2, : shape[1] // 2] = 255
    n, half = size * size, size // 2
    padded = np.pad(image.astype(np.int64), half, mode="symmetric")
    integral = np.zeros((padded.shape[0] + 1, padded.shape[1] + 1), np.int64)
    np.cumsum(np.cumsum(padded, axis=0), axis=1, out=integral[1:, 1:])
    k = size
    box = integral[k:, k:] - integral[:-k, k:] - integral[k:, :-k] + integral[:-k, :-k]
    high = (4 * (n * image.astype(np.int64) - box) + n) // (2 * n)
    expected = np.clip(high + 128, 0, 255).astype(np.uint8)
    assert prefilter_image(image, size=size).tobytes() == expected.tobytes()
