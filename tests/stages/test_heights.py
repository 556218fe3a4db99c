"""Tests of stages/_heights.py: height smoothing, local ground and per-label percentiles."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.ndimage import median_filter

from stages._heights import (
    _fraction,
    _ground_heights,
    _median_filter_nearest,
    _percentile_by_label,
    _percentiles_by_label,
    local_ground,
    relative_height,
    smooth_height,
)


def test_smooth_height_removes_isolated_spikes_and_keeps_nan():
    height = np.zeros((20, 20), np.float32)
    height[10, 10] = 0.5
    height[3, 3] = np.nan
    smoothed = smooth_height(height, window=5)
    assert smoothed[10, 10] == 0.0
    assert np.isnan(smoothed[3, 3])
    with pytest.raises(ValueError, match="1, 3 or 5"):
        smooth_height(height, window=7)


@given(st.lists(st.tuples(st.integers(0, 4), st.floats(-1, 1, allow_nan=False)), max_size=60))
def test_percentile_by_label_matches_numpy_nearest_rank(pairs):
    labels = np.array([p[0] for p in pairs], dtype=np.int64)
    values = np.array([p[1] for p in pairs], dtype=np.float64)
    result = _percentile_by_label(values, labels, 5, 90.0)
    for label in range(5):
        chosen = values[labels == label]
        if chosen.size == 0:
            assert result[label] == np.inf
        else:
            expected = np.percentile(chosen, 90, method="lower")
            assert result[label] == pytest.approx(expected)


@given(
    st.integers(1, 40),
    st.integers(1, 40),
    st.sampled_from([1, 2, 3, 5, 8, 9]),
    st.integers(0, 2**31 - 1),
)
def test_median_filter_nearest_equals_scipy(rows, cols, size, seed):
    rng = np.random.default_rng(seed)
    image = np.round(rng.normal(0, 0.01, (rows, cols)) * 500).astype(np.float32) / 500
    expected = median_filter(image, size=size, mode="nearest")
    np.testing.assert_array_equal(_median_filter_nearest(image, size=size), expected)


def test_percentiles_by_label_match_one_at_a_time():
    rng = np.random.default_rng(3)
    values = rng.normal(size=500)
    labels = rng.integers(0, 7, 500)
    both = _percentiles_by_label(values, labels, 8, (90.0, 50.0))
    np.testing.assert_array_equal(both[0], _percentile_by_label(values, labels, 8, 90.0))
    np.testing.assert_array_equal(both[1], _percentile_by_label(values, labels, 8, 50.0))


@given(
    st.lists(
        st.tuples(st.integers(0, 6), st.floats(-1e3, 1e3, allow_nan=False, width=32)),
        max_size=80,
    )
)
def test_percentiles_by_label_of_float32_values_equal_numpys_lower_percentile(pairs):
    # float32 values take the packed-key sort; it must pick the same nearest-rank value
    # (exactly: the float64 path's combined key cannot tell a label's values apart when
    # they differ by less than its rounding, e.g. 0 and 1.4e-45 under label 1)
    labels = np.array([p[0] for p in pairs], dtype=np.int64)
    values = np.array([p[1] for p in pairs], dtype=np.float32)
    result = _percentiles_by_label(values, labels, 8, (90.0, 50.0, 0.0, 100.0))
    for label in range(8):
        chosen = values[labels == label].astype(np.float64)
        for row, q in zip(result, (90, 50, 0, 100), strict=True):
            expected = np.percentile(chosen, q, method="lower") if chosen.size else np.inf
            assert row[label] == expected


def _heights_with_holes(rng, shape, dtype):
    height = rng.normal(0, 0.02, shape).astype(dtype)
    height[rng.random(shape) < rng.uniform(0, 0.4)] = np.nan
    height[rng.random(shape) < 0.01] = np.inf
    height[rng.random(shape) < 0.01] = -0.0
    return height


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_smooth_height_and_local_ground_equal_their_numpy_twins(dtype):
    # the twins: the np.where steps the compiled passes replaced
    rng = np.random.default_rng(8)
    for _ in range(10):
        height = _heights_with_holes(rng, tuple(rng.integers(9, 80, 2)), dtype)
        valid = np.isfinite(height)
        filled = np.where(valid, height, np.float32(0.0)).astype(np.float32, copy=False)
        for window in (3, 5):
            twin = np.where(valid, cv2.medianBlur(filled, window), np.float32(np.nan))
            np.testing.assert_array_equal(
                smooth_height(height, window=window).view(np.int32), twin.view(np.int32)
            )
        small_shape = (filled.shape[1] // 8, filled.shape[0] // 8)  # 72 px: a factor of 8
        small = cv2.resize(filled, small_shape, interpolation=cv2.INTER_AREA)
        coarse = _median_filter_nearest(small, size=min(9, *small.shape))
        twin = cv2.resize(coarse, filled.shape[::-1], interpolation=cv2.INTER_LINEAR)
        np.testing.assert_array_equal(local_ground(height, window_px=72), twin)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_relative_height_is_the_smoothed_map_minus_its_local_ground_bit_for_bit(dtype):
    rng = np.random.default_rng(9)
    for _ in range(10):
        height = _heights_with_holes(rng, tuple(rng.integers(9, 80, 2)), dtype)
        for window in (1, 3, 5):
            smoothed = smooth_height(height, window=window)
            twin = smoothed - local_ground(smoothed, window_px=36)
            relative = relative_height(height, smoothing_px=window, ground_window_px=36)
            np.testing.assert_array_equal(relative.view(np.int32), twin.view(np.int32))


def test_ground_heights_equal_boolean_indexing():
    rng = np.random.default_rng(10)
    for dtype in (np.float32, np.float64):
        height = _heights_with_holes(rng, (30, 40), dtype)
        mask = rng.random(height.shape) < 0.3
        expected = height[np.isfinite(height) & ~mask]
        got = _ground_heights(height, mask)
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got.view(np.uint8), expected.view(np.uint8))


def test_fraction_is_the_mean_of_the_mask_bit_for_bit():
    rng = np.random.default_rng(11)
    for _ in range(50):
        mask = rng.random(tuple(rng.integers(1, 300, 2))) < rng.random()
        assert _fraction(mask) == float(mask.mean())


def test_fraction_is_a_python_float_not_numpy_float64():
    # np.count_nonzero gives a numpy int: the share came out np.float64 (float(mean) did
    # not), and DepthRuleStats' repr read ``depth_valid_fraction=np.float64(0.95...)``
    share = _fraction(np.array([[True, False, True]]))
    assert type(share) is float and repr(share) == "0.6666666666666666"


def test_relative_height_errors_name_its_own_arguments():
    # its checks were copied from smooth_height and local_ground and named their
    # ``window`` and ``window_px``, which a caller of relative_height never passed
    height = np.zeros((20, 20), np.float32)
    with pytest.raises(ValueError, match=r"smoothing_px .* must be 1, 3 or 5.*got 4"):
        relative_height(height, smoothing_px=4, ground_window_px=36)
    with pytest.raises(ValueError, match=r"ground_window_px must be >= 9.*got 8"):
        relative_height(height, smoothing_px=5, ground_window_px=8)
