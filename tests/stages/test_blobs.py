"""Tests of stages/_blobs.py: compact blobs no threshold reached (R8)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from object_masks import disk

from stages._blobs import (
    _blob_statistics,
    _core_sums,
    _is_solid,
    _seeded_regions,
    _tile_spread,
    add_compact_blobs,
)
from stages._regions import _label_sums, _object_boxes
from stages._sectors import sector_edges

SHAPE = (160, 160)



def _reachable(reach, contrast, free, *, sign=1.0):
    """The pixels a blob's reach can take, in numpy: the reference for the compiled walk."""
    share = np.float32(0.5) * reach.astype(np.float32)
    return (reach > 0) & (np.float32(sign) * contrast >= share) & free


def _fill_seeded_holes(seeded, parts):
    """``seeded[parts]`` with the background pockets it encloses filled: the whole frame's
    background flooded from its border (4-steps), the reference for the compiled walk."""
    outside = np.pad(~seeded[parts], 1, constant_values=True).astype(np.uint8)
    cv2.floodFill(outside, None, (0, 0), 2, flags=4)
    return outside[1:-1, 1:-1] != 2


def blotchy_ground(seed=0, *, ground=76.0):
    """Lava-like ground: dark and light blotches of 1-3 px, as dark and as light as a rock,
    on slight pixel noise (its pixel spread is wide, its spread at 5-9 px much less)."""
    rng = np.random.default_rng(seed)
    image = ground + rng.normal(0, 3, SHAPE)
    for gray in (36.0, 110.0):
        spots = np.zeros(SHAPE, np.uint8)
        spots[rng.random(SHAPE) < 0.025] = 1
        spots = cv2.dilate(spots, np.ones((2, 2), np.uint8)) > 0
        image[spots] = gray + rng.normal(0, 3, spots.sum())
    return image


def to_uint8(image):
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def test_a_compact_dark_blob_on_a_fine_blotchy_texture_is_found():
    image = blotchy_ground()
    rock = disk(SHAPE, 80, 80, 6)  # 113 px, as dark as the ground's blotches
    image[rock] = 40 + np.random.default_rng(1).normal(0, 3, rock.sum())
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_compact_blobs(labels, to_uint8(image), min_sigmas=4.0)
    assert added == 1
    blob = found > 0
    assert np.count_nonzero(blob & rock) / np.count_nonzero(blob | rock) > 0.7


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_blotchy_texture_alone_yields_nothing(seed):
    labels = np.zeros(SHAPE, np.int32)
    found, added = add_compact_blobs(labels, to_uint8(blotchy_ground(seed)), min_sigmas=4.0)
    assert added == 0 and not found.any()


def test_a_flat_shadow_next_to_a_found_light_rock_is_not_added():
    image = blotchy_ground()
    rock = disk(SHAPE, 80, 70, 8)
    shadow = disk(SHAPE, 80, 82, 8) & ~rock  # cast to the right, touching the rock
    image[rock] = 170
    image[shadow] = 35
    labels = np.zeros(SHAPE, np.int32)
    labels[rock] = 1  # the thresholds found the lit rock
    found, added = add_compact_blobs(labels, to_uint8(image), min_sigmas=4.0)
    assert added == 0
    np.testing.assert_array_equal(found, labels)
    # the same dark patch with nothing beside it is a rock
    alone, added_alone = add_compact_blobs(
        np.zeros(SHAPE, np.int32), to_uint8(np.where(rock, blotchy_ground(), image)),
        min_sigmas=4.0,
    )
    assert added_alone == 1 and np.count_nonzero((alone > 0) & shadow) > 0.8 * shadow.sum()


def test_objects_are_kept_and_blobs_numbered_after_them():
    image = blotchy_ground()
    rock = disk(SHAPE, 40, 40, 6)
    other = disk(SHAPE, 110, 110, 7)
    image[rock] = 40
    image[other] = 45
    labels = np.zeros(SHAPE, np.int32)
    labels[other] = 5
    found, added = add_compact_blobs(labels, to_uint8(image), min_sigmas=4.0)
    assert added == 1 and set(np.unique(found)) == {0, 5, 6}
    np.testing.assert_array_equal(found == 5, other)
    assert labels.max() == 5  # the input is not modified


def test_a_thin_streak_is_not_a_blob():
    image = blotchy_ground()
    image[78:81, 30:130] = 38  # a 3 px wide dark streak: no interior, not compact
    found, added = add_compact_blobs(np.zeros(SHAPE, np.int32), to_uint8(image), min_sigmas=4.0)
    assert added == 0


