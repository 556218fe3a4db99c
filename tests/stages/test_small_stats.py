"""Tests of stages/_small_stats.py: compiled median, percentile and projection spreads,
twins of the numpy code they replace in the describe stage (bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._small_stats import (
    back_project,
    boundary_jump_counts,
    footprint_spreads,
    huber_weights,
    median64,
    percentile64,
    projection_spreads,
)


def _bits(value) -> bytes:
    return np.float64(value).tobytes()


def _samples(rng: np.random.Generator, trials: int):
    for trial in range(trials):
        size = int(rng.integers(1, 400))
        kind = trial % 5
        if kind == 0:
            values = rng.normal(size=size) * 10.0 ** rng.integers(-4, 2)
        elif kind == 1:
            values = rng.integers(-3, 4, size=size) * 0.5  # many ties and zeros
        elif kind == 2:
            values = np.where(rng.random(size) < 0.5, -0.0, 0.0)  # signed zeros
        elif kind == 3:
            values = rng.normal(size=size) * 1e-3 + 1.0
        else:
            values = rng.standard_t(3, size) * 0.004  # heights: heavy tails
        if trial % 23 == 0:
            values[rng.integers(size)] = np.nan
        yield values


def test_median64_is_numpys_median_bit_for_bit():
    rng = np.random.default_rng(3)
    for values in _samples(rng, 1500):
        before = values.copy()
        assert _bits(median64(values)) == _bits(np.median(values))
        assert before.tobytes() == values.tobytes()  # not reordered
    for size in (1, 2, 7, 8, 1001):
        ints = rng.integers(0, 500, size=size)
        assert _bits(median64(ints)) == _bits(np.median(ints))


def test_percentile64_is_numpys_percentile_bit_for_bit():
    rng = np.random.default_rng(4)
    for values in _samples(rng, 1500):
        for q in (98, 50, 0, 100, 2.5, 99.9):
            assert _bits(percentile64(values, q)) == _bits(np.percentile(values, q))


def test_small_stats_reject_empty_arrays_and_bad_percentiles():
    with pytest.raises(ValueError, match="at least one"):
        median64(np.zeros(0))
    with pytest.raises(ValueError, match="at least one"):
        percentile64(np.zeros(0), 98)
    with pytest.raises(ValueError, match=r"\[0, 100\]"):
        percentile64(np.ones(3), 101)


def test_projection_spreads_are_numpys_max_minus_min_bit_for_bit():
    rng = np.random.default_rng(5)
    angles = np.radians(np.arange(0.0, 180.0, 3.0))
    cos, sin = np.cos(angles), np.sin(angles)
    for trial in range(300):
        size = int(rng.integers(1, 1500))
        if trial % 2:
            x, y = rng.normal(size=size) * 0.1, rng.normal(size=size) * 0.1 + 2.0
        else:  # pixel grids on the ground: ties and collinear points
            grid = rng.integers(0, 40, size=(size, 2))
            x, y = grid[:, 0] * 0.0031 - 0.05, grid[:, 1] * 0.0047 + 1.3
        proj = x[:, None] * cos[None, :] + y[:, None] * sin[None, :]
        expected = proj.max(axis=0) - proj.min(axis=0)
        assert projection_spreads(x, y, cos, sin).tobytes() == expected.tobytes()
    with pytest.raises(ValueError, match="non-empty"):
        projection_spreads(np.zeros(0), np.zeros(0), cos, sin)


def _numpy_jump_counts(mask, background, disparity, jump_px):
    """The four shifted-array passes background_jump_fraction made before (describe v9)."""
    total = hidden = 0
    for first, second in (
        ((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
        ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
    ):
        for inside, outside in ((first, second), (second, first)):
            d_in, d_out = disparity[inside], disparity[outside]
            ok = mask[inside] & background[outside] & np.isfinite(d_in) & np.isfinite(d_out)
            total += int(np.count_nonzero(ok))
            hidden += int(np.count_nonzero((d_out - d_in)[ok] > jump_px))
    return total, hidden


def test_boundary_jump_counts_are_the_shifted_array_counts():
    rng = np.random.default_rng(6)
    for _ in range(200):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 30)))
        labels = rng.integers(0, 3, size=shape)
        disparity = rng.normal(10.0, 1.0, size=shape)
        disparity[rng.random(shape) < 0.2] = np.nan
        mask = labels == 1
        expected = _numpy_jump_counts(mask, labels == 0, disparity, 1.0)
        assert boundary_jump_counts(mask, labels == 0, disparity, jump_px=1.0) == expected
    with pytest.raises(ValueError, match="equal 2-D"):
        boundary_jump_counts(
            np.ones((2, 2), bool), np.ones((2, 3), bool), np.ones((2, 2)), jump_px=1.0
        )


def test_huber_weights_are_the_numpy_reweighting_bit_for_bit():
    from stages._ground import _median

    rng = np.random.default_rng(7)
    for trial in range(300):
        size = int(rng.integers(1, 500))
        measured = rng.normal(10.0, 0.5, size=size)
        fitted = measured + rng.standard_t(2, size) * 0.1
        if trial % 5 == 0:
            fitted[: size // 2] = measured[: size // 2]  # exact fits: zero residuals
        reject = bool(trial % 2)
        resid = np.abs(measured - fitted)
        sigma = 1.4826 * float(_median(resid)) + 1e-9
        expected = 1.0 / np.maximum(1.0, resid / (2.0 * sigma))
        if reject:
            expected[resid > 4.0 * sigma] = 0.0
        got = huber_weights(measured, fitted, huber_k=2.0, reject_k=4.0, reject=reject)
        assert got.tobytes() == expected.tobytes()


def test_back_project_is_pixel_points_numpy_arithmetic_bit_for_bit():
    rng = np.random.default_rng(8)
    for trial in range(100):
        size = int(rng.integers(1, 800))
        rows = rng.integers(0, 500, size=size)
        cols = rng.integers(0, 500, size=size)
        disparity = rng.uniform(-1.0, 40.0, size=size)  # some not > 0: NaN points
        disparity[rng.random(size) < 0.1] = np.nan
        if trial % 2:
            rows, cols = rows.astype(np.float64) + 0.5, cols.astype(np.float64)
        k, f, cx, cy = 34.3, 490.0, 249.5, 251.25
        d = np.where(disparity > 0, disparity, np.nan)
        z = k / d
        expected = np.stack(
            [(cols.astype(np.float64) - cx) * z / f, (rows.astype(np.float64) - cy) * z / f, z],
            axis=-1,
        )
        got = back_project(rows, cols, disparity, k_m_px=k, focal_px=f, cx=cx, cy=cy)
        assert got.tobytes() == expected.tobytes()


def _numpy_footprint_spreads(x, y, cos, sin):
    """footprint_dimensions' numpy steps before they were compiled (describe v9)."""
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    for axis in (0, 1):
        values = (x, y)[axis]
        if values.size:
            centre = np.median(values)
            mad = 1.4826 * np.median(np.abs(values - centre))
            inlier = np.abs(values - centre) <= 4.0 * mad + 1e-12
            x, y = x[inlier], y[inlier]
    if x.size < 2:
        return np.empty(0)
    proj = x[:, None] * cos[None, :] + y[:, None] * sin[None, :]
    return proj.max(axis=0) - proj.min(axis=0)


def test_footprint_spreads_are_the_numpy_outlier_filter_and_spreads_bit_for_bit():
    rng = np.random.default_rng(9)
    angles = np.radians(np.arange(0.0, 180.0, 3.0))
    cos, sin = np.cos(angles), np.sin(angles)
    for trial in range(300):
        size = int(rng.integers(0, 600))
        grid = rng.integers(0, 30, size=(size, 2))
        x, y = grid[:, 0] * 0.004 - 0.06, grid[:, 1] * 0.006 + 1.5
        if trial % 3 == 0 and size:  # ground behind the silhouette: far outliers
            far = rng.random(size) < 0.05
            y[far] += 0.5
        if trial % 4 == 0 and size:
            x[rng.random(size) < 0.1] = np.nan
        if trial % 11 == 0:
            x[:] = 0.25  # one column of points: MAD 0
        expected = _numpy_footprint_spreads(x, y, cos, sin)
        assert footprint_spreads(x, y, cos, sin).tobytes() == expected.tobytes()
