"""Tests of stages/_fronts.py: the growth kernel of rules R7 and R7c against its dilation
loop (the code it replaced, kept here as its numpy twin)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stages._fronts import grow_fronts, merge_fronts
from stages._regions import _object_boxes


def _dilation_loop(front: np.ndarray, weak: np.ndarray, max_steps: int):
    """Grey dilation of the ids (3x3 square) into the weak pixels, step by step."""
    front, weak = front.copy(), weak.copy()
    for _ in range(max_steps):
        reach = cv2.dilate(front, np.ones((3, 3), np.uint8))
        new = weak & (reach > 0)
        if not new.any():
            break
        weak &= ~new
        np.copyto(front, reach, where=new)
    return front, weak


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_grow_fronts_equals_the_dilation_loop_on_random_frames(dtype):
    rng = np.random.default_rng(7)
    for _ in range(60):
        rows, cols = rng.integers(1, 30, 2)
        ids = rng.integers(1, 9, (rows, cols))
        front = np.where(rng.random((rows, cols)) < 0.15 * rng.random(), ids, 0).astype(dtype)
        weak = (rng.random((rows, cols)) < rng.random()) & (front == 0)
        steps = int(rng.integers(0, 14))
        expected_front, expected_weak = _dilation_loop(front, weak, steps)
        was_weak = weak.copy()
        taken = grow_fronts(front, weak, max_steps=steps)
        np.testing.assert_array_equal(front, expected_front)
        np.testing.assert_array_equal(weak, expected_weak)
        assert taken == np.count_nonzero(was_weak & ~expected_weak)


def test_grow_fronts_lets_the_higher_id_take_a_pixel_both_reach_and_stops_after_max_steps():
    front = np.zeros((3, 9), np.uint16)
    front[1, 0], front[1, 4] = 2, 5
    weak = np.ones((3, 9), bool)
    weak[front > 0] = False
    taken = grow_fronts(front, weak, max_steps=2)
    # one step: ids 2 and 5 each take their 3x3; two steps: they meet at column 2 where
    # both arrive at once and 5 wins, column 6 is 5's second step, column 7 is not reached
    np.testing.assert_array_equal(front[1], [2, 2, 5, 5, 5, 5, 5, 0, 0])
    assert taken == np.count_nonzero(front) - 2
    assert not weak[front > 0].any() and weak[:, 7:].all()


def test_grow_fronts_rejects_mismatched_or_bad_inputs():
    front = np.zeros((4, 4), np.uint16)
    with pytest.raises(ValueError, match="one shape"):
        grow_fronts(front, np.zeros((4, 5), bool), max_steps=1)
    with pytest.raises(TypeError, match="bool"):
        grow_fronts(front, np.zeros((4, 4), np.uint8), max_steps=1)
    with pytest.raises(ValueError, match="max_steps"):
        grow_fronts(front, np.zeros((4, 4), bool), max_steps=-1)


def _merge_numpy(labels: np.ndarray, dark_front: np.ndarray, light_front: np.ndarray):
    """R7's numpy steps that merge_fronts replaced."""
    out = labels.copy()
    background = labels == 0
    for front in (dark_front, light_front):
        np.copyto(out, front, where=background & (front > 0), casting="unsafe")
    grew = np.unique(out[out != labels])
    return out, grew, _object_boxes(out, int(labels.max()))


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_merge_fronts_equals_copies_unique_and_boxes_on_random_growths(dtype):
    rng = np.random.default_rng(11)
    for _ in range(60):
        rows, cols = rng.integers(1, 30, 2)
        labels = np.where(
            rng.random((rows, cols)) < 0.2 * rng.random(), rng.integers(1, 9, (rows, cols)), 0
        ).astype(np.int32)
        dark = rng.random(9) < 0.5
        fronts = []
        weak = rng.random((rows, cols)) < rng.random()
        for side in (dark, ~dark):
            front = np.where(side[labels], labels, 0).astype(dtype)
            # the sides take disjoint pixels
            mine = weak & (rng.random((rows, cols)) < 0.5) & (labels == 0)
            weak &= ~mine
            grow_fronts(front, mine, max_steps=int(rng.integers(0, 4)))
            fronts.append(front)
        expected = _merge_numpy(labels, *fronts)
        for got, want in zip(merge_fronts(labels, *fronts), expected, strict=True):
            np.testing.assert_array_equal(got, want)
