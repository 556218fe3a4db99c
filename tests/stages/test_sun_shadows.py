"""Tests of stages/_sun_shadows.py: the frame's anti-sun direction, R6b's cast shadows, R6c's
flat ones and R7g's pieces off the sun's side."""

from __future__ import annotations

import numpy as np
import pytest

from stages._sun_shadows import (
    anti_sun_direction,
    trim_flat_shadow_sides,
    trim_off_side_pieces,
    trim_sun_shadows,
)

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


def _blotched_rock(blotch_side: int):
    """Three lit rocks (sun from the left) and a light rock (10x10, contrast 3) with a dark
    5x4 piece (contrast -2) beside it on its ``blotch_side`` (+1: right, -1: left), one
    object; returns labels, contrast and the piece."""
    labels = np.zeros((100, 120), np.int32)
    contrast = np.zeros(labels.shape)
    _lit_rocks(labels, contrast, np.zeros(labels.shape, np.uint8))
    labels[50:60, 50:60], contrast[50:60, 50:60] = 4, 3.0
    piece = (slice(53, 57), slice(60, 65) if blotch_side > 0 else slice(45, 50))
    labels[piece], contrast[piece] = 4, -2.0
    return labels, contrast, piece


def test_r7g_drops_a_light_rocks_dark_piece_on_the_sun_side_only():
    # lava_0007 object 51 (102 px on an 85-px rock, IoU 0.72 -> 0.89 without its 21-px
    # piece): a rock with a blotch of ground on its wrong side, one object; its other face
    # (and a cast shadow) lies on the other side
    labels, contrast, piece = _blotched_rock(-1)
    out, trimmed = trim_off_side_pieces(labels, contrast)
    assert trimmed == 20 and not out[piece].any()
    assert np.array_equal(out[50:60, 50:60], labels[50:60, 50:60])
    labels, contrast, piece = _blotched_rock(+1)
    out, trimmed = trim_off_side_pieces(labels, contrast)
    assert trimmed == 0 and np.array_equal(out, labels)
    # a dark rock's light piece on the side away from the sun goes the same way
    labels, contrast, piece = _blotched_rock(+1)
    contrast[labels == 4] *= -1
    out, trimmed = trim_off_side_pieces(labels, contrast)
    assert trimmed == 20 and not out[piece].any()


def test_r7g_keeps_pieces_near_the_centre_and_needs_a_sun_direction():
    labels, contrast, _ = _blotched_rock(-1)
    contrast[54:56, 54:56] = -2.0  # a dark facet inside the rock, left of nothing
    contrast[54:56, 52:54] = -2.0
    out, trimmed = trim_off_side_pieces(labels, contrast)
    assert trimmed == 20 and out[54:56, 52:56].all()
    # no clear pairs, no direction: nothing dropped; 0 or 180 degrees: the rule is off
    alone = np.where(labels == 4, labels, 0)
    assert trim_off_side_pieces(alone, contrast)[1] == 0
    for off in (0.0, 180.0):
        assert trim_off_side_pieces(labels, contrast, max_side_deg=off)[1] == 0
    with pytest.raises(ValueError, match="max_side_deg"):
        trim_off_side_pieces(labels, contrast, max_side_deg=-1.0)
    with pytest.raises(ValueError, match="one shape"):
        trim_off_side_pieces(labels[:-1], contrast)


