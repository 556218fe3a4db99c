"""Tests of stages/_sun_shadows.py: the frame's anti-sun direction and R6b's cast shadows."""

from __future__ import annotations

import numpy as np
import pytest

from stages._sun_shadows import anti_sun_direction, trim_sun_shadows

_GROUND = 150


def _lit_rocks(labels, contrast, image, *, side=1, first=1):
    """Three lit rocks (12x12) along the top of a 100x120 frame, each with its dark half on
    the ``side`` (+1: right, -1: left) -- a sun from the other side."""
    for i, x in enumerate((10, 50, 90)):
        labels[5:17, x : x + 12] = first + i
        lit, dark = (slice(x, x + 6), slice(x + 6, x + 12))[:: side]
        contrast[5:17, lit], image[5:17, lit] = 3.0, 230
        contrast[5:17, dark], image[5:17, dark] = -3.0, 60


def _frame(shadow_side: int):
    """Three lit rocks (sun from the left) and a dark rock (gray 20, 10x10) with a lighter
    6-px strip (gray 50, a third of the ground's gray) on its ``shadow_side``, one object."""
    labels = np.zeros((100, 120), np.int32)
    contrast = np.zeros(labels.shape)
    image = np.full(labels.shape, _GROUND, np.uint8)
    _lit_rocks(labels, contrast, image)
    labels[50:60, 50:60], image[50:60, 50:60] = 4, 20
    strip = (slice(50, 60), slice(60, 66) if shadow_side > 0 else slice(44, 50))
    labels[strip], image[strip] = 4, 50
    contrast[labels == 4] = -3.0
    return labels, image, contrast, strip


def test_the_lit_rocks_dark_sides_point_away_from_the_sun():
    labels, _, contrast, _ = _frame(+1)
    assert anti_sun_direction(labels, contrast) == pytest.approx([0.0, 1.0])


def test_no_direction_from_too_few_or_disagreeing_pairs():
    labels, _, contrast, _ = _frame(+1)
    assert anti_sun_direction(labels, contrast, min_pairs=4) is None
    # three more rocks lit from the right: the pairs cancel out
    image = np.zeros(labels.shape, np.uint8)
    more = np.zeros_like(labels)
    _lit_rocks(more, contrast, image, side=-1, first=5)
    labels[25:37] = more[5:17]
    contrast[25:37] = contrast[5:17]
    contrast[5:17] = np.where(labels[5:17] > 0, np.sign(np.arange(120) % 40 - 15.5) * -3, 0)
    assert anti_sun_direction(labels, contrast) is None


def test_a_dark_rock_loses_its_lighter_piece_on_the_shadow_side():
    labels, image, contrast, strip = _frame(+1)
    out, trimmed = trim_sun_shadows(labels, image, contrast)
    assert trimmed == 1
    assert not out[strip].any()
    assert np.array_equal(out[50:60, 50:60], labels[50:60, 50:60])
    assert np.array_equal(out[:20], labels[:20])  # the lit rocks are light or mixed: kept


def test_a_lighter_piece_on_the_sun_side_is_a_lit_face_and_stays():
    labels, image, contrast, _ = _frame(-1)
    out, trimmed = trim_sun_shadows(labels, image, contrast)
    assert trimmed == 0 and np.array_equal(out, labels)


def test_a_piece_lighter_than_half_the_ground_or_objects_to_skip_stay():
    labels, image, contrast, strip = _frame(+1)
    image[strip] = 90  # 0.6 of the ground: lit more than the sky lights a shadow
    assert trim_sun_shadows(labels, image, contrast)[1] == 0
    image[strip] = 50
    skip = np.zeros(labels.max() + 1, bool)
    skip[4] = True
    assert trim_sun_shadows(labels, image, contrast, skip=skip)[1] == 0
    assert trim_sun_shadows(labels, image, contrast, max_angle_deg=0)[1] == 0


def test_a_trim_that_would_cut_the_rock_in_two_is_left_undone():
    """A lighter band across the middle of a dark object, on the shadow side of the core's
    centroid by its position, would leave two rock pieces of 30+ px: a facet, not a shadow."""
    labels, image, contrast, _ = _frame(+1)
    labels[50:60, 60:66] = 0
    image[50:60, 60:66] = _GROUND
    labels[50:60, 44:70] = 4
    image[50:60, 44:70] = 20
    image[50:60, 58:62] = 50  # the band
    contrast[labels == 4] = -3.0
    out, trimmed = trim_sun_shadows(labels, image, contrast, min_area_px=30)
    assert trimmed == 0 and np.array_equal(out, labels)


def test_bad_arguments_are_refused():
    labels, image, contrast, _ = _frame(+1)
    with pytest.raises(ValueError, match="one shape"):
        trim_sun_shadows(labels[:-1], image, contrast)
    with pytest.raises(ValueError, match="max_angle_deg in"):
        trim_sun_shadows(labels, image, contrast, max_angle_deg=120)
    with pytest.raises(ValueError, match="skip must hold"):
        trim_sun_shadows(labels, image, contrast, skip=np.zeros(2, bool))
    with pytest.raises(ValueError, match="min_pairs"):
        anti_sun_direction(labels, contrast, min_pairs=0)
