"""Tests of stages/_depth_rules.py: regimes, raised, flat, far-row and no-depth rules (R0-R3)."""

from __future__ import annotations

import numpy as np
import pytest
from height_maps import correlated_noise
from object_masks import disk

from stages._depth_rules import (
    _frame_bands,
    _judged_pass,
    _row_band_sigma,
    apply_depth_rules,
    drop_faint_depthless,
    gray_contrast,
)
from stages._heights import relative_height, smooth_height


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


def test_depth_rules_read_a_given_relative_height_map_as_their_own():
    # segment_image computes R0's relative heights once for the depth rules and R7e
    shape = (60, 60)
    rng = np.random.default_rng(3)
    height = (0.004 * rng.standard_normal(shape)).astype(np.float32)
    height[20:35, 15:40] += 0.05
    height[:6, :10] = np.nan
    mask = disk(shape, 45, 45, 6)
    relative = relative_height(height, smoothing_px=5, ground_window_px=72)
    assert np.array_equal(np.isnan(relative), np.isnan(smooth_height(height, window=5)))
    own = apply_depth_rules(mask, height)
    given = apply_depth_rules(mask, height, relative=relative)
    assert np.array_equal(own[0], given[0])
    assert own[1] == given[1]
    with pytest.raises(ValueError, match="relative"):
        apply_depth_rules(mask, height, relative=relative[:-1])


def test_drop_faint_depthless_judges_only_objects_without_heights():
    # regression: mojave texture blotches in the matcher's blind band along the right border
    # (no heights, so no vote) were reported as rocks
    shape = (60, 100)
    image = np.full(shape, 150, np.uint8)
    labels = np.zeros(shape, np.int32)
    height = np.zeros(shape, np.float32)
    height[:, 80:] = np.nan  # blind band
    background = np.full(shape, 150.0, np.float32)
    low, high = background - 10, background + 10
    labels[10:20, 85:95], image[10:20, 85:95] = 1, 135  # faint: 1.5 bands below the ground
    labels[30:40, 85:95], image[30:40, 85:95] = 2, 100  # clear: 5 bands below
    labels[10:20, 10:20], image[10:20, 10:20] = 3, 162  # faint but has heights: the vote's
    labels[30:40, 40:50], image[30:40, 40:50] = 4, 175  # clear, light, with heights
    out, dropped = drop_faint_depthless(
        labels, image, height, background=background, low=low, high=high
    )
    assert dropped == 1
    assert not out[10:20, 85:95].any()
    # renumbered 1..3, the others whole
    assert sorted(np.unique(out)) == [0, 1, 2, 3]
    for region in (np.s_[30:40, 85:95], np.s_[10:20, 10:20], np.s_[30:40, 40:50]):
        assert (out[region] > 0).all() and np.unique(out[region]).size == 1
    with pytest.raises(ValueError, match="min_contrast"):
        drop_faint_depthless(
            labels, image, height, background=background, low=low, high=high, min_contrast=0.5
        )


def test_gray_contrast_counts_threshold_bands_on_each_side():
    image = np.array([[100, 130, 140, 150, 170, 200]], dtype=np.uint8)
    background = np.full(image.shape, 140, np.float32)
    low = np.full(image.shape, 120, np.float32)  # 20 levels below
    high = np.full(image.shape, 150, np.float32)  # 10 levels above
    contrast = gray_contrast(image, background=background, low=low, high=high)
    assert contrast.dtype == np.float32
    np.testing.assert_allclose(contrast[0], [-2.0, -0.5, 0.0, 1.0, 3.0, 6.0])
    # a threshold on the ground level itself counts one gray level as the band
    flat = gray_contrast(image, background=background, low=background, high=high)
    assert flat[0, 0] == pytest.approx(-40.0)
    with pytest.raises(ValueError, match="one shape"):
        gray_contrast(image, background=background[:, :3], low=low, high=high)
    with pytest.raises(ValueError, match="min_band_fraction"):
        gray_contrast(image, background=background, low=low, high=high, min_band_fraction=-1)


def test_gray_contrast_band_is_at_least_half_the_frames_band():
    # a sector with an unusually narrow ground peak (smooth sand) is a poor unit
    image = np.full((8, 8), 150, np.uint8)
    image[0, 0] = 130
    background = np.full(image.shape, 150, np.float32)
    low, high = background - 20, background + 20
    low[0, 0] = 148  # a 2-level band where the frame's is 20
    contrast = gray_contrast(image, background=background, low=low, high=high)
    assert contrast[0, 0] == pytest.approx(-2.0)  # 20 levels over half of 20
    local = gray_contrast(image, background=background, low=low, high=high, min_band_fraction=0)
    assert local[0, 0] == pytest.approx(-10.0)


