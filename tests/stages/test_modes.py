"""Tests of stages/_modes.py: every sector's modes at once, against find_modes (scipy)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._modes import find_all_modes
from stages._sectors import find_modes, sector_histograms, smooth_histograms


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
