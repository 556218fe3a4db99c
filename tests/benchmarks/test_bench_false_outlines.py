"""The outline parts of benchmarks/bench_false_outlines.py on hand-made label arrays."""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark

bench_false_outlines = load_benchmark("bench_false_outlines.py")


def _dark_rock_with_its_shadow():
    """A dark 10x10 truth rock (gray 30) and an object that also holds its cast shadow: a
    10x6 strip of gray 70 beside it on ground of gray 150 (dunes_s7's dunes_0001 object 1)."""
    true = np.zeros((40, 50), np.int32)
    true[10:20, 10:20] = 1
    pred = np.zeros_like(true)
    pred[10:20, 10:26] = 1
    image = np.full(true.shape, 150, np.uint8)
    image[10:20, 10:20] = 30
    image[10:20, 20:26] = 70
    return pred, true, image


def test_a_cast_shadow_is_the_off_rock_part_and_the_lighter_class():
    pred, true, image = _dark_rock_with_its_shadow()
    parts = bench_false_outlines.describe_false_object(pred, true, image, 1)
    assert parts["rock"] == 1 and parts["obj_px"] == 160 and parts["rock_px"] == 100
    assert (parts["on"], parts["off"], parts["missed"]) == (100, 60, 0)
    assert parts["iou"] == pytest.approx(100 / 160)
    assert parts["gray_on"].strip() == "30" and parts["gray_off"].strip() == "70"
    assert parts["gray_missed"].strip() == "-" and parts["ground"] == 150
    # the lighter Otsu class is the shadow: all of it off the rock
    assert parts["light_share"] == pytest.approx(60 / 160) and parts["light_on_rock"] == 0


def test_a_lit_half_misses_the_rest_of_its_rock():
    pred, true, image = _dark_rock_with_its_shadow()
    pred[:] = 0
    pred[10:20, 10:14] = 3  # 40 px of the rock only
    parts = bench_false_outlines.describe_false_object(pred, true, image, 3)
    assert (parts["on"], parts["off"], parts["missed"]) == (40, 0, 60)
    assert parts["iou"] == pytest.approx(0.4)


def test_an_object_on_bare_ground_has_no_parts():
    pred, true, image = _dark_rock_with_its_shadow()
    pred[:] = 0
    pred[30:35, 30:40] = 2
    assert bench_false_outlines.describe_false_object(pred, true, image, 2) is None
