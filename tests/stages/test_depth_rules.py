"""Tests of stages/_depth_rules.py: local ground, raised, flat and no-depth rules (R0-R3)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.ndimage import median_filter

from stages import _depth_rules as depth_rules
from stages._depth_rules import (
    _median_filter_nearest,
    _percentile_by_label,
    _percentiles_by_label,
    apply_depth_rules,
    drop_faint_depthless,
    gray_contrast,
    local_ground,
    smooth_height,
)


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


def _correlated_noise(shape, sigma_m, block_px=6, seed=0):
    """Stereo-like height noise: constant over blocks of the matching-window scale."""
    rng = np.random.default_rng(seed)
    blocks = rng.normal(0, sigma_m, (shape[0] // block_px, shape[1] // block_px))
    return np.kron(blocks, np.ones((block_px, block_px))).astype(np.float32)


def test_noisy_depth_votes_out_a_flat_blotch_and_keeps_a_low_rock():
    shape = (120, 120)
    height = _correlated_noise(shape, 0.008)
    blotch = np.zeros(shape, bool)
    blotch[10:40, 10:110] = True  # dark texture blotch lying on the ground
    rock = disk(shape, 85, 60, 12)
    # a 2-3 cm rock read low by the stereo: only its top stands clear of the noise
    height[rock] += 0.025 * np.clip(1 - ((np.mgrid[:120, :120][0] - 85) / 12.0) ** 2, 0, 1)[rock]
    combined, stats = apply_depth_rules(blotch | rock, height)
    assert 0.005 < stats.ground_sigma_m < 0.015
    assert "object vote" in stats.notes[0]
    assert not combined[blotch].any()
    assert combined[rock].all()
    assert not (combined & ~(blotch | rock)).any()  # no object from height alone


def test_noisy_vote_reads_a_partly_depthless_object():
    # regression: on dunes a bright ripple cut by the frame's bottom rows (no height there)
    # had under half its pixels valid, escaped the vote and was reported as a rock
    shape = (120, 120)
    # fine-grained noise: the 4 px ring around the object holds many independent heights
    height = _correlated_noise(shape, 0.018, block_px=2, seed=1)
    height[96:] = np.nan  # the matcher has no rows below the frame
    ripple = np.zeros(shape, bool)
    ripple[80:120, 20:60] = True  # 40 % of it has a height, all at ground level
    height[ripple] *= 0.3  # smooth sand: the matcher's heights on it barely scatter
    combined, stats = apply_depth_rules(ripple, height)
    assert "object vote" in stats.notes[0]
    assert not combined.any()
    # with no height at all the intensity decision stands (R3)
    height[60:] = np.nan
    combined, _ = apply_depth_rules(ripple, height)
    assert combined[ripple].all()


def test_noisy_vote_reads_heights_against_the_ground_around_the_object():
    # a blotch on a 30 px swell (too narrow for the 72 px local ground) lies on the swell;
    # a rock as high above its own surroundings on flat ground stands
    shape = (156, 156)
    height = _correlated_noise(shape, 0.008, seed=2)
    swell = disk(shape, 40, 80, 22)
    height[swell] += 0.02
    blotch = disk(shape, 40, 80, 8)
    height[blotch] = 0.02 + 0.3 * (height[blotch] - 0.02)  # a smooth stain on the swell
    rock = disk(shape, 120, 80, 8)
    height[rock] += 0.02
    combined, stats = apply_depth_rules(blotch | rock, height)
    assert "object vote" in stats.notes[0]
    assert not combined[blotch].any()
    assert combined[rock].all()


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


def test_noisy_vote_asks_less_height_of_a_clear_rock_than_of_a_faint_blotch():
    # rule R2c: stereo windows flatten a small rock's heights to a few mm, as low as a
    # blotch's noise; its gray level, far past the threshold, is the evidence that remains
    shape = (120, 160)
    height = _correlated_noise(shape, 0.012, block_px=2, seed=3)
    rock, blotch = disk(shape, 60, 40, 9), disk(shape, 60, 120, 9)
    for region in (rock, blotch):
        height[region] = 0.004 + 0.2 * height[region]  # the same flattened bump on both
    contrast = np.zeros(shape, np.float32)
    contrast[rock] = -3.0  # three threshold bands darker than the ground
    contrast[blotch] = -1.2  # barely past the low threshold: ground texture
    combined, stats = apply_depth_rules(rock | blotch, height, contrast=contrast)
    assert "object vote" in stats.notes[0]
    assert combined[rock].all()
    assert not combined[blotch].any()
    # without the gray level the height evidence alone calls both flat
    combined, _ = apply_depth_rules(rock | blotch, height)
    assert not combined.any()
    with pytest.raises(ValueError, match="contrast"):
        apply_depth_rules(rock, height, contrast=contrast[:, :10])


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
    height[:40] = _correlated_noise((40, 120), 0.2, block_px=4, seed=5)  # the far rows
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
    height[:60] = _correlated_noise((60, 120), 0.04, block_px=4, seed=5)  # the far rows
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
    height = _correlated_noise(shape, 0.03)
    blotch = np.zeros(shape, bool)
    blotch[10:60, 10:110] = True
    combined, stats = apply_depth_rules(blotch, height)
    assert stats.ground_sigma_m > 0.015
    assert "unusable" in stats.notes[0]
    np.testing.assert_array_equal(combined, blotch)


@given(st.lists(st.tuples(st.integers(0, 4), st.floats(-1, 1, allow_nan=False)), max_size=60))
def test_percentile_by_label_matches_numpy_nearest_rank(pairs):
    labels = np.array([p[0] for p in pairs], dtype=np.int64)
    values = np.array([p[1] for p in pairs], dtype=np.float64)
    result = _percentile_by_label(values, labels, 5, 90.0)
    for label in range(5):
        chosen = values[labels == label]
        if chosen.size == 0:
            assert result[label] == np.inf
        else:
            expected = np.percentile(chosen, 90, method="lower")
            assert result[label] == pytest.approx(expected)


@given(
    st.integers(1, 40),
    st.integers(1, 40),
    st.sampled_from([1, 2, 3, 5, 8, 9]),
    st.integers(0, 2**31 - 1),
)
def test_median_filter_nearest_equals_scipy(rows, cols, size, seed):
    rng = np.random.default_rng(seed)
    image = np.round(rng.normal(0, 0.01, (rows, cols)) * 500).astype(np.float32) / 500
    expected = median_filter(image, size=size, mode="nearest")
    np.testing.assert_array_equal(_median_filter_nearest(image, size=size), expected)


def test_percentiles_by_label_match_one_at_a_time():
    rng = np.random.default_rng(3)
    values = rng.normal(size=500)
    labels = rng.integers(0, 7, 500)
    both = _percentiles_by_label(values, labels, 8, (90.0, 50.0))
    np.testing.assert_array_equal(both[0], _percentile_by_label(values, labels, 8, 90.0))
    np.testing.assert_array_equal(both[1], _percentile_by_label(values, labels, 8, 50.0))


def _dome_and_blotch(seed, *, dome_m=0.014, rock_contrast=-1.2, blotch_contrast=-1.2):
    """A rock read as a smooth low dome and a flat blotch, both small, on fine noise."""
    shape = (120, 160)
    height = _correlated_noise(shape, 0.012, block_px=2, seed=seed)
    rock, blotch = disk(shape, 60, 40, 6), disk(shape, 60, 120, 6)
    # the matching windows smooth both: their own noise is flattened, the rock's top too
    height[rock | blotch] *= 0.2
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    height += (dome_m * np.exp(-((yy - 60) ** 2 + (xx - 40) ** 2) / 32.0)).astype(np.float32)
    contrast = np.zeros(shape, np.float32)
    contrast[rock], contrast[blotch] = rock_contrast, blotch_contrast
    return height, rock, blotch, contrast


@pytest.mark.parametrize("seed", [1, 4, 5])
def test_noisy_vote_keeps_a_faint_rock_that_stands_as_a_bump(seed, monkeypatch):
    # rule R2d: on lava the vote removed small faint rocks whose upper heights the stereo
    # windows pulled down to the noise; their smoothed heights still make a bump
    height, rock, blotch, contrast = _dome_and_blotch(seed)
    combined, stats = apply_depth_rules(rock | blotch, height, contrast=contrast)
    assert "object vote" in stats.notes[0]
    assert combined[rock].all()
    assert not combined[blotch].any()
    # the percentile vote alone calls the rock flat
    monkeypatch.setattr(depth_rules, "_BUMP_SCORE", np.inf)
    combined, _ = apply_depth_rules(rock | blotch, height, contrast=contrast)
    assert not combined[rock].any()


def test_noisy_vote_bump_needs_a_bump_not_just_a_clear_gray_level():
    # regression: on a dunes frame a ripple's shading 2 bands dark at the bottom border, on
    # a weak swell (bump 1.6 sigmas), was kept by bump plus contrast alone
    height, rock, blotch, contrast = _dome_and_blotch(0, dome_m=0.0, blotch_contrast=-2.2)
    bumps = depth_rules._height_bumps(height - local_ground(height), rock | blotch)
    assert 1.0 < bumps[blotch].max() < depth_rules._BUMP_MIN_SIGMAS
    assert bumps[blotch].max() + 2.2 >= depth_rules._BUMP_SCORE
    combined, _ = apply_depth_rules(blotch, height, contrast=contrast)
    assert not combined[blotch].any()


def test_height_bumps_peak_on_a_window_sized_rock_not_on_a_swell():
    shape = (160, 160)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    height = _correlated_noise(shape, 0.003, block_px=2, seed=7)
    rock = 0.01 * np.exp(-((yy - 40) ** 2 + (xx - 40) ** 2) / 32.0)
    swell = 0.01 * np.exp(-((yy - 110) ** 2 + (xx - 110) ** 2) / 800.0)
    height = (height + rock + swell).astype(np.float32)
    height[:, :3] = np.nan
    bumps = depth_rules._height_bumps(height, np.zeros(shape, bool))
    assert bumps.dtype == np.float32
    assert bumps[40, 40] > 3 * bumps[110, 110]
    assert bumps[40, 40] > depth_rules._BUMP_SCORE
    assert (bumps[:, :3] == 0).all()  # no height, no evidence
