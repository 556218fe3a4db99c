"""Scene drawing shortcuts (renderer v5) keep the random draws of the scene model."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.synth.scene import _convex_hull, _hull_edges, _inside_convex, _scale


@pytest.mark.parametrize("bounds", [(0.0, 1.0), (0, 200), (-20.0, 70.0), (0.55, 1.0), (2.5, 4.0)])
def test_batched_draws_equal_generator_uniform(bounds):
    # _make_rocks draws a rock's scalars with one Generator.random call and maps them
    # with _scale: the values must be those of the scalar Generator.uniform calls
    batched, scalar = np.random.default_rng(3), np.random.default_rng(3)
    u = batched.random(500).tolist()
    assert [_scale(bounds, v) for v in u] == [scalar.uniform(*bounds) for _ in range(500)]


def test_hull_edges_computed_once_give_the_same_inside_test():
    rng = np.random.default_rng(0)
    hull = _convex_hull(rng.uniform(-3.0, 3.0, size=(12, 2)))
    xy = rng.uniform(-4.0, 4.0, size=(400, 2))
    edges = _hull_edges(hull)
    for margin in (0.0, 0.2):
        expected = _inside_convex(hull, xy, margin)
        assert np.array_equal(_inside_convex(hull, xy, margin, edges=edges), expected)
        assert 0 < expected.sum() < len(xy)
