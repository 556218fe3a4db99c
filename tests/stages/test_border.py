"""Tests of the border-cut size bound (stages/_border.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages._border import border_largest_bound, height_width_ratio


def test_ratio_is_the_quantile_of_height_over_width():
    widths = np.array([0.10, 0.20, 0.10, 0.05, 0.40])
    heights = np.array([0.02, 0.08, 0.05, 0.01, 0.12])  # ratios 0.2, 0.4, 0.5, 0.2, 0.3
    assert height_width_ratio(heights, widths, quantile=0.5) == pytest.approx(0.3)
    assert height_width_ratio(heights, widths, quantile=0.9) == pytest.approx(
        float(np.quantile([0.2, 0.4, 0.5, 0.2, 0.3], 0.9))
    )


def test_ratio_leaves_out_narrow_and_unknown_objects():
    widths = np.array([0.10, 0.10, 0.10, 0.10, 0.10, 0.01, np.nan, 0.10])
    heights = np.array([0.03, 0.03, 0.03, 0.03, 0.03, 0.05, 0.05, np.nan])
    # only the five 0.10 m wide objects with a height count: every ratio is 0.3
    assert height_width_ratio(heights, widths, quantile=0.9) == pytest.approx(0.3)
    assert math.isnan(height_width_ratio(heights, widths, quantile=0.9, min_objects=6))


def test_ratio_reads_heights_below_the_ground_as_flat():
    widths = np.full(5, 0.1)
    heights = np.array([-0.01, -0.02, -0.01, -0.03, -0.01])
    assert height_width_ratio(heights, widths, quantile=0.9) == 0.0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"quantile": 1.0}, "quantile"),
        ({"quantile": 0.0}, "quantile"),
        ({"min_objects": 0}, "min_objects"),
        ({"min_width_m": -1.0}, "min_width_m"),
    ],
)
def test_ratio_rejects_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        height_width_ratio(np.ones(5), np.ones(5), **kwargs)


def test_ratio_rejects_mismatched_arrays():
    with pytest.raises(ValueError, match="one shape"):
        height_width_ratio(np.ones(5), np.ones(4))


def test_bound_raises_a_cut_width_to_what_the_height_implies():
    # a rock cut by the border: 0.05 m visible, 0.06 m high; whole rocks are at most half
    # as high as wide, so this one is at least 0.12 m wide
    assert border_largest_bound(0.05, 0.06, ratio=0.5) == pytest.approx(0.12)
    assert border_largest_bound(0.20, 0.06, ratio=0.5) == 0.20  # the visible part is wider
    assert border_largest_bound(0.05, -0.01, ratio=0.5) == 0.05


@pytest.mark.parametrize(
    "width, height, ratio",
    [(0.05, math.nan, 0.5), (0.05, 0.06, math.nan), (0.05, 0.06, 0.0)],
)
def test_bound_without_height_or_ratio_keeps_the_width(width, height, ratio):
    assert border_largest_bound(width, height, ratio=ratio) == width


def test_bound_keeps_an_unknown_width_unknown():
    # an unmeasured rock is classed 'obstacle' (NaN); the bound must not make it a sample
    assert math.isnan(border_largest_bound(math.nan, 0.01, ratio=0.5))
