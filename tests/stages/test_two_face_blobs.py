"""Tests of stages/_two_face_blobs.py: a lit and a shaded face side by side as one blob (R8c)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from object_masks import disk

from stages._blobs import add_compact_blobs
from stages._two_face_blobs import _face_counts, add_two_faced_blobs, two_faced_candidates
from stages.segment import segment_image

SHAPE = (160, 160)
ROCK = disk(SHAPE, 80, 80, 8)
# the rock's right half faces the light
LIT = ROCK & (np.arange(SHAPE[1])[None, :] > 80)


def soft_ground(seed):
    """Lava-like ground: blotches a few pixels wide that fade into each other, on slight
    pixel noise."""
    rng = np.random.default_rng(seed)
    smooth = cv2.GaussianBlur(rng.normal(0, 1, SHAPE), (0, 0), 2.5)
    return 76 + 8 * smooth / smooth.std() + rng.normal(0, 2, SHAPE)


def to_uint8(image):
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def two_faced_rock(seed, *, shaded=46.0, lit=112.0):
    """A small faceted rock: a shaded half and a lit half with sharp outlines, each several
    ground spreads from the ground's gray level on its own side."""
    rng = np.random.default_rng(seed + 10)
    image = soft_ground(seed)
    image[ROCK] = shaded + rng.normal(0, 2, ROCK.sum())
    image[LIT] = lit + rng.normal(0, 2, LIT.sum())
    return to_uint8(image)


def l_shaped(seed):
    """A dark bar and a light bar meeting at a corner, as far out as the rock's faces."""
    rng = np.random.default_rng(seed + 10)
    image = soft_ground(seed)
    dark = np.zeros(SHAPE, bool)
    dark[60:100, 70:76] = True
    light = np.zeros(SHAPE, bool)
    light[94:100, 76:110] = True
    image[dark] = 46 + rng.normal(0, 2, dark.sum())
    image[light] = 112 + rng.normal(0, 2, light.sum())
    return to_uint8(image), dark | light


def iou(a, b):
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_two_faced_rock_is_added_whole(seed):
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_two_faced_blobs(labels, two_faced_rock(seed), min_sigmas=3.0)
    assert added == 1
    assert iou(found > 0, ROCK) > 0.5


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_r8_alone_finds_one_face_of_it(seed):
    # why R8c exists: R8 searches one side of the ground's gray level at a time, and each
    # face alone is a piece of the rock
    labels = np.zeros(SHAPE, np.int32)
    found, _ = add_compact_blobs(labels, two_faced_rock(seed), min_sigmas=3.0)
    on_rock = np.unique(found[ROCK & (found > 0)])
    assert on_rock.size >= 1
    assert all(iou(found == k, ROCK) < 0.5 for k in on_rock)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_one_sided_rock_is_left_to_r8(seed):
    image = two_faced_rock(seed, lit=46.0)
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_two_faced_blobs(labels, image, min_sigmas=3.0)
    assert added == 0
    assert not found.any()


@pytest.mark.parametrize("seed", [0, 2])
def test_faces_further_apart_than_join_px_are_not_joined(seed):
    # the lit half moved 4 px right: a dark and a light blob with a gap of ground
    rng = np.random.default_rng(seed + 10)
    image = soft_ground(seed)
    shaded = ROCK & ~LIT
    lit = np.roll(LIT, 4, axis=1)
    image[shaded] = 46 + rng.normal(0, 2, shaded.sum())
    image[lit] = 112 + rng.normal(0, 2, lit.sum())
    image = to_uint8(image)
    labels = np.zeros(SHAPE, np.int32)
    candidates, _ = two_faced_candidates(labels, image, min_sigmas=3.0, join_px=2)
    assert not (candidates[shaded | lit] > 0).any()
    found, added = add_two_faced_blobs(labels, image, min_sigmas=3.0, join_px=2)
    assert added == 0
    # joined from further away, the two faces are one candidate
    candidates, _ = two_faced_candidates(labels, image, min_sigmas=3.0, join_px=6)
    on_faces = np.unique(candidates[(shaded | lit) & (candidates > 0)])
    assert on_faces.size == 1
    blob = candidates == on_faces[0]
    assert np.count_nonzero(blob & shaded) > 0.5 * shaded.sum()
    assert np.count_nonzero(blob & lit) > 0.5 * lit.sum()


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_two_faced_blob_that_is_not_solid_is_not_added(seed):
    image, shape = l_shaped(seed)
    labels = np.zeros(SHAPE, np.int32)
    candidates, n = two_faced_candidates(labels, image, min_sigmas=3.0)
    on_shape = np.unique(candidates[shape & (candidates > 0)])
    assert on_shape.size == 1
    assert iou(candidates == on_shape[0], shape) > 0.5
    found, added = add_two_faced_blobs(labels, image, min_sigmas=3.0)
    assert added == 0
    assert not found.any()
    _, kept = add_two_faced_blobs(labels, image, min_sigmas=3.0, min_solidity=0.0)
    assert kept >= 1


