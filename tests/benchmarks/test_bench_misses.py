"""The miss classes of benchmarks/bench_misses.py on hand-made label arrays."""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark

bench_misses = load_benchmark("bench_misses.py")


def _scene():
    """Five 10x10 truth rocks on a 60x80 frame and a prediction that meets each differently."""
    true = np.zeros((60, 80), np.int32)
    pred = np.zeros_like(true)
    for k, x in enumerate((2, 16, 30, 44, 58), start=1):
        true[10:20, x : x + 10] = k
    pred[10:20, 2:12] = 1  # rock 1 matched exactly
    # rock 2 untouched
    pred[10:20, 30:52] = 3  # rocks 3 and 4 share one object (IoU 100 / 220 and 80 / 240)
    true[10:20, 40:44] = 0  # ... with ground between them
    pred[10:13, 58:68] = 5  # rock 5: a speck of 30 px
    image = np.full(true.shape, 100, np.uint8)
    image[true > 0] = 60
    image[::2] += 4  # a ground spread of a few levels
    rng = np.full(true.shape, 2.5, np.float32)
    return pred, true, image, rng


def test_each_missed_rock_gets_the_class_of_the_object_that_covers_most_of_it():
    rows = bench_misses.classify_misses(*_scene())
    kinds = [row["class"] for row in rows]
    assert kinds == ["matched", "untouched", "shared", "shared", "partial"]
    assert [row["pieces"] for row in rows] == [1, 0, 1, 1, 1]
    assert all(row["contrast"] < -5 for row in rows)  # dark rocks, several spreads below
    assert [row["rock"] for row in rows] == [1, 2, 3, 4, 5]
    assert rows[0]["px"] == 100 and rows[0]["range_m"] == pytest.approx(2.5)


def test_an_object_with_as_much_ground_again_is_fat():
    pred, true, image, rng = _scene()
    pred[:] = 0
    pred[8:22, 14:30] = 2  # rock 2 (100 px) inside a 224 px object
    rows = bench_misses.classify_misses(pred, true, image, rng)
    assert rows[1]["class"] == "fat"
    assert np.count_nonzero([row["class"] == "untouched" for row in rows]) == 4


def test_a_ceiling_paints_the_missed_rocks_in_as_new_objects():
    pred, true, _, _ = _scene()
    painted = bench_misses._painted(pred, true, [2, 5])
    assert np.array_equal(painted[true == 2], np.full(100, 6))
    assert np.array_equal(painted[true == 5], np.full(100, 7))
    assert np.array_equal(painted[true == 1], pred[true == 1])


def test_false_objects_are_sorted_by_the_rock_under_them():
    pred, true, image, _ = _scene()
    pred[40:50, 2:12] = 6  # on bare ground
    pred[10:20, 12:14] = 7  # a sliver beside matched rock 1, all on ground
    pred[18:20, 2:12] = 8  # a second piece of matched rock 1
    rows = bench_misses.classify_false_objects(pred, true, image)
    kinds = {row["object"]: row["class"] for row in rows}
    assert kinds == {3: "on_missed", 5: "on_missed", 6: "ground", 7: "ground", 8: "extra"}
    assert {row["object"]: row["px"] for row in rows}[6] == 100
    erased = bench_misses._erased(pred, [6, 7])
    assert not np.isin(erased, [6, 7]).any() and np.array_equal(erased == 3, pred == 3)
