"""Tests of the quicklook PNGs (OpenCV drawing)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipeline.camera import Camera
from pipeline.stage import FrameContext
from stages import quicklook
from stages.quicklook import (
    STAGE,
    _crossings,
    _diff_panel,
    draws_frame,
    encode_png,
    objects_image,
    range_contours_image,
    residual_image,
    residual_labels,
)

SHAPE = (72, 96)


def _gray(value=120):
    return np.full(SHAPE, value, dtype=np.uint8)


def _labels():
    labels = np.zeros(SHAPE, dtype=np.int32)
    labels[10:30, 10:40] = 1
    labels[40:60, 50:80] = 2
    return labels


def _is_gray(image):
    return (image[..., 0] == image[..., 1]) & (image[..., 1] == image[..., 2])


def test_objects_image_outlines_each_object():
    labels = _labels()
    out = objects_image(_gray(), labels)
    assert out.shape == (*SHAPE, 3) and out.dtype == np.uint8
    for k in (1, 2):
        mask = labels == k
        boundary = mask & ~cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert (~_is_gray(out))[boundary].mean() > 0.6  # outline drawn (ids overlay a few)
    far = ~cv2.dilate((labels > 0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert (out[far] == 120).all()  # background untouched


def test_objects_image_without_objects_is_the_gray_image():
    out = objects_image(_gray(77), np.zeros(SHAPE, dtype=np.int32))
    assert (out == 77).all()


def test_range_contours_follow_levels():
    rows = np.arange(SHAPE[0], dtype=np.float32)[:, None]
    rng = np.broadcast_to(3.0 - 2.0 * rows / (SHAPE[0] - 1), SHAPE).astype(np.float32)
    out = range_contours_image(_gray(), rng, step_m=0.25)
    assert out.shape == (*SHAPE, 3)
    colored_rows = np.flatnonzero((~_is_gray(out))[:, -3:].any(axis=1))  # right edge: no text
    crossings = [2.75, 2.5, 2.25, 2.0, 1.75, 1.5, 1.25]
    expected = [(3.0 - level) / 2.0 * (SHAPE[0] - 1) for level in crossings]
    for row in expected:
        assert np.min(np.abs(colored_rows - row)) <= 1.0
    assert colored_rows.size <= 2 * len(crossings)


def test_range_contours_with_no_valid_range_is_the_image():
    out = range_contours_image(_gray(50), np.full(SHAPE, np.nan, dtype=np.float32))
    assert (out == 50).all()
    flat = range_contours_image(_gray(50), np.full(SHAPE, 1.1, dtype=np.float32))
    assert (flat == 50).all()


def test_range_contours_limit_the_number_of_levels():
    rows = np.arange(SHAPE[0], dtype=np.float32)[:, None]
    rng = np.broadcast_to(1.0 + rows, SHAPE).astype(np.float32)  # 72 m span
    out = range_contours_image(_gray(), rng, step_m=0.01)
    colored_rows = np.flatnonzero((~_is_gray(out))[:, -3:].any(axis=1))
    assert 0 < colored_rows.size <= 2 * 30


def test_range_contours_label_a_strip_lower_than_the_text():
    # the label's row bounds cross (text taller than the image): it sits on the last row,
    # as np.clip put it, instead of failing
    shape = (6, 200)
    cols = np.arange(shape[1], dtype=np.float32)[None, :]
    rng = np.broadcast_to(1.0 + cols / 40.0, shape).astype(np.float32)
    out = range_contours_image(np.full(shape, 120, np.uint8), rng, step_m=1.0)
    assert out.shape == (*shape, 3)
    assert (~_is_gray(out)).any()


def test_contour_line_pixels_equal_the_whole_grid_numpy_rule():
    # the compiled pass replaced a dozen numpy passes: the same pixels, order and levels
    rng = np.random.default_rng(5)
    smooth = np.cumsum(rng.normal(0.0, 0.05, (60, 80)), axis=1).astype(np.float32) + 2.0
    smooth[10:20, 30:40] = np.nan
    smooth[50:, :10] = -1.0  # negative levels draw no line
    step = np.float32(0.25)
    ok = np.isfinite(smooth)
    level = np.full(smooth.shape, -1, np.int32)
    level[ok] = np.floor(smooth[ok] / step).astype(np.int32)
    cross = np.zeros(level.shape, np.int32)
    for a, b in (
        ((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
        ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
    ):
        la, lb = level[a], level[b]
        change = (la >= 0) & (lb >= 0) & (la != lb)
        np.maximum(cross[a], np.where(change, np.maximum(la, lb), 0), out=cross[a])
    rows, cols = np.nonzero(cross)
    got = [np.empty(smooth.size, np.int64) for _ in range(3)]
    n = _crossings(smooth, step, *got)
    assert n == rows.size > 100
    np.testing.assert_array_equal(got[0][:n], rows)
    np.testing.assert_array_equal(got[1][:n], cols)
    np.testing.assert_array_equal(got[2][:n], cross[rows, cols])


def test_range_contours_validate():
    with pytest.raises(ValueError, match="step_m"):
        range_contours_image(_gray(), np.ones(SHAPE, np.float32), step_m=0.0)
    with pytest.raises(ValueError, match="shape"):
        range_contours_image(_gray(), np.ones((5, 5), np.float32))


def test_residual_image_panels():
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, SHAPE, dtype=np.uint8)
    residual = np.zeros(SHAPE, dtype=np.float32)
    residual[:, :5] = np.nan
    out = residual_image(left, left, residual)
    width = SHAPE[1]
    assert out.shape == (SHAPE[0], 2 * width + 4, 3)
    body = slice(20, None)  # below the panel titles
    assert (out[body, : width - 1] == 128).all()  # left - right = 0 everywhere
    right_panel = out[body, width + 4 :]
    assert (right_panel[:, 5:] == 128).all()
    assert (right_panel[:, :5] == (90, 20, 0)).all()  # undefined residual is marked


def test_residual_image_scales_differences():
    left = np.full(SHAPE, 100, dtype=np.uint8)
    right = left.copy()
    right[40:, :] = 110  # left - right = -10 there
    out = residual_image(left, right, np.full(SHAPE, 10.0, dtype=np.float32))
    assert out[60, 40, 0] == 1  # 128 - 127/10 * 10, clipped scale at the 99th percentile
    assert out[60, SHAPE[1] + 4 + 40, 0] == 255


def test_residual_panel_pass_equals_the_numpy_float32_rule():
    # the compiled panel replaced numpy's float32 passes: the same truncated gray levels,
    # clipped at both ends, undefined (NaN, inf) pixels dark blue
    rng = np.random.default_rng(2)
    diff = rng.normal(0.0, 40.0, SHAPE).astype(np.float32)
    diff[0, :4] = [np.nan, np.inf, -np.inf, 1e30]
    scale = 127.0 / 37.3
    out = np.zeros((*SHAPE, 3), np.uint8)
    _diff_panel(diff, np.float32(scale), np.array((90, 20, 0), np.uint8), out)
    finite = np.isfinite(diff)
    level = np.multiply(np.where(finite, diff, np.float32(0.0)), scale)
    level = np.clip(level + 128.0, 0, 255).astype(np.uint8)
    expected = np.repeat(level[..., None], 3, axis=2)
    expected[~finite] = (90, 20, 0)
    np.testing.assert_array_equal(out, expected)
    assert out[0, 3, 0] == 255 and out[0, 1, 0] == 90


def test_encode_png_round_trip():
    image = objects_image(_gray(), _labels())
    decoded = cv2.imdecode(np.frombuffer(encode_png(image), np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(decoded, image)


def _inputs():
    rows = np.arange(SHAPE[0], dtype=np.float32)[:, None]
    return {
        "left": _gray(),
        "right": _gray(110),
        "labels": _labels(),
        "range": np.broadcast_to(3.0 - rows / SHAPE[0], SHAPE).astype(np.float32),
        "residual": np.zeros(SHAPE, dtype=np.float32),
    }


def test_stage_writes_three_decodable_pngs():
    assert STAGE.name == "quicklook"
    assert STAGE.inputs == ("left", "right", "labels", "range", "residual")
    assert [(p.name, p.kind) for p in STAGE.outputs] == [("quicklooks", "files")]
    frame = FrameContext(
        frame_id="f007", archive="t", camera=Camera(focal_px=100.0, baseline_m=0.1)
    )
    result = STAGE.run(_inputs(), frame=frame, params=STAGE.defaults())
    expected_shapes = {
        "quicklooks/f007/objects.png": (*SHAPE, 3),
        "quicklooks/f007/range_contours.png": (*SHAPE, 3),
        "quicklooks/f007/residual.png": (SHAPE[0], 2 * SHAPE[1] + 4, 3),
    }
    assert set(result.files) == set(expected_shapes)
    for path, content in result.files.items():
        image = cv2.imdecode(np.frombuffer(content, np.uint8), cv2.IMREAD_UNCHANGED)
        assert image is not None and image.shape == expected_shapes[path]


def test_regression_residual_quicklook_said_left_minus_pseudo_left_for_reference_left(
    monkeypatch,
):
    """Bug (user audit): with the camera's reference "left" the depth residual is right
    minus pseudo-right, but the quicklook's panel was titled "left - pseudo-left" (and its
    first panel was left - right, the opposite sign). Titles and sign follow the reference."""
    assert residual_labels("right") == ("left - right", "left - pseudo-left")
    assert residual_labels("left") == ("right - left", "right - pseudo-right")
    with pytest.raises(ValueError, match="'right' or 'left'"):
        residual_labels("centre")
    left = _gray(100)
    right = left.copy()
    right[40:, :] = 110
    residual = np.zeros(SHAPE, np.float32)
    inputs = {**_inputs(), "left": left, "right": right, "residual": residual}
    camera = Camera(focal_px=100.0, baseline_m=0.1, reference="left")
    frame = FrameContext(frame_id="f007", archive="t", camera=camera)
    files = STAGE.run(inputs, frame=frame, params=STAGE.defaults()).files
    image = cv2.imdecode(
        np.frombuffer(files["quicklooks/f007/residual.png"], np.uint8), cv2.IMREAD_UNCHANGED
    )
    np.testing.assert_array_equal(image, residual_image(left, right, residual, reference="left"))
    assert image[60, 40, 0] == 255  # right - left = +10: light, where left - right is dark
    assert residual_image(left, right, residual)[60, 40, 0] == 1
    drawn = []
    monkeypatch.setattr(quicklook, "_text", lambda image, text, *a: drawn.append(text))
    residual_image(left, right, residual, reference="left")
    assert drawn == ["right - left", "right - pseudo-right"]


def test_stage_disabled_writes_nothing():
    frame = FrameContext(frame_id="f0", archive="t", camera=Camera(focal_px=100.0, baseline_m=0.1))
    params = STAGE.resolve_params({"enabled": False})
    assert STAGE.run(_inputs(), frame=frame, params=params).files == {}


def test_png_encoding_is_lossless_and_smaller_than_opencv_default():
    rng = np.random.default_rng(3)
    gray = cv2.GaussianBlur(rng.integers(0, 256, SHAPE, dtype=np.uint8), (5, 5), 1.5)
    image = objects_image(gray, _labels())
    content = encode_png(image)
    decoded = cv2.imdecode(np.frombuffer(content, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(decoded, image)
    assert len(content) < len(cv2.imencode(".png", image)[1])


def test_every_n_draws_about_one_frame_in_n_chosen_by_frame_id():
    camera = Camera(focal_px=100.0, baseline_m=0.1)
    params = STAGE.resolve_params({"every": 4})
    ids = [f"mojave-{k:05d}" for k in range(400)]
    drawn = [fid for fid in ids if draws_frame(fid, every=4)]
    assert 60 <= len(drawn) <= 140  # about a quarter
    assert all(draws_frame(fid, every=1) for fid in ids)
    for fid in (drawn[0], next(f for f in ids if f not in drawn)):
        frame = FrameContext(frame_id=fid, archive="t", camera=camera)
        result = STAGE.run(_inputs(), frame=frame, params=params)
        assert (len(result.files) == 3) == (fid in drawn)
        assert bool(result.notes) == (fid not in drawn)
    with pytest.raises(ValueError, match="integer >= 1"):
        draws_frame("f0", every=0)


def test_regression_a_few_far_outliers_widened_the_contour_step_to_metres():
    # a 1024x768 frame without a pose: 0.06 % of the pixels wrongly matched near 0 px read
    # 170 m, the step grew to 5.25 m, and no contour crossed the 1.4-3.8 m ground
    rows = np.arange(SHAPE[0], dtype=np.float32)[:, None]
    rng = np.broadcast_to(3.0 - 2.0 * rows / (SHAPE[0] - 1), SHAPE).astype(np.float32).copy()
    clean = range_contours_image(_gray(), rng, step_m=0.25)
    rng[-2:, :2] = 170.0  # a 2x2 speck of wrong matches, in a corner
    out = range_contours_image(_gray(), rng, step_m=0.25)
    colored_rows = np.flatnonzero((~_is_gray(out))[:, -3:].any(axis=1))
    for level in (2.75, 2.5, 2.25, 2.0, 1.75, 1.5, 1.25):
        assert np.min(np.abs(colored_rows - (3.0 - level) / 2.0 * (SHAPE[0] - 1))) <= 1.0
    np.testing.assert_array_equal(out[:, -3:], clean[:, -3:])
