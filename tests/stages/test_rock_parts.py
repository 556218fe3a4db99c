"""Tests of stages/_rock_parts.py: necks (R4b), attached shadows (R6), weak halves (R7),
opposite halves (R7b), other faces (R7c), faint rims (R7d)."""

from __future__ import annotations

import numpy as np
import pytest
from object_masks import disk

from stages._rock_parts import (
    grow_other_faces,
    grow_weak_halves,
    join_opposite_halves,
    split_at_necks,
    trim_attached_shadows,
    trim_faint_rims,
)


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


def test_trim_attached_shadows_removes_the_lighter_class_of_a_dark_rock_only():
    yy, xx = np.mgrid[:80, :80]
    image = np.full((80, 80), 160, np.uint8)
    rock = (yy - 25) ** 2 + (xx - 25) ** 2 <= 64
    shadow = ((yy - 25) ** 2 + (xx - 33) ** 2 <= 64) & ~rock
    image[rock], image[shadow] = 40, 130
    light_rock = (yy - 60) ** 2 + (xx - 60) ** 2 <= 64
    light_shadow = ((yy - 60) ** 2 + (xx - 68) ** 2 <= 64) & ~light_rock
    image[light_rock], image[light_shadow] = 230, 100
    labels = np.zeros((80, 80), np.int32)
    labels[rock | shadow] = 1
    labels[light_rock | light_shadow] = 2
    trimmed = trim_attached_shadows(labels, image)
    np.testing.assert_array_equal(trimmed == 1, rock)
    np.testing.assert_array_equal(trimmed == 2, light_rock | light_shadow)
    with pytest.raises(ValueError, match="one shape"):
        trim_attached_shadows(labels, image[:10])


def half_rock(shape=(40, 40), *, weak=-0.8):
    """A disk whose left half is past the low threshold (contrast -2, labelled 1) and whose
    right half has contrast ``weak`` (between the thresholds) on flat ground (contrast 0)."""
    rock = disk(shape, 20, 20, 10)
    left = rock & (np.arange(shape[1])[None, :] < 20)
    contrast = np.zeros(shape, np.float32)
    contrast[left] = -2.0
    contrast[rock & ~left] = weak
    return rock, left, contrast


def test_grow_weak_halves_completes_a_rock_whose_other_half_is_just_inside_the_threshold():
    rock, left, contrast = half_rock()
    labels = left.astype(np.int32)
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1)
    assert np.array_equal(grown > 0, rock) and set(np.unique(grown)) == {0, 1}
    assert count == np.count_nonzero(rock & ~left)
    # the same for a light rock
    grown, _ = grow_weak_halves(labels, -contrast, between=np.abs(contrast) < 1)
    assert np.array_equal(grown > 0, rock)


def test_grow_weak_halves_takes_only_weak_pixels_of_the_objects_own_side():
    rock, left, contrast = half_rock(weak=0.8)  # the other half is lighter: not this rock's
    labels = left.astype(np.int32)
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1)
    assert count == 0 and np.array_equal(grown, labels)
    rock, left, contrast = half_rock(weak=-0.5)  # too close to the ground
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1)
    assert count == 0


def test_grow_weak_halves_leaves_pixels_a_rule_removed():
    """A trimmed shadow (past the threshold, removed by R6) is not grown back."""
    rock, left, contrast = half_rock(weak=-1.5)
    labels = left.astype(np.int32)
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1)
    assert count == 0 and np.array_equal(grown, labels)


def test_grow_weak_halves_keeps_growth_only_when_the_object_stays_as_solid():
    # a compact rock next to a weak streak of texture: growing along it would make it ragged
    shape = (40, 60)
    rock = disk(shape, 20, 15, 8)
    contrast = np.where(rock, np.float32(-2.0), np.float32(0.0))
    contrast[19:21, 23:58] = -0.8
    labels = rock.astype(np.int32)
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1)
    assert count == 0 and np.array_equal(grown, labels)
    # ... or a few steps along it
    grown, count = grow_weak_halves(labels, contrast, between=np.abs(contrast) < 1, max_steps=3)
    assert count == 0
    # a slack as large as any drop keeps the growth
    grown, count = grow_weak_halves(
        labels, contrast, between=np.abs(contrast) < 1, max_steps=60, solidity_slack=1.0
    )
    assert count == np.count_nonzero((contrast == np.float32(-0.8)) & (labels == 0))


def test_grow_weak_halves_steps_limit_the_growth_and_bad_arguments_raise():
    rock, left, contrast = half_rock()
    labels = left.astype(np.int32)
    between = np.abs(contrast) < 1
    grown, _ = grow_weak_halves(labels, contrast, between=between, max_steps=3)
    assert (grown > 0).sum() < rock.sum() and grown[20, 22] == 1 and grown[20, 28] == 0
    grown, count = grow_weak_halves(labels, contrast, between=between, max_steps=0)
    assert count == 0 and np.array_equal(grown, labels)
    with pytest.raises(ValueError, match="solidity_slack >= 0"):
        grow_weak_halves(labels, contrast, between=between, solidity_slack=-0.1)
    with pytest.raises(ValueError, match="min_contrast > 0"):
        grow_weak_halves(labels, contrast, between=between, min_contrast=0)
    with pytest.raises(ValueError, match="one shape"):
        grow_weak_halves(labels, contrast[:10], between=between)
    with pytest.raises(TypeError, match="bool"):
        grow_weak_halves(labels, contrast, between=between.astype(np.uint8))


