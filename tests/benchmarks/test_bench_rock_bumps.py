"""The bump measures of benchmarks/bench_rock_bumps.py on hand-made disparity maps."""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark

bench_rock_bumps = load_benchmark("bench_rock_bumps.py")
bench_untouched_depth = load_benchmark("bench_untouched_depth.py")


def _dome(peak: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40x40 ground at disparity 10 with a round rock of radius 6 rising to ``peak`` px."""
    yy, xx = np.mgrid[:40, :40]
    r2 = (yy - 20) ** 2 + (xx - 20) ** 2
    mask = r2 <= 36
    disparity = np.full((40, 40), 10.0)
    disparity[mask] += peak * (1 - r2[mask] / 36.0)
    ring = bench_untouched_depth._ring(mask, ~mask)
    return disparity, mask, ring


def test_a_flattened_rock_keeps_the_share_of_its_bump_it_was_flattened_to():
    truth, mask, ring = _dome(1.0)
    half, _, _ = _dome(0.5)
    tops = [bench_rock_bumps.top_bump(d, mask, ring) for d in (truth, half)]
    # the top is the 90th percentile of the dome's heights over the ring's 10 px
    assert tops[0] > 0.6 and tops[1] == pytest.approx(tops[0] / 2)
    medians = [bench_untouched_depth._bump(d, mask, ring) for d in (truth, half)]
    kept = bench_rock_bumps.kept_shares(np.array([medians[0]]), np.array([medians[1]]))
    assert kept == pytest.approx([0.5])


def test_rocks_without_a_measurable_bump_are_left_out_of_the_kept_shares():
    truth = np.array([1.0, 0.05, np.nan, 0.4])
    run = np.array([0.3, 0.05, 0.2, np.nan])
    np.testing.assert_allclose(bench_rock_bumps.kept_shares(truth, run), [0.3])


def test_a_rock_with_too_few_finite_pixels_has_no_top():
    disparity, mask, ring = _dome(1.0)
    disparity[mask] = np.nan
    assert np.isnan(bench_rock_bumps.top_bump(disparity, mask, ring))
