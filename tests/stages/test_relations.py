"""Tests of the scene-graph relations on hand-made label and disparity arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages._relations import (
    RELATION_COLUMNS,
    boundary_disparity_difference,
    contact_pixels,
    horizontal_overlap,
    ordering_matrices,
    region_neighbours,
    relate_objects,
)


def test_ordering_matrices_with_margin():
    x = np.array([0.0, 0.5, 0.52, np.nan])
    y = np.array([1.0, 1.0, 2.0, 1.5])
    m = ordering_matrices(x, y, margin_m=0.05)
    assert m["left_of"][0, 1] and m["right_of"][1, 0]
    assert not m["left_of"][1, 2] and not m["right_of"][2, 1]  # 2 cm apart: near-tie
    assert m["in_front_of"][1, 2] and m["behind"][2, 1]
    assert not m["in_front_of"][0, 1] and not m["behind"][1, 0]
    for name in m:
        assert not m[name][3].any() and not m[name][:, 3].any()  # unknown position: no edge
        assert not np.diag(m[name]).any()
    with pytest.raises(ValueError, match="margin_m"):
        ordering_matrices(x, y, margin_m=-1.0)


def test_ordering_matrices_only_within_radius():
    # 0 and 1 are 0.5 m apart, 2 is 3 m from both: with a 1 m radius only 0-1 is ordered
    x = np.array([0.0, 0.3, 0.0])
    y = np.array([1.0, 1.4, 4.0])
    local = ordering_matrices(x, y, margin_m=0.05, radius_m=1.0)
    every = ordering_matrices(x, y, margin_m=0.05)
    assert local["left_of"][0, 1] and local["in_front_of"][0, 1] and local["behind"][1, 0]
    for name in local:
        assert not local[name][2].any() and not local[name][:, 2].any()
    assert every["in_front_of"][0, 2] and every["behind"][2, 1]
    boundary = ordering_matrices(x, y, margin_m=0.05, radius_m=0.5)  # distance == radius
    assert boundary["left_of"][0, 1]
    with pytest.raises(ValueError, match="radius_m"):
        ordering_matrices(x, y, margin_m=0.05, radius_m=0.0)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-5, 5), min_size=2, max_size=6),
    st.floats(0.0, 1.0),
)
def test_ordering_facts_come_in_both_directions(xs, margin):
    x = np.array(xs)
    m = ordering_matrices(x, np.zeros_like(x), margin_m=margin)
    np.testing.assert_array_equal(m["left_of"], m["right_of"].T)
    np.testing.assert_array_equal(m["in_front_of"], m["behind"].T)
    assert not (m["left_of"] & m["right_of"]).any()


def test_horizontal_overlap():
    assert horizontal_overlap(0, 9, 5, 20) == pytest.approx(5 / 10)
    assert horizontal_overlap(0, 9, 2, 4) == pytest.approx(1.0)  # narrower inside wider
    assert horizontal_overlap(0, 9, 10, 12) == 0.0
    assert horizontal_overlap(0, 9, 30, 40) == 0.0
    assert horizontal_overlap(3, 3, 3, 3) == 1.0


def _squares(gap: int) -> np.ndarray:
    labels = np.zeros((12, 20), dtype=np.int32)
    labels[3:8, 2:7] = 1
    labels[3:8, 7 + gap : 12 + gap] = 2
    return labels


def test_region_neighbours_touching_and_gaps():
    touching = region_neighbours(_squares(0), 1, gap_px=0)
    # object 1's boundary: 16 pixels, its right column of 5 touches object 2
    assert touching == {2: pytest.approx(5 / 16)}
    assert region_neighbours(_squares(2), 1, gap_px=2) == {2: pytest.approx(5 / 16)}
    assert region_neighbours(_squares(3), 1, gap_px=2) == {}
    assert region_neighbours(_squares(0), 9, gap_px=1) == {}
    with pytest.raises(ValueError, match="gap_px"):
        region_neighbours(_squares(0), 1, gap_px=-1)


def test_boundary_disparity_difference():
    labels = _squares(0)
    disparity = np.where(labels == 1, 20.0, np.where(labels == 2, 12.0, 5.0))
    disparity[3:8, 2] = 100.0  # far from the shared boundary: outside the band
    diff = boundary_disparity_difference(disparity, labels == 1, labels == 2, band_px=2)
    assert diff == pytest.approx(8.0)
    assert boundary_disparity_difference(
        disparity, labels == 2, labels == 1, band_px=2
    ) == pytest.approx(-8.0)
    disparity[labels == 2] = np.nan
    assert math.isnan(boundary_disparity_difference(disparity, labels == 1, labels == 2, band_px=2))
    with pytest.raises(ValueError, match="band_px"):
        boundary_disparity_difference(disparity, labels == 1, labels == 2, band_px=0)


def _edges(columns):
    return set(
        zip(
            columns["subject_id"].tolist(),
            columns["relation"].tolist(),
            columns["object_id"].tolist(),
            strict=True,
        )
    )


def test_relate_objects_known_graph():
    labels = np.zeros((30, 40), dtype=np.int32)
    labels[10:20, 5:15] = 1  # near, left
    labels[10:20, 15:25] = 2  # touches 1, farther, centre
    labels[2:6, 33:37] = 3  # isolated, far right and far away
    disparity = np.full(labels.shape, 4.0)
    disparity[labels == 1] = 20.0
    disparity[labels == 2] = 15.0
    disparity[labels == 3] = 6.0
    columns = relate_objects(
        labels,
        disparity,
        object_ids=np.array([1, 2, 3]),
        x_m=np.array([-0.4, 0.0, 0.8]),
        y_m=np.array([1.0, 1.5, 3.0]),
        bbox_x_min=np.array([5, 15, 33]),
        bbox_x_max=np.array([14, 24, 36]),
        radius_m=math.inf,
    )
    expected = {
        (1, "left_of", 2), (2, "right_of", 1), (1, "left_of", 3), (3, "right_of", 1),
        (2, "left_of", 3), (3, "right_of", 2),
        (1, "in_front_of", 2), (2, "behind", 1), (1, "in_front_of", 3), (3, "behind", 1),
        (2, "in_front_of", 3), (3, "behind", 2),
        (1, "adjacent", 2), (2, "adjacent", 1),
        (1, "occludes", 2),
    }  # fmt: skip
    assert _edges(columns) == expected
    assert list(columns) == list(RELATION_COLUMNS)
    order = list(zip(columns["subject_id"].tolist(), columns["relation"].tolist(), strict=True))
    assert order == sorted(
        order,
        key=lambda e: (
            e[0],
            ["left_of", "right_of", "in_front_of", "behind", "adjacent", "occludes"].index(e[1]),
        ),
    )
    pick = (columns["subject_id"] == 1) & (columns["object_id"] == 2)
    np.testing.assert_allclose(columns["distance_m"][pick], math.hypot(0.4, 0.5))
    np.testing.assert_allclose(columns["overlap"][pick], 0.0)
    adjacent = pick & (columns["relation"] == "adjacent")
    # 36 boundary pixels; within 3 px of object 2: the right column (10) and the last two
    # pixels before it on the top and bottom rows (4)
    assert columns["shared_boundary"][adjacent][0] == pytest.approx(14 / 36)
    far = (columns["subject_id"] == 3) & (columns["object_id"] == 1)
    np.testing.assert_allclose(columns["shared_boundary"][far], 0.0)


def test_relate_objects_radius_leaves_adjacent_and_occludes_alone():
    # same scene as test_relate_objects_known_graph with the default 1 m radius: object 3
    # (2.3 m from 1, 1.7 m from 2) loses its ordering edges; 1-2 (0.64 m) keep theirs
    labels = np.zeros((30, 40), dtype=np.int32)
    labels[10:20, 5:15] = 1
    labels[10:20, 15:25] = 2
    labels[2:6, 33:37] = 3
    disparity = np.where(labels == 1, 20.0, np.where(labels == 2, 15.0, 4.0))
    kwargs = {
        "object_ids": np.array([1, 2, 3]),
        "bbox_x_min": np.array([5, 15, 33]),
        "bbox_x_max": np.array([14, 24, 36]),
    }
    columns = relate_objects(
        labels, disparity, x_m=np.array([-0.4, 0.0, 0.8]), y_m=np.array([1.0, 1.5, 3.0]), **kwargs
    )
    assert _edges(columns) == {
        (1, "left_of", 2), (2, "right_of", 1), (1, "in_front_of", 2), (2, "behind", 1),
        (1, "adjacent", 2), (2, "adjacent", 1), (1, "occludes", 2),
    }  # fmt: skip
    # regions touching in the image are adjacent (and 1 occludes 2) whatever their distance
    apart = relate_objects(
        labels,
        disparity,
        x_m=np.array([-0.4, 0.0, 0.8]),
        y_m=np.array([1.0, 5.0, 3.0]),
        radius_m=0.5,
        **kwargs,
    )
    assert _edges(apart) == {(1, "adjacent", 2), (2, "adjacent", 1), (1, "occludes", 2)}


def test_relate_objects_equal_depth_neighbours_do_not_occlude():
    labels = _squares(1)
    disparity = np.where(labels > 0, 10.3, 4.0)
    disparity[labels == 2] = 10.0
    columns = relate_objects(
        labels,
        disparity,
        object_ids=np.array([1, 2]),
        x_m=np.array([0.0, 0.02]),
        y_m=np.array([1.0, 1.0]),
        bbox_x_min=np.array([2, 8]),
        bbox_x_max=np.array([6, 12]),
    )
    assert _edges(columns) == {(1, "adjacent", 2), (2, "adjacent", 1)}


@pytest.mark.parametrize("n_objects", [0, 1])
def test_relate_objects_fewer_than_two_objects(n_objects):
    labels = np.zeros((10, 10), dtype=np.int32)
    labels[2:4, 2:4] = n_objects
    ids = np.arange(1, n_objects + 1)
    columns = relate_objects(
        labels,
        np.full((10, 10), 5.0),
        object_ids=ids,
        x_m=np.zeros(n_objects),
        y_m=np.zeros(n_objects),
        bbox_x_min=np.full(n_objects, 2),
        bbox_x_max=np.full(n_objects, 3),
    )
    for name, kind in RELATION_COLUMNS.items():
        assert columns[name].shape == (0,)
        assert columns[name].dtype.kind == ("U" if kind == "str" else np.dtype(kind).kind)


def test_relate_objects_validates():
    labels = np.zeros((10, 10), dtype=np.int32)
    with pytest.raises(ValueError, match="one shape"):
        relate_objects(
            labels, np.zeros((9, 10)), object_ids=np.array([]), x_m=np.array([]),
            y_m=np.array([]), bbox_x_min=np.array([]), bbox_x_max=np.array([]),
        )  # fmt: skip
    with pytest.raises(ValueError, match="one value per object"):
        relate_objects(
            labels, np.zeros((10, 10)), object_ids=np.array([1, 2]), x_m=np.array([0.0]),
            y_m=np.zeros(2), bbox_x_min=np.zeros(2), bbox_x_max=np.zeros(2),
        )  # fmt: skip


def test_contact_pixels():
    assert contact_pixels(_squares(0) == 1, _squares(0) == 2, gap_px=0) == 5
    assert contact_pixels(_squares(1) == 1, _squares(1) == 2, gap_px=0) == 0
    assert contact_pixels(_squares(1) == 1, _squares(1) == 2, gap_px=1) == 5
    diagonal = np.zeros((4, 4), dtype=bool)
    other = np.zeros((4, 4), dtype=bool)
    diagonal[0, 0], other[1, 1] = True, True
    assert contact_pixels(diagonal, other, gap_px=0) == 0  # corners do not touch
    with pytest.raises(ValueError, match="gap_px"):
        contact_pixels(diagonal, other, gap_px=-1)


def _pair_columns(labels, disparity, **kwargs):
    return relate_objects(
        labels,
        disparity,
        object_ids=np.array([1, 2]),
        x_m=np.array([0.0, 0.0]),
        y_m=np.array([1.0, 1.0]),
        bbox_x_min=np.array([2, 8]),
        bbox_x_max=np.array([6, 12]),
        **kwargs,
    )


def test_occludes_needs_contact():
    labels = _squares(1)  # one background column between the regions
    disparity = np.where(labels == 1, 12.0, np.where(labels == 2, 10.0, 4.0))
    assert "occludes" not in _pair_columns(labels, disparity)["relation"]
    split = _pair_columns(labels, disparity, contact_gap_px=1)
    assert (1, "occludes", 2) in _edges(split)
    with pytest.raises(ValueError, match="contact_gap_px"):
        _pair_columns(labels, disparity, gap_px=1, contact_gap_px=2)


def test_small_disparity_step_at_a_contact_is_an_occlusion():
    labels = _squares(0)
    disparity = np.where(labels == 1, 10.0, np.where(labels == 2, 10.3, 4.0))
    assert (2, "occludes", 1) in _edges(_pair_columns(labels, disparity))
    assert "occludes" not in _pair_columns(labels, disparity, occlusion_jump_px=0.5)["relation"]


def test_relate_objects_reads_disparity_not_above_zero_as_invalid():
    """describe passes the raw float32 disparity (crops cleaned where read): the edges must
    be those of the float64 map with NaN for every value <= 0, as describe passed before."""
    labels = _squares(0)
    raw = np.where(labels == 1, 12.0, np.where(labels == 2, 10.0, 4.0)).astype(np.float32)
    raw[labels == 1] = np.where(np.arange(np.count_nonzero(labels == 1)) % 2, -1.0, 12.0)
    raw[:, 7] = 0.0
    clean = raw.astype(np.float64)
    clean[~(clean > 0)] = np.nan
    got, expected = _pair_columns(labels, raw), _pair_columns(labels, clean)
    assert _edges(got) == _edges(expected)
    assert (1, "occludes", 2) in _edges(got)
    for name in RELATION_COLUMNS:
        assert got[name].tobytes() == expected[name].tobytes()


def test_relate_objects_with_given_object_slices_equals_its_own():
    from scipy import ndimage

    labels = _squares(0)
    disparity = np.where(labels == 1, 12.0, np.where(labels == 2, 10.0, 4.0))
    given = _pair_columns(
        labels, disparity, object_slices=ndimage.find_objects(np.where(labels > 0, labels, 0))
    )
    own = _pair_columns(labels, disparity)
    for name in RELATION_COLUMNS:
        assert given[name].tobytes() == own[name].tobytes()
