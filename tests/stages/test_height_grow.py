"""Tests of stages/_height_grow.py: a partial near rock grows over its raised rest (R7f)."""

from __future__ import annotations

import numpy as np
import pytest

from stages._height_grow import grow_raised_parts

SHAPE = (60, 80)
ROCK_M = 0.04  # a near rock's height, 10 sigmas of 4 mm
NOISE_M = 0.004


def partial_rock_scene(*, rest_contrast: float = -0.6, found_cols: int = 18):
    """A dark rock, rows 15-44 and columns 20-49, standing ``ROCK_M`` high; only its left
    ``found_cols`` columns are object 1 (past the low threshold, contrast -2), the rest is
    ``rest_contrast`` bands from the ground's gray level (within the thresholds)."""
    labels = np.zeros(SHAPE, np.int32)
    contrast = np.zeros(SHAPE, np.float32)
    relative = np.zeros(SHAPE, np.float32)
    rows, cols = slice(15, 45), slice(20, 50)
    relative[rows, cols] = ROCK_M
    contrast[rows, cols] = rest_contrast
    found = slice(20, 20 + found_cols)
    contrast[rows, found] = -2.0
    labels[rows, found] = 1
    return labels, contrast, relative, np.full(SHAPE[0], NOISE_M)


def test_partial_rock_grows_over_its_raised_rest_on_its_gray_side():
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    # the raised footprint (12 columns, R7f's farthest growth), no ground pixel, but for
    # its two outer corners: their window holds more ground (contrast 0) than rock
    assert set(np.unique(out)) == {0, 1}
    assert not (out > 0)[relative == 0].any()
    missed = np.argwhere((relative > 0) & (out == 0))
    assert missed.tolist() == [[15, 49], [44, 49]] and grown == 30 * 12 - 2


def test_raised_fringe_on_the_other_gray_side_is_not_taken():
    # the stereo fringe: raised ground around the rock whose gray scatters both ways; the
    # 5x5 mean of a checkerboard of +-1 bands is near the ground's level
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    relative[10:50, 15:55] = np.maximum(relative[10:50, 15:55], 0.03)
    checker = np.indices(SHAPE).sum(axis=0) % 2 * 2.0 - 1.0
    ring = (relative > 0) & (labels == 0)
    contrast[ring] = checker[ring]
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)


def test_rest_lighter_than_the_ground_does_not_join_a_dark_object():
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=0.6)
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)


def test_small_object_low_core_or_noisy_rows_are_not_grown():
    first = {"strong_fraction": 0.0, "broad_fraction": 0.0}  # the first case alone
    labels, contrast, relative, noise = partial_rock_scene(found_cols=4)  # 120 px < 150
    assert grow_raised_parts(labels, contrast, relative, noise, **first)[1] == 0
    labels, contrast, relative, noise = partial_rock_scene()
    # a 12 mm row noise: too noisy a row (the core stands 3.3 sigmas, too low as well)
    noisy = np.full(SHAPE[0], 0.012)
    assert grow_raised_parts(labels, contrast, relative, noisy, **first)[1] == 0
    # 4.4 sigmas of a 9 mm row noise: a row R7f reads, too low a core
    assert grow_raised_parts(labels, contrast, relative, np.full(SHAPE[0], 0.009), **first)[1] == 0
    assert grow_raised_parts(labels, contrast, relative * 0.45, noise, **first)[1] == 0


def test_rows_between_seven_and_a_half_and_ten_mm_of_noise_are_read():
    # segment v38: lava_0003 rock 26 (2.7 m away) lay in a row of 7.5-10 mm noise, above
    # R7f's old 7.5 mm bar, and stayed a partial object (IoU 0.44; 0.61 grown)
    labels, contrast, relative, _ = partial_rock_scene()
    row_noise = np.full(SHAPE[0], 0.0085)
    first = {"strong_fraction": 0.0, "broad_fraction": 0.0}
    # a 6 cm rock: 7 sigmas of 8.5 mm
    out, grown = grow_raised_parts(labels, contrast, relative * 1.5, row_noise, **first)
    assert grown > 0 and not (out > 0)[relative == 0].any()
    old_bar = grow_raised_parts(
        labels, contrast, relative * 1.5, row_noise, max_noise_m=0.0075, **first
    )
    assert old_bar[1] == 0