def _anti_sun_twin(labels, contrast, *, min_pairs=3, min_agreement=0.5):
    """anti_sun_direction as it was before its compiled pass: bincounts of the objects'
    pixels (its pair tests copied from the module's constants)."""
    count = int(labels.max())
    if count == 0:
        return None
    where = np.flatnonzero(labels.ravel())
    owners = labels.ravel()[where]
    rows, cols = np.divmod(where, labels.shape[1])
    values = contrast.ravel()[where]
    size = np.bincount(owners, minlength=count + 1).astype(np.float64)
    centroids = []
    for side in (values > 1, values < -1):
        k = owners[side]
        n = np.bincount(k, minlength=count + 1).astype(np.float64)
        y = np.bincount(k, weights=rows[side], minlength=count + 1)
        x = np.bincount(k, weights=cols[side], minlength=count + 1)
        centroids.append((n, y / np.maximum(n, 1), x / np.maximum(n, 1)))
    (n_lit, y_lit, x_lit), (n_dark, y_dark, x_dark) = centroids
    pair = (n_lit >= 0.2 * size) & (n_dark >= 0.2 * size) & (size > 0)
    pair[0] = False
    offsets = np.stack([y_dark - y_lit, x_dark - x_lit], axis=1)[pair]
    lengths = np.hypot(offsets[:, 0], offsets[:, 1])
    keep = lengths >= 1.0
    if np.count_nonzero(keep) < min_pairs:
        return None
    weights = np.minimum(n_lit, n_dark)[pair][keep]
    total = (offsets[keep] / lengths[keep, None] * weights[:, None]).sum(axis=0)
    length = float(np.hypot(*total))
    if length < min_agreement * float(weights.sum()):
        return None
    return total / length


