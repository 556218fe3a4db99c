"""Tests of stages/_depth_rules.py: local ground, raised, flat and no-depth rules (R0-R3)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._depth_rules import apply_depth_rules, smooth_height


def disk(shape, cy, cx, r):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r


def test_smooth_height_removes_isolated_spikes_and_keeps_nan():
    height = np.zeros((20, 20), np.float32)
    height[10, 10] = 0.5
    height[3, 3] = np.nan
    smoothed = smooth_height(height, window=5)
    assert smoothed[10, 10] == 0.0
    assert np.isnan(smoothed[3, 3])
    with pytest.raises(ValueError, match="1, 3 or 5"):
        smooth_height(height, window=7)


def test_depth_rule_flat_dark_shadow_is_background():
    shape = (60, 60)
    shadow = disk(shape, 30, 30, 10)  # intensity says object
    height = np.zeros(shape, np.float32)  # but it lies on the ground
    combined, stats = apply_depth_rules(shadow, height)
    assert not combined.any()
    assert stats.flat_removed_px == shadow.sum()


def test_depth_rule_gray_equal_raised_block_is_object():
    shape = (60, 60)
    height = np.zeros(shape, np.float32)
    height[20:35, 15:40] = 0.08  # invisible in intensity
    combined, stats = apply_depth_rules(np.zeros(shape, bool), height)
    assert combined[22:33, 17:38].all()
    assert stats.raised_added_px > 300
    assert not combined[:15].any()


def test_depth_rules_keep_intensity_where_depth_is_invalid_and_the_rock_foot():
    shape = (60, 60)
    mask = disk(shape, 30, 30, 12)
    height = np.full(shape, np.nan, np.float32)
    combined, stats = apply_depth_rules(mask, height)
    np.testing.assert_array_equal(combined, mask)
    assert stats.depth_valid_fraction == 0.0
    # a rock's foot is flat but next to raised pixels: kept
    height = np.zeros(shape, np.float32)
    height[disk(shape, 30, 30, 10)] = 0.1
    combined, _ = apply_depth_rules(mask, height, base_px=3)
    assert combined[30, 41]


def test_depth_rules_validate():
    mask = np.zeros((10, 10), bool)
    with pytest.raises(ValueError, match="shape"):
        apply_depth_rules(mask, np.zeros((5, 5), np.float32))
    with pytest.raises(ValueError, match="flat_tol_m"):
        apply_depth_rules(mask, np.zeros((10, 10), np.float32), flat_tol_m=0.1)
    with pytest.raises(TypeError, match="float"):
        apply_depth_rules(mask, np.zeros((10, 10), np.int32))


def test_noisy_depth_keeps_small_objects_and_removes_a_large_flat_one():
    rng = np.random.default_rng(0)
    shape = (120, 120)
    # stereo noise is correlated over the matching window: 3 cm blocks of 6 px
    blocks = rng.normal(0, 0.03, (20, 20)).astype(np.float32)
    height = np.kron(blocks, np.ones((6, 6), np.float32))
    blotch = np.zeros(shape, bool)
    blotch[10:60, 10:110] = True  # large dark texture blotch lying on the ground
    pebble = disk(shape, 95, 60, 4)  # small object: too few samples to judge
    height[pebble] = 0.0
    combined, stats = apply_depth_rules(blotch | pebble, height)
    assert stats.ground_sigma_m > 0.015
    assert "object-level" in stats.notes[0]
    assert not combined[blotch].any()
    assert combined[pebble].all()
