"""The depth stage: declaration, run wrapper, reference flipping, parameter errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.stage import FrameContext
from stages.depth import STAGE, resolve_disparity_range, resolve_row_band, resolve_row_gradient
from stages.geometry import plane_disparity_coefficients, plane_from_pose

CAMERA = Camera(focal_px=120.0, baseline_m=0.1, height_m=1.2, pitch_deg=38.0)


def _ground_pair(camera: Camera = CAMERA, shape=(96, 128), seed=0):
    """A textured ground plane seen by ``camera``: (left, right, true disparity)."""
    assert camera.height_m is not None and camera.pitch_deg is not None
    plane = plane_from_pose(height_m=camera.height_m, pitch_deg=camera.pitch_deg)
    a, b, c = plane_disparity_coefficients(plane, camera=camera, shape=shape)
    ys, xs = np.indices(shape, dtype=float)
    disparity = a * xs + b * ys + c
    h, w = shape
    world = ndimage.gaussian_filter(np.random.default_rng(seed).normal(128, 45, (h, w + 40)), 1)
    # right(x) = left(x + d): sample the left texture at x + d
    right = ndimage.map_coordinates(world, [ys, xs + disparity], order=3)
    left = world[:, :w]
    as_u8 = lambda img: np.clip(np.round(img), 0, 255).astype(np.uint8)  # noqa: E731
    return as_u8(left), as_u8(right), disparity.astype(np.float32)


def _run(left, right, camera=CAMERA, **overrides):
    params = STAGE.resolve_params(overrides)
    frame = FrameContext(frame_id="f0", archive="test", camera=camera)
    return STAGE.run({"left": left, "right": right}, frame=frame, params=params)


def test_declaration():
    assert STAGE.name == "depth" and STAGE.inputs == ("left", "right")
    assert STAGE.output_names == ("disparity", "range", "residual", "height", "ground_plane")
    for product in STAGE.outputs:
        assert {"units", "long_name"} <= set(product.attrs)
    plane = STAGE.outputs[-1]
    assert plane.dims == ("frame", "coef") and plane.frame_shape((5, 7), {}) == (4,)
    assert STAGE.defaults()["method"] == "adaptive"


def test_run_returns_declared_shapes_dtypes_and_figures():
    left, right, truth = _ground_pair()
    result = _run(left, right)
    params = STAGE.defaults()
    for product in STAGE.outputs:
        array = result.arrays[product.name]
        assert array.dtype == np.dtype(product.dtype), product.name
        assert array.shape == product.frame_shape(right.shape, params), product.name
    for name in ("rms_residual", "valid_fraction", "lr_consistency", "ground_fit_inliers"):
        assert np.isfinite(result.figures[name]), name
    d = result.arrays["disparity"]
    ok = np.isfinite(d)
    assert result.figures["valid_fraction"] == pytest.approx(ok.mean())
    assert np.median(np.abs(d[ok] - truth[ok])) < 0.2
    # the ground is flat: heights near zero, fitted pose near the true one
    assert np.nanmedian(np.abs(result.arrays["height"])) < 0.02
    assert result.figures["ground_height_m"] == pytest.approx(1.2, abs=0.05)
    assert result.figures["ground_pitch_deg"] == pytest.approx(38.0, abs=1.0)
    assert result.figures["rms_residual"] < 10


def test_range_is_f_b_over_disparity():
    left, right, _ = _ground_pair()
    result = _run(left, right)
    d, z = result.arrays["disparity"], result.arrays["range"]
    ok = np.isfinite(d)
    np.testing.assert_allclose(z[ok], CAMERA.focal_px * CAMERA.baseline_m / d[ok], rtol=1e-6)
    assert np.all(np.isnan(z[~ok]))


def test_left_reference_is_the_mirrored_right_reference():
    left, right, _ = _ground_pair()
    as_left = Camera(focal_px=120.0, baseline_m=0.1, height_m=1.2, pitch_deg=38.0,
                     reference="left")  # fmt: skip
    lref = _run(left, right, camera=as_left)
    mirrored = _run(right[:, ::-1].copy(), left[:, ::-1].copy())
    np.testing.assert_array_equal(lref.arrays["disparity"], mirrored.arrays["disparity"][:, ::-1])
    np.testing.assert_array_equal(lref.arrays["residual"], mirrored.arrays["residual"][:, ::-1])


def test_left_reference_disparity_is_positive_and_in_left_geometry():
    # left(x) = right(x - 5): the left pixel at x is at x - 5 in the right image
    world = ndimage.gaussian_filter(np.random.default_rng(3).normal(128, 45, (64, 140)), 1)
    world = np.clip(world, 0, 255).astype(np.uint8)
    right, left = world[:, 5:125], world[:, 0:120]
    bare = Camera(focal_px=100.0, baseline_m=0.1, reference="left")
    result = _run(left, right, camera=bare, max_disparity=16)
    d = result.arrays["disparity"]
    assert np.nanmedian(d) == pytest.approx(5.0, abs=1e-3)
    assert np.all(np.isnan(d[:, :5]))  # the left image's first columns have no partner


def test_tiled_stage_equals_whole_frame():
    left, right, _ = _ground_pair(shape=(96, 128))
    whole = _run(left, right, tile_px=0)
    tiled = _run(left, right, tile_px=48)
    assert "tiles" in " ".join(tiled.notes)
    for name in ("disparity", "range", "residual"):
        np.testing.assert_array_equal(tiled.arrays[name], whole.arrays[name])


@pytest.mark.parametrize("method", ["sgm", "opencv-sgbm"])
def test_other_methods_run(method):
    left, right, truth = _ground_pair()
    result = _run(left, right, method=method)
    d = result.arrays["disparity"]
    ok = np.isfinite(d)
    assert ok.mean() > 0.5
    assert np.median(np.abs(d[ok] - truth[ok])) < 0.5


def test_derived_range_and_explicit_range():
    shape = (96, 128)
    lo, hi = resolve_disparity_range(CAMERA, shape, STAGE.defaults())
    assert lo == 0 and 3 <= hi < shape[1]
    params = {**STAGE.defaults(), "max_disparity": 40}
    assert resolve_disparity_range(CAMERA, shape, params) == (0, 40)
    params = {**STAGE.defaults(), "nearest_range_m": 0.5}
    assert resolve_disparity_range(CAMERA, shape, params) == (0, 24)


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        ({"method": "census"}, "must be one of"),
        ({"max_disparity": -3}, ">= 0"),
        ({"windows": 5}, "expects str"),
        ({"min_ncc": 1.5}, "<= 1"),
        ({"sgm_paths": 6}, "must be one of"),
        ({"subpixel": "cubic"}, "must be one of"),
    ],
)
def test_bad_params_are_rejected_by_the_declaration(overrides, words):
    with pytest.raises(ParamError, match=words):
        STAGE.resolve_params(overrides)


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        ({"windows": "5,8"}, "odd"),
        ({"windows": "a,b"}, "comma-separated"),
        ({"min_disparity": 10, "max_disparity": 11}, "at least 2"),
    ],
)
def test_bad_param_combinations_raise_param_error_on_run(overrides, words):
    left, right, _ = _ground_pair(shape=(32, 48))
    with pytest.raises(ParamError, match=words):
        _run(left, right, **overrides)


def test_mismatched_images_raise_value_error():
    left, right, _ = _ground_pair(shape=(32, 48))
    with pytest.raises(ValueError, match="one shape"):
        _run(left, right[:, :40])


def test_ground_refine_option_sharpens_the_ground():
    left, right, truth = _ground_pair()
    plain = _run(left, right)
    refined = _run(left, right, ground_refine=True)
    assert plain.figures["ground_refined_fraction"] == 0.0
    assert refined.figures["ground_refined_fraction"] > 0.5
    d0, d1 = plain.arrays["disparity"], refined.arrays["disparity"]
    assert np.array_equal(np.isfinite(d0), np.isfinite(d1))  # never adds or drops a match
    ok = np.isfinite(d1)
    assert np.median(np.abs(d1[ok] - truth[ok])) <= np.median(np.abs(d0[ok] - truth[ok]))


def test_row_band_only_for_the_adaptive_method_with_a_pose():
    params = STAGE.defaults()
    floor, ceiling = resolve_row_band(CAMERA, (96, 128), params)
    assert floor is not None and ceiling is not None and floor.shape == ceiling.shape == (96,)
    assert np.all(ceiling > floor)
    assert resolve_row_band(CAMERA, (96, 128), {**params, "floor_margin": 1.0})[0] is None
    assert resolve_row_band(CAMERA, (96, 128), {**params, "ceiling_ratio": 0.0})[1] is None
    assert resolve_row_band(CAMERA, (96, 128), {**params, "method": "sgm"}) == (None, None)
    bare = Camera(focal_px=120.0, baseline_m=0.1)
    assert resolve_row_band(bare, (96, 128), params) == (None, None)
    with pytest.raises(ParamError, match="ceiling_ratio"):
        resolve_row_band(CAMERA, (96, 128), {**params, "ceiling_ratio": 0.5})


def test_row_gradient_is_the_pose_grounds_for_the_adaptive_method():
    params = STAGE.defaults()
    plane = plane_from_pose(height_m=1.2, pitch_deg=38.0)
    _, beta, _ = plane_disparity_coefficients(plane, camera=CAMERA, shape=(96, 128))
    gradient = resolve_row_gradient(CAMERA, (96, 128), params)
    assert gradient > 0 and gradient == pytest.approx(beta)  # nearer, larger, down the image
    assert resolve_row_gradient(CAMERA, (96, 128), {**params, "method": "sgm"}) == 0.0
    assert resolve_row_gradient(Camera(focal_px=120.0, baseline_m=0.1), (96, 128), params) == 0


def test_default_band_keeps_the_ground_matches():
    # the band holds the ground with margins: on a ground plane the larger windows find the
    # same matches with and without it
    left, right, truth = _ground_pair()
    floored = _run(left, right).arrays["disparity"]
    whole = _run(left, right, floor_margin=1.0, ceiling_ratio=0.0).arrays["disparity"]
    valid = np.isfinite(whole)
    assert np.mean(np.isfinite(floored)) >= np.mean(valid) - 0.01
    both = valid & np.isfinite(floored)
    assert np.median(np.abs(floored[both] - truth[both])) < 0.2
    assert np.mean(floored[both] == whole[both]) > 0.98


def test_subpixel_setting_changes_only_the_fraction():
    left, right, truth = _ground_pair()
    blend = _run(left, right).arrays["disparity"]
    parabola = _run(left, right, subpixel="parabola").arrays["disparity"]
    assert STAGE.defaults()["subpixel"] == "blend"
    assert np.array_equal(np.isfinite(blend), np.isfinite(parabola))
    ok = np.isfinite(blend)
    # only the subpixel estimate differs (its accuracy: tests/stages/test_stereo.py)
    assert 0 < np.max(np.abs(blend[ok] - parabola[ok])) <= 0.5
    assert np.median(np.abs(blend[ok] - truth[ok])) < 0.1


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ({"windows": "abc"}, "comma-separated odd sizes"),
        ({"windows": "9,5"}, "increasing"),
        ({"prefilter": 4}, "prefilter must be 0 .off. or an odd int"),
        ({"sgm_window": 4}, "sgm_window must be an odd integer"),
    ],
)
def test_settings_only_the_matcher_checks_fail_at_planning(override, words):
    """Bug: `--set depth.windows=abc` (and an even prefilter or sgm_window) passed planning
    and failed every frame at the depth stage; they are now a ParamError before any work."""
    with pytest.raises(ParamError, match=words):
        STAGE.resolve_params(override)
    assert STAGE.resolve_params({})["windows"] == STAGE.defaults()["windows"]


def _ramp_pair(shape=(96, 160), near_px=80.0, far_px=40.0):
    """A textured slope whose disparity grows from ``far_px`` (top row) to ``near_px``."""
    h, w = shape
    ys, xs = np.indices(shape, dtype=float)
    disparity = far_px + (near_px - far_px) * ys / (h - 1)
    world = ndimage.gaussian_filter(np.random.default_rng(0).normal(128, 45, (h, w + 90)), 1)
    right = ndimage.map_coordinates(world, [ys, xs + disparity], order=3)
    as_u8 = lambda img: np.clip(np.round(img), 0, 255).astype(np.uint8)  # noqa: E731
    return as_u8(world[:, :w]), as_u8(right)


def test_regression_poseless_frame_searched_only_64_px_without_a_note():
    # a user's 1024x768 frames without height_m/pitch_deg were matched up to the fixed 64 px
    # only (their near ground needs 90): 7 % of the bottom rows valid, and nothing said so
    left, right = _ramp_pair()
    bare = Camera(focal_px=400.0, baseline_m=0.1)
    result = _run(left, right, camera=bare)
    assert result.figures["max_disparity"] == 64
    (note,) = result.notes
    assert "no camera pose" in note and "ground plane fitted from the disparity" in note
    assert "up to 64 px" in note and f"{400.0 * 0.1 / 64:.2f} m" in note
    assert "likely cut off" in note and "depth.max_disparity" in note
    # an explicit limit: only the ground plane's source is noted
    (note,) = _run(left, right, camera=bare, max_disparity=90).notes
    assert "ground plane fitted" in note and "64" not in note
    # a frame whose matches stay well below the limit is not told it was cut off
    left, right = _ramp_pair(near_px=40.0, far_px=20.0)
    (note,) = _run(left, right, camera=bare).notes
    assert "up to 64 px" in note and "cut off" not in note
    # with a pose nothing is assumed
    assert _run(left, right).notes == []


def test_regression_exchanged_left_and_right_were_not_noted():
    # a pair entered the other way round in the index matched 12 % of the frame; only
    # segment's 'height valid on 12 %' hinted at it
    left, right, _ = _ground_pair(shape=(128, 160))
    exchanged = _run(right, left)
    assert exchanged.figures["valid_fraction"] < 0.5
    assert any("left and right look exchanged" in note for note in exchanged.notes)
    assert "swap the frame's left and right columns" in " ".join(exchanged.notes)
    assert not any("exchanged" in note for note in _run(left, right).notes)


def test_regression_camera_pose_disagreeing_with_the_disparity_was_not_noted():
    # a user's baseline_m in millimetres, or a focal length 20 % short, ran 'done' with
    # every range and size scaled: the pose was rejected for a fitted plane without a word
    left, right, _ = _ground_pair()
    assert _run(left, right).notes == []
    mm = Camera(focal_px=120.0, baseline_m=100.0, height_m=1.2, pitch_deg=38.0)
    # (its pose's search band also piles the matches up at the limit: noted apart)
    (note,) = [n for n in _run(left, right, camera=mm, max_disparity=32).notes if "ground" in n]
    assert "the disparity's ground lies 1.2e+03 m below" in note
    assert "height_m = 1.2, pitch_deg = 38" in note and "millimetres" in note
    short = Camera(focal_px=120.0, baseline_m=0.1, height_m=1.2, pitch_deg=30.0)
    (note,) = _run(left, right, camera=short).notes
    assert "pitch_deg = 30" in note and "millimetres" not in note and "focal_px" in note


def test_regression_unrectified_pair_was_not_noted():
    # a right image 6-8 rows lower than the left (an unrectified pair) matched 13-24 % of
    # the frame and ran 'done' without a word
    left, right, _ = _ground_pair(shape=(160, 200))
    offset = _run(left, np.roll(right, 8, axis=0))
    assert offset.figures["valid_fraction"] < 0.3
    (note,) = [n for n in offset.notes if "unrectified" in n]
    assert "rows lower than the left" in note and "rectify" in note
    assert not any("unrectified" in n for n in _run(left, right).notes)


def test_regression_a_set_max_disparity_below_the_near_ground_cut_it_silently():
    # the README's catalog example sets depth.max_disparity = 64; a 1024x768 camera whose
    # near ground needs 90 px lost its bottom rows without a word
    left, right = _ramp_pair()  # 40 px at the top to 80 px at the bottom
    posed = Camera(focal_px=400.0, baseline_m=0.1, height_m=1.0, pitch_deg=30.0)
    notes = _run(left, right, camera=posed, max_disparity=64, floor_margin=1.0,
                 ceiling_ratio=0.0).notes  # fmt: skip
    assert any(n.startswith("matches pile up at the search limit") for n in notes), notes
    assert "raise depth.max_disparity" in " ".join(notes)
    notes = _run(left, right, camera=posed, max_disparity=100, floor_margin=1.0,
                 ceiling_ratio=0.0).notes  # fmt: skip
    assert not any("search limit" in n for n in notes), notes


def test_regression_rectification_fill_edge_drew_the_windows_across_it():
    # black wedges along the border (rectification's fill, at another place in each image)
    # were matched as they came: the fill got disparities and the windows across its edge
    # matched that edge, not the ground
    left, right, truth = _ground_pair(shape=(120, 200), seed=4)
    ys, xs = np.indices(right.shape)
    right_fill, left_fill = xs + ys < 40, xs + ys < 46
    right[right_fill], left[left_fill] = 0, 0
    result = _run(left, right)
    disparity = result.arrays["disparity"]
    assert not np.isfinite(disparity[right_fill]).any()
    near_edge = ~right_fill & (xs + ys < 40 + 20)
    found = np.isfinite(disparity[near_edge])
    assert found.mean() > 0.6
    assert np.mean(np.abs(disparity[near_edge][found] - truth[near_edge][found]) > 2) < 0.03
    assert any("black fill along the border" in note for note in result.notes)
    assert 0.9 < result.figures["valid_fraction"] <= 1.0  # of the imaged pixels
    plain = _run(*_ground_pair(shape=(120, 200), seed=4)[:2])
    assert not any("fill" in note for note in plain.notes)


def test_regression_integer_images_in_0_255_are_matched_as_uint8_again():
    # the matcher takes integer gray levels in 0..255 (stages._stereo_filters); the fill
    # check added in depth v7 took uint8 only and failed such a pair with a TypeError
    # about "image" (and the quick block matching of the pair checks needs uint8 too)
    left, right, _ = _ground_pair(shape=(120, 200), seed=4)
    ys, xs = np.indices(right.shape)
    right[xs + ys < 40], left[xs + ys < 46] = 0, 0
    as_uint8 = _run(left, right)
    as_uint16 = _run(left.astype(np.uint16), right.astype(np.uint16))
    for name in ("disparity", "residual", "height"):
        np.testing.assert_array_equal(as_uint16.arrays[name], as_uint8.arrays[name])
    assert as_uint16.notes == as_uint8.notes
