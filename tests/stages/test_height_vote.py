"""Tests of stages/_height_vote.py: the noisy regime's object vote (R2 vote, R2c, R2d)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from height_maps import correlated_noise
from object_masks import disk

from stages import _height_vote as height_vote
from stages._depth_rules import apply_depth_rules
from stages._heights import local_ground


def test_noisy_depth_votes_out_a_flat_blotch_and_keeps_a_low_rock():
    shape = (120, 120)
    height = correlated_noise(shape, 0.008)
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
    height = correlated_noise(shape, 0.018, block_px=2, seed=1)
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
    height = correlated_noise(shape, 0.008, seed=2)
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


def test_noisy_vote_asks_less_height_of_a_clear_rock_than_of_a_faint_blotch():
    # rule R2c: stereo windows flatten a small rock's heights to a few mm, as low as a
    # blotch's noise; its gray level, far past the threshold, is the evidence that remains
    shape = (120, 160)
    height = correlated_noise(shape, 0.012, block_px=2, seed=3)
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


def _dome_and_blotch(seed, *, dome_m=0.014, rock_contrast=-1.2, blotch_contrast=-1.2):
    """A rock read as a smooth low dome and a flat blotch, both small, on fine noise."""
    shape = (120, 160)
    height = correlated_noise(shape, 0.012, block_px=2, seed=seed)
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
    monkeypatch.setattr(height_vote, "_BUMP_SCORE", np.inf)
    combined, _ = apply_depth_rules(rock | blotch, height, contrast=contrast)
    assert not combined[rock].any()


def test_noisy_vote_bump_needs_a_bump_not_just_a_clear_gray_level():
    # regression: on a dunes frame a ripple's shading 2 bands dark at the bottom border, on
    # a weak swell (bump 1.6 sigmas), was kept by bump plus contrast alone
    height, rock, blotch, contrast = _dome_and_blotch(0, dome_m=0.0, blotch_contrast=-2.2)
    bumps = height_vote._height_bumps(height - local_ground(height), rock | blotch)
    assert 1.0 < bumps[blotch].max() < height_vote._BUMP_MIN_SIGMAS
    assert bumps[blotch].max() + 2.2 >= height_vote._BUMP_SCORE
    combined, _ = apply_depth_rules(blotch, height, contrast=contrast)
    assert not combined[blotch].any()


def test_height_bumps_peak_on_a_window_sized_rock_not_on_a_swell():
    shape = (160, 160)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    height = correlated_noise(shape, 0.003, block_px=2, seed=7)
    rock = 0.01 * np.exp(-((yy - 40) ** 2 + (xx - 40) ** 2) / 32.0)
    swell = 0.01 * np.exp(-((yy - 110) ** 2 + (xx - 110) ** 2) / 800.0)
    height = (height + rock + swell).astype(np.float32)
    height[:, :3] = np.nan
    bumps = height_vote._height_bumps(height, np.zeros(shape, bool))
    assert bumps.dtype == np.float32
    assert bumps[40, 40] > 3 * bumps[110, 110]
    assert bumps[40, 40] > height_vote._BUMP_SCORE
    assert (bumps[:, :3] == 0).all()  # no height, no evidence



def test_shared_bump_weights_give_the_same_maps():
    # R2d and R8b share the weights of one validity mask; another mask gets its own
    shape = (120, 140)
    height = correlated_noise(shape, 0.003, block_px=2, seed=3).astype(np.float32)
    height[:, :5] = np.nan
    other = height.copy()
    other[40:60, 60:90] = np.nan
    mask = disk(shape, 60, 70, 8)
    weights = height_vote.BumpWeights()
    for relative in (height, 0.5 * height, other, height):
        np.testing.assert_array_equal(
            height_vote._height_bumps(relative, mask, _weights=weights),
            height_vote._height_bumps(relative, mask),
        )

def test_object_counts_and_peaks_equal_their_numpy_twins():
    # the twins: whole-frame bincounts and np.maximum.at (the code the kernels replaced)
    rng = np.random.default_rng(12)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        mask = rng.random(shape) < rng.random()
        count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
        valid = rng.random(shape) < 0.8
        values = rng.normal(0, 2, shape).astype(np.float32)
        n_pixels, n_valid = height_vote._object_counts(components, valid, count)
        valid_components = np.where(valid, components, 0)
        np.testing.assert_array_equal(
            n_pixels, np.bincount(components.ravel(), minlength=count)
        )
        np.testing.assert_array_equal(
            n_valid, np.bincount(components[valid], minlength=count)
        )
        peak = np.full(count, -np.inf)
        height_vote._object_peaks(components, valid, values, peak)
        in_object = valid_components > 0
        expected = np.full(count, -np.inf)
        np.maximum.at(expected, valid_components[in_object], values[in_object])
        np.testing.assert_array_equal(peak, expected)


def test_ring_pass_gathers_the_ring_pixels_in_raster_order():
    rng = np.random.default_rng(17)
    mask = rng.random((30, 40)) < 0.2
    count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9))
    grown = cv2.dilate(components.astype(np.uint16), kernel)
    relative = rng.normal(0, 0.01, (30, 40)).astype(np.float32)
    relative[rng.random((30, 40)) < 0.2] = np.nan
    owners = np.empty(components.size, np.int64)
    values = np.empty(components.size, np.float32)
    n = height_vote._ring_pass(components, grown, relative, owners, values)
    ring = (components == 0) & (grown > 0) & np.isfinite(relative)
    np.testing.assert_array_equal(owners[:n], grown[ring].astype(np.int64))
    np.testing.assert_array_equal(values[:n], relative[ring])


def _numpy_height_bumps(relative, mask):
    # the whole-frame numpy steps the compiled passes of _height_bumps replaced
    valid = np.isfinite(relative)
    filled = np.where(valid, relative, np.float32(0.0)).astype(np.float32, copy=False)
    levels = []
    for scale, weight in zip(
        (height_vote._BUMP_INNER_PX, height_vote._BUMP_OUTER_PX),
        height_vote._weight_levels(valid),
        strict=True,
    ):
        size = height_vote._kernel_size(scale)
        level = cv2.GaussianBlur(filled, (size, size), scale)
        level /= weight
        levels.append(level)
    bumps = levels[0]
    bumps -= levels[1]
    ground = valid[::2, ::2] & ~mask[::2, ::2]
    noise = height_vote._robust_sigma(bumps[::2, ::2][ground])
    if not noise > 0:
        return np.zeros(relative.shape, np.float32)
    bumps *= np.float32(1.0 / noise)
    bumps[~valid] = 0.0
    return bumps


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_height_bumps_equal_their_numpy_twin_bit_for_bit(dtype):
    rng = np.random.default_rng(21)
    for _ in range(12):
        shape = tuple(rng.integers(3, 60, 2))
        relative = (rng.normal(0, 0.01, shape) * rng.uniform(0.1, 10)).astype(dtype)
        relative[rng.random(shape) < rng.uniform(0, 0.5)] = np.nan
        mask = rng.random(shape) < rng.uniform(0, 0.6)
        np.testing.assert_array_equal(
            height_vote._height_bumps(relative, mask).view(np.int32),
            _numpy_height_bumps(relative, mask).view(np.int32),
        )


def test_object_pixels_equal_boolean_indexing():
    # the twins: the boolean-mask gathers the compiled pass replaced
    rng = np.random.default_rng(23)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        mask = rng.random(shape) < rng.random()
        count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
        values = rng.normal(0, 1, shape).astype(np.float32)
        values[rng.random(shape) < 0.2] = np.nan
        values[rng.random(shape) < 0.05] = -0.0
        in_object = np.isfinite(values) & (components > 0)
        owners, kept = height_vote._object_pixels(
            components, values, int(in_object.sum()), heights=True
        )
        np.testing.assert_array_equal(owners, components[in_object])
        np.testing.assert_array_equal(kept.view(np.int32), values[in_object].view(np.int32))
        inside = components > 0
        owners, kept = height_vote._object_pixels(
            components, values, int(inside.sum()), heights=False
        )
        np.testing.assert_array_equal(owners, components[inside])
        np.testing.assert_array_equal(
            kept.view(np.int32), np.abs(values[inside]).view(np.int32)
        )