def test_gray_contrast_kernel_equals_the_numpy_formula_with_nans():
    # the compiled pass replaced six numpy passes: the same float32 values, NaN bands kept
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (40, 60)).astype(np.uint8)
    background = np.round(rng.random(image.shape) * 255).astype(np.float32)
    low = background - (rng.random(image.shape) * 30).astype(np.float32)
    high = background + (rng.random(image.shape) * 30).astype(np.float32)
    image[5] = background[5].clip(0, 255).astype(np.uint8)  # on the ground level itself
    background[0, :5], low[1, :5], high[2, :5] = np.nan, np.nan, np.nan
    for fraction in (0.0, 0.5, 1.0):
        level = image.astype(np.float32) - background
        darker = level < 0
        band = np.where(darker, background - low, high - background)
        coarse = np.s_[::4, ::4]
        frame_low = float(np.median(background[coarse] - low[coarse]))
        frame_high = float(np.median(high[coarse] - background[coarse]))
        floors = np.where(
            darker,
            np.float32(max(1.0, fraction * frame_low)),
            np.float32(max(1.0, fraction * frame_high)),
        )
        expected = level / np.maximum(band, floors)
        contrast = gray_contrast(
            image, background=background, low=low, high=high, min_band_fraction=fraction
        )
        assert contrast.dtype == np.float32
        np.testing.assert_array_equal(contrast, expected)


def test_drop_faint_depthless_judges_objects_the_vote_could_not_read():
    # regression: on dunes the end of a ripple trough at the bottom border had 17 % valid
    # heights, too few for the vote (30 %) and too many for the old 10 % limit: kept
    labels = np.zeros((60, 60), np.int32)
    labels[40:60, 10:30] = 1
    image = np.full(labels.shape, 150, np.uint8)
    image[labels == 1] = 125  # 1.25 bands below the ground: faint
    background = np.full(labels.shape, 150, np.float32)
    low, high = background - 20, background + 20
    height = np.full(labels.shape, np.nan, np.float32)
    height[:44] = 0.0  # 4 of 20 rows of the object have heights: 20 %
    out, dropped = drop_faint_depthless(
        labels, image, height, background=background, low=low, high=high
    )
    assert dropped == 1 and not out.any()


def test_drop_faint_depthless_needs_a_clear_gray_level():
    # regression: a dunes ripple trough in the right border's blind band lay 2.3 threshold
    # bands below the ground, past the old 2-band bar, and was reported as a rock
    labels = np.zeros((40, 80), np.int32)
    labels[10:30, 5:25], labels[10:30, 45:65] = 1, 2
    background = np.full(labels.shape, 150, np.float32)
    low, high = background - 10, background + 10
    image = np.full(labels.shape, 150, np.uint8)
    image[labels == 1] = 127  # 2.3 bands: a trough
    image[labels == 2] = 120  # 3 bands: clear
    height = np.full(labels.shape, np.nan, np.float32)
    out, dropped = drop_faint_depthless(
        labels, image, height, background=background, low=low, high=high
    )
    assert dropped == 1
    assert not out[10:30, 5:25].any() and out[10:30, 45:65].all()


def test_drop_faint_depthless_does_not_trust_an_unusually_narrow_band():
    # regression: on smooth dunes sand a sector's ground peak was a few gray levels wide and
    # ripple shading cut by the frame's border lay 3-6 of those bands out: "clear"
    labels = np.zeros((60, 60), np.int32)
    labels[40:55, 40:55] = 1
    background = np.full(labels.shape, 150, np.float32)
    low, high = background - 20, background + 20  # the frame's band: 20 levels
    low[30:, 30:], high[30:, 30:] = 146, 154  # a narrow sector: 4 levels
    image = np.full(labels.shape, 150, np.uint8)
    image[labels == 1] = 134  # 4 narrow bands, 1.6 of half the frame's band
    height = np.full(labels.shape, np.nan, np.float32)
    fields = {"background": background, "low": low, "high": high}
    out, dropped = drop_faint_depthless(labels, image, height, **fields)
    assert dropped == 1 and not out.any()
    out, dropped = drop_faint_depthless(labels, image, height, **fields, min_band_fraction=0)
    assert dropped == 0 and out[labels == 1].all()
    with pytest.raises(ValueError, match="min_band_fraction"):
        drop_faint_depthless(labels, image, height, **fields, min_band_fraction=2)


def test_precise_depth_reads_far_rows_against_their_own_noise():
    # rule R0b, regression: on dunes frames with 5 mm noise overall the rows near the
    # horizon scattered by 0.2 m and R1 made "raised" objects of that noise
    shape = (200, 120)
    rng = np.random.default_rng(4)
    height = rng.normal(0, 0.001, shape).astype(np.float32)
    height[:40] = correlated_noise((40, 120), 0.2, block_px=4, seed=5)  # the far rows
    rock = disk(shape, 150, 60, 8)
    height[rock] += 0.03  # a 3 cm rock as gray as the sand, near the camera
    combined, stats = apply_depth_rules(np.zeros(shape, bool), height)
    assert stats.ground_sigma_m <= 0.005  # precise regime: R1 adds objects from height
    assert combined[rock].mean() > 0.9
    assert not combined[:20].any()


