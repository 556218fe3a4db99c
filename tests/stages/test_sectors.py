"""Tests of stages/_sectors.py: sector histograms, smoothing, modes, interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages._sectors import (
    find_modes,
    interpolate_sector_grid,
    sector_edges,
    sector_histograms,
    smooth_histograms,
)

LEVELS = np.arange(256)


def gaussian_hist(*components: tuple[float, float, float]) -> np.ndarray:
    """Histogram (256,) of Gaussian components given as (mean, sigma, pixel count)."""
    hist = np.zeros(256)
    for mean, sigma, count in components:
        bump = np.exp(-0.5 * ((LEVELS - mean) / sigma) ** 2)
        hist += count * bump / bump.sum()
    return np.round(hist).astype(np.int64)


def sample_hist(rng, *components: tuple[float, float, int]) -> np.ndarray:
    """Histogram of actual random samples (noisy, like a real 30x30 sector)."""
    values = np.concatenate([rng.normal(m, s, n) for m, s, n in components])
    return np.bincount(np.clip(np.round(values), 0, 255).astype(int), minlength=256)


# --- sector geometry and histograms ---------------------------------------------------------


def test_sector_edges_align_with_250_pixel_tiles():
    for sectors in (8, 16):
        edges = sector_edges(500, sectors)
        assert edges[0] == 0 and edges[-1] == 500
        assert 250 in edges
        assert np.all(np.diff(edges) > 0)


@settings(max_examples=25, deadline=None)
@given(
    rows=st.integers(8, 40),
    cols=st.integers(8, 40),
    sectors=st.integers(1, 8),
    seed=st.integers(0, 2**16),
)
def test_sector_histograms_equal_a_per_sector_bincount(rows, cols, sectors, seed):
    image = np.random.default_rng(seed).integers(0, 256, (rows, cols), dtype=np.uint8)
    hist = sector_histograms(image, sectors=sectors)
    ry, rx = sector_edges(rows, sectors), sector_edges(cols, sectors)
    assert hist.shape == (sectors, sectors, 256)
    for i in range(sectors):
        for j in range(sectors):
            block = image[ry[i] : ry[i + 1], rx[j] : rx[j + 1]]
            np.testing.assert_array_equal(hist[i, j], np.bincount(block.ravel(), minlength=256))


def test_sector_histograms_reject_bad_input():
    with pytest.raises(TypeError, match="uint8"):
        sector_histograms(np.zeros((20, 20), np.float32), sectors=4)
    with pytest.raises(ValueError, match="sectors <= 10"):
        sector_histograms(np.zeros((10, 20), np.uint8), sectors=16)
    with pytest.raises(ValueError, match="2-D"):
        sector_histograms(np.zeros((4, 20, 20), np.uint8), sectors=2)


def test_nine_point_smoothing_keeps_a_symmetric_peak_in_place():
    hist = gaussian_hist((100, 6, 900))
    smoothed = smooth_histograms(hist, passes=2)
    assert int(np.argmax(smoothed)) == 100
    assert smoothed.sum() == pytest.approx(hist.sum(), rel=1e-6)
    assert smoothed.max() < hist.max()


# --- modes -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "components, expected",
    [
        ([(120, 8, 900)], [120]),
        ([(60, 6, 300), (150, 8, 600)], [60, 150]),
        ([(40, 5, 200), (120, 8, 500), (210, 6, 200)], [40, 120, 210]),
    ],
    ids=["unimodal", "bimodal", "trimodal"],
)
def test_find_modes_counts_uni_bi_trimodal(components, expected):
    rng = np.random.default_rng(3)
    hist = sample_hist(rng, *components)
    positions, heights = find_modes(smooth_histograms(hist, passes=1), prominence=0.1)
    assert len(positions) == len(expected)
    np.testing.assert_allclose(positions, expected, atol=4)
    assert np.all(heights > 0)


def test_find_modes_ignores_noise_wiggles_but_finds_saturated_peak():
    rng = np.random.default_rng(7)
    noisy = sample_hist(rng, (100, 10, 961))
    assert len(find_modes(smooth_histograms(noisy), prominence=0.1)[0]) == 1
    saturated = gaussian_hist((100, 8, 700))
    saturated[255] += 250
    positions, _ = find_modes(smooth_histograms(saturated), prominence=0.1)
    assert positions.tolist()[0] == pytest.approx(100, abs=2)
    assert positions[-1] >= 250


def test_find_modes_validates():
    with pytest.raises(ValueError, match="prominence"):
        find_modes(np.ones(256), prominence=1.5)
    with pytest.raises(ValueError, match="256"):
        find_modes(np.ones(100), prominence=0.1)
    assert find_modes(np.zeros(256), prominence=0.1)[0].size == 0


# --- Chow-Kaneko interpolation ---------------------------------------------------------------


def test_interpolation_hits_sector_centres_and_has_no_block_edges():
    rng = np.random.default_rng(1)
    grid = rng.uniform(50, 200, (8, 8))
    field = interpolate_sector_grid(grid, (160, 160))
    # 20-pixel sectors: centres between pixels 9 and 10
    centre_values = (field[9::20, 9::20] + field[10::20, 10::20]) / 2
    np.testing.assert_allclose(centre_values, grid, atol=(grid.max() - grid.min()) / 10)
    # between the outermost centres the field is a convex blend: no step exceeds the
    # steepest sector-to-sector slope; beyond them it is extrapolated linearly
    inner = field[10:150, 10:150]
    steepest_y = np.abs(np.diff(grid, axis=0)).max() / 20 + 1e-3
    steepest_x = np.abs(np.diff(grid, axis=1)).max() / 20 + 1e-3
    assert np.abs(np.diff(inner, axis=0)).max() <= steepest_y * 1.01
    assert np.abs(np.diff(inner, axis=1)).max() <= steepest_x * 1.01
    assert np.abs(np.diff(field, axis=0)).max() <= 2 * steepest_y


def test_interpolation_of_a_constant_is_constant_and_validates():
    np.testing.assert_allclose(interpolate_sector_grid(np.full((4, 4), 7.0), (37, 53)), 7.0)
    with pytest.raises(ValueError, match="finite"):
        interpolate_sector_grid(np.full((4, 4), np.nan), (40, 40))


def test_cached_pixel_weights_equal_fresh_ones_and_are_read_only():
    from stages._sectors import _interpolation_weights, _pixel_weights, sector_edges

    for length, sectors in ((500, 16), (37, 5), (500, 16)):
        weights = _pixel_weights(length, sectors)
        np.testing.assert_array_equal(
            weights, _interpolation_weights(length, sector_edges(length, sectors))
        )
        assert not weights.flags.writeable
