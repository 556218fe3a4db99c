"""Tests of stages/_select.py: the median absolute deviation by selection and the rank median
filter, against numpy and scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import median_filter

from stages._select import (
    median32,
    median_abs_deviation32,
    median_filter_nearest32,
    median_u8,
)


def _numpy_mad(values: np.ndarray) -> np.float32:
    return np.median(np.abs(values - np.median(values)))


def test_median_abs_deviation32_equals_numpy_on_heights_ties_and_signs():
    rng = np.random.default_rng(8)
    for trial in range(400):
        size = int(rng.integers(1, 300))
        values = (rng.normal(size=size) * 10.0 ** rng.integers(-8, 3)).astype(np.float32)
        if trial % 3 == 0:
            values = np.round(values, 1).astype(np.float32)  # many ties
        if trial % 4 == 0:
            values[rng.random(size) < 0.5] = 0.0
        if trial % 5 == 0:
            values = np.abs(values) * (-1 if trial % 2 else 1)  # one sign only
        mad = median_abs_deviation32(values)
        assert mad.dtype == np.float32 and mad == _numpy_mad(values)


def test_median_abs_deviation32_on_a_frame_of_heights_and_constant_values():
    rng = np.random.default_rng(9)
    heights = (rng.standard_t(3, 200_001) * 0.004).astype(np.float32)  # odd size, heavy tails
    assert median_abs_deviation32(heights) == _numpy_mad(heights)
    assert median_abs_deviation32(heights[:-1]) == _numpy_mad(heights[:-1])
    flat = np.full(1000, 0.25, np.float32)
    assert median_abs_deviation32(flat) == 0.0


def test_median_abs_deviation32_rejects_other_arrays():
    with pytest.raises(ValueError, match="float32"):
        median_abs_deviation32(np.zeros(5))
    with pytest.raises(ValueError, match="non-empty"):
        median_abs_deviation32(np.zeros(0, np.float32))


def test_median32_equals_numpy_on_ranges_and_ties_and_leaves_values_alone():
    rng = np.random.default_rng(10)
    for trial in range(300):
        size = int(rng.integers(1, 400))
        values = (rng.lognormal(size=size) * 10.0 ** rng.integers(-3, 3)).astype(np.float32)
        if trial % 3 == 0:
            values = np.round(values, 1).astype(np.float32)  # many ties
        if trial % 4 == 0:
            values = -values
        before = values.copy()
        middle = median32(values)
        assert middle.dtype == np.float32 and middle == np.median(values)
        assert np.array_equal(values, before)
    ranges = (rng.lognormal(1.0, 0.5, 250_001)).astype(np.float32)  # a frame's ranges
    assert median32(ranges) == np.median(ranges)
    assert median32(ranges[:-1]) == np.median(ranges[:-1])
    with pytest.raises(ValueError, match="float32"):
        median32(np.zeros(5))


def _partition_median_filter(image: np.ndarray, size: int) -> np.ndarray:
    """The selection ``stages._heights._median_filter_nearest`` made before the rank filter."""
    half = size // 2
    padded = np.pad(image, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (size, size))
    flat = windows.reshape(image.shape[0], image.shape[1], size * size)
    middle = (size * size) // 2
    return np.partition(flat, middle, axis=-1)[..., middle].astype(image.dtype, copy=False)


def test_median_filter_nearest32_has_the_bits_of_the_partition_it_replaces():
    rng = np.random.default_rng(11)
    for trial in range(200):
        rows, cols = (int(v) for v in rng.integers(1, 70, 2))
        size = int(rng.choice([1, 3, 5, 7, 9, 11]))
        image = rng.normal(0, 0.05, (rows, cols)).astype(np.float32)
        if trial % 2:
            image = np.round(image, 2).astype(np.float32) + np.float32(0.0)  # ties, no -0.0
        if trial % 5 == 0:
            image[rng.random(image.shape) < 0.3] = 0.0  # invalid heights filled as ground
        before = image.copy()
        filtered = median_filter_nearest32(image, size=size)
        expected = _partition_median_filter(image, size)
        assert filtered.dtype == np.float32
        assert filtered.tobytes() == expected.tobytes()
        np.testing.assert_array_equal(filtered, median_filter(image, size=size, mode="nearest"))
        assert np.array_equal(image, before)


def test_median_filter_nearest32_rejects_other_arrays_and_even_windows():
    with pytest.raises(ValueError, match="float32"):
        median_filter_nearest32(np.zeros((4, 4)), size=3)
    with pytest.raises(ValueError, match="odd"):
        median_filter_nearest32(np.zeros((4, 4), np.float32), size=4)


def test_median_u8_is_the_float_np_median_gives_rules_r6_and_r6b():
    rng = np.random.default_rng(12)
    for trial in range(400):
        size = int(rng.integers(1, 600))
        low, high = sorted(int(v) for v in rng.integers(0, 256, 2))
        values = rng.integers(low, high + 1, size).astype(np.uint8)  # narrow spreads: ties
        if trial % 7 == 0:
            values[:] = 255 if trial % 2 else 0
        expected = float(np.median(values))
        assert median_u8(values) == expected
        assert isinstance(median_u8(values), float)
    with pytest.raises(ValueError, match="uint8"):
        median_u8(np.zeros(3, np.int32))
    with pytest.raises(ValueError, match="non-empty"):
        median_u8(np.zeros(0, np.uint8))
