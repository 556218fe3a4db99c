"""Tests of stages/_regions.py: masks, holes, components, depth rules R1-R4, Otsu baseline."""

from __future__ import annotations

import numpy as np
import pytest

from stages._regions import (
    apply_depth_rules,
    depth_edges,
    fill_holes,
    label_objects,
    smooth_height,
    threshold_mask,
)


def disk(shape, cy, cx, r):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r


def test_threshold_mask_both_polarities():
    image = np.array([[10, 100, 200]], np.uint8)
    mask = threshold_mask(image, np.full((1, 3), 50.0), np.full((1, 3), 150.0))
    assert mask.tolist() == [[True, False, True]]
    with pytest.raises(ValueError, match="one shape"):
        threshold_mask(image, np.zeros((2, 3)), np.zeros((1, 3)))


def test_fill_holes_fills_enclosed_pockets_only():
    ring = disk((40, 40), 20, 20, 10) & ~disk((40, 40), 20, 20, 4)
    filled = fill_holes(ring)
    assert filled[20, 20] and filled.sum() == disk((40, 40), 20, 20, 10).sum()
    # a pocket open to the border stays background
    cup = np.zeros((20, 20), bool)
    cup[5:15, 0:10] = True
    cup[8:12, 0:6] = False
    assert not fill_holes(cup)[10, 2]
    with pytest.raises(TypeError, match="bool"):
        fill_holes(cup.astype(np.uint8))


def test_label_objects_drops_specks_and_numbers_densely():
    mask = disk((64, 64), 20, 20, 8) | disk((64, 64), 45, 45, 6)
    mask[2:4, 60:62] = True  # 4-pixel speck
    labels = label_objects(mask, min_area_px=30)
    assert labels.dtype == np.int32
    assert sorted(np.unique(labels).tolist()) == [0, 1, 2]
    assert labels[2, 60] == 0
    with pytest.raises(ValueError, match="min_area_px"):
        label_objects(mask, min_area_px=0)


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


def test_touching_blocks_at_different_depth_split():
    shape = (60, 80)
    mask = np.zeros(shape, bool)
    mask[20:40, 10:70] = True  # one intensity blob ...
    disparity = np.full(shape, 10.0, np.float32)
    disparity[20:40, 10:40] = 20.0  # ... made of a near block
    disparity[20:40, 40:70] = 14.0  # and a farther one
    edges = depth_edges(disparity, jump_px=1.5)
    assert edges[25, 40] and not edges[25, 39]  # the far side of the jump
    assert label_objects(mask, min_area_px=30).max() == 1
    labels = label_objects(mask, min_area_px=30, edges=edges)
    assert labels.max() == 2
    assert labels[30, 15] != labels[30, 65]
    assert np.count_nonzero(labels) == mask.sum()  # edge pixels go to their nearest block


def test_depth_edges_inside_one_object_do_not_fragment_it():
    shape = (40, 40)
    mask = disk(shape, 20, 20, 12)
    disparity = np.full(shape, 12.0, np.float32)
    disparity[20, 20] = 30.0  # an isolated outlier: median filtered away
    labels = label_objects(mask, edges=depth_edges(disparity, jump_px=1.5))
    assert labels.max() == 1


def test_elongation_of_a_disk_a_bar_and_a_line():
    from stages._regions import elongation

    labels = np.zeros((60, 80), np.int32)
    labels[disk(labels.shape, 20, 20, 10)] = 1
    labels[40:44, 10:70] = 2  # 60 x 4 bar
    labels[55, 5:75] = 3  # one-pixel line
    ratio = elongation(labels)
    assert ratio[1] == pytest.approx(1.0, abs=0.05)
    assert ratio[2] == pytest.approx(15.0, rel=0.1)
    assert ratio[3] > 50


def test_drop_streaks_keeps_compact_objects_and_renumbers():
    from stages._regions import drop_streaks

    labels = np.zeros((60, 80), np.int32)
    labels[40:44, 10:70] = 1  # a ripple trough
    labels[disk(labels.shape, 20, 20, 10)] = 2  # a rock
    kept, dropped = drop_streaks(labels, max_elongation=4.5)
    assert dropped == 1
    assert sorted(np.unique(kept).tolist()) == [0, 1]
    assert kept[20, 20] == 1 and kept[42, 40] == 0
    with pytest.raises(ValueError, match="max_elongation"):
        drop_streaks(labels, max_elongation=1.0)


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
