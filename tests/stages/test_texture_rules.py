"""Tests of stages/_texture_rules.py: elongation, streaks (R5, R5b, R5d), ripple fields (R5c)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from object_masks import disk

from stages._regions import label_objects
from stages._texture_rules import (
    _central_sums,
    _gradient_coherence,
    _sums,
    drop_ripple_pieces,
    drop_streaks,
    elongation,
)


def test_elongation_of_a_disk_a_bar_and_a_line():
    labels = np.zeros((60, 80), np.int32)
    labels[disk(labels.shape, 20, 20, 10)] = 1
    labels[40:44, 10:70] = 2  # 60 x 4 bar
    labels[55, 5:75] = 3  # one-pixel line
    ratio = elongation(labels)
    assert ratio[1] == pytest.approx(1.0, abs=0.05)
    assert ratio[2] == pytest.approx(15.0, rel=0.1)
    assert ratio[3] > 50


def test_drop_streaks_keeps_compact_objects_and_renumbers():
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


def test_drop_streaks_keeps_an_elongated_object_far_out_of_its_ring_of_ground():
    # rule R5d: flat mojave rocks (3.0-3.6x wider than tall) 2 bands out of a wide sector
    # threshold but 10-27 spreads out of the smooth ground around them were dropped as streaks
    rng = np.random.default_rng(5)
    image = rng.normal(100.0, 3.0, (80, 100)).clip(0, 255).astype(np.uint8)
    labels = np.zeros(image.shape, np.int32)
    labels[10:17, 10:35] = 1  # a flat light rock, 3.6x: 60 gray levels = 13 spreads out
    labels[30:37, 10:35] = 2  # a faint streak of the same shape: 12 levels = 2.7 spreads
    labels[50:54, 10:70] = 3  # a long clear streak, 15x: longer than any rock
    image[labels == 1] = 160
    image[labels == 2] = 112
    image[labels == 3] = 160
    contrast = np.where(labels > 0, np.float32(2.0), np.float32(0.0))  # R5b: not clear
    kept, dropped = drop_streaks(labels, max_elongation=3.0, contrast=contrast, image=image)
    assert dropped == 2
    assert kept[12, 20] == 1 and not kept[30:37].any() and not kept[50:54].any()
    # the same rock on ground as textured as it is bright is a streak
    rough = rng.normal(100.0, 30.0, image.shape).clip(0, 255).astype(np.uint8)
    rough[labels == 1] = 160
    _, dropped = drop_streaks(labels, max_elongation=3.0, image=rough)
    assert dropped == 3
    with pytest.raises(ValueError, match="image"):
        drop_streaks(labels, max_elongation=3.0, image=image[:10])
    with pytest.raises(ValueError, match="clear_spreads"):
        drop_streaks(labels, max_elongation=3.0, image=image, clear_spreads=0.0)


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


def test_drop_ripple_pieces_at_range_drops_a_blob_as_dark_as_the_streaks_beside_it():
    # rule R5c at range: on a dunes frame of seed 5 six aliased ripple troughs near the
    # horizon, black blobs on smooth sand (their ring has no texture: ratio 9-15), were kept
    # as rocks beside dashes of the same gray; a rock darker than the dashes stays
    shape = (160, 200)
    image = np.full(shape, 150, np.uint8)
    dashes = np.zeros(shape, bool)
    for row in (40, 46, 52):
        dashes[row : row + 3, 0:50] = dashes[row : row + 3, 150:200] = True
    image[dashes] = 75
    labels = np.zeros(shape, np.int32)
    blob, rock = disk(shape, 47, 100, 4), disk(shape, 47, 75, 4)
    image[blob], image[rock] = 75, 20
    labels[rock], labels[blob] = 1, 2
    texture = label_objects(dashes | blob | rock, min_area_px=20, fill=False)
    kept, dropped = drop_ripple_pieces(labels, texture=texture, image=image)
    assert dropped == 1
    assert kept[rock].all() and not kept[blob].any()
    # the same dashes 60 rows away (another range, another ripple shading): the blob stays
    far = np.roll(dashes, 60, axis=0)
    image = np.where(dashes, np.uint8(150), image)
    image[far] = 75
    texture = label_objects(far | blob | rock, min_area_px=20, fill=False)
    _, dropped = drop_ripple_pieces(labels, texture=texture, image=image)
    assert dropped == 0


def test_moment_sums_equal_bincounts_of_the_nonzero_pixels():
    # the numpy twin: np.nonzero's pixels and weighted bincounts (the code replaced)
    rng = np.random.default_rng(14)
    for _ in range(20):
        shape = tuple(rng.integers(1, 50, 2))
        labels = np.where(rng.random(shape) < 0.3, rng.integers(1, 9, shape), 0).astype(np.int32)
        count = int(labels.max()) + 1
        ys, xs = np.nonzero(labels)
        ids = labels[ys, xs]
        area, sum_y, sum_x = _sums(labels, count)
        np.testing.assert_array_equal(area, np.bincount(ids, minlength=count))
        np.testing.assert_array_equal(sum_y, np.bincount(ids, ys, minlength=count))
        np.testing.assert_array_equal(sum_x, np.bincount(ids, xs, minlength=count))
        safe = np.maximum(area, 1).astype(np.float64)
        mx, my = sum_x / safe, sum_y / safe
        dx, dy = xs - mx[ids], ys - my[ids]
        for got, weights in zip(
            _central_sums(labels, mx, my), (dx * dx, dy * dy, dx * dy), strict=True
        ):
            np.testing.assert_array_equal(got, np.bincount(ids, weights, minlength=count))
