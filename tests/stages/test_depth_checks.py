"""Checks of a frame's depth against the catalog's camera (stages._depth_checks)."""

from __future__ import annotations

import re

import numpy as np
from scipy import ndimage

from pipeline.camera import Camera
from stages._depth_checks import (
    limit_note,
    offset_note,
    pose_notes,
    poseless_note,
    swapped_note,
)
from stages.depth import STAGE

POSE = Camera(focal_px=400.0, baseline_m=0.1, height_m=1.2, pitch_deg=38.0)
BARE = Camera(focal_px=400.0, baseline_m=0.1)


def _pair(shape=(128, 160), disparity=6.0):
    """A textured frontal pair of constant disparity: (left, right)."""
    h, w = shape
    world = ndimage.gaussian_filter(np.random.default_rng(1).normal(128, 45, (h, w + 40)), 1)
    world = np.clip(np.round(world), 0, 255).astype(np.uint8)
    d = int(disparity)
    return world[:, :w].copy(), world[:, d : d + w].copy()


def test_swapped_note_only_for_a_pair_that_matches_the_other_way_round():
    left, right = _pair()
    assert swapped_note(left, right, 32) == []
    (note,) = swapped_note(right, left, 32)
    assert "left and right look exchanged" in note and "swap" in note
    assert swapped_note(left[:40, :60], right[:40, :60], 32) == []  # too small to tell


def test_pose_notes_thresholds_follow_the_search_band_margins():
    assert pose_notes(BARE, "ransac", 1.0, 30.0) == []  # nothing to compare with
    assert pose_notes(POSE, "pose", 1.2 * 1.2, 38.0 + 4.0) == []  # inside the margins
    (note,) = pose_notes(POSE, "pose", 1.2 * 1.3, 38.0)
    assert "the pose bounded the search" in note and "millimetres" not in note
    (note,) = pose_notes(POSE, "pose", 1.2, 44.0)
    assert "44.0 deg" in note
    (note,) = pose_notes(POSE, "ransac", 1200.0, 38.0)
    assert "pose was rejected" in note and "baseline_m in millimetres" in note
    assert pose_notes(POSE, "pose", float("nan"), 38.0) == []


def test_poseless_note_says_the_limit_only_when_it_is_the_default():
    params = STAGE.defaults()
    flat = np.full((10, 10), 20.0, np.float32)
    note = poseless_note(BARE, flat, 64, params)
    assert "ground plane fitted from the disparity" in note and "up to 64 px" in note
    assert f"{40.0 / 64:.2f} m" in note and "cut off" not in note
    piled = flat.copy()
    piled[:2] = 63.5
    assert "20.0% of the matches lie within 1 px" in poseless_note(BARE, piled, 64, params)
    explicit = {**params, "max_disparity": 90}
    assert "64" not in poseless_note(BARE, piled, 90, explicit)
    nearest = {**params, "nearest_range_m": 0.5}
    assert "px" not in poseless_note(BARE, piled, 80, nearest)


def test_regression_height_without_pitch_was_ignored_without_a_word():
    # a user who knew the mast height but not the tilt gave height_m alone: it is not used
    # (a pose needs both) and the note only said 'no camera pose'
    height_only = Camera(focal_px=400.0, baseline_m=0.1, height_m=1.5)
    note = poseless_note(height_only, np.full((4, 4), 9.0, np.float32), 64, STAGE.defaults())
    assert "(height_m = 1.5 alone is not used: a pose needs both)" in note
    pitch_only = Camera(focal_px=400.0, baseline_m=0.1, pitch_deg=30.0)
    note = poseless_note(pitch_only, np.full((4, 4), 9.0, np.float32), 64, STAGE.defaults())
    assert "pitch_deg = 30 alone is not used" in note


def test_offset_note_finds_the_rows_the_right_image_is_moved_by():
    left, right = _pair()
    assert offset_note(left, right, 32) == []
    for rows, where in ((6, "lower"), (-8, "higher")):
        (note,) = offset_note(left, np.roll(right, rows, axis=0), 32)
        found = re.search(r"right image about (\d+) rows (\w+) than the left", note)
        assert found and found.group(2) == where, note
        assert abs(int(found.group(1)) - abs(rows)) <= 2  # steps of 2 rows at half size


def test_limit_note_names_where_the_limit_came_from():
    params = STAGE.defaults()
    flat = np.full((10, 10), 20.0, np.float32)
    assert limit_note(flat, 64, params) == []
    piled = flat.copy()
    piled[:2] = 63.5
    (note,) = limit_note(piled, 64, {**params, "max_disparity": 64})
    assert note.startswith("matches pile up at the search limit: 20.0% within 1 px of 64 px")
    assert "(depth.max_disparity)" in note and "raise depth.max_disparity" in note
    (note,) = limit_note(piled, 64, {**params, "nearest_range_m": 0.6})
    assert "lower depth.nearest_range_m" in note
    (note,) = limit_note(piled, 64, params)
    assert "from the camera pose" in note


def test_share_at_limit_is_a_python_float():
    # it returned np.float64 under its float annotation (as _heights._fraction did)
    from stages._depth_checks import _share_at_limit

    disparity = np.array([[1.0, 9.5, np.nan], [10.0, 3.0, 9.0]], np.float32)
    share = _share_at_limit(disparity, 10)
    assert type(share) is float and share == 3 / 5
    assert type(_share_at_limit(np.full((2, 2), np.nan, np.float32), 10)) is float
