"""Tests of stages/_regions.py: masks, holes, components, split (R4), streaks (R5), R6, R7."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stages._regions import (
    depth_edges,
    fill_holes,
    grow_other_faces,
    grow_weak_halves,
    join_opposite_halves,
    label_objects,
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


def test_drop_streaks_keeps_a_clear_flat_rock_but_not_a_faint_trough_or_a_long_streak():
    # rule R5b: far rocks seen edge-on measured 3.0-3.6x wider than tall on mojave and lava
    # and were dropped as streaks; they stand out in gray level, ripple troughs barely do
    from stages._regions import drop_streaks, elongation

    labels = np.zeros((80, 100), np.int32)
    labels[10:17, 10:35] = 1  # a flat rock, 3.6x, 3 threshold bands dark
    labels[30:37, 10:35] = 2  # a trough of the same shape, 1.5 bands dark
    labels[50:54, 10:70] = 3  # a long streak, 15x, 3 bands dark
    contrast = np.zeros(labels.shape, np.float32)
    contrast[labels == 1] = contrast[labels == 3] = -3.0
    contrast[labels == 2] = -1.5
    assert 3.0 < elongation(labels)[1] < 4.0
    kept, dropped = drop_streaks(labels, max_elongation=3.0, contrast=contrast)
    assert dropped == 2
    assert kept[12, 20] == 1 and not kept[30:37].any() and not kept[50:54].any()
    # without the gray levels every elongated object goes
    _, dropped = drop_streaks(labels, max_elongation=3.0)
    assert dropped == 3
    with pytest.raises(ValueError, match="one shape"):
        drop_streaks(labels, max_elongation=3.0, contrast=contrast[:10])
    with pytest.raises(ValueError, match="clear_elongation"):
        drop_streaks(labels, max_elongation=3.0, contrast=contrast, clear_elongation=1.0)


def test_trim_attached_shadows_removes_the_lighter_class_of_a_dark_rock_only():
    from stages._regions import trim_attached_shadows

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



def _ripples(shape, angle_deg, *, period=20.0, length=60):
    """A rippled sand image and its ground-texture objects (troughs cut into streaks).

    Gray ``128 + 30 sin`` across ripples running at ``angle_deg`` (0 along the rows); the
    troughs (sin < -0.7) are cut every ``length`` pixels along the ripples and labelled.
    """
    yy, xx = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    yy, xx = yy - shape[0] / 2, xx - shape[1] / 2
    theta = np.radians(angle_deg)
    along = xx * np.cos(theta) + yy * np.sin(theta)
    across = -xx * np.sin(theta) + yy * np.cos(theta)
    wave = np.sin(2 * np.pi * across / period)
    image = np.clip(128 + 30 * wave, 0, 255).astype(np.uint8)
    troughs = (wave < -0.7) & (np.floor(along / length) % 2 == 0)
    texture = label_objects(troughs, min_area_px=20, fill=False)
    return image, texture, wave, along


@pytest.mark.parametrize("angle_deg", [0.0, 35.0, -70.0])
def test_drop_ripple_pieces_drops_a_piece_of_trough_but_keeps_a_rock(angle_deg):
    # rule R5c: on dunes frames fragments of ripple shading (30-300 px, 1-2.7 threshold
    # bands from the ground level) passed the depth and streak rules as rocks
    from stages._regions import drop_ripple_pieces

    shape = (200, 200)
    image, texture, wave, along = _ripples(shape, angle_deg)
    labels = np.zeros(shape, np.int32)
    piece = (wave < -0.7) & (np.abs(along - 20) < 6) & disk(shape, 100, 100, 30)
    labels[piece] = 1  # a piece of a trough, as dark as the troughs around it
    rock = disk(shape, 60, 150, 5)
    image[rock] = 40  # a dark rock among the ripples
    labels[rock] = 2
    kept, dropped = drop_ripple_pieces(labels, texture=texture, image=image)
    assert dropped == 1
    assert not kept[piece].any() and kept[rock].all()


def test_drop_ripple_pieces_needs_a_field_of_parallel_streaks_around_the_object():
    from stages._regions import drop_ripple_pieces

    streaks_only = {"min_gradient_coherence": 1.0}  # the image's gradients are ripples too

    shape = (200, 200)
    image, texture, wave, along = _ripples(shape, 0.0)
    labels = np.zeros(shape, np.int32)
    labels[(wave < -0.7) & (np.abs(along - 20) < 6) & disk(shape, 100, 100, 30)] = 1
    _, dropped = drop_ripple_pieces(labels, texture=texture, image=image, **streaks_only)
    assert dropped == 1
    # streaks in every direction: no common direction (coherence < 0.8)
    crossed = np.zeros(shape, np.int32)
    for k, (cy, cx, angle) in enumerate(
        [(30, 30, 0), (30, 170, 45), (170, 30, 90), (170, 170, -45), (100, 30, 60)], start=1
    ):
        crossed[_bar(shape, cy, cx, 60, 3, angle)] = k
    _, dropped = drop_ripple_pieces(labels, texture=crossed, image=image, **streaks_only)
    assert dropped == 0
    # parallel streaks, but too far away
    _, dropped = drop_ripple_pieces(
        labels, texture=texture, image=image, radius_px=2, **streaks_only
    )
    assert dropped == 0
    # streaks smaller together than the object: specks of texture around a rock
    specks = np.where(np.isin(texture, [1, 2, 3]), texture, 0)
    big = np.zeros(shape, np.int32)
    big[disk(shape, 100, 100, 40) & (wave < -0.7)] = 1
    assert (specks > 0).sum() < (big > 0).sum()
    _, dropped = drop_ripple_pieces(
        big, texture=specks, image=image, radius_px=300, **streaks_only
    )
    assert dropped == 0
    with pytest.raises(ValueError, match="one shape"):
        drop_ripple_pieces(labels, texture=texture[:10], image=image)
    with pytest.raises(ValueError, match="min_coherence"):
        drop_ripple_pieces(labels, texture=texture, image=image, min_coherence=0)


def _bar(shape, cy, cx, length, width, angle_deg):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    theta = np.radians(angle_deg)
    along = (xx - cx) * np.cos(theta) + (yy - cy) * np.sin(theta)
    across = -(xx - cx) * np.sin(theta) + (yy - cy) * np.cos(theta)
    return (np.abs(along) <= length / 2) & (np.abs(across) <= width / 2)


def test_drop_ripple_pieces_sees_ripples_too_faint_to_leave_streaks_in_the_gradients():
    # on a dunes frame of seed 11 the ripple shading crossed the thresholds only in two
    # pieces near the camera: no streaks, but every gray-level gradient around runs one way
    from stages._regions import _gradient_coherence, drop_ripple_pieces

    shape = (200, 200)
    image, _, wave, along = _ripples(shape, 30.0)
    no_streaks = np.zeros(shape, np.int32)
    labels = np.zeros(shape, np.int32)
    piece = (wave < -0.7) & (np.abs(along - 20) < 6) & disk(shape, 100, 100, 30)
    labels[piece] = 1
    centre = np.array([100.0]), np.array([100.0])
    assert _gradient_coherence(image, *centre, radius_px=100) > 0.95
    kept, dropped = drop_ripple_pieces(labels, texture=no_streaks, image=image)
    assert dropped == 1 and not kept.any()
    # isotropic texture of the same contrast: no common direction, the piece stays
    noise = np.random.default_rng(3).normal(128, 20, shape)
    soil = np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 4 - 3 * 128, 0, 255).astype(np.uint8)
    soil[piece] = image[piece]
    assert _gradient_coherence(soil, *centre, radius_px=100) < 0.5
    _, dropped = drop_ripple_pieces(labels, texture=no_streaks, image=soil)
    assert dropped == 0
    # 1 disables the gradient evidence
    _, dropped = drop_ripple_pieces(
        labels, texture=no_streaks, image=image, min_gradient_coherence=1.0
    )
    assert dropped == 0


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