def two_halves(shape=(40, 40), gap=2):
    """A disk split into a lit left half (object 1) and a shaded right half (object 2),
    ``gap`` ground-gray columns (the terminator) between them."""
    rock = disk(shape, 20, 20, 10)
    xx = np.arange(shape[1])[None, :]
    lit, shaded = rock & (xx < 20 - gap // 2), rock & (xx >= 20 - gap // 2 + gap)
    labels = lit.astype(np.int32) + 2 * shaded.astype(np.int32)
    contrast = np.where(lit, np.float32(2.0), np.where(shaded, np.float32(-2.0), np.float32(0)))
    return rock, labels, contrast


def test_join_opposite_halves_makes_one_rock_of_a_lit_and_a_shaded_half():
    rock, labels, contrast = two_halves()
    joined, count = join_opposite_halves(labels, contrast)
    assert count == 1 and set(np.unique(joined)) == {0, 1}
    # the terminator between the halves is part of the rock (a closing: all but its ends)
    assert not (joined[rock == 0] > 0).any() and np.count_nonzero(rock & (joined == 0)) <= 8
    assert (joined[14:27, 19:21] == 1).all()


def test_join_opposite_halves_leaves_same_side_far_or_ragged_pairs_alone():
    rock, labels, contrast = two_halves()
    # two darker halves: R4 or the thresholds separated them, not the light
    joined, count = join_opposite_halves(labels, -np.abs(contrast))
    assert count == 0 and np.array_equal(joined, labels)
    # halves farther apart than the gap
    rock, labels, contrast = two_halves(gap=8)
    joined, count = join_opposite_halves(labels, contrast, gap_px=5)
    assert count == 0
    # a rock and a lighter neighbour beside it: their union is not one compact blob
    shape = (40, 70)
    labels = disk(shape, 20, 15, 10).astype(np.int32) + 2 * disk(shape, 20, 47, 10)
    contrast = np.where(labels == 1, np.float32(-2.0), np.float32(2.0))
    joined, count = join_opposite_halves(labels, contrast, gap_px=12)
    assert count == 0 and np.array_equal(joined, labels)
    joined, count = join_opposite_halves(labels, contrast, gap_px=0)
    assert count == 0
    with pytest.raises(ValueError, match="gap_px >= 0"):
        join_opposite_halves(labels, contrast, gap_px=-1)
    with pytest.raises(ValueError, match="one shape"):
        join_opposite_halves(labels, contrast[:10])


def test_grow_weak_halves_opposite_completes_the_other_face_of_a_rock():
    # rule R7c: a lit rock on lava found by its shaded half only; its lit face, lighter than
    # the ground, lies on the other side of the ground's gray level
    rock, left, contrast = half_rock(weak=0.6)
    labels = left.astype(np.int32)
    grown, count = grow_weak_halves(labels, contrast, between=labels == 0)
    assert count == 0  # R7 takes only the object's own side
    grown, count = grow_weak_halves(
        labels, contrast, between=labels == 0, min_contrast=0.5, opposite=True
    )
    assert np.array_equal(grown > 0, rock) and count == np.count_nonzero(rock & ~left)
    # the same for a light rock whose shaded face is darker than the ground
    grown, _ = grow_weak_halves(
        labels, -contrast, between=labels == 0, min_contrast=0.5, opposite=True
    )
    assert np.array_equal(grown > 0, rock)
    # a face too close to the ground's gray is not taken
    grown, count = grow_weak_halves(
        labels, contrast, between=labels == 0, min_contrast=0.7, opposite=True
    )
    assert count == 0


def test_grow_weak_halves_opposite_leaves_a_neighbouring_light_blotch():
    # a dark rock beside a long light streak of texture: taking it would make the rock ragged
    shape = (40, 60)
    rock = disk(shape, 20, 15, 8)
    contrast = np.where(rock, np.float32(-2.0), np.float32(0.0))
    contrast[19:21, 23:58] = 1.5
    labels = rock.astype(np.int32)
    grown, count = grow_weak_halves(
        labels, contrast, between=labels == 0, min_contrast=0.5, opposite=True
    )
    assert count == 0 and np.array_equal(grown, labels)


def test_grow_other_faces_takes_a_face_not_a_rim():
    # R7c: the lit half of a rock is taken; a one-pixel rim of light pixels is not (a fifth)
    rock, left, contrast = half_rock(weak=0.6)
    labels = left.astype(np.int32)
    grown, count = grow_other_faces(labels, contrast)
    assert np.array_equal(grown > 0, rock) and count == np.count_nonzero(rock & ~left)
    shape = (40, 40)
    core = disk(shape, 20, 20, 9)
    rim = disk(shape, 20, 20, 10) & ~core & (np.arange(40)[None, :] >= 20)
    contrast = np.where(core, np.float32(-2.0), np.float32(0.0))
    contrast[rim] = 1.0
    labels = core.astype(np.int32)
    grown, count = grow_other_faces(labels, contrast)
    assert count == 0 and np.array_equal(grown, labels)
    with pytest.raises(ValueError, match="min_gain >= 0"):
        grow_weak_halves(labels, contrast, between=labels == 0, min_gain=-1.0)


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