def test_second_case_grows_small_or_low_objects_over_a_rest_clearly_on_their_side():
    # mojave seed 3, mojave_0000 rock 4 and mojave_0006 rock 5: objects of 100-140 px (or
    # 3 sigmas) whose rest is 0.65 bands darker than the ground were left partial
    labels, contrast, relative, noise = partial_rock_scene(found_cols=4)  # 120 px
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown > 0 and not (out > 0)[relative == 0].any()
    assert np.all(out[17:43, 20:32] == 1)
    # a core of 4.5 sigmas: below the first case's 5, above the second's 2.5
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative * 0.45, noise)
    # its rim's 5x5 windows hold more ground: out of the 0.45 bands but for the inner rows
    assert grown > 0 and np.all(out[17:43, 20:48] == 1) and not (out > 0)[relative == 0].any()
    # a rest within the second case's 0.45 bands stays out of small objects
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=-0.3, found_cols=4)
    assert grow_raised_parts(labels, contrast, relative, noise)[1] == 0
    # and objects under 60 px are never grown
    labels, contrast, relative, noise = partial_rock_scene(found_cols=1)  # 30 px
    assert grow_raised_parts(labels, contrast, relative, noise)[1] == 0


def test_growth_stops_at_half_the_core_height_and_after_max_steps():
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = 0.4 * ROCK_M  # the far part lies below half the core
    out, grown = grow_raised_parts(
        labels, contrast, relative, noise, strong_fraction=0, broad_fraction=0
    )
    # less the two outer corners' 2 px each that the opening with a disk rounds off
    assert grown == 30 * 6 - 4 and np.all(out[17:43, 20:44] == 1) and not out[:, 44:].any()
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(
        labels, contrast, relative, noise, max_steps=3, strong_fraction=0, broad_fraction=0
    )
    assert grown == 30 * 3 and np.all(out[15:45, 20:41] == 1) and not out[:, 41:].any()
    # the second case reaches it: above a quarter of the core, 0.6 bands out on its side
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = 0.4 * ROCK_M
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert np.all(out[17:43, 20:49] == 1)


def test_third_case_grows_large_objects_over_a_broad_faint_rest_not_a_thin_rim():
    # lava_0002 rock 4: a large flat dark rock found in part (223 of 1298 px) whose rest
    # stands 0.5-1 cm (1-2 sigmas) and 0.4 bands dark: neither earlier case reaches it
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=-0.3)
    relative *= 0.15  # 6 mm: 1.5 sigmas
    out, grown = grow_raised_parts(labels, contrast, relative, noise, broad_fraction=0)
    assert grown == 0
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown > 0 and np.all(out[18:42, 20:47] == 1) and not (out > 0)[relative == 0].any()
    # a rock found whole with a 6-px wide tongue of raised, faintly dark fringe to its
    # right: the opening with a 15-px disk cuts it off but for a few px at its root
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    relative[27:33, 50:62] = 0.006
    contrast[27:33, 50:62] = -0.3
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown <= 6 and not out[:, 51:].any()
    out, grown = grow_raised_parts(labels, contrast, relative, noise, broad_fraction=0)
    assert grown == 0


def test_pixels_of_other_objects_are_kept_and_highest_core_grows_first():
    labels, contrast, relative, noise = partial_rock_scene()
    labels[15:45, 44:50] = 2  # a lower dark object on the rock's right edge
    relative[15:45, 44:50] = 0.8 * ROCK_M
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 30 * 6 - 4  # the corners next to object 2 rounded off
    assert np.all(out[17:43, 20:44] == 1) and np.all(out[15:45, 44:50] == 2)


def test_zero_fraction_disables_and_bad_arguments_are_refused():
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative, noise, fraction=0)
    assert grown == 0 and out is labels
    with pytest.raises(ValueError, match="fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, fraction=1.5)
    with pytest.raises(ValueError, match="one value per row"):
        grow_raised_parts(labels, contrast, relative, noise[:-1])
    with pytest.raises(ValueError, match="must have one shape"):
        grow_raised_parts(labels, contrast[:-1], relative, noise)
    with pytest.raises(ValueError, match="strong_fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, strong_fraction=-0.1)
    with pytest.raises(ValueError, match="broad_fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, broad_fraction=2.0)
    with pytest.raises(ValueError, match="strong_min_object_px >= 1"):
        grow_raised_parts(labels, contrast, relative, noise, strong_min_object_px=0)


def test_invalid_heights_are_not_grown_over():
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = np.nan
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 30 * 6 - 4 and not out[:, 44:].any()


def test_raised_ground_above_the_top_row_and_thin_strands_are_not_taken():
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    # raised, dark ground behind the rock (above its top row) and a 2-px strand to its right
    relative[5:15, 20:50] = ROCK_M
    contrast[5:15, 20:50] = -0.6
    relative[28:30, 50:60] = ROCK_M
    contrast[28:30, 50:60] = -0.6
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)
