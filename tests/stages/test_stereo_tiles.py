"""Tiled stereo matching (stages._stereo_tiles) equals whole-frame matching."""

from __future__ import annotations

import numpy as np
import pytest
from stereo_scenes import occlusion_scene

from stages._stereo import match_disparity
from stages._stereo_tiles import match_tiled


@pytest.mark.parametrize("prefilter", [0, 15])
def test_tiled_equals_whole_frame(prefilter):
    right, left, _, _ = occlusion_scene(shape=(80, 130))
    args = {"min_disparity": 0, "max_disparity": 20, "speckle_size": 20, "prefilter": prefilter}
    whole = match_disparity(right, left, **args)
    tiled = match_tiled(right, left, tile_px=32, **args)
    np.testing.assert_array_equal(tiled.disparity, whole.disparity)
    np.testing.assert_array_equal(tiled.status, whole.status)


@pytest.mark.parametrize("row_gradient", [0.0, 0.05])
def test_tiled_equals_whole_frame_with_row_bands(row_gradient):
    right, left, _, _ = occlusion_scene(shape=(80, 130))
    floor = (np.arange(80) // 10).astype(np.int64)
    band = {"row_min_disparity": floor, "row_max_disparity": floor + 13}
    args = {
        "min_disparity": 0, "max_disparity": 20, "speckle_size": 20, "windows": "5,9,15",
        "row_gradient": row_gradient,
    }  # fmt: skip
    whole = match_disparity(right, left, **band, **args)
    tiled = match_tiled(right, left, tile_px=32, **band, **args)
    np.testing.assert_array_equal(tiled.disparity, whole.disparity)
    np.testing.assert_array_equal(tiled.status, whole.status)
