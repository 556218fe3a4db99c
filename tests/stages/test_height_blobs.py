"""Tests of stages/_height_blobs.py: faint blobs kept as height bumps with crisp edges (R8b)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from height_maps import correlated_noise
from object_masks import disk

from stages._blobs import blob_scales
from stages._height_blobs import _blob_cues, add_height_blobs, detail_ratio
from stages.segment import segment_image

SHAPE = (160, 160)
ROCK = disk(SHAPE, 80, 80, 6)


def soft_ground(seed):
    """Lava-like ground: blotches a few pixels wide that fade into each other, on slight
    pixel noise."""
    rng = np.random.default_rng(seed)
    smooth = cv2.GaussianBlur(rng.normal(0, 1, SHAPE), (0, 0), 2.5)
    return 76 + 8 * smooth / smooth.std() + rng.normal(0, 2, SHAPE)


def crisp_rock(seed):
    """A faceted rock (a shaded and a lit half with sharp outlines) about 3 ground spreads
    darker than the ground at its scale: past R8b's search, short of R8's 4 spreads."""
    rng = np.random.default_rng(seed + 10)
    image = soft_ground(seed)
    lit = ROCK & (np.arange(SHAPE[1])[None, :] > 80)
    image[ROCK] = 44 + rng.normal(0, 2, ROCK.sum())
    image[lit] = 60 + rng.normal(0, 2, lit.sum())
    return to_uint8(image)


def soft_blotch(seed):
    """As dark as :func:`crisp_rock` on average, but fading into the ground like its blotches."""
    weight = cv2.GaussianBlur(ROCK.astype(float), (0, 0), 2.0)
    return to_uint8(soft_ground(seed) * (1 - weight) + 52.0 * weight)


def to_uint8(image):
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def heights(seed, *, rock_m):
    """Stereo-like height noise of 6 mm with the rock standing ``rock_m`` high, spread by
    the matching windows."""
    noise = correlated_noise((162, 162), 0.006, seed=seed)[: SHAPE[0], : SHAPE[1]]
    return noise + cv2.GaussianBlur(ROCK.astype(np.float32) * rock_m, (0, 0), 3.0)


@pytest.mark.parametrize("seed", [0, 3, 4])
def test_a_crisp_faint_rock_standing_as_a_bump_is_added(seed):
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_height_blobs(
        labels, crisp_rock(seed), heights(seed, rock_m=0.025), min_sigmas=3.0
    )
    assert added == 1
    blob = found > 0
    assert np.count_nonzero(blob & ROCK) / np.count_nonzero(blob | ROCK) > 0.5


@pytest.mark.parametrize("seed", [0, 4])
def test_the_same_rock_on_flat_heights_is_not_added(seed):
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_height_blobs(
        labels, crisp_rock(seed), heights(seed, rock_m=0.0), min_sigmas=3.0
    )
    assert added == 0
    assert not found.any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_soft_blotch_on_a_bump_is_not_added(seed):
    # the ground's own blotches are candidates too (R8's search at 3 spreads finds several
    # in each of these frames): none has the crisp edges
    image = soft_blotch(seed)
    detail, around = detail_ratio(image)
    assert detail[ROCK].mean() < around[ROCK].mean()
    labels = np.zeros(SHAPE, np.int32)
    _, added = add_height_blobs(labels, image, heights(seed, rock_m=0.025), min_sigmas=3.0)
    assert added == 0


def test_invalid_heights_add_nothing():
    labels = np.zeros(SHAPE, np.int32)
    relative = np.full(SHAPE, np.nan, np.float32)
    _, added = add_height_blobs(labels, crisp_rock(0), relative, min_sigmas=3.0)
    assert added == 0


def test_objects_are_kept_and_blobs_numbered_after_them():
    labels = np.zeros(SHAPE, np.int32)
    labels[5:15, 5:15] = 1
    labels[140:150, 5:15] = 3
    found, added = add_height_blobs(
        labels, crisp_rock(0), heights(0, rock_m=0.025), min_sigmas=3.0
    )
    assert added == 1
    assert np.array_equal(found[labels > 0], labels[labels > 0])
    assert set(np.unique(found[labels == 0]).tolist()) == {0, 4}


def test_bad_arguments_raise_clear_errors():
    labels = np.zeros(SHAPE, np.int32)
    image = crisp_rock(0)
    with pytest.raises(ValueError, match="relative must have"):
        add_height_blobs(labels, image, np.zeros((10, 10), np.float32), min_sigmas=3.0)
    with pytest.raises(TypeError, match="relative must be float"):
        add_height_blobs(labels, image, np.zeros(SHAPE, np.int32), min_sigmas=3.0)
    with pytest.raises(ValueError, match="min_texture"):
        add_height_blobs(
            labels, image, np.zeros(SHAPE, np.float32), min_sigmas=3.0, min_texture=-1.0
        )
    with pytest.raises(ValueError, match="height_blob_sigmas"):
        segment_image(image, height_blob_sigmas=-1.0)


def test_segment_image_runs_r8b_only_with_usable_heights():
    image = crisp_rock(0)
    relief = heights(0, rock_m=0.025).astype(np.float32)
    plain = segment_image(image, height=relief, sectors=8).labels
    with_bumps = segment_image(image, height=relief, sectors=8, height_blob_sigmas=3.0).labels
    # R8b only adds: every object of the plain segmentation stays as it was
    assert np.array_equal(with_bumps[plain > 0], plain[plain > 0])
    no_depth = segment_image(image, sectors=8).labels
    assert np.array_equal(segment_image(image, sectors=8, height_blob_sigmas=3.0).labels, no_depth)


def test_blob_cues_equal_their_numpy_twin():
    # the twin: the ufunc.at and the two bincounts of blob ids the compiled pass replaced
    rng = np.random.default_rng(5)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        first = int(rng.integers(1, 6))
        count = int(rng.integers(1, 6))
        found = rng.integers(0, first + count - 1, shape).astype(np.int32)
        bumps, detail, around = rng.normal(0, 2, (3, *shape)).astype(np.float32)
        bumps[rng.random(shape) < 0.05] = np.nan
        peak, pixels, detail_sum, around_sum = _blob_cues(
            found, first, count, bumps, detail, around
        )
        blob_ids = np.where(found >= first, found - first + 1, 0)
        on = blob_ids > 0
        expected = np.full(count, -np.inf)
        np.maximum.at(expected, blob_ids[on], bumps[on])
        np.testing.assert_array_equal(peak, expected)
        np.testing.assert_array_equal(pixels, np.bincount(blob_ids.ravel(), minlength=count))
        for sums, values in ((detail_sum, detail), (around_sum, around)):
            np.testing.assert_array_equal(
                sums, np.bincount(blob_ids[on], values[on], minlength=count)
            )


def test_shared_blob_scales_give_the_same_blobs():
    image = crisp_rock(0)
    relative = heights(0, rock_m=0.025)
    labels = np.zeros(SHAPE, np.int32)
    alone = add_height_blobs(labels, image, relative, min_sigmas=3.0)
    shared = add_height_blobs(
        labels, image, relative, min_sigmas=3.0, _scales=blob_scales(image)
    )
    # maps of another image are not used
    stale = add_height_blobs(
        labels, image, relative, min_sigmas=3.0, _scales=blob_scales(soft_blotch(0))
    )
    assert alone[1] == 1
    for found, added in (shared, stale):
        assert added == alone[1]
        np.testing.assert_array_equal(found, alone[0])


def test_detail_ratio_equals_its_numpy_twin_bit_for_bit():
    # the twin: the whole-frame numpy steps the compiled squared difference replaced
    rng = np.random.default_rng(9)
    for shape in ((7, 9), (40, 33), (64, 80)):
        image = rng.integers(0, 256, shape).astype(np.uint8)
        pixels = image.astype(np.float32)
        fine = pixels - cv2.GaussianBlur(pixels, (0, 0), 1.0)
        twin = np.sqrt(cv2.GaussianBlur(fine * fine, (0, 0), 2.0))
        detail, _ = detail_ratio(image)
        np.testing.assert_array_equal(detail.view(np.int32), twin.view(np.int32))
