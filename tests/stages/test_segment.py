"""Tests of stages/segment.py: the stage contract, both methods, tiling, parameter errors."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.stage import FrameContext
from stages._depth_rules import _row_band_sigma
from stages._sectors import sector_edges, sector_histograms
from stages.segment import (
    STAGE,
    _RowNoise,
    _seams,
    segment_image,
    tiled_sector_histograms,
)


def disk(shape, cy, cx, r):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r


def scene(shape=(160, 160), *, ground=140.0, gradient=0.0, rocks=(), noise=4.0, seed=0):
    """Gray ground (optionally with a left-to-right illumination ramp) plus disk rocks."""
    rng = np.random.default_rng(seed)
    xx = np.arange(shape[1])[None, :] / shape[1]
    image = ground + gradient * (xx - 0.5) + rng.normal(0, noise, shape)
    for cy, cx, r, gray in rocks:
        inside = disk(shape, cy, cx, r)
        image[inside] = gray + rng.normal(0, noise, inside.sum())
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def frame_context():
    return FrameContext(frame_id="f0", archive="test", camera=Camera(focal_px=500, baseline_m=0.1))


def iou(a, b):
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


@pytest.mark.parametrize("gray", [40, 230], ids=["dark-on-light", "light-on-dark"])
def test_faithful_method_finds_dark_and_light_rocks(gray):
    ground = 150 if gray < 128 else 90
    image = scene(ground=ground, rocks=[(60, 70, 14, gray)])
    result = segment_image(image, method="sector-histogram", sectors=8)
    assert result.labels.max() == 1
    assert iou(result.labels == 1, disk(image.shape, 60, 70, 14)) > 0.9


def test_both_polarities_in_one_frame():
    image = scene(rocks=[(40, 40, 12, 40), (110, 110, 14, 235)])
    labels = segment_image(image, method="sector-histogram", sectors=8).labels
    assert labels.max() == 2
    assert labels[40, 40] != labels[110, 110]
    assert labels[40, 40] > 0 and labels[110, 110] > 0


def test_no_block_artifacts_on_an_illumination_gradient():
    image = scene(gradient=80.0, rocks=[(80, 100, 15, 30)], seed=2)
    for sectors in (8, 16):
        result = segment_image(image, method="sector-histogram", sectors=sectors)
        assert result.labels.max() == 1, f"{sectors}x{sectors}: spurious objects"
        assert iou(result.labels > 0, disk(image.shape, 80, 100, 15)) > 0.85
        # no object pixel on any sector boundary away from the rock
        boundary = np.zeros(image.shape, bool)
        boundary[sector_edges(160, sectors)[1:-1], :] = True
        boundary[:, sector_edges(160, sectors)[1:-1]] = True
        assert not (boundary & (result.labels > 0) & ~disk(image.shape, 80, 100, 18)).any()


def test_curtain_case_a_rock_larger_than_a_sector():
    image = scene(rocks=[(80, 80, 30, 60)], seed=5)  # covers several 20-px sectors fully
    result = segment_image(image, method="sector-histogram", sectors=8)
    assert result.sectors.phantom.any()
    assert result.labels.max() == 1
    assert iou(result.labels == 1, disk(image.shape, 80, 80, 30)) > 0.9


def test_depth_mode_uses_height_faithful_mode_ignores_it():
    shape = (160, 160)
    image = scene(rocks=[(50, 50, 12, 50)], seed=3)  # a dark patch: a shadow on the ground
    height = np.zeros(shape, np.float32)
    height[disk(shape, 110, 110, 14)] = 0.1  # a rock exactly as gray as the ground
    faithful = segment_image(image, method="sector-histogram", height=height, sectors=8)
    depth = segment_image(image, method="sector-histogram+depth", height=height, sectors=8)
    assert faithful.labels[50, 50] > 0 and faithful.labels[110, 110] == 0
    assert depth.labels[50, 50] == 0 and depth.labels[110, 110] > 0
    assert depth.labels.max() == 1
    assert depth.depth.flat_removed_px > 0


def test_depth_mode_without_depth_falls_back_on_intensity():
    image = scene(rocks=[(60, 70, 14, 40)])
    # R7, R7b and R7c (intensity rules of the depth method) may add a rim pixel: off here
    result = segment_image(image, sectors=8, weak_bands=0, join_gap_px=0, face_bands=0)
    reference = segment_image(image, method="sector-histogram", sectors=8)
    np.testing.assert_array_equal(result.labels, reference.labels)
    assert any("intensity" in note for note in result.notes)


def test_depth_mode_splits_touching_rocks():
    shape = (160, 160)
    image = scene(rocks=[(80, 60, 20, 50), (80, 95, 20, 50)], seed=4)
    disparity = np.full(shape, 10.0, np.float32)
    disparity[disk(shape, 80, 60, 20)] = 18.0
    disparity[disk(shape, 80, 95, 20) & ~disk(shape, 80, 60, 20)] = 13.0
    faithful = segment_image(image, method="sector-histogram", sectors=8)
    depth = segment_image(image, disparity=disparity, sectors=8)
    assert faithful.labels.max() == 1
    assert depth.labels.max() == 2


@pytest.mark.parametrize("shape", [(160, 160), (150, 130)])
def test_tiled_histograms_equal_untiled(shape):
    image = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    for sectors, tile_px in ((16, 40), (8, 64), (16, 1)):
        np.testing.assert_array_equal(
            tiled_sector_histograms(image, sectors=sectors, tile_px=tile_px),
            sector_histograms(image, sectors=sectors),
        )


def test_stage_run_returns_declared_shapes_and_dtypes_tiled_or_not():
    image = scene(rocks=[(60, 70, 14, 40), (120, 30, 10, 220)])
    height = np.zeros(image.shape, np.float32)
    height[disk(image.shape, 60, 70, 14) | disk(image.shape, 120, 30, 10)] = 0.1
    disparity = np.full(image.shape, 12.0, np.float32)
    inputs = {"right": image, "height": height, "disparity": disparity}
    outputs = {}
    for tile_px in (1024, 48):
        params = STAGE.resolve_params({"sectors": 8, "tile_px": tile_px})
        result = STAGE.run(inputs, frame=frame_context(), params=params)
        assert set(result.arrays) == set(STAGE.output_names)
        for product in STAGE.outputs:
            array = result.arrays[product.name]
            assert array.shape == product.frame_shape(image.shape, params), product.name
            assert array.dtype == np.dtype(product.dtype), product.name
        labels = result.arrays["labels"]
        assert sorted(np.unique(labels).tolist()) == list(range(labels.max() + 1))
        assert result.figures["n_objects"] == labels.max() == 2
        assert result.figures["n_phantom_sectors"] == result.arrays["sector_phantom"].sum()
        outputs[tile_px] = labels
    np.testing.assert_array_equal(outputs[1024], outputs[48])


def test_bad_parameters_raise_clear_errors():
    with pytest.raises(ParamError, match="method"):
        STAGE.resolve_params({"method": "watershed"})
    with pytest.raises(ParamError, match=">= 2"):
        STAGE.resolve_params({"sectors": 1})
    with pytest.raises(ParamError, match="height_smoothing_px"):
        STAGE.resolve_params({"height_smoothing_px": 4})
    image = scene(shape=(40, 40))
    with pytest.raises(ValueError, match=r"sectors must be in \[2, 10\].*sectors=10\)"):
        segment_image(image, sectors=16)
    # regression: a 6x6 frame was told "sectors must be in [2, 1]", a range no value fits
    with pytest.raises(ValueError, match="too small to segment.*at least 8x8"):
        segment_image(scene(shape=(40, 40))[:6, :6], sectors=2)
    with pytest.raises(ValueError, match="method must be one of"):
        segment_image(image, method="otsu", sectors=4)
    with pytest.raises(ValueError, match="uint8"):
        segment_image(image.astype(np.float32), sectors=4)
    with pytest.raises(ValueError, match="reference image has"):
        segment_image(image, sectors=4, height=np.zeros((10, 10), np.float32))
    with pytest.raises(ValueError, match="ripple_texture_ratio"):
        segment_image(image, sectors=4, ripple_texture_ratio=-1.0)
    with pytest.raises(ValueError, match="weak_bands, weak_growth_px, join_gap_px and face"):
        segment_image(image, sectors=4, weak_growth_px=-1)
    with pytest.raises(ValueError, match="face_bands must be >= 0"):
        segment_image(image, sectors=4, face_bands=-0.5)
    with pytest.raises(ValueError, match=r"neck_ratio and rim_fraction must be in \[0, 1\)"):
        segment_image(image, sectors=4, neck_ratio=1.0)
    with pytest.raises(ValueError, match=r"neck_ratio and rim_fraction must be in \[0, 1\)"):
        segment_image(image, sectors=4, rim_fraction=-0.1)
    with pytest.raises(ValueError, match="blob_sigmas must be >= 0"):
        segment_image(image, sectors=4, blob_sigmas=-1.0)
    with pytest.raises(ValueError, match="shadow_noise_m must be >= 0"):
        segment_image(image, sectors=4, shadow_noise_m=-0.001)
    with pytest.raises(ValueError, match=r"sun_shadow_angle_deg must be in \[0, 90\]"):
        segment_image(image, sectors=4, sun_shadow_angle_deg=91.0)


def test_depth_mode_splits_rocks_at_one_range_joined_by_a_neck():
    """R4b: two rocks touching through a narrow neck, no depth edge between them."""
    image = scene(rocks=[(80, 55, 14, 50), (80, 100, 14, 50)], seed=5)
    image[79:82, 55:101] = 50  # a 3-pixel bridge of rock gray
    first, second = disk(image.shape, 80, 55, 14), disk(image.shape, 80, 100, 14)
    split = segment_image(image, sectors=8).labels
    whole = segment_image(image, sectors=8, neck_ratio=0).labels
    assert whole.max() == 1
    assert split.max() == 2 and split[80, 55] != split[80, 100]
    assert iou(split == split[80, 55], first) > 0.9 and iou(split == split[80, 100], second) > 0.9


def test_depth_mode_completes_a_rock_whose_other_half_is_just_inside_the_threshold():
    """R7: the half of a rock between the thresholds joins the half past one."""
    image = scene(shape=(320, 320), ground=100.0)  # noise 4: the high threshold is at 118
    rock = disk(image.shape, 150, 150, 10)
    weak = rock & (np.arange(320)[None, :] >= 150)
    image[rock & ~weak] = 200
    # inside the threshold but more than 0.7 bands above the ground (no mode of its own)
    image[weak] = np.random.default_rng(0).integers(113, 118, weak.sum())
    found = {}
    for weak_bands in (0.0, 0.7):
        labels = segment_image(image, sectors=4, weak_bands=weak_bands).labels
        found[weak_bands] = labels == labels[150, 145]
    assert iou(found[0.0], rock) < 0.5 and iou(found[0.7], rock) > 0.95


def test_depth_mode_adds_a_compact_blob_inside_the_thresholds_only_when_asked():
    """R8: a rock 12 levels darker than a ground of pixel noise 4 lies inside the thresholds
    (3.5 sigmas, 14 levels) but is many spreads out at its own scale."""
    image = scene(shape=(160, 160), ground=100.0, rocks=[(80, 80, 7, 88.0)])
    rock = disk(image.shape, 80, 80, 7)
    off = segment_image(image, sectors=4).labels
    on = segment_image(image, sectors=4, blob_sigmas=4.0).labels
    assert not off[rock].any()
    assert iou(on > 0, rock) > 0.8 and on.max() == 1


def test_segment_image_defaults_match_the_stage_defaults():
    import inspect

    signature = inspect.signature(segment_image)
    for name, value in STAGE.defaults().items():
        if name == "tile_px":
            continue
        assert signature.parameters[name].default == value, name


def test_left_reference_catalog_segments_the_left_image():
    """Regression: with reference = "left" the stage segmented `right`, so labels and the
    depth products were in different geometries."""
    rock_left = scene(rocks=[(60, 90, 14, 40)])
    rock_right = scene(rocks=[(60, 40, 14, 40)])
    inputs = {"left": rock_left, "right": rock_right}
    camera = Camera(focal_px=500, baseline_m=0.1, reference="left")
    frame = FrameContext(frame_id="f0", archive="test", camera=camera)
    params = STAGE.resolve_params({"method": "sector-histogram", "sectors": 8})
    labels = STAGE.run(inputs, frame=frame, params=params).arrays["labels"]
    assert labels[60, 90] > 0 and labels[60, 40] == 0


@pytest.mark.parametrize("method", ["sector-histogram", "sector-histogram+depth"])
def test_regression_rectification_fill_was_segmented_as_an_obstacle(method):
    # a rectified frame's black wedges along the border came out as one large dark object
    # (21,000 px on a user's frame), and skewed the histograms of the sectors they cut
    rocks = [(60, 70, 12, 40), (110, 120, 10, 40)]
    plain = scene(rocks=rocks, seed=3)
    ys, xs = np.indices(plain.shape)
    wedge = xs + ys < 50
    filled = plain.copy()
    filled[wedge] = 0
    result = segment_image(filled, method=method, sectors=8)
    assert not np.any(result.labels[wedge])
    assert result.labels.max() == 2
    for cy, cx, r, _gray in rocks:
        assert iou(result.labels == result.labels[cy, cx], disk(plain.shape, cy, cx, r)) > 0.85
    assert any("black fill along the border" in note for note in result.notes)
    assert not any("fill" in note for note in segment_image(plain, method=method, sectors=8).notes)


def test_seams_equal_the_whole_frame_comparisons():
    # the twin: the neighbour comparisons the compiled pass replaced
    rng = np.random.default_rng(4)
    for _ in range(30):
        labels = rng.integers(0, 4, tuple(rng.integers(1, 30, 2))).astype(np.int32)
        expected = np.zeros(labels.shape, dtype=bool)
        for a, b, rows in ((labels[:, 1:], labels[:, :-1], False), (labels[1:], labels[:-1], True)):
            differ = (a != b) & (a > 0) & (b > 0)
            if rows:
                expected[1:, :] |= differ
            else:
                expected[:, 1:] |= differ
        np.testing.assert_array_equal(_seams(labels), expected)


def test_row_noise_equals_the_row_band_sigma_of_each_labelling():
    # R7e and R7f's row noise samples the heights once and remembers the bands: the same
    # values as R0b's row noise of each labelling measured afresh
    rng = np.random.default_rng(6)
    relative = rng.normal(0, 0.005, (120, 97)).astype(np.float32)
    relative[rng.random(relative.shape) < 0.1] = np.nan
    noise = _RowNoise(relative)
    labels = np.zeros(relative.shape, np.int32)
    for _ in range(4):
        y, x = rng.integers(0, 100), rng.integers(0, 80)
        labels[y : y + 20, x : x + 15] = 1  # an object grows in one band or two
        usable = np.isfinite(relative) & (labels == 0)
        np.testing.assert_array_equal(noise(labels), _row_band_sigma(relative, usable))