def test_precise_depth_does_not_read_the_heights_of_far_rows_whose_noise_is_unusable():
    # rule R0b, regression: on a dunes frame of seed 4 a stereo error of +14-25 cm on the
    # smooth far sand (band noise 36 mm) stood 4 band sigmas high and R1 made 2 rocks as gray
    # as the sand of it, while R2 removed true rocks there whose heights read as flat
    shape = (200, 120)
    rng = np.random.default_rng(4)
    height = rng.normal(0, 0.001, shape).astype(np.float32)
    height[:60] = correlated_noise((60, 120), 0.04, block_px=4, seed=5)  # the far rows
    error = np.zeros(shape, bool)
    error[20:30, 20:40] = True
    height[error] = 0.4  # a matching error, 10 band sigmas high
    mask = np.zeros(shape, bool)
    far_rock = disk(shape, 45, 90, 5)
    mask[far_rock] = True  # dark, its heights lost in the noise
    height[far_rock] = -0.05
    near_shadow = disk(shape, 150, 60, 8)
    mask[near_shadow] = True  # on the ground near the camera: still flat
    combined, stats = apply_depth_rules(mask, height)
    assert stats.ground_sigma_m <= 0.005
    assert not combined[error].any()
    assert combined[far_rock].all()
    assert not combined[near_shadow].any()


def test_unusable_depth_keeps_the_intensity_decision():
    shape = (120, 120)
    height = correlated_noise(shape, 0.03)
    blotch = np.zeros(shape, bool)
    blotch[10:60, 10:110] = True
    combined, stats = apply_depth_rules(blotch, height)
    assert stats.ground_sigma_m > 0.015
    assert "unusable" in stats.notes[0]
    np.testing.assert_array_equal(combined, blotch)


def test_row_band_sigma_memo_gives_the_same_noise():
    # R7e and R7f share the bands whose ground did not change; changed bands are measured
    rng = np.random.default_rng(2)
    relative = rng.normal(0, 0.004, (150, 120)).astype(np.float32)
    relative[:, -10:] = np.nan
    usable = np.isfinite(relative)
    memo: dict = {}
    for _ in range(4):
        expected = _row_band_sigma(relative, usable)
        np.testing.assert_array_equal(_row_band_sigma(relative, usable, _memo=memo), expected)
        y, x = rng.integers(0, 140), rng.integers(0, 100)
        usable = usable.copy()
        usable[y : y + 10, x : x + 20] = False
    assert len(memo) == 10


def test_frame_bands_are_the_floats_np_median_gave():
    def numpy_bands(background, low, high):  # the code median32 replaced
        coarse = np.s_[::4, ::4]
        return (
            float(np.median(background[coarse] - low[coarse])),
            float(np.median(high[coarse] - background[coarse])),
        )

    rng = np.random.default_rng(21)
    for trial in range(30):
        shape = tuple(int(v) for v in rng.integers(1, 120, 2))
        background = rng.normal(120, 20, shape).astype(np.float32)
        low = background - rng.gamma(2, 5, shape).astype(np.float32)
        high = np.round(background + rng.gamma(2, 5, shape)).astype(np.float32)  # ties
        if trial % 5 == 0:
            low[rng.random(shape) < 0.2] = np.nan  # NaN bands: np.median's NaN
        got = _frame_bands(background, low, high)
        expected = numpy_bands(background, low, high)
        np.testing.assert_array_equal(np.array(got), np.array(expected))


def test_judged_pass_gathers_what_boolean_indexing_gives():
    # the twins: R3b's lookup of the judged objects and its four boolean gathers
    from stages._regions import _lookup

    rng = np.random.default_rng(15)
    for _ in range(20):
        shape = tuple(rng.integers(1, 30, 2))
        labels = rng.integers(0, 7, shape).astype(np.int32)
        judged = rng.random(7) < 0.5
        judged[0] = False
        image = rng.integers(0, 256, shape).astype(np.uint8)
        maps = [rng.normal(100, 30, shape) for _ in range(3)]  # float64: rounded to float32
        inside = _lookup(judged, labels)
        ids = np.empty(int(inside.sum()), labels.dtype)
        fields = np.empty((4, ids.size), np.float32)
        _judged_pass(labels, judged, image, *maps, ids, fields)
        np.testing.assert_array_equal(ids, labels[inside])
        for got, field in zip(fields, (image, *maps), strict=True):
            np.testing.assert_array_equal(got, field[inside].astype(np.float32))
