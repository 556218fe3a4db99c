"""Tests of the camera model's back-projection."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.camera import Camera


def _disparity(shape, seed=0):
    d = np.random.default_rng(seed).uniform(-2.0, 40.0, shape)
    d[0, :3] = np.nan
    d[1, 1] = 0.0
    return d


@pytest.mark.parametrize(
    "camera",
    [
        Camera(focal_px=420.0, baseline_m=0.12),
        Camera(focal_px=100.0, baseline_m=0.3, cx=10.5, cy=3.0),
    ],
)
def test_camera_points_are_the_pinhole_formula_bit_for_bit(camera):
    # the in-place, broadcast computation must give exactly the per-pixel formula (depth's
    # height product is built on it and must not change with how it is computed)
    d = _disparity((23, 31))
    points = camera.camera_points(d.astype(np.float32))
    dd = d.astype(np.float32).astype(np.float64)
    dd = np.where(dd > 0, dd, np.nan)
    cx, cy = camera.principal_point(dd.shape)
    ys, xs = np.indices(dd.shape, dtype=np.float64)
    z = camera.k_m_px / dd
    expected = np.stack([(xs - cx) * z / camera.focal_px, (ys - cy) * z / camera.focal_px, z], -1)
    assert points.shape == (23, 31, 3) and points.dtype == np.float64
    np.testing.assert_array_equal(points.view(np.uint64), expected.view(np.uint64))
    invalid = ~(d.astype(np.float32) > 0)  # NaN, zero and negative disparities
    assert invalid.sum() > 3 and np.isnan(points[invalid]).all()
    assert np.isfinite(points[~invalid]).all()


def test_camera_points_rejects_a_stack_of_maps():
    with pytest.raises(ValueError, match="2-D"):
        Camera(focal_px=100.0, baseline_m=0.1).camera_points(np.ones((2, 3, 4)))