def test_objects_are_kept_and_a_rock_by_one_is_not_added():
    image = two_faced_rock(0)
    labels = np.zeros(SHAPE, np.int32)
    # an object 2 px left of the rock (columns 72-88): the rock lies in its 3 px ring
    labels[70:90, 60:70] = 1
    found, added = add_two_faced_blobs(labels, image, min_sigmas=3.0)
    assert added == 0
    np.testing.assert_array_equal(found, labels)
    far = np.zeros(SHAPE, np.int32)
    far[10:30, 10:22] = 1
    found, added = add_two_faced_blobs(far, image, min_sigmas=3.0)
    assert added == 1
    np.testing.assert_array_equal(found[far > 0], 1)
    assert iou(found == 2, ROCK) > 0.5


def test_segment_image_adds_no_second_object_on_a_rock_the_thresholds_found():
    image = two_faced_rock(0)
    off = segment_image(image, method="sector-histogram+depth").labels
    on = segment_image(image, method="sector-histogram+depth", two_face_sigmas=3.0).labels
    assert max(iou(off == k, ROCK) for k in np.unique(off[off > 0])) > 0.9
    np.testing.assert_array_equal(on, off)


def test_segment_image_refuses_negative_two_face_sigmas():
    with pytest.raises(ValueError, match="two_face_sigmas"):
        segment_image(two_faced_rock(0), two_face_sigmas=-1.0)


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"min_sigmas": 0.0}, ValueError),
        ({"min_sigmas": 3.0, "join_px": 0}, ValueError),
        ({"min_sigmas": 3.0, "min_share": 0.6}, ValueError),
        ({"min_sigmas": 3.0, "min_solidity": 1.5}, ValueError),
    ],
)
def test_bad_settings_are_refused(kwargs, error):
    with pytest.raises(error):
        add_two_faced_blobs(np.zeros(SHAPE, np.int32), two_faced_rock(0), **kwargs)


def test_a_float_image_is_refused():
    with pytest.raises(TypeError, match="uint8"):
        two_faced_candidates(
            np.zeros(SHAPE, np.int32), two_faced_rock(0).astype(float), min_sigmas=3.0
        )


def test_face_counts_equal_bincounts_of_masked_ids():
    # the twin: the four bincounts R8c's candidate tests read before the compiled pass
    rng = np.random.default_rng(13)
    for _ in range(20):
        shape = tuple(rng.integers(1, 50, 2))
        ids = rng.integers(0, 7, shape).astype(np.int32)
        dark, light, ring = (rng.random(shape) < share for share in (0.3, 0.2, 0.1))
        counts = np.zeros((4, 7), np.int64)
        _face_counts(ids, dark, light, ring, counts)
        flat = ids.ravel()
        for row, mask in zip(counts, (np.ones(shape, bool), dark, light, ring), strict=True):
            np.testing.assert_array_equal(row, np.bincount(flat[mask.ravel()], minlength=7))


@pytest.mark.parametrize("seed", [0, 2])
def test_the_input_labels_are_not_modified_and_blobs_numbered_after_them(seed):
    # the labels are copied only once a blob is added (the blobs by their component ids)
    labels = np.zeros(SHAPE, np.int32)
    labels[:6, :6] = 3
    before = labels.copy()
    found, added = add_two_faced_blobs(labels, two_faced_rock(seed), min_sigmas=3.0)
    assert added == 1 and set(np.unique(found)) == {0, 3, 4}
    np.testing.assert_array_equal(labels, before)
    blobs, n = two_faced_candidates(labels, two_faced_rock(seed), min_sigmas=3.0)
    assert n >= 1 and np.array_equal(found == 4, blobs == 1)
