"""Tests of stages/_outlines.py: necks (R4b), faint rims (R7d)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from object_masks import disk

from stages._outlines import split_at_necks, trim_faint_rims


def dumbbell(shape=(40, 60), *, bridge_px=2):
    """Two disks of radius 8 (centres 24 px apart) joined by a bar ``bridge_px`` rows high."""
    left, right = disk(shape, 20, 18, 8), disk(shape, 20, 42, 8)
    bar = np.zeros(shape, bool)
    bar[20 - bridge_px // 2 : 20 - bridge_px // 2 + bridge_px, 18:43] = True
    return left, right, bar


def test_split_at_necks_parts_two_rocks_joined_by_a_narrow_neck():
    left, right, bar = dumbbell()
    labels = (left | right | bar).astype(np.int32) * 3
    split, count = split_at_necks(labels)
    assert count == 1 and set(np.unique(split)) == {0, 1, 2}
    # each rock is one part, whole, and the bridge's pixels go to the nearer rock
    assert len(np.unique(split[left])) == 1 and len(np.unique(split[right])) == 1
    assert split[20, 18] != split[20, 42]
    assert np.array_equal(split > 0, labels > 0)
    sizes = [np.count_nonzero(split == split[20, x]) for x in (18, 42)]
    assert abs(sizes[0] - sizes[1]) <= 2


def test_split_at_necks_leaves_blobs_waists_streak_ends_and_specks_whole():
    shape = (40, 60)
    # one convex rock; two overlapping disks whose waist is wider than half their depth
    waist = disk(shape, 20, 25, 8) | disk(shape, 20, 35, 8)
    labels = np.zeros(shape, np.int32)
    labels[waist] = 1
    labels[disk(shape, 8, 52, 5)] = 2
    assert split_at_necks(labels) == (labels, 0)
    # a rock with a streak hanging from it: the streak is no lobe (longer than 2.5x its width)
    left, _, _ = dumbbell()
    streak = np.zeros(shape, bool)
    streak[16:24, 30:59] = True
    tail = np.zeros(shape, bool)
    tail[19:21, 18:31] = True
    labels = (left | streak | tail).astype(np.int32)
    assert split_at_necks(labels)[1] == 0
    # parts smaller than min_lobe_px are not split off; 0 disables; bad arguments raise
    left, right, bar = dumbbell()
    labels = (left | right | bar).astype(np.int32)
    assert split_at_necks(labels, min_lobe_px=300)[1] == 0
    assert split_at_necks(labels, neck_ratio=0)[1] == 0
    for bad in ({"neck_ratio": 1.0}, {"min_lobe_px": 0}, {"solidity_gain": -0.1}):
        with pytest.raises(ValueError, match="neck_ratio"):
            split_at_necks(labels, **bad)


def square(shape, top, bottom):
    mask = np.zeros(shape, bool)
    mask[top:bottom, top:bottom] = True
    return mask


def test_trim_faint_rims_drops_outline_pixels_near_the_ground_gray_only():
    shape = (40, 40)
    rock = square(shape, 12, 28)
    rim = square(shape, 11, 29) & ~rock  # one pixel all round
    contrast = np.zeros(shape, np.float32)
    contrast[rock] = -3.0
    contrast[rim] = -0.5  # blurred edge: 0.17 of the rock's contrast
    labels = (rock | rim).astype(np.int32)
    trimmed, count = trim_faint_rims(labels, contrast)
    assert np.array_equal(trimmed > 0, rock) and count == np.count_nonzero(rim)
    # a rim at half the rock's contrast is the rock's edge: kept; so is a light face (R7c)
    contrast[rim] = -1.5
    assert trim_faint_rims(labels, contrast) == (labels, 0)
    contrast[rim] = 0.8
    assert trim_faint_rims(labels, contrast)[1] == 0
    # the same for a light rock; one layer is peeled, not two
    wide_rim = square(shape, 10, 30) & ~rock
    contrast[rock], contrast[wide_rim] = 3.0, 0.5
    labels = (rock | wide_rim).astype(np.int32)
    trimmed, count = trim_faint_rims(labels, contrast)
    assert np.array_equal(trimmed > 0, rock | rim)


def test_trim_faint_rims_keeps_a_cut_at_the_frame_border():
    shape = (30, 30)
    contrast = np.full(shape, -0.2, np.float32)
    contrast[:, :10] = -3.0
    labels = np.zeros(shape, np.int32)
    labels[:, :12] = 1  # a rock cut by the frame's edges with a faint 2-px rim on its right
    trimmed, count = trim_faint_rims(labels, contrast)
    assert np.array_equal(trimmed > 0, np.arange(30)[None, :] * np.ones((30, 1)) < 11)
    assert count == 30
    assert trim_faint_rims(labels, contrast, fraction=0) == (labels, 0)
    with pytest.raises(ValueError, match="fraction must be in"):
        trim_faint_rims(labels, contrast, fraction=1.0)
    with pytest.raises(ValueError, match="one shape"):
        trim_faint_rims(labels, contrast[:5])


def test_trim_faint_rims_equals_its_whole_frame_twin():
    # the twin: the rule as it read whole-frame maps of the objects' signs and medians
    from stages._heights import _percentile_by_label
    from stages._regions import _lookup, _renumber

    rng = np.random.default_rng(17)
    for dtype in (np.float32, np.float64):
        for _ in range(10):
            shape = tuple(rng.integers(5, 60, 2))
            labels = np.zeros(shape, np.int32)
            for k in range(1, 6):
                y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
                labels[y : y + rng.integers(3, 15), x : x + rng.integers(3, 15)] = k
            labels = _renumber(labels, 1)
            contrast = rng.normal(0, 2, shape).astype(dtype)
            out, trimmed = trim_faint_rims(labels, contrast, fraction=0.3)
            count = int(labels.max())
            inside = labels.ravel() > 0
            median = _percentile_by_label(
                contrast.ravel()[inside].astype(np.float32), labels.ravel()[inside], count + 1, 50.0
            )
            median[~np.isfinite(median)] = 0.0
            median[0] = 0.0
            cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
            outline = (cv2.dilate((labels == 0).view(np.uint8), cross) > 0) & (labels > 0)
            own_side = contrast * _lookup(np.sign(median), labels).astype(np.float32)
            faint = outline & (own_side >= 0) & (own_side < 0.3 * _lookup(np.abs(median), labels))
            assert trimmed == np.count_nonzero(faint)
            twin = _renumber(np.where(faint, 0, labels), 1) if trimmed else labels
            np.testing.assert_array_equal(out, twin)