def test_bad_arguments_raise_clear_errors():
    image = to_uint8(blotchy_ground())
    labels = np.zeros(SHAPE, np.int32)
    with pytest.raises(ValueError, match="one shape"):
        add_compact_blobs(labels[:10], image, min_sigmas=4.0)
    with pytest.raises(TypeError, match="uint8"):
        add_compact_blobs(labels, image.astype(np.float32), min_sigmas=4.0)
    with pytest.raises(ValueError, match="min_sigmas > 0"):
        add_compact_blobs(labels, image, min_sigmas=0.0)
    with pytest.raises(ValueError, match="odd ground_px"):
        add_compact_blobs(labels, image, min_sigmas=4.0, ground_px=40)
    with pytest.raises(ValueError, match=r"must be in \[0, 1\]"):
        add_compact_blobs(labels, image, min_sigmas=4.0, min_solidity=1.5)


def test_blob_statistics_equal_their_numpy_twin():
    # the twin: ufunc.at and bincounts of masked copies (the code the kernel replaced)
    rng = np.random.default_rng(11)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        grown = rng.random(shape) < rng.random()
        n_blobs, blob_ids = cv2.connectedComponents(grown.view(np.uint8), connectivity=8)
        z = rng.normal(0, 3, shape).astype(np.float32)
        ring = rng.random(shape) < 0.3
        interior = cv2.erode(grown.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        peaks, areas, touching, inner, boxes = _blob_statistics(
            blob_ids, n_blobs, z, ring, interior
        )
        np.testing.assert_array_equal(boxes, _object_boxes(blob_ids, n_blobs - 1))
        owners = blob_ids[grown]
        expected = np.full(n_blobs, -np.inf)
        np.maximum.at(expected, owners, z[grown])
        np.testing.assert_array_equal(peaks, expected)
        # the dark side: the peaks of a negated copy
        expected = np.full(n_blobs, -np.inf)
        np.maximum.at(expected, owners, -z[grown])
        np.testing.assert_array_equal(
            _blob_statistics(blob_ids, n_blobs, z, ring, interior, sign=-1.0)[0], expected
        )
        np.testing.assert_array_equal(areas, np.bincount(owners, minlength=n_blobs))
        np.testing.assert_array_equal(
            touching, np.bincount(blob_ids[ring], minlength=n_blobs) > 0
        )
        np.testing.assert_array_equal(
            inner, np.bincount(blob_ids[interior], minlength=n_blobs)
        )


def test_tile_spread_memo_measures_changed_tiles_alike():
    # R8b's search reuses R8's tile spreads where no free pixel changed
    rng = np.random.default_rng(9)
    values = rng.normal(0, 4, (130, 170)).astype(np.float32)
    use = rng.random(values.shape) < 0.9
    memo: dict = {}
    for _ in range(4):
        np.testing.assert_array_equal(
            _tile_spread(values, use, 30, _memo=memo), _tile_spread(values, use, 30)
        )
        y, x = rng.integers(0, 120), rng.integers(0, 160)
        use = use.copy()
        use[y : y + 12, x : x + 9] = False
    # another tiling starts afresh
    np.testing.assert_array_equal(
        _tile_spread(values, use, 20, _memo=memo), _tile_spread(values, use, 20)
    )


def _tile_spread_numpy(values, use, tile_px):
    """_tile_spread's numpy twin: per tile, np.partition of the sample's absolute values."""
    rows, cols = values.shape
    row_edges = sector_edges(rows, max(1, round(rows / tile_px)))
    col_edges = sector_edges(cols, max(1, round(cols / tile_px)))
    grid = np.full((row_edges.size - 1, col_edges.size - 1), np.nan, np.float32)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            r0, r1 = row_edges[i], row_edges[i + 1]
            c0, c1 = col_edges[j], col_edges[j + 1]
            sample = values[r0:r1:2, c0:c1:2][use[r0:r1:2, c0:c1:2]]
            if sample.size >= 12:
                middle = sample.size // 2
                grid[i, j] = 1.4826 * np.partition(np.abs(sample), middle)[middle]
    if np.isnan(grid).all():
        grid[:] = 0.5
    grid[np.isnan(grid)] = np.nanmedian(grid)
    return cv2.resize(grid, (cols, rows), interpolation=cv2.INTER_LINEAR)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_tile_spread_equals_its_numpy_twin(dtype):
    # the compiled tiles against np.partition per tile: ties (rounded values), empty and
    # sparse tiles, odd and even sample sizes
    rng = np.random.default_rng(31)
    for _ in range(40):
        shape = tuple(rng.integers(8, 130, 2))
        values = np.round(rng.normal(0, 4, shape), int(rng.integers(0, 3))).astype(dtype)
        use = rng.random(shape) < rng.uniform(0.0, 1.0)
        tile_px = int(rng.integers(8, 40))
        np.testing.assert_array_equal(
            _tile_spread(values, use, tile_px), _tile_spread_numpy(values, use, tile_px)
        )


def test_seeded_regions_fill_nested_rings_as_the_whole_frame_flood():
    # each part flooded in its own box: nested rings (a pocket between two parts, inside
    # the outer one) and parts on the frame's edge, against the whole frame's flood
    rings = np.zeros((30, 30), np.uint8)
    cv2.rectangle(rings, (2, 2), (27, 27), 1, 1)
    cv2.rectangle(rings, (8, 8), (21, 21), 1, 1)
    rings[14, 14] = 1
    edge = np.zeros((12, 15), np.uint8)
    cv2.rectangle(edge, (-3, -3), (7, 6), 1, 1)
    for past in (rings.astype(bool), edge.astype(bool)):
        reach = past.astype(np.uint8)
        contrast = np.full(past.shape, 9.0, np.float32)
        free = np.ones(past.shape, bool)
        n_parts, parts = cv2.connectedComponents(past.view(np.uint8), connectivity=8)
        seeded = np.arange(n_parts) > 0
        np.testing.assert_array_equal(
            _seeded_regions(past, reach, contrast, free), _fill_seeded_holes(seeded, parts)
        )


def test_seeded_regions_equal_reach_components_and_fill():
    # the fused walk against the composition it replaced: the reach map, its 8-connected
    # parts, those holding a core pixel of the map, their pockets filled
    rng = np.random.default_rng(21)
    for _ in range(200):
        shape = tuple(rng.integers(1, 45, 2))
        reach = rng.integers(0, 40, shape).astype(np.uint8)
        reach[rng.random(shape) < rng.uniform(0.05, 0.5)] = 0
        contrast = rng.normal(5, 10, shape).astype(np.float32)
        contrast[rng.random(shape) < 0.05] = np.nan
        free = rng.random(shape) < 0.85
        cores = rng.random(shape) < rng.uniform(0.0, 0.1)
        for sign in (1.0, -1.0):
            past = _reachable(reach, contrast, free, sign=sign)
            n_parts, parts = cv2.connectedComponents(past.view(np.uint8), connectivity=8)
            seeded = np.zeros(n_parts, bool)
            seeded[parts[cores & past]] = True
            seeded[0] = False
            np.testing.assert_array_equal(
                _seeded_regions(cores, reach, contrast, free, sign=sign),
                _fill_seeded_holes(seeded, parts),
            )


def test_core_sums_equal_connected_components_and_label_sums():
    # the compiled walk over the core pixels against OpenCV's components and the
    # whole-frame raster sums: the same cores (numbered maybe otherwise), the same floats
    rng = np.random.default_rng(22)
    for _ in range(200):
        shape = tuple(rng.integers(1, 45, 2))
        cores = rng.random(shape) < rng.uniform(0.0, 0.6)
        contrast = rng.normal(5, 10, shape).astype(np.float32)
        at, owner, counts, sums = _core_sums(cores, contrast)
        n_cores, core_ids = cv2.connectedComponents(cores.view(np.uint8), connectivity=8)
        want_counts, want_sums = _label_sums(core_ids, contrast, n_cores)
        np.testing.assert_array_equal(at, np.flatnonzero(cores))
        assert counts.size == n_cores and counts[0] == 0 and sums[0] == 0
        # one-to-one between the numberings
        theirs = core_ids.ravel()[at]
        pairs = np.unique(np.stack([owner, theirs]), axis=1)
        assert pairs.shape[1] == n_cores - 1 == np.unique(pairs[0]).size == np.unique(pairs[1]).size
        order = np.argsort(pairs[0])
        mine, match = pairs[0][order], pairs[1][order]
        np.testing.assert_array_equal(counts[mine], want_counts[match])
        np.testing.assert_array_equal(sums[mine], want_sums[match])


def _hull_of_outline_px(region):
    """_is_solid's former hull: of the region's external contours."""
    contours, _ = cv2.findContours(
        region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    hull = cv2.convexHull(np.vstack(contours))
    return cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1


def test_is_solid_equals_the_test_on_the_outlines_hull():
    # the hull of each row's ends against the hull of the outline: the same test at the
    # very threshold a region's own solidity sets
    rng = np.random.default_rng(37)
    for _ in range(300):
        shape = tuple(rng.integers(2, 40, 2))
        noise = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 1.5)
        region = noise > rng.uniform(0.3, 0.6)
        if not region.any():
            continue
        solidity = np.count_nonzero(region) / _hull_of_outline_px(region)
        for threshold in (solidity, np.nextafter(solidity, 2.0), rng.random()):
            assert _is_solid(region, min_solidity=threshold) == (
                np.count_nonzero(region) >= threshold * _hull_of_outline_px(region)
            )
