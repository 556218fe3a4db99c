"""The report's scene-graph figure: objects as discs by size class, ``adjacent`` edges as
lines, ``occludes`` edges as arrows, the ordering relations left out; its caption's counts."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from pipeline._report_figures import (
    GRAPH_CLASS_COLORS,
    GRAPH_DRAWN,
    GRAPH_EDGE_COLORS,
    relation_counts,
    scene_graph_caption,
    scene_graph_image,
)
from stages._relations import RELATIONS

RADIUS = 6
DIM = 0.5
# three objects: 1 and 2 side by side (adjacent), 3 below them, nearer, occluding 2
NODES = {
    "object_id": [1, 2, 3],
    "centroid_x": [20.0, 60.0, 40.0],
    "centroid_y": [15.0, 15.0, 45.0],
    "size_class": ["sample", "obstacle", "obstacle"],
}
EDGES = {
    "subject_id": [1, 2, 3, 1, 3],
    "relation": ["adjacent", "adjacent", "occludes", "left_of", "right_of"],
    "object_id": [2, 1, 2, 3, 1],
}
EMPTY_EDGES: dict[str, list] = {c: [] for c in EDGES}


def _gray(shape=(60, 80)) -> np.ndarray:
    """A ramp of even gray levels: dimmed by a half, every pixel stays an integer."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    return ((rows + cols) % 100 * 2 + 40).astype(np.uint8)


def _dimmed(gray: np.ndarray) -> np.ndarray:
    level = (gray.astype(np.float64) * (1 - DIM)).astype(np.uint8)
    return np.repeat(level[..., None], 3, axis=-1)


def _draw(nodes=NODES, edges=EDGES, **kw) -> np.ndarray:
    kw = {"dim": DIM, "radius_px": RADIUS, "label_ids": False, **kw}
    return scene_graph_image(_gray(), nodes, edges, **kw)


def _disc(out: np.ndarray, x: float, y: float, r: float) -> np.ndarray:
    rows, cols = np.mgrid[0 : out.shape[0], 0 : out.shape[1]]
    return (rows - y) ** 2 + (cols - x) ** 2 <= r**2


def _share(out: np.ndarray, mask: np.ndarray, bgr) -> float:
    return float(np.mean(np.all(out[mask] == np.array(bgr, np.uint8), axis=-1)))


def _mode(out: np.ndarray, mask: np.ndarray) -> tuple[int, ...]:
    colours, counts = np.unique(out[mask], axis=0, return_counts=True)
    return tuple(int(c) for c in colours[np.argmax(counts)])


def test_nodes_are_discs_coloured_by_size_class_at_their_centroids():
    out = _draw()
    assert out.shape == (60, 80, 3) and out.dtype == np.uint8
    for x, y, cls in zip(
        NODES["centroid_x"], NODES["centroid_y"], NODES["size_class"], strict=True
    ):
        # an edge's stroke crosses the disc from its centre: the class colour still dominates
        assert _mode(out, _disc(out, x, y, RADIUS - 1.5)) == GRAPH_CLASS_COLORS[cls]
    # without edges the disc is the class colour throughout (but its anti-aliased rim)
    alone = _draw(edges=EMPTY_EDGES)
    for x, y, cls in zip(
        NODES["centroid_x"], NODES["centroid_y"], NODES["size_class"], strict=True
    ):
        assert _share(alone, _disc(alone, x, y, RADIUS - 2.5), GRAPH_CLASS_COLORS[cls]) == 1
    # a class other than sample / obstacle gets a third colour, not one of theirs
    other = _draw(nodes={**NODES, "size_class": ["sample", None, "obstacle"]}, edges=EMPTY_EDGES)
    centre = tuple(int(c) for c in other[15, 60])
    assert centre not in set(GRAPH_CLASS_COLORS.values())
    assert centre != tuple(int(c) for c in _dimmed(_gray())[15, 60])


def test_adjacent_edge_is_a_line_between_the_centroids():
    out = _draw()
    mid = (15, 40)  # between objects 1 and 2
    np.testing.assert_array_equal(out[mid], GRAPH_EDGE_COLORS["adjacent"])
    # stored in both directions, drawn once: one direction alone draws the same picture
    one_way = {k: v[:1] + v[2:] for k, v in EDGES.items()}
    np.testing.assert_array_equal(_draw(edges=one_way), out)


def test_ordering_relations_are_not_drawn():
    assert set(GRAPH_DRAWN) == {"adjacent", "occludes"}
    out = _draw()
    # left_of / right_of link objects 1 and 3: the image under their midpoint is untouched
    mid = (30, 30)
    np.testing.assert_array_equal(out[mid], _dimmed(_gray())[mid])
    without = {k: v[:3] for k, v in EDGES.items()}
    np.testing.assert_array_equal(_draw(edges=without), out)


def test_occludes_edge_is_an_arrow_with_its_head_at_the_occluded_object():
    def arrow_pixels_near(out, x, y):
        # the ring just outside the disc, where the shaft leaves or the head lands
        ring = _disc(out, x, y, RADIUS + 8) & ~_disc(out, x, y, RADIUS + 0.5)
        return int(np.sum(np.all(out[ring] == GRAPH_EDGE_COLORS["occludes"], axis=-1)))

    edges = {"subject_id": [3], "relation": ["occludes"], "object_id": [2]}
    out = _draw(edges=edges)
    near_occluded = arrow_pixels_near(out, 60.0, 15.0)
    near_occluder = arrow_pixels_near(out, 40.0, 45.0)
    assert near_occluded > near_occluder > 0
    # the other way round, the head moves to the other end
    back = _draw(edges={"subject_id": [2], "relation": ["occludes"], "object_id": [3]})
    assert arrow_pixels_near(back, 40.0, 45.0) > arrow_pixels_near(back, 60.0, 15.0)
    # the arrow's midpoint is drawn
    np.testing.assert_array_equal(out[30, 50], GRAPH_EDGE_COLORS["occludes"])


