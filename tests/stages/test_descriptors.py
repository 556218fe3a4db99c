"""Tests of the per-object measurement functions (hand-made arrays, known answers)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.camera import Camera
from stages._descriptors import (
    DESCRIPTOR_COLUMNS,
    GroundFrame,
    background_jump_fraction,
    classify_size,
    cooccurrence_contrast,
    describe_objects,
    frame_ground,
    polarity_against,
    second_moment_ellipse,
    size_class_borderline,
    top_height,
)

CAMERA = Camera(focal_px=200.0, baseline_m=0.2, height_m=1.2, pitch_deg=30.0)


def _random_points(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-2, -1, 0.5], [2, 1, 6], size=(50, 3))


def test_ground_frame_from_camera_matches_camera_to_ground():
    points = _random_points()
    frame = GroundFrame.from_camera(CAMERA)
    np.testing.assert_allclose(frame.to_ground(points), CAMERA.camera_to_ground(points), atol=1e-12)
    assert frame.source == "camera"


def test_ground_frame_from_plane_matches_camera_pose():
    theta = math.radians(CAMERA.pitch_deg)
    up = np.array([0.0, -math.cos(theta), -math.sin(theta)])
    plane = np.r_[up * 3.0, CAMERA.height_m * 3.0]  # unnormalised coefficients are fine
    frame = GroundFrame.from_plane(plane)
    points = _random_points(1)
    np.testing.assert_allclose(frame.to_ground(points), CAMERA.camera_to_ground(points), atol=1e-12)
    assert frame.source == "plane"


def test_ground_frame_from_plane_looking_straight_down():
    frame = GroundFrame.from_plane([0.0, 0.0, -1.0, 2.0])
    # the camera is 2 m up; a point 2 m along the axis lies on the ground below it
    np.testing.assert_allclose(frame.to_ground(np.array([0.0, 0.0, 2.0])), [0, 0, 0], atol=1e-12)


@pytest.mark.parametrize(
    "plane, message",
    [
        ([0, -1, 0, -1.0], "camera above"),
        ([0, 0, 0, 1.0], "must not be zero"),
        ([0, -1, 0, np.nan], "4 finite"),
        ([0, -1, 0], "4 finite"),
    ],
)
def test_ground_frame_from_plane_rejects_bad_planes(plane, message):
    with pytest.raises(ValueError, match=message):
        GroundFrame.from_plane(plane)


def test_ground_frame_from_camera_needs_pose():
    with pytest.raises(ValueError, match="height_m and pitch_deg"):
        GroundFrame.from_camera(Camera(focal_px=100.0, baseline_m=0.1))


def test_frame_ground_prefers_pose_then_plane():
    no_pose = Camera(focal_px=100.0, baseline_m=0.1)
    assert frame_ground(CAMERA, [0, -1, 0, 5.0]).source == "camera"
    assert frame_ground(no_pose, [0, -1, 0, 5.0]).source == "plane"
    assert frame_ground(no_pose, [np.nan] * 4) is None
    assert frame_ground(no_pose, None) is None


def test_ellipse_of_a_disk_has_its_diameter():
    yy, xx = np.mgrid[-15:16, -15:16]
    rows, cols = np.nonzero(xx**2 + yy**2 <= 10.5**2)
    major, minor, _ = second_moment_ellipse(rows, cols)
    assert major == pytest.approx(21.0, abs=0.3)
    assert minor == pytest.approx(21.0, abs=0.3)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30))
def test_ellipse_of_a_rectangle(width, height):
    rows, cols = np.nonzero(np.ones((height, width), dtype=bool))
    major, minor, angle = second_moment_ellipse(rows, cols)
    assert major == pytest.approx(4 * math.sqrt(max(width, height) ** 2 / 12))
    assert minor == pytest.approx(4 * math.sqrt(min(width, height) ** 2 / 12))
    if width > height:
        assert angle == pytest.approx(0.0, abs=1e-9)
    elif height > width:
        assert angle == pytest.approx(90.0)


def test_ellipse_angle_is_clockwise_from_x():
    diagonal = np.arange(20)
    _, minor, angle = second_moment_ellipse(diagonal, diagonal)  # going right and down
    assert angle == pytest.approx(45.0)
    _, _, angle = second_moment_ellipse(diagonal, -diagonal)  # going left and down
    assert angle == pytest.approx(-45.0)


def test_ellipse_rejects_empty():
    with pytest.raises(ValueError, match="non-empty"):
        second_moment_ellipse(np.array([]), np.array([]))


def test_cooccurrence_contrast():
    mask = np.ones((6, 6), dtype=bool)
    checker = (np.indices((6, 6)).sum(axis=0) % 2) * 10
    assert cooccurrence_contrast(checker, mask) == pytest.approx(100.0)
    stripes = (np.arange(6)[:, None] % 2) * 10 * np.ones((1, 6))
    assert cooccurrence_contrast(stripes, mask) == pytest.approx(50.0)
    assert cooccurrence_contrast(np.full((6, 6), 7), mask) == 0.0
    single = np.zeros((6, 6), dtype=bool)
    single[2, 2] = True
    assert math.isnan(cooccurrence_contrast(checker, single))
    # pixels outside the mask never enter a pair
    half = np.zeros((6, 6), dtype=bool)
    half[:, :3] = True
    wild = np.where(half, 5, np.arange(36).reshape(6, 6) * 7)
    assert cooccurrence_contrast(wild, half) == 0.0


def test_polarity_against():
    assert polarity_against(50.0, np.array([100, 120, 90])) == "darker"
    assert polarity_against(150.0, np.array([100, 120, 90])) == "lighter"
    assert polarity_against(200.0, np.array([])) == "lighter"


def test_top_height_uses_the_topmost_valid_pixels():
    rows = np.array([5, 5, 5, 6, 6, 6, 7, 7, 7, 8, 8, 8])
    heights = np.array([np.nan, 0.30, 0.32, 0.28, 0.27, 0.26, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1])
    value, row = top_height(rows, heights, min_pixels=3)
    assert value == pytest.approx(0.30)  # median of 0.30, 0.32, 0.28
    assert row in (5, 6)
    value, _ = top_height(rows, heights, top_fraction=1.0)
    assert value == pytest.approx(np.nanmedian(heights))
    assert top_height(rows, np.full(rows.shape, np.nan)) == (
        pytest.approx(math.nan, nan_ok=True),
        -1,
    )


@pytest.mark.parametrize(
    "largest, height, expected",
    [
        (0.05, 0.04, "sample"),
        (0.10, 0.09, "sample"),
        (0.11, 0.05, "obstacle"),
        (0.08, 0.10, "sample"),
        (0.08, 0.11, "obstacle"),
        (math.nan, 0.02, "obstacle"),
        (0.05, math.nan, "obstacle"),
    ],
)
def test_classify_size(largest, height, expected):
    got = classify_size(largest, height, sample_max_m=0.10, rover_clearance_m=0.10)
    assert got == expected


def _borderline(largest, height, fraction=0.25, limit=0.5):
    # limits and fractions that are powers of two: the band's edges are exact floats
    return size_class_borderline(
        largest,
        height,
        sample_max_m=limit,
        rover_clearance_m=limit,
        borderline_fraction=fraction,
    )


@pytest.mark.parametrize(
    "largest, height, expected",
    [
        (0.25, 0.25, False),  # well inside both limits: a sure sample
        (0.375, 0.25, True),  # width at the band's lower edge (0.5 - 0.125)
        (0.374, 0.25, False),  # just inside it
        (0.5, 0.25, True),  # width at its limit
        (0.625, 0.25, True),  # width at the band's upper edge (0.5 + 0.125)
        (0.626, 0.25, False),  # beyond: a sure obstacle
        (0.25, 0.375, True),  # height at the band's lower edge
        (0.25, 0.625, True),  # height at the upper edge
        (0.25, 0.7, False),  # height beyond it: a sure obstacle
        (0.5, 0.7, False),  # a width at its limit does not matter: too high anyway
        (0.7, 0.5, False),  # nor a height at its limit: too wide anyway
        (1.0, 1.0, False),
        (math.nan, 0.25, True),  # unknown sizes: classed obstacle by rule, not measured
        (0.25, math.nan, True),
        (math.nan, math.nan, True),
        (math.nan, 0.7, False),  # the known height alone makes it an obstacle
    ],
)
def test_size_class_borderline(largest, height, expected):
    assert _borderline(largest, height) is expected


def test_size_class_borderline_at_the_default_limits_and_fraction():
    kw = {"sample_max_m": 0.10, "rover_clearance_m": 0.10}
    assert size_class_borderline(0.095, 0.02, **kw)  # 5 mm under the width limit
    assert size_class_borderline(0.105, 0.02, **kw)  # 5 mm over it
    assert size_class_borderline(0.05, 0.098, **kw)  # 2 mm under the clearance
    assert not size_class_borderline(0.08, 0.02, **kw)  # 2 cm under: a sure sample
    assert not size_class_borderline(0.12, 0.02, **kw)  # 2 cm over: a sure obstacle
    # the same sizes, other limits: the band scales with the limit
    assert not size_class_borderline(0.095, 0.02, sample_max_m=0.2, rover_clearance_m=0.10)


def test_size_class_borderline_fraction_zero_is_never():
    for largest, height in ((0.5, 0.25), (0.25, 0.5), (math.nan, 0.25), (math.nan, math.nan)):
        assert _borderline(largest, height, fraction=0.0) is False
    assert _borderline(0.25, 0.25, fraction=1.0) is True  # the band reaches down to 0
    assert _borderline(1.0, 0.25, fraction=1.0) is True  # and up to twice the limit


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"borderline_fraction": -0.1}, ValueError, r"borderline_fraction .* \[0, 1\].*-0.1"),
        ({"borderline_fraction": 1.5}, ValueError, r"borderline_fraction .* \[0, 1\].*1.5"),
        ({"borderline_fraction": math.nan}, ValueError, "borderline_fraction"),
        ({"borderline_fraction": "0.1"}, TypeError, "borderline_fraction must be a number"),
        ({"borderline_fraction": True}, TypeError, "borderline_fraction must be a number"),
        ({"sample_max_m": -0.1}, ValueError, "sample_max_m must be a finite size >= 0"),
        ({"rover_clearance_m": math.inf}, ValueError, "rover_clearance_m must be a finite"),
        ({"rover_clearance_m": None}, TypeError, "rover_clearance_m must be a number"),
    ],
)
def test_size_class_borderline_rejects_bad_settings(kwargs, error, message):
    settings = {"sample_max_m": 0.10, "rover_clearance_m": 0.10, "borderline_fraction": 0.1}
    with pytest.raises(error, match=message):
        size_class_borderline(0.05, 0.05, **{**settings, **kwargs})


def test_background_jump_fraction():
    labels = np.zeros((10, 10), dtype=np.int32)
    labels[3:7, 3:7] = 1
    mask = labels == 1
    disparity = np.full((10, 10), 10.0)
    assert background_jump_fraction(mask, labels, disparity, jump_px=1.0) == 0.0
    disparity[:, :3] = 15.0  # something nearer just left of the object
    assert background_jump_fraction(mask, labels, disparity, jump_px=1.0) == pytest.approx(0.25)
    disparity[:, :3] = np.nan
    assert background_jump_fraction(mask, labels, disparity, jump_px=1.0) == 0.0


def test_background_jump_ignores_wraparound():
    labels = np.zeros((6, 6), dtype=np.int32)
    labels[:, :2] = 1  # touches the left edge: np.roll would wrap to the right edge
    disparity = np.full((6, 6), 5.0)
    disparity[:, -1] = 50.0
    assert background_jump_fraction(labels == 1, labels, disparity, jump_px=1.0) == 0.0


def _flat(shape, value):
    return np.full(shape, value, dtype=np.float32)


def test_describe_objects_validates_inputs():
    labels = np.zeros((8, 8), dtype=np.int32)
    ok = _flat((8, 8), 1.0)
    with pytest.raises(TypeError, match="integers"):
        describe_objects(ok, ok, ok, ok, ok, camera=CAMERA)
    with pytest.raises(ValueError, match="labels' shape"):
        describe_objects(labels, _flat((8, 9), 1.0), ok, ok, ok, camera=CAMERA)
    with pytest.raises(ValueError, match="2-D"):
        describe_objects(np.zeros(8, np.int32), ok, ok, ok, ok, camera=CAMERA)
    with pytest.raises(TypeError, match="Camera"):
        describe_objects(labels, ok, ok, ok, ok, camera={"focal_px": 1})
    with pytest.raises(ValueError, match="fringe_dark_ratio"):
        describe_objects(labels, ok, ok, ok, ok, camera=CAMERA, fringe_dark_ratio=1.0)
    with pytest.raises(ValueError, match="borderline_fraction"):  # also without objects
        describe_objects(labels, ok, ok, ok, ok, camera=CAMERA, borderline_fraction=2.0)


def test_describe_objects_empty_gives_typed_columns():
    z = _flat((8, 8), 1.0)
    cols = describe_objects(np.zeros((8, 8), np.int32), z, z, z, z, camera=CAMERA)
    assert list(cols) == list(DESCRIPTOR_COLUMNS)
    for name, kind in DESCRIPTOR_COLUMNS.items():
        assert cols[name].shape == (0,)
        assert cols[name].dtype.kind == ("U" if kind == "str" else np.dtype(kind).kind)


def test_regression_an_object_against_rectification_fill_was_read_as_seen_whole():
    # a rock cut by a rectified frame's black fill is only partly seen, like one cut by the
    # border, but was flagged as seen whole, and the fill darkened its ground ring
    labels = np.zeros((40, 40), dtype=np.int32)
    labels[10:16, 8:14] = 1  # against the fill
    labels[25:31, 25:31] = 2  # in the open
    gray = np.full((40, 40), 100, dtype=np.uint8)
    gray[labels > 0] = 60
    fill = np.zeros((40, 40), bool)
    fill[:, :8] = True  # a strip along the left border, 20 % of the frame
    nan = _flat((40, 40), np.nan)
    no_pose = Camera(focal_px=200.0, baseline_m=0.2)
    plain = describe_objects(labels, gray, nan, nan, nan, camera=no_pose)
    gray[fill] = 0
    cut = describe_objects(labels, gray, nan, nan, nan, camera=no_pose)
    np.testing.assert_array_equal(plain["touches_border"], [False, False])
    np.testing.assert_array_equal(cut["touches_border"], [True, False])
    np.testing.assert_array_equal(cut["polarity"], ["darker", "darker"])


def test_describe_objects_image_fields_and_appearance():
    labels = np.zeros((20, 20), dtype=np.int32)
    labels[4:8, 2:12] = 1  # 4 x 10 bar, dark
    labels[12:20, 15:18] = 2  # 8 x 3 bar on the bottom edge, light
    gray = np.full((20, 20), 100, dtype=np.uint8)
    gray[labels == 1] = 40
    gray[labels == 2] = 200
    gray[12:20:2, 15:18] = 210  # row stripes inside object 2
    nan = _flat((20, 20), np.nan)
    no_pose = Camera(focal_px=200.0, baseline_m=0.2)
    cols = describe_objects(labels, gray, nan, nan, nan, camera=no_pose)
    np.testing.assert_array_equal(cols["object_id"], [1, 2])
    np.testing.assert_array_equal(cols["area_px"], [40, 24])
    np.testing.assert_allclose(cols["centroid_x"], [6.5, 16.0])
    np.testing.assert_allclose(cols["centroid_y"], [5.5, 15.5])
    np.testing.assert_array_equal(cols["bbox_x_min"], [2, 15])
    np.testing.assert_array_equal(cols["bbox_x_max"], [11, 17])
    np.testing.assert_array_equal(cols["bbox_y_near"], [7, 19])
    np.testing.assert_array_equal(cols["bbox_y_far"], [4, 12])
    np.testing.assert_array_equal(cols["polarity"], ["darker", "lighter"])
    np.testing.assert_allclose(cols["mean_gray"], [40.0, 205.0])
    np.testing.assert_allclose(cols["texture_std"], [0.0, 5.0])
    # object 2: 8 rows x 3 cols; 16 horizontal pairs differ by 0, 21 vertical pairs by 10
    np.testing.assert_allclose(cols["texture_contrast"], [0.0, 100.0 * 21 / (16 + 21)])
    np.testing.assert_allclose(
        cols["ellipse_major_px"], [4 * math.sqrt(100 / 12), 4 * math.sqrt(64 / 12)]
    )
    np.testing.assert_allclose(cols["ellipse_angle_deg"], [0.0, 90.0], atol=1e-9)
    np.testing.assert_array_equal(cols["touches_border"], [False, True])
    # no depth and no ground frame: NaN metric fields, unreliable depth, conservative class
    assert np.isnan(cols["range_m"]).all() and np.isnan(cols["width_m"]).all()
    np.testing.assert_array_equal(cols["depth_valid_fraction"], [0.0, 0.0])
    np.testing.assert_array_equal(cols["depth_unreliable"], [True, True])
    np.testing.assert_array_equal(cols["size_class"], ["obstacle", "obstacle"])
    # ... an obstacle by rule, not by measurement: borderline
    np.testing.assert_array_equal(cols["size_class_borderline"], [True, True])
    off = describe_objects(labels, gray, nan, nan, nan, camera=no_pose, borderline_fraction=0)
    np.testing.assert_array_equal(off["size_class_borderline"], [False, False])