def test_anti_sun_direction_equals_its_bincount_twin_bit_for_bit():
    rng = np.random.default_rng(11)
    found = 0
    for _ in range(40):
        shape = tuple(rng.integers(20, 90, 2))
        labels = np.zeros(shape, np.int32)
        contrast = rng.normal(0, 1.5, shape).astype(np.float32)
        for k in range(1, rng.integers(2, 12)):
            y, x = rng.integers(0, shape[0] - 8), rng.integers(0, shape[1] - 8)
            h, w = rng.integers(3, 9, 2)
            labels[y : y + h, x : x + w] = k
            contrast[y : y + h, x : x + w // 2] += 2.5
            contrast[y : y + h, x + w // 2 : x + w] -= 2.5 * rng.uniform(0.5, 1.5)
        contrast[rng.random(shape) < 0.02] = np.nan
        got = anti_sun_direction(labels, contrast, min_pairs=2, min_agreement=0.3)
        want = _anti_sun_twin(labels, contrast, min_pairs=2, min_agreement=0.3)
        if want is None:
            assert got is None
        else:
            found += 1
            np.testing.assert_array_equal(got, want)
    assert found > 10


_R6C = {"max_noise_m": 0.0075, "min_height_m": 0.01, "flat_tol_m": 0.003}


def _shaded_rock(shadow_side: int, *, shadow_bands: float = -2.0, shadow_m: float = 0.0):
    """Three lit rocks (sun from the left), and a dark rock (10x10, 3 cm high, 1 band below
    the ground's gray) whose lit face no rule found, one object with its cast shadow (an 8-px
    strip on ``shadow_side``, ``shadow_bands`` and ``shadow_m`` high)."""
    labels = np.zeros((100, 120), np.int32)
    contrast = np.zeros(labels.shape)
    image = np.zeros(labels.shape, np.uint8)
    _lit_rocks(labels, contrast, image)
    relative = np.zeros(labels.shape)
    labels[50:60, 50:60], contrast[50:60, 50:60], relative[50:60, 50:60] = 4, -1.0, 0.03
    strip = (slice(50, 60), slice(60, 68) if shadow_side > 0 else slice(42, 50))
    labels[strip], contrast[strip], relative[strip] = 4, shadow_bands, shadow_m
    return labels, contrast, relative, np.full(100, 0.004), strip


def test_r6c_drops_a_dark_rocks_flat_darker_side_away_from_the_sun():
    labels, contrast, relative, sigma, strip = _shaded_rock(+1)
    out, trimmed = trim_flat_shadow_sides(labels, contrast, relative, sigma, **_R6C)
    # the strip's pixels within 30 degrees of the anti-sun direction (+x) from the rock's centre
    rows, cols = np.mgrid[strip]
    dy, dx = rows - 54.5, cols - 54.5
    cone = dx >= np.cos(np.radians(30)) * np.hypot(dy, dx)
    assert trimmed == np.count_nonzero(cone) > 60
    assert not out[strip][cone].any()
    assert (out[50:60, 50:60] == 4).all()
    assert (out[labels != 4] == labels[labels != 4]).all()


@pytest.mark.parametrize(
    ("side", "bands", "height_m", "noise_m"),
    [
        (-1, -2.0, 0.0, 0.004),  # on the sun's side: a lit face's place, not a shadow's
        (+1, -1.2, 0.0, 0.004),  # hardly darker than the rock's shaded face
        (+1, -2.0, 0.03, 0.004),  # as high as the rock: its face
        (+1, -2.0, 0.0, 0.01),  # rows too noisy to call it flat
    ],
)
def test_r6c_keeps_what_may_be_rock(side, bands, height_m, noise_m):
    labels, contrast, relative, _, _ = _shaded_rock(side, shadow_bands=bands, shadow_m=height_m)
    sigma = np.full(100, noise_m)
    out, trimmed = trim_flat_shadow_sides(labels, contrast, relative, sigma, **_R6C)
    assert trimmed == 0
    assert (out == labels).all()


def test_r6c_needs_a_sun_direction_and_a_standing_rest():
    labels, contrast, relative, sigma, _ = _shaded_rock(+1)
    lone = np.where(labels == 4, labels, 0)
    assert trim_flat_shadow_sides(lone, contrast, relative, sigma, **_R6C)[1] == 0
    # the rock itself read flat but for its top rows: what is left would not stand up
    relative[53:60, 50:60] = 0.0
    assert trim_flat_shadow_sides(labels, contrast, relative, sigma, **_R6C)[1] == 0


def test_r6c_refuses_bad_arguments():
    labels, contrast, relative, sigma, _ = _shaded_rock(+1)
    with pytest.raises(ValueError, match="one value per row"):
        trim_flat_shadow_sides(labels, contrast, relative, sigma[:-1], **_R6C)
    with pytest.raises(ValueError, match="max_angle_deg"):
        trim_flat_shadow_sides(labels, contrast, relative, sigma, max_angle_deg=95, **_R6C)


def test_object_sums_hold_the_bincounts_and_boxes_they_replaced():
    # R6b, R6c and R7g read sizes, darkness (np.bincount's float64 sums) and boxes from
    # the sun direction's pass; the twins: the whole-frame bincounts and _object_boxes
    from stages._regions import _object_boxes
    from stages._sun_shadows import _object_sums

    rng = np.random.default_rng(13)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        labels = rng.integers(0, 7, shape).astype(np.int32)
        labels[rng.random(shape) < 0.4] = 0
        contrast = (rng.normal(0, 2, shape) * 10 ** rng.uniform(-6, 3, shape)).astype(np.float32)
        count = int(labels.max())
        sums, boxes = _object_sums(labels, contrast, count)
        inside = labels.ravel() > 0
        owners = labels.ravel()[inside]
        np.testing.assert_array_equal(sums[0], np.bincount(owners, minlength=count + 1))
        darkness = np.bincount(owners, weights=contrast.ravel()[inside], minlength=count + 1)
        np.testing.assert_array_equal(sums[7], darkness)
        np.testing.assert_array_equal(boxes, _object_boxes(labels, count))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_other_pass_equals_the_whole_frame_comparison(dtype):
    from stages._regions import _lookup
    from stages._sun_shadows import _other_pass

    rng = np.random.default_rng(14)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        labels = rng.integers(0, 6, shape).astype(np.int32)
        contrast = rng.normal(0, 1.2, shape).astype(dtype)
        contrast[rng.random(shape) < 0.05] = np.nan
        side_of = np.where(rng.random(6) < 0.5, 1.0, -1.0).astype(np.float32)
        side_of[0] = 0.0
        min_bands = float(rng.uniform(0.3, 1.7))
        expected = (labels > 0) & (contrast * _lookup(side_of, labels) <= -min_bands)
        other = np.empty(shape, bool)
        has_other = np.zeros(6, bool)
        threshold = np.asarray(-min_bands, dtype=np.result_type(dtype, np.float32))[()]
        _other_pass(labels, contrast, side_of, threshold, other, has_other)
        np.testing.assert_array_equal(other, expected)
        np.testing.assert_array_equal(has_other, np.bincount(labels[expected], minlength=6) > 0)
