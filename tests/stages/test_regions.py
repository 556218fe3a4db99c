"""Tests of stages/_regions.py: masks, holes, components, split at depth edges (R4)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from object_masks import disk
from scipy.ndimage import distance_transform_edt, find_objects

from stages._regions import (
    _box_window,
    _core_parents,
    _dense_components,
    _label_areas,
    _label_sums,
    _lookup,
    _object_boxes,
    _renumber,
    _renumber_numpy,
    _solidity,
    _split_at_edges,
    depth_edges,
    fill_holes,
    label_objects,
    threshold_mask,
)


def test_threshold_mask_both_polarities():
    image = np.array([[10, 100, 200]], np.uint8)
    mask = threshold_mask(image, np.full((1, 3), 50.0), np.full((1, 3), 150.0))
    assert mask.tolist() == [[True, False, True]]
    with pytest.raises(ValueError, match="one shape"):
        threshold_mask(image, np.zeros((2, 3)), np.zeros((1, 3)))


def test_fill_holes_fills_enclosed_pockets_only():
    ring = disk((40, 40), 20, 20, 10) & ~disk((40, 40), 20, 20, 4)
    filled = fill_holes(ring)
    assert filled[20, 20] and filled.sum() == disk((40, 40), 20, 20, 10).sum()
    # a pocket open to the border stays background
    cup = np.zeros((20, 20), bool)
    cup[5:15, 0:10] = True
    cup[8:12, 0:6] = False
    assert not fill_holes(cup)[10, 2]
    with pytest.raises(TypeError, match="bool"):
        fill_holes(cup.astype(np.uint8))


def test_label_objects_drops_specks_and_numbers_densely():
    mask = disk((64, 64), 20, 20, 8) | disk((64, 64), 45, 45, 6)
    mask[2:4, 60:62] = True  # 4-pixel speck
    labels = label_objects(mask, min_area_px=30)
    assert labels.dtype == np.int32
    assert sorted(np.unique(labels).tolist()) == [0, 1, 2]
    assert labels[2, 60] == 0
    with pytest.raises(ValueError, match="min_area_px"):
        label_objects(mask, min_area_px=0)


def test_touching_blocks_at_different_depth_split():
    shape = (60, 80)
    mask = np.zeros(shape, bool)
    mask[20:40, 10:70] = True  # one intensity blob ...
    disparity = np.full(shape, 10.0, np.float32)
    disparity[20:40, 10:40] = 20.0  # ... made of a near block
    disparity[20:40, 40:70] = 14.0  # and a farther one
    edges = depth_edges(disparity, jump_px=1.5)
    assert edges[25, 40] and not edges[25, 39]  # the far side of the jump
    assert label_objects(mask, min_area_px=30).max() == 1
    labels = label_objects(mask, min_area_px=30, edges=edges)
    assert labels.max() == 2
    assert labels[30, 15] != labels[30, 65]
    assert np.count_nonzero(labels) == mask.sum()  # edge pixels go to their nearest block


def test_depth_edges_inside_one_object_do_not_fragment_it():
    shape = (40, 40)
    mask = disk(shape, 20, 20, 12)
    disparity = np.full(shape, 12.0, np.float32)
    disparity[20, 20] = 30.0  # an isolated outlier: median filtered away
    labels = label_objects(mask, edges=depth_edges(disparity, jump_px=1.5))
    assert labels.max() == 1


def _dense_components_with_stats(mask, min_area_px, connectivity):
    """The numpy twin of _dense_components' kernel: OpenCV's areas and a lookup table."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        mask.view(np.uint8), connectivity=connectivity, ltype=cv2.CV_32S
    )
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    keep[0] = False
    lookup = np.zeros(count, dtype=np.int32)
    lookup[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lookup[labels]


@pytest.mark.parametrize("connectivity", [4, 8])
def test_dense_components_equal_opencvs_areas_and_lookup(connectivity):
    rng = np.random.default_rng(5)
    for _ in range(20):
        shape = tuple(rng.integers(1, 60, 2))
        mask = rng.random(shape) < rng.random()
        min_area = int(rng.integers(1, 12))
        result = _dense_components(mask, min_area, connectivity)
        assert result.dtype == np.int32
        np.testing.assert_array_equal(
            result, _dense_components_with_stats(mask, min_area, connectivity)
        )


def test_object_boxes_equal_find_objects():
    rng = np.random.default_rng(6)
    for _ in range(30):
        shape = tuple(rng.integers(1, 50, 2))
        labels = np.where(rng.random(shape) < 0.2, rng.integers(1, 12, shape), 0)
        labels = labels.astype(rng.choice([np.int32, np.int64, np.uint16]))
        count = int(labels.max())
        boxes = _object_boxes(labels, count)
        spans = find_objects(labels)
        assert boxes.shape == (count + 1, 4) and boxes[0, 1] < boxes[0, 0]
        for k in range(1, count + 1):
            if spans[k - 1] is None:
                assert boxes[k, 1] < boxes[k, 0] and boxes[k, 3] < boxes[k, 2]
            else:
                assert _box_window(boxes[k]) == spans[k - 1]
    # ids above count are left out, not written past the table
    assert _object_boxes(np.array([[0, 3, 1]]), 1).tolist()[1] == [0, 0, 2, 2]


def test_object_boxes_by_runs_equal_find_objects_on_blobs():
    # the kernel works by runs of one id along the rows: long runs, runs of touching
    # objects and runs at the frame's edges, ids above count among them
    rng = np.random.default_rng(16)
    for _ in range(40):
        shape = tuple(rng.integers(1, 60, 2))
        seeds = np.where(rng.random(shape) < 0.02, rng.integers(1, 15, shape), 0)
        size = tuple(int(v) for v in rng.integers(1, 12, 2))
        labels = cv2.dilate(seeds.astype(np.uint16), np.ones(size, np.uint8)).astype(np.int32)
        count = max(int(labels.max()) - int(rng.integers(0, 3)), 0)
        boxes = _object_boxes(labels, count)
        spans = find_objects(np.where(labels <= count, labels, 0))
        for k in range(1, count + 1):
            if k > len(spans) or spans[k - 1] is None:
                assert boxes[k, 1] < boxes[k, 0] and boxes[k, 3] < boxes[k, 2]
            else:
                assert _box_window(boxes[k]) == spans[k - 1]


def test_renumber_equals_its_numpy_twin():
    rng = np.random.default_rng(13)
    for trial in range(30):
        shape = tuple(rng.integers(1, 50, 2))
        ids = rng.integers(1, 40, shape) * (1000 if trial % 3 == 0 else 1)  # sparse ids
        labels = np.where(rng.random(shape) < 0.4, ids, 0)
        labels = labels.astype(np.int64 if trial % 2 else np.int32)
        min_area = int(rng.integers(1, 6))
        result = _renumber(labels, min_area)
        assert result.dtype == np.int32
        np.testing.assert_array_equal(result, _renumber_numpy(labels, min_area))


def test_lookup_equals_fancy_indexing_and_checks_the_range():
    rng = np.random.default_rng(15)
    labels = rng.integers(0, 9, (30, 40)).astype(np.int32)
    tables = (rng.random(9) < 0.5, rng.integers(0, 300, 9).astype(np.uint16), rng.normal(size=9))
    for table in tables:
        result = _lookup(table, labels)
        assert result.dtype == table.dtype
        np.testing.assert_array_equal(result, table[labels])
    with pytest.raises(IndexError, match="range"):
        _lookup(np.zeros(5), labels)


def test_label_areas_equal_bincounts():
    rng = np.random.default_rng(17)
    for dtype in (np.int32, np.uint16, np.int64):
        shape = tuple(rng.integers(1, 50, 2))
        labels = np.where(rng.random(shape) < 0.5, rng.integers(1, 7, shape), 0).astype(dtype)
        np.testing.assert_array_equal(
            _label_areas(labels, 9), np.bincount(labels.ravel(), minlength=9)
        )
    with pytest.raises(IndexError, match="must lie in"):
        _label_areas(np.full((2, 2), 9, np.int32), 9)


def test_label_sums_equal_bincounts():
    rng = np.random.default_rng(16)
    for _ in range(10):
        shape = tuple(rng.integers(1, 50, 2))
        labels = np.where(rng.random(shape) < 0.5, rng.integers(1, 7, shape), 0).astype(np.int32)
        values = rng.normal(0, 2, shape).astype(np.float32)
        counts, sums = _label_sums(labels, values, 7)
        inside = labels > 0
        np.testing.assert_array_equal(counts, np.bincount(labels.ravel(), minlength=7))
        np.testing.assert_array_equal(
            sums, np.bincount(labels[inside], values[inside], minlength=7)
        )


def _split_at_edges_twin(labels, edges, min_area_px):
    """_split_at_edges with whole-frame feature transforms (no crop)."""
    cores = _dense_components((labels > 0) & ~edges, min_area_px, connectivity=4)
    if int(cores.max()) < 2:
        return labels
    core_pixels = cores > 0
    parent = np.zeros(int(cores.max()) + 1, dtype=np.int64)
    parent[cores[core_pixels]] = labels[core_pixels]
    split_objects = np.flatnonzero(np.bincount(parent[1:], minlength=int(labels.max()) + 1) >= 2)
    if split_objects.size == 0:
        return labels
    result = labels.astype(np.int64)
    offset = int(labels.max())
    _, (iy, ix) = distance_transform_edt(~core_pixels, return_indices=True)
    nearest = cores[iy, ix]
    for k in split_objects:
        mine = (labels == k) & (parent[nearest] == k)
        result[mine] = offset + nearest[mine]
    return result


def test_split_at_edges_crops_equal_the_whole_frame_transform():
    # ties are common on the pixel grid (a pixel as far from two cores): the crops must
    # pick the very core the whole frame's transform picks
    rng = np.random.default_rng(19)
    splits = 0
    for _ in range(150):
        shape = tuple(rng.integers(20, 90, 2))
        noise = rng.random(shape).astype(np.float32)
        mask = cv2.GaussianBlur(noise, (0, 0), rng.uniform(1, 5)) > 0.5
        labels = _dense_components(mask, 5)
        edges = rng.random(shape) < 0.02
        for axis in (0, 1):
            seeds = (rng.random(shape) < 0.003).astype(np.uint8)
            size = (1, int(rng.integers(3, 40)))[:: 1 if axis else -1]
            edges |= cv2.dilate(seeds, np.ones(size, np.uint8)).astype(bool)
        result = _split_at_edges(labels, edges, 5)
        np.testing.assert_array_equal(result, _split_at_edges_twin(labels, edges, 5))
        splits += result is not labels
    assert splits > 50


def test_core_parents_equal_the_masked_scatter():
    # the compiled pass against the numpy scatter it replaced in _split_at_edges
    rng = np.random.default_rng(23)
    for _ in range(100):
        shape = tuple(rng.integers(1, 40, 2))
        noise = rng.random(shape).astype(np.float32)
        labels = _dense_components(cv2.GaussianBlur(noise, (0, 0), 1.5) > 0.5, 1)
        cores = _dense_components((labels > 0) & (rng.random(shape) > 0.1), 2, connectivity=4)
        expected = np.zeros(int(cores.max()) + 1, np.int64)
        expected[cores[cores > 0]] = labels[cores > 0]
        np.testing.assert_array_equal(_core_parents(cores, labels), expected)


def _solidity_of_all_pixels(mask):
    """_solidity's twin: the convex hull of every pixel (cv2.findNonZero)."""
    points = cv2.findNonZero(mask.astype(np.uint8))
    hull = cv2.convexHull(points)
    return len(points) / (cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0)


def test_solidity_from_the_row_ends_equals_the_hull_of_all_pixels():
    # the hull of each row's first and last pixel: the same vertices, the same float, on
    # blobs, rings, straight edges (pixels on a hull edge), single pixels and lines
    rng = np.random.default_rng(29)
    masks = [np.ones((1, 1), bool), np.ones((1, 7), bool), np.ones((5, 1), bool)]
    for _ in range(300):
        shape = tuple(rng.integers(2, 40, 2))
        noise = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 1.5)
        masks.append(noise > rng.uniform(0.3, 0.6))
        square = np.zeros(shape, bool)
        square[1 : shape[0] - 1, 1 : shape[1] - 1] = rng.random() < 0.5
        masks.append(square | (rng.random(shape) < 0.05))
    for mask in masks:
        if mask.any():
            assert _solidity(mask) == _solidity_of_all_pixels(mask)
