"""The cause attribution and the visible-surface size of benchmarks/bench_class_causes.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_modules import load_benchmark

from pipeline.camera import Camera
from stages._ground import GroundFrame

bench = load_benchmark("bench_class_causes.py")


def _ok(*right: str) -> dict[str, bool]:
    return {name: name in right for name in bench.COMBOS}


def test_a_rock_the_pipeline_classes_right_has_no_cause():
    assert bench.attribute(_ok("pipeline", "both")) == "right"


def test_the_cause_is_the_perfect_input_that_fixes_the_class():
    assert bench.attribute(_ok("masks", "both", "surface")) == "mask"
    assert bench.attribute(_ok("depth", "both")) == "depth"
    assert bench.attribute(_ok("depth", "heights")) == "depth (heights)"
    assert bench.attribute(_ok("masks", "depth")) == "mask or depth"
    assert bench.attribute(_ok("both", "surface")) == "mask+depth"


def test_wrong_on_perfect_inputs_is_the_stage_or_the_visible_surface():
    assert bench.attribute(_ok("surface")) == "describe"
    assert bench.attribute(_ok()) == "visible surface"
    assert bench.attribute(_ok(), border=True) == "border-cut: visible surface"


def test_one_image_row_at_one_depth_is_as_wide_as_its_pixels():
    camera = Camera(focal_px=430.0, baseline_m=0.1, height_m=1.2, pitch_deg=40.0)
    ground = GroundFrame.from_camera(camera)
    cols = np.arange(200, 230)
    rows = np.full(cols.shape, 260)
    disparity = np.full(cols.shape, 25.0)  # Z = 430 * 0.1 / 25 = 1.72 m
    largest = bench.visible_surface_largest(
        rows, cols, disparity, camera=camera, ground=ground, shape=(500, 500)
    )
    z = camera.k_m_px / 25.0
    assert largest == pytest.approx(cols.size * z / camera.focal_px, rel=1e-6)
    disparity[1:] = np.nan  # one valid pixel: nothing to measure
    assert math.isnan(
        bench.visible_surface_largest(
            rows, cols, disparity, camera=camera, ground=ground, shape=(500, 500)
        )
    )
