"""Tests of stages/_shadow_sides.py: a lit rock's shaded face on, its cast shadow off (R7e)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._rock_parts import join_opposite_halves
from stages._shadow_sides import _label_counts, split_shadow_sides

SHAPE = (40, 60)
ROCK_M = 0.04  # a rock's height (metres), far above 3 sigmas of 4 mm
NOISE_M = 0.004
_SLACK = 0.2  # R7b's solidity slack for the scene's square objects


def lit_rock_scene(*, shadow_object: bool, face_m: float = ROCK_M, face_px: int = 6):
    """A lit face (columns 24-33), its shaded face (``face_px`` columns up to 21) and cast
    shadow (the 10 columns before), rows 10-29.

    The lit face is object 1, lighter than the ground; the shaded face is as dark as the
    shadow and both make object 2 (``shadow_object``), or the face is ground gray and the
    shadow, dark, is no object. Columns 22-23 are ground gray (the terminator).
    """
    labels = np.zeros(SHAPE, np.int32)
    contrast = np.zeros(SHAPE, np.float32)
    relative = np.zeros(SHAPE, np.float32)
    rows = slice(10, 30)
    labels[rows, 24:34] = 1
    contrast[rows, 24:34] = 3.0
    relative[rows, 22:34] = ROCK_M
    face = slice(22 - face_px, 22)
    relative[rows, face] = face_m
    contrast[rows, face.start - 10 : face.start] = -3.0  # the shadow, on the ground
    if shadow_object:
        contrast[rows, face] = -3.0
        labels[rows, face.start - 10 : 22] = 2
    return labels, contrast, relative, np.full(SHAPE[0], NOISE_M)


def test_dark_neighbour_gives_its_raised_face_and_loses_its_flat_shadow():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    out, moved = split_shadow_sides(labels, contrast, relative, noise)
    # the face and the terminator joined the lit face (a closing leaves the terminator's
    # corners), the shadow left is dropped
    assert 20 * 6 + 2 * 16 <= moved <= 20 * 8
    assert set(np.unique(out)) == {0, 1}
    assert np.array_equal(out, np.where(out > 0, 1, 0))
    assert np.array_equal(np.nonzero(out.any(axis=0))[0], np.arange(16, 34))
    assert np.array_equal(np.nonzero(out.any(axis=1))[0], np.arange(10, 30))
    assert np.all(out[10:30, 16:22] == 1) and np.all(out[12:28, 22:24] == 1)


def test_dark_rock_standing_whole_beside_a_lit_one_keeps_its_pixels():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    relative[10:30, 6:16] = ROCK_M  # no flat part: a dark rock, not a face and a shadow
    out, moved = split_shadow_sides(labels, contrast, relative, noise)
    assert moved == 0 and np.array_equal(out, labels)


def test_ground_gray_face_between_a_lit_face_and_a_shadow_no_object_holds():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=False, face_px=3)
    out, moved = split_shadow_sides(labels, contrast, relative, noise)
    # the raised gray columns between lit face and shadow join (but the closing's corners);
    # the dark shadow does not
    assert 16 * 5 <= moved <= 20 * 5
    assert np.all(out[12:28, 19:34] == 1)
    assert not out[:, :19].any() and not out[:10].any() and not out[30:].any()
    # gray pixels at ground level there are ground: nothing joins
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=False, face_m=0.0, face_px=3)
    relative[10:30, 22:24] = 0.0
    out, moved = split_shadow_sides(labels, contrast, relative, noise)
    assert moved == 0 and np.array_equal(out, labels)


def test_gray_face_before_a_shadow_object_the_matcher_stood_up_joins_the_lit_face():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=False, face_px=3)
    labels[10:30, 9:19] = 2  # the shadow, an object of its own, as high as the rock
    relative[10:30, 9:19] = ROCK_M
    out, moved = split_shadow_sides(labels, contrast, relative, noise)
    # not split (nothing of it lies flat), but the gray face between them joins the lit face
    assert 16 * 5 <= moved <= 20 * 5
    assert np.all(out[12:28, 19:34] == out[20, 30]) and np.all(out[10:30, 9:19] == out[20, 12])
    assert out[20, 12] != out[20, 30] and set(np.unique(out)) == {0, 1, 2}


def test_rows_too_noisy_or_rule_off_change_nothing():
    for shadow_object in (True, False):
        labels, contrast, relative, noise = lit_rock_scene(shadow_object=shadow_object)
        noisy = np.full(SHAPE[0], 0.01)  # 10 mm: far rows
        assert split_shadow_sides(labels, contrast, relative, noisy)[1] == 0
        assert split_shadow_sides(labels, contrast, relative, noise, max_noise_m=0)[1] == 0
        invalid = np.full(SHAPE, np.nan, np.float32)  # no heights: nothing to read
        out, moved = split_shadow_sides(labels, contrast, invalid, noise)
        assert moved == 0 and np.array_equal(out, labels)


def test_bad_arguments_say_what_was_expected():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    with pytest.raises(ValueError, match="must have one shape"):
        split_shadow_sides(labels, contrast[:, :-1], relative, noise)
    with pytest.raises(ValueError, match="one value per row"):
        split_shadow_sides(labels, contrast, relative, noise[:-1])
    with pytest.raises(ValueError, match="max_noise_m >= 0"):
        split_shadow_sides(labels, contrast, relative, noise, max_noise_m=-1.0)
    with pytest.raises(ValueError, match="gap_px >= 1"):
        split_shadow_sides(labels, contrast, relative, noise, gap_px=0)


def test_label_counts_equal_their_bincounts():
    # the twin: the three bincounts of masked copies the compiled pass replaced
    rng = np.random.default_rng(6)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        count = int(rng.integers(1, 8))
        labels = rng.integers(0, count, shape).astype(np.int32)
        labels[rng.random(shape) < 0.5] = 0
        precise = rng.random(shape) < 0.7
        flat = precise & (rng.random(shape) < 0.4)
        n_pixels, n_precise, n_flat = _label_counts(labels, precise, flat, count)
        np.testing.assert_array_equal(n_pixels, np.bincount(labels.ravel(), minlength=count))
        np.testing.assert_array_equal(n_precise, np.bincount(labels[precise], minlength=count))
        np.testing.assert_array_equal(n_flat, np.bincount(labels[flat], minlength=count))


def test_cast_shadow_split_before_r7b_joins_it_whole_mojave_0011_rock_4():
    """Regression (mojave_0011 rock 4): R7b joined a lit face to its dark neighbour, shaded
    face plus flat cast shadow, whole (IoU 0.81 -> 0.68, a sample measured as an obstacle)
    and R7e, after it, never saw the pair. R7e splits clearly raised faces before R7b too."""
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    rock = (labels > 0) & (relative > 0)
    # the scene's square corners cost its closed union solidity: a wider slack than R7b's
    whole, count = join_opposite_halves(labels, contrast, solidity_slack=_SLACK)
    assert count == 1 and np.count_nonzero(whole > 0) > np.count_nonzero(rock) + 150
    split, moved = split_shadow_sides(
        labels, contrast, relative, noise, cases=(1,), facing_only=True
    )
    assert moved > 0 and set(np.unique(split)) == {0, 1}
    out, count = join_opposite_halves(split, contrast, solidity_slack=_SLACK)
    assert count == 0 and np.array_equal(out, split)
    assert np.count_nonzero(out[rock] == 1) == np.count_nonzero(rock)
    assert not (out[10:30, :16] > 0).any()  # the cast shadow is gone


def test_hardly_raised_shaded_face_is_left_to_r7b():
    # the stereo flattened the shaded face: before R7b a few raised pixels are no reason to
    # call the rest a cast shadow (mojave seed 2, mojave_0008 rock 7); R7b joins it whole
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True, face_m=0.0)
    relative[10:30, 22:24] = 0.0
    relative[19, 21] = ROCK_M
    out, moved = split_shadow_sides(
        labels, contrast, relative, noise, cases=(1,), facing_only=True
    )
    assert moved == 0 and np.array_equal(out, labels)
    # the call after R7d splits it all the same (its one raised pixel) and drops the rest
    assert split_shadow_sides(labels, contrast, relative, noise)[1] > 0
    joined, count = join_opposite_halves(out, contrast, solidity_slack=_SLACK)
    assert count == 1 and set(np.unique(joined)) == {0, 1}


def test_dark_rock_body_beside_a_small_highlight_is_left_to_r7b():
    # lava seed 3, lava_0008 rock 9: a dark rock body (its raised part larger than the lit
    # object) beside a highlight; before R7b the highlight does not take it (IoU 0.87 ->
    # 0.71 when it did), R7b joins the two
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    labels[labels == 1] = 0
    labels[18:22, 24:26] = 1  # the lit object, 8 px, on the rock
    out, moved = split_shadow_sides(
        labels, contrast, relative, noise, cases=(1,), facing_only=True
    )
    assert moved == 0 and np.array_equal(out, labels)
    assert split_shadow_sides(labels, contrast, relative, noise, cases=(1,))[1] > 0


def test_cases_run_on_their_own():
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=True)
    out, moved = split_shadow_sides(labels, contrast, relative, noise, cases=(2,))
    assert moved == 0 and np.array_equal(out, labels)
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=False, face_px=3)
    out, moved = split_shadow_sides(labels, contrast, relative, noise, cases=(1,))
    assert moved == 0 and np.array_equal(out, labels)
    assert split_shadow_sides(labels, contrast, relative, noise, cases=(2,))[1] > 0
    with pytest.raises(ValueError, match="cases"):
        split_shadow_sides(labels, contrast, relative, noise, cases=(3,))


@pytest.mark.parametrize("shadow_object", [True, False])
def test_labels_with_a_gap_no_longer_fail_on_the_absent_id(shadow_object):
    # an absent id (a rule before R7e may empty an object) has no contrast values, its
    # median +inf read as light: its (empty) box failed cv2.dilate (spans None before)
    labels, contrast, relative, noise = lit_rock_scene(shadow_object=shadow_object, face_px=3)
    dense, moved = split_shadow_sides(labels, contrast, relative, noise)
    assert moved > 0
    with_gap = np.where(labels == 2, 4, labels)
    with_gap[with_gap == 1] = 3
    out, moved_gap = split_shadow_sides(with_gap, contrast, relative, noise)
    # the same pixels moved, and the result renumbered 1..n as without the gap
    assert moved_gap == moved
    np.testing.assert_array_equal(out, dense)