def test_empty_nodes_and_edges():
    dimmed = _dimmed(_gray())
    # no objects: the dimmed image alone
    np.testing.assert_array_equal(_draw(nodes={c: [] for c in NODES}, edges=EMPTY_EDGES), dimmed)
    # objects without relations: their discs and nothing else
    out = _draw(edges=EMPTY_EDGES)
    discs = np.zeros(out.shape[:2], bool)
    for x, y in zip(NODES["centroid_x"], NODES["centroid_y"], strict=True):
        discs |= _disc(out, x, y, RADIUS + 2)  # with the anti-aliased rim
    np.testing.assert_array_equal(out[~discs], dimmed[~discs])
    assert np.any(out[discs] != dimmed[discs])


def test_edges_without_a_drawable_node_are_skipped():
    nodes = {**NODES, "centroid_x": [20.0, 60.0, float("nan")]}
    edges = {
        "subject_id": [3, 1, 4],
        "relation": ["occludes", "adjacent", "adjacent"],
        "object_id": [2, 1, 1],
    }  # NaN centroid, a self-edge, an unknown id
    np.testing.assert_array_equal(
        _draw(nodes=nodes, edges=edges), _draw(nodes=nodes, edges=EMPTY_EDGES)
    )


def test_pyarrow_tables_and_extra_columns_are_accepted():
    nodes = pa.table({**NODES, "area_px": [10, 20, 30]})
    edges = pa.table({**EDGES, "distance_m": [0.1] * 5})
    np.testing.assert_array_equal(_draw(nodes=nodes, edges=edges), _draw())


def test_ids_are_written_beside_the_discs():
    plain, labelled = _draw(), _draw(label_ids=True)
    changed = np.any(plain != labelled, axis=-1)
    assert changed.any()
    rows, cols = np.nonzero(changed)
    # to the upper right of the discs, not over their centres
    for x, y in zip(NODES["centroid_x"], NODES["centroid_y"], strict=True):
        assert not changed[int(y), int(x)]
    assert cols.min() > min(NODES["centroid_x"])


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"image": np.zeros((4, 5, 3))}, ValueError, r"2-D \(M, N\) gray image"),
        ({"nodes": [(1, 2.0, 3.0, "sample")]}, TypeError, "nodes must be a mapping"),
        ({"edges": "adjacent"}, TypeError, "edges must be a mapping"),
        (
            {"nodes": {k: v for k, v in NODES.items() if k != "centroid_y"}},
            ValueError,
            r"nodes lacks the column\(s\) \['centroid_y'\]",
        ),
        (
            {"edges": {k: v for k, v in EDGES.items() if k != "relation"}},
            ValueError,
            r"edges lacks the column\(s\) \['relation'\]",
        ),
        ({"nodes": {**NODES, "centroid_x": [1.0, 2.0]}}, ValueError, "of one length"),
        ({"nodes": {**NODES, "object_id": [1, 1, 2]}}, ValueError, "must be unique"),
        ({"nodes": {**NODES, "object_id": [1, None, 2]}}, ValueError, "integer object ids"),
        ({"edges": {**EDGES, "subject_id": [1.5, 2, 3, 1, 3]}}, ValueError, "integer object"),
        ({"nodes": {**NODES, "centroid_x": ["a", "b", "c"]}}, ValueError, "must be numbers"),
        ({"dim": 1.5}, ValueError, r"dim must be a number in \[0, 1\]"),
        ({"radius_px": 0}, ValueError, "radius_px must be an int >= 1"),
        ({"radius_px": 2.5}, ValueError, "radius_px must be an int >= 1"),
    ],
)
def test_bad_inputs_say_what_was_expected(kwargs, error, match):
    args = {"image": _gray(), "nodes": NODES, "edges": EDGES, **kwargs}
    image, nodes, edges = args.pop("image"), args.pop("nodes"), args.pop("edges")
    with pytest.raises(error, match=match):
        scene_graph_image(image, nodes, edges, **args)


def test_relation_counts_and_caption():
    counts = relation_counts(EDGES["relation"])
    assert list(counts)[: len(RELATIONS)] == list(RELATIONS)
    for name in RELATIONS:
        assert counts[name] == EDGES["relation"].count(name)
    caption = scene_graph_caption(counts)
    for name in RELATIONS:
        assert f"{name} {counts[name]}" in caption
    assert "adjacent 2 (1 pair)" in caption  # stored both ways, drawn once
    assert "adjacent 4 (2 pairs)" in scene_graph_caption({**counts, "adjacent": 4})
    hidden = [r for r in RELATIONS if r not in GRAPH_DRAWN]
    assert f"Not drawn: {', '.join(hidden)}." in caption
    assert "line = adjacent" in caption and "arrow = occludes" in caption
    assert "magenta" not in caption and "magenta" in scene_graph_caption(counts, unclassified=True)
    none = scene_graph_caption(relation_counts([]))
    assert "no relations" in none and "Edge rows" not in none
