"""Tests of stages/_modes.py: every sector's modes at once, against find_modes (scipy), and
every sector's thresholds, against their Python twin (the code the kernel replaced)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._modes import find_all_modes, sector_thresholds
from stages._sectors import (
    FWHM_TO_SIGMA,
    find_modes,
    sector_histograms,
    smooth_histograms,
)


# the Python twin of sector_thresholds: stages._continuity before the kernel
def _valley(smoothed: np.ndarray, background: int, other: int) -> float:
    """Lowest bin between two modes; on a flat valley, its end nearest the background."""
    lo, hi = (other, background) if other < background else (background, other)
    segment = smoothed[lo : hi + 1]
    minima = np.flatnonzero(segment <= segment.min() + 1e-12) + lo
    return float(minima.max() if other < background else minima.min())


def _half_width(smoothed: np.ndarray, peak: int, step: int) -> float:
    """Distance from ``peak`` to the first bin below half its height, walking by ``step``."""
    half = smoothed[peak] / 2.0
    side = smoothed[peak::step] if step > 0 else smoothed[peak::-1]
    below = np.flatnonzero(side < half)
    return float(below[0]) if below.size else float(side.size)


def _side_threshold(smoothed, background, positions, step, *, band_sigmas, min_band, merge):
    """Threshold on one side (step -1: darker, +1: lighter) and the width-based band.

    Walks outwards from the background mode: a neighbouring mode behind a shallow valley
    (valley higher than ``merge`` times the lower of the two peaks) is ground texture and is
    absorbed; the first mode behind a deep valley sets the threshold at that valley; with no
    such mode the threshold lies ``max(min_band, band_sigmas * sigma)`` beyond the outermost
    ground mode.
    """
    side = positions[positions > background] if step > 0 else positions[positions < background]
    side = np.sort(side) if step > 0 else np.sort(side)[::-1]
    edge = background
    for mode in side:
        valley = _valley(smoothed, edge, int(mode))
        floor = smoothed[int(round(valley))]
        if floor > merge * min(smoothed[edge], smoothed[int(mode)]):
            edge = int(mode)  # shallow valley: the same ground, another facet or tone
            continue
        if abs(valley - edge) >= min_band:
            band = max(min_band, band_sigmas * _half_width(smoothed, edge, step) * FWHM_TO_SIGMA)
            return valley, band
        break  # a deep valley too close to the ground: fall back on the peak width
    band = max(min_band, band_sigmas * _half_width(smoothed, edge, step) * FWHM_TO_SIGMA)
    return edge + step * band, band


def _sector_band(smoothed, background, positions, *, band_sigmas, min_band, merge):
    """Low and high thresholds around a real background mode; also the width-based bands."""
    low, band_low = _side_threshold(
        smoothed,
        background,
        positions,
        -1,
        band_sigmas=band_sigmas,
        min_band=min_band,
        merge=merge,
    )
    high, band_high = _side_threshold(
        smoothed,
        background,
        positions,
        1,
        band_sigmas=band_sigmas,
        min_band=min_band,
        merge=merge,
    )
    return low, high, band_low, band_high


def _assert_same_modes(smoothed: np.ndarray, prominence: float) -> None:
    positions, counts = find_all_modes(smoothed, prominence=prominence)
    for index in np.ndindex(smoothed.shape[:-1]):
        expected, _ = find_modes(smoothed[index], prominence=prominence)
        np.testing.assert_array_equal(positions[index][: counts[index]], expected)


@pytest.mark.parametrize("prominence", [0.0, 0.1, 0.5])
def test_find_all_modes_equals_find_modes_on_sector_histograms(prominence):
    rng = np.random.default_rng(3)
    # a lit gradient with dark and light disks and noise: uni- to multimodal sectors
    yy, xx = np.mgrid[:128, :128]
    image = 90 + 60 * xx / 128 + rng.normal(0, 8, (128, 128))
    for _ in range(12):
        cy, cx, r = rng.integers(0, 128, 2).tolist() + [int(rng.integers(4, 20))]
        image[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.choice([30, 220])
    hist = sector_histograms(np.clip(image, 0, 255).astype(np.uint8), sectors=8)
    for passes in (0, 1):
        _assert_same_modes(smooth_histograms(hist, passes=passes), prominence)


def test_find_all_modes_equals_find_modes_on_plateaus_edges_and_empty_histograms():
    rng = np.random.default_rng(4)
    hists = np.zeros((40, 256))
    for row in hists[1:]:
        # few distinct values: plateaus, ties and peaks at gray levels 0 and 255
        row[:] = rng.integers(0, 4, 256) * rng.integers(0, 2, 256)
    hists[2, :] = 5.0  # one flat plateau over every bin
    hists[3, 0], hists[3, 255] = 9.0, 9.0
    _assert_same_modes(hists, 0.1)
    _assert_same_modes(hists, 0.0)
    positions, counts = find_all_modes(hists, prominence=0.1)
    assert counts[0] == 0 and positions.shape == (40, 129)
    with pytest.raises(ValueError, match="prominence"):
        find_all_modes(hists, prominence=1.5)


def _field_histograms(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:160, :160]
    image = 80 + 70 * yy / 160 + rng.normal(0, 6, (160, 160))
    image += 25 * (np.sin(xx / 5.0) > 0.6)  # a second ground tone: facets to merge
    for _ in range(20):
        cy, cx, r = rng.integers(0, 160, 2).tolist() + [int(rng.integers(4, 18))]
        image[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.choice([25, 40, 215, 240])
    hist = sector_histograms(np.clip(image, 0, 255).astype(np.uint8), sectors=10)
    return smooth_histograms(hist, passes=1)


@pytest.mark.parametrize(("band_sigmas", "min_band", "merge"), [(3.5, 6.0, 0.35), (2.5, 0.0, 1.0)])
def test_sector_thresholds_equal_the_python_twin_for_every_mode_as_background(
    band_sigmas, min_band, merge
):
    smoothed = _field_histograms(9)
    positions, counts = find_all_modes(smoothed, prominence=0.1)
    rng = np.random.default_rng(2)
    for _ in range(3):
        # each sector's background: one of its modes at random; sectors without are phantom
        phantom = counts == 0
        pick = rng.integers(0, np.maximum(counts, 1))
        level = np.take_along_axis(positions, pick[..., None], axis=2)[..., 0].astype(float)
        phantom |= rng.random(counts.shape) < 0.1
        low, high, band_low, band_high = sector_thresholds(
            smoothed,
            level,
            phantom,
            positions,
            counts,
            band_sigmas=band_sigmas,
            min_band=min_band,
            merge=merge,
            fwhm_to_sigma=FWHM_TO_SIGMA,
        )
        for index in np.ndindex(level.shape):
            got = (low[index], high[index], band_low[index], band_high[index])
            if phantom[index]:
                assert np.isnan(got).all()
                continue
            expected = _sector_band(
                smoothed[index],
                int(level[index]),
                positions[index][: counts[index]],
                band_sigmas=band_sigmas,
                min_band=min_band,
                merge=merge,
            )
            assert got == expected
