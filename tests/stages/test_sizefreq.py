"""Tests of the rock size-frequency distribution and the Golombek-Rapp fit."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from stages._sizefreq import (
    cumulative_fractional_area,
    fit_size_frequency,
    model_cfa,
    q_of_k,
    size_frequency_from_table,
    visible_ground_area_m2,
)


def draw_population(
    k: float, area_m2: float, *, d_min: float, d_max: float = 3.0, seed: int = 0
) -> np.ndarray:
    """Rock diameters whose cumulative fractional area follows k exp(-q(k) D) above d_min.

    The number density is -dF/dD / (pi D^2 / 4), proportional to exp(-q D) / D^2; diameters
    are drawn from it (inverse CDF on a fine grid) until the rocks cover the model's area.
    """
    rng = np.random.default_rng(seed)
    q = q_of_k(k)
    grid = np.linspace(d_min, d_max, 20001)
    cdf = np.cumsum(np.exp(-q * grid) / grid**2)
    cdf /= cdf[-1]
    target = area_m2 * (model_cfa(np.array([d_min]), k)[0] - model_cfa(np.array([d_max]), k)[0])
    diameters: list[float] = []
    covered = 0.0
    while covered < target:
        d = float(np.interp(rng.uniform(), cdf, grid))
        diameters.append(d)
        covered += math.pi * d**2 / 4
    return np.array(diameters)


def test_model():
    assert q_of_k(0.1) == pytest.approx(1.79 + 1.52)
    np.testing.assert_allclose(model_cfa(np.array([0.0, 1.0]), 0.2), [0.2, 0.2 * math.exp(-2.55)])
    with pytest.raises(ValueError, match="k must be in"):
        model_cfa(np.array([0.0]), 1.5)


def test_cumulative_fractional_area_by_hand():
    d, f = cumulative_fractional_area([1.0, 1.0, 2.0, np.nan, -1.0], ground_area_m2=10.0)
    np.testing.assert_allclose(d, [2.0, 1.0])
    np.testing.assert_allclose(f, [math.pi / 10, (math.pi + math.pi / 2) / 10])
    d, f = cumulative_fractional_area([], ground_area_m2=10.0)
    assert d.size == 0 and f.size == 0
    with pytest.raises(ValueError, match="ground_area_m2"):
        cumulative_fractional_area([1.0], ground_area_m2=0.0)


@pytest.mark.parametrize("k, seed", [(0.05, 1), (0.12, 2), (0.25, 3)])
def test_fit_recovers_k_from_a_model_population(k, seed):
    area = 400.0
    diameters = draw_population(k, area, d_min=0.05, seed=seed)
    fit = fit_size_frequency(diameters, ground_area_m2=area, d_min_m=0.05)
    assert fit.k == pytest.approx(k, rel=0.1)
    assert fit.q == pytest.approx(q_of_k(fit.k))
    assert fit.n_rocks == diameters.size
    assert fit.rms_log < 0.5
    covered = np.sum(math.pi * diameters**2 / 4) / area
    assert fit.rock_area_fraction == pytest.approx(covered)


def test_missing_small_rocks_do_not_bias_the_fit():
    area, k = 400.0, 0.12
    diameters = draw_population(k, area, d_min=0.02, seed=5)
    detected = diameters[diameters >= 0.08]  # the camera resolves only the larger rocks
    fit = fit_size_frequency(detected, ground_area_m2=area, d_min_m=0.08)
    assert fit.k == pytest.approx(k, rel=0.15)


def test_fit_needs_enough_rocks():
    fit = fit_size_frequency([0.1, 0.2], ground_area_m2=5.0)
    assert math.isnan(fit.k) and math.isnan(fit.q) and fit.n_rocks == 2
    assert fit.rock_area_fraction == pytest.approx(math.pi * (0.01 + 0.04) / 4 / 5.0)
    with pytest.raises(ValueError, match="d_min_m"):
        fit_size_frequency([0.1], ground_area_m2=5.0, d_min_m=1.0, d_max_m=0.5)


def test_size_frequency_from_any_table_kind():
    diameters = draw_population(0.1, 200.0, d_min=0.05, seed=7)
    rng = np.where(np.arange(diameters.size) % 10 == 0, 9.0, 2.0)
    columns = {"width_m": diameters, "range_m": rng, "object_id": np.arange(diameters.size)}
    fits = [
        size_frequency_from_table(t, ground_area_m2=200.0, d_min_m=0.05, max_range_m=5.0)
        for t in (columns, pd.DataFrame(columns), pa.table(columns))
    ]
    assert fits[0] == fits[1] == fits[2]
    assert fits[0].n_rocks == int(np.sum(rng <= 5.0))
    with pytest.raises(ValueError, match="lacks column"):
        size_frequency_from_table({"width_m": diameters}, ground_area_m2=1.0)
    with pytest.raises(TypeError, match="pyarrow.Table"):
        size_frequency_from_table([1, 2, 3], ground_area_m2=1.0)


def test_visible_ground_area_looking_straight_down():
    # optical axis straight down from 2 m: every pixel covers (2 / f)^2 of ground
    area = visible_ground_area_m2(
        (40, 60), focal_px=100.0, principal_point=(29.5, 19.5), up=np.array([0, 0, -1.0]),
        camera_height_m=2.0,
    )  # fmt: skip
    assert area == pytest.approx(40 * 60 * (2.0 / 100.0) ** 2)
    nothing = visible_ground_area_m2(
        (40, 60), focal_px=100.0, principal_point=(29.5, 19.5), up=np.array([0, 0, -1.0]),
        camera_height_m=2.0, max_range_m=1.9,
    )  # fmt: skip
    assert nothing == 0.0


def test_visible_ground_area_of_a_horizontal_camera_sees_only_below_the_horizon():
    up = np.array([0.0, -1.0, 0.0])  # level camera: upper half of the image is sky
    near = visible_ground_area_m2(
        (41, 41), focal_px=50.0, principal_point=(20.0, 20.0), up=up, camera_height_m=1.0,
        max_range_m=3.0,
    )  # fmt: skip
    farther = visible_ground_area_m2(
        (41, 41), focal_px=50.0, principal_point=(20.0, 20.0), up=up, camera_height_m=1.0,
        max_range_m=6.0,
    )  # fmt: skip
    # the band 0..3 m of range spans about 3 m x (41 / 50) * Z wide: a trapezoid
    assert 0 < near < farther
    rows_hit = [r for r in range(41) if r > 20 and 1.0 * 50 / (r - 20) <= 3.0]
    expected = sum((50.0 / (r - 20)) ** 2 / 50.0**2 / ((r - 20) / 50.0) * 41 for r in rows_hit)
    assert near == pytest.approx(expected)
    with pytest.raises(ValueError, match="camera_height_m"):
        visible_ground_area_m2(
            (4, 4), focal_px=1.0, principal_point=(0, 0), up=up, camera_height_m=0
        )
