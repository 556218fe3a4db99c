"""Tests of stages/_height_grow.py: a partial near rock grows over its raised rest (R7f)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stages._height_grow import (
    _ground_mean,
    _grow,
    _kept_ground_mean,
    _measure,
    _median_row,
    _reach_steps,
    _window_masks,
    grow_raised_parts,
)

SHAPE = (60, 80)
ROCK_M = 0.04  # a near rock's height, 10 sigmas of 4 mm
NOISE_M = 0.004


def partial_rock_scene(*, rest_contrast: float = -0.6, found_cols: int = 18):
    """A dark rock, rows 15-44 and columns 20-49, standing ``ROCK_M`` high; only its left
    ``found_cols`` columns are object 1 (past the low threshold, contrast -2), the rest is
    ``rest_contrast`` bands from the ground's gray level (within the thresholds)."""
    labels = np.zeros(SHAPE, np.int32)
    contrast = np.zeros(SHAPE, np.float32)
    relative = np.zeros(SHAPE, np.float32)
    rows, cols = slice(15, 45), slice(20, 50)
    relative[rows, cols] = ROCK_M
    contrast[rows, cols] = rest_contrast
    found = slice(20, 20 + found_cols)
    contrast[rows, found] = -2.0
    labels[rows, found] = 1
    return labels, contrast, relative, np.full(SHAPE[0], NOISE_M)


def test_partial_rock_grows_over_its_raised_rest_on_its_gray_side():
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    # the raised footprint (12 columns, R7f's farthest growth), no ground pixel, but for
    # its two outer corners: their window holds more ground (contrast 0) than rock
    assert set(np.unique(out)) == {0, 1}
    assert not (out > 0)[relative == 0].any()
    missed = np.argwhere((relative > 0) & (out == 0))
    assert missed.tolist() == [[15, 49], [44, 49]] and grown == 30 * 12 - 2


def test_raised_fringe_on_the_other_gray_side_is_not_taken():
    # the stereo fringe: raised ground around the rock whose gray scatters both ways; the
    # 5x5 mean of a checkerboard of +-1 bands is near the ground's level
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    relative[10:50, 15:55] = np.maximum(relative[10:50, 15:55], 0.03)
    checker = np.indices(SHAPE).sum(axis=0) % 2 * 2.0 - 1.0
    ring = (relative > 0) & (labels == 0)
    contrast[ring] = checker[ring]
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)


def test_rest_lighter_than_the_ground_does_not_join_a_dark_object():
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=0.6)
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)


def test_small_object_low_core_or_noisy_rows_are_not_grown():
    first = {"strong_fraction": 0.0, "broad_fraction": 0.0}  # the first case alone
    labels, contrast, relative, noise = partial_rock_scene(found_cols=4)  # 120 px < 150
    assert grow_raised_parts(labels, contrast, relative, noise, **first)[1] == 0
    labels, contrast, relative, noise = partial_rock_scene()
    # a 12 mm row noise: too noisy a row (the core stands 3.3 sigmas, too low as well)
    noisy = np.full(SHAPE[0], 0.012)
    assert grow_raised_parts(labels, contrast, relative, noisy, **first)[1] == 0
    # 4.4 sigmas of a 9 mm row noise: a row R7f reads, too low a core
    assert grow_raised_parts(labels, contrast, relative, np.full(SHAPE[0], 0.009), **first)[1] == 0
    assert grow_raised_parts(labels, contrast, relative * 0.45, noise, **first)[1] == 0


def test_rows_between_seven_and_a_half_and_ten_mm_of_noise_are_read():
    # segment v38: lava_0003 rock 26 (2.7 m away) lay in a row of 7.5-10 mm noise, above
    # R7f's old 7.5 mm bar, and stayed a partial object (IoU 0.44; 0.61 grown)
    labels, contrast, relative, _ = partial_rock_scene()
    row_noise = np.full(SHAPE[0], 0.0085)
    first = {"strong_fraction": 0.0, "broad_fraction": 0.0}
    # a 6 cm rock: 7 sigmas of 8.5 mm
    out, grown = grow_raised_parts(labels, contrast, relative * 1.5, row_noise, **first)
    assert grown > 0 and not (out > 0)[relative == 0].any()
    old_bar = grow_raised_parts(
        labels, contrast, relative * 1.5, row_noise, max_noise_m=0.0075, **first
    )
    assert old_bar[1] == 0


def test_second_case_grows_small_or_low_objects_over_a_rest_clearly_on_their_side():
    # mojave seed 3, mojave_0000 rock 4 and mojave_0006 rock 5: objects of 100-140 px (or
    # 3 sigmas) whose rest is 0.65 bands darker than the ground were left partial
    labels, contrast, relative, noise = partial_rock_scene(found_cols=4)  # 120 px
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown > 0 and not (out > 0)[relative == 0].any()
    assert np.all(out[17:43, 20:32] == 1)
    # a core of 4.5 sigmas: below the first case's 5, above the second's 2.5
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative * 0.45, noise)
    # its rim's 5x5 windows hold more ground: out of the 0.45 bands but for the inner rows
    assert grown > 0 and np.all(out[17:43, 20:48] == 1) and not (out > 0)[relative == 0].any()
    # a rest within the second case's 0.45 bands stays out of small objects
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=-0.3, found_cols=4)
    assert grow_raised_parts(labels, contrast, relative, noise)[1] == 0
    # and objects under 60 px are never grown
    labels, contrast, relative, noise = partial_rock_scene(found_cols=1)  # 30 px
    assert grow_raised_parts(labels, contrast, relative, noise)[1] == 0


def test_growth_stops_at_half_the_core_height_and_after_max_steps():
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = 0.4 * ROCK_M  # the far part lies below half the core
    out, grown = grow_raised_parts(
        labels, contrast, relative, noise, strong_fraction=0, broad_fraction=0
    )
    # less the two outer corners' 2 px each that the opening with a disk rounds off
    assert grown == 30 * 6 - 4 and np.all(out[17:43, 20:44] == 1) and not out[:, 44:].any()
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(
        labels, contrast, relative, noise, max_steps=3, strong_fraction=0, broad_fraction=0
    )
    assert grown == 30 * 3 and np.all(out[15:45, 20:41] == 1) and not out[:, 41:].any()
    # the second case reaches it: above a quarter of the core, 0.6 bands out on its side
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = 0.4 * ROCK_M
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert np.all(out[17:43, 20:49] == 1)


def test_third_case_grows_large_objects_over_a_broad_faint_rest_not_a_thin_rim():
    # lava_0002 rock 4: a large flat dark rock found in part (223 of 1298 px) whose rest
    # stands 0.5-1 cm (1-2 sigmas) and 0.4 bands dark: neither earlier case reaches it
    labels, contrast, relative, noise = partial_rock_scene(rest_contrast=-0.3)
    relative *= 0.15  # 6 mm: 1.5 sigmas
    out, grown = grow_raised_parts(labels, contrast, relative, noise, broad_fraction=0)
    assert grown == 0
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown > 0 and np.all(out[18:42, 20:47] == 1) and not (out > 0)[relative == 0].any()
    # a rock found whole with a 6-px wide tongue of raised, faintly dark fringe to its
    # right: the opening with a 15-px disk cuts it off but for a few px at its root
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    relative[27:33, 50:62] = 0.006
    contrast[27:33, 50:62] = -0.3
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown <= 6 and not out[:, 51:].any()
    out, grown = grow_raised_parts(labels, contrast, relative, noise, broad_fraction=0)
    assert grown == 0


def test_pixels_of_other_objects_are_kept_and_highest_core_grows_first():
    labels, contrast, relative, noise = partial_rock_scene()
    labels[15:45, 44:50] = 2  # a lower dark object on the rock's right edge
    relative[15:45, 44:50] = 0.8 * ROCK_M
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 30 * 6 - 4  # the corners next to object 2 rounded off
    assert np.all(out[17:43, 20:44] == 1) and np.all(out[15:45, 44:50] == 2)


def test_zero_fraction_disables_and_bad_arguments_are_refused():
    labels, contrast, relative, noise = partial_rock_scene()
    out, grown = grow_raised_parts(labels, contrast, relative, noise, fraction=0)
    assert grown == 0 and out is labels
    with pytest.raises(ValueError, match="fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, fraction=1.5)
    with pytest.raises(ValueError, match="one value per row"):
        grow_raised_parts(labels, contrast, relative, noise[:-1])
    with pytest.raises(ValueError, match="must have one shape"):
        grow_raised_parts(labels, contrast[:-1], relative, noise)
    with pytest.raises(ValueError, match="strong_fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, strong_fraction=-0.1)
    with pytest.raises(ValueError, match="broad_fraction must be in"):
        grow_raised_parts(labels, contrast, relative, noise, broad_fraction=2.0)
    with pytest.raises(ValueError, match="strong_min_object_px >= 1"):
        grow_raised_parts(labels, contrast, relative, noise, strong_min_object_px=0)


def test_invalid_heights_are_not_grown_over():
    labels, contrast, relative, noise = partial_rock_scene()
    relative[15:45, 44:50] = np.nan
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 30 * 6 - 4 and not out[:, 44:].any()


def test_raised_ground_above_the_top_row_and_thin_strands_are_not_taken():
    labels, contrast, relative, noise = partial_rock_scene(found_cols=30)
    # raised, dark ground behind the rock (above its top row) and a 2-px strand to its right
    relative[5:15, 20:50] = ROCK_M
    contrast[5:15, 20:50] = -0.6
    relative[28:30, 50:60] = ROCK_M
    contrast[28:30, 50:60] = -0.6
    out, grown = grow_raised_parts(labels, contrast, relative, noise)
    assert grown == 0 and np.array_equal(out, labels)


def test_ground_mean_equals_its_opencv_twin_bit_for_bit():
    # the twin: the cv2.blur expressions the compiled pass replaced, on magnitudes whose
    # double sums round (1e-6 to 1e6), NaN, -0 and frames down to 1 px (OpenCV's there)
    rng = np.random.default_rng(3)
    for _ in range(60):
        shape = tuple(rng.integers(1, 40, 2))
        contrast = rng.normal(0, 1, shape) * 10 ** rng.uniform(-6, 6, shape)
        contrast = contrast.astype(np.float32)
        contrast[rng.random(shape) < 0.03] = np.nan
        contrast[rng.random(shape) < 0.03] = -0.0
        ground = rng.random(shape) < rng.uniform(0, 1)
        weight = ground.astype(np.float32)
        with np.errstate(invalid="ignore"):
            total = cv2.blur(contrast * weight, (5, 5))
        share = cv2.blur(weight, (5, 5))
        twin = np.where(share > 0, total / np.maximum(share, np.float32(1e-6)), np.float32(0))
        mean = _ground_mean(contrast, ground)
        np.testing.assert_array_equal(mean.view(np.int32), twin.view(np.int32))


def test_kept_ground_mean_equals_the_whole_frames_where_asked():
    # R7f's cases keep the mean between them and make again only the columns near a growth:
    # where a case reads it, the same bits as the whole frame's mean of its own labels
    rng = np.random.default_rng(6)
    for _ in range(30):
        shape = (int(rng.integers(5, 40)), int(rng.integers(5, 60)))
        contrast = (rng.normal(0, 1, shape) * 10 ** rng.uniform(-6, 3, shape)).astype(np.float32)
        labels = (rng.random(shape) < 0.3).astype(np.int32)
        measures: dict = {}
        for _case in range(3):
            spans = []
            for _span in range(int(rng.integers(1, 4))):
                x0 = int(rng.integers(0, shape[1]))
                spans.append((x0, int(rng.integers(x0 + 1, shape[1] + 1))))
            mean = _kept_ground_mean(measures, contrast, labels, spans)
            whole = _ground_mean(contrast, labels == 0)
            for x0, x1 in spans:
                np.testing.assert_array_equal(
                    mean[:, x0:x1].view(np.int32), whole[:, x0:x1].view(np.int32)
                )
            # a growth inside a few columns, as _grow records it
            x0 = int(rng.integers(0, shape[1]))
            x1 = int(rng.integers(x0 + 1, shape[1] + 1))
            labels = labels.copy()
            labels[:, x0:x1][rng.random((shape[0], x1 - x0)) < 0.4] = 2
            measures["stale"].append((x0, x1))


def test_frame_narrower_than_the_contrast_window_grows_without_key_error():
    # a frame under 5 px on a side takes OpenCV's whole-frame mean and kept none: its
    # growth must still be recorded (KeyError 'stale' until fixed; grown as before v41)
    labels = np.zeros((100, 4), np.int32)
    contrast = np.zeros(labels.shape, np.float32)
    relative = np.zeros(labels.shape, np.float32)
    relative[10:90] = ROCK_M
    contrast[10:90] = -0.6
    contrast[10:90, :2] = -2.0
    labels[10:90, :2] = 1
    for maps in ((labels, contrast, relative), (labels.T, contrast.T, relative.T)):
        frame, gray, heights = (np.ascontiguousarray(m) for m in maps)
        out, grown = grow_raised_parts(frame, gray, heights, np.full(frame.shape[0], NOISE_M))
        assert grown == 160 and np.array_equal(out > 0, heights > 0)


def test_median_row_equals_numpys_median_of_the_rows():
    rng = np.random.default_rng(4)
    for _ in range(200):
        own = rng.random(tuple(rng.integers(1, 12, 2))) < rng.uniform(0.05, 1)
        if own.any():
            window = np.where(own, 3, rng.integers(0, 3, own.shape)).astype(np.int32)
            assert _median_row(window, 3) == int(np.median(np.nonzero(own)[0]))


def test_cases_sharing_their_measures_equal_cases_measuring_again():
    # R7f's second and third cases read the first's measures, updated for the objects it
    # grew: the same as measuring the grown labels again
    rng = np.random.default_rng(5)
    labels = np.zeros((120, 160), np.int32)
    relative = rng.normal(0, 0.003, labels.shape).astype(np.float32)
    contrast = rng.normal(0, 0.5, labels.shape).astype(np.float32)
    for k, (y, x, r) in enumerate([(30, 30, 14), (80, 50, 10), (40, 110, 16), (95, 120, 9)]):
        yy, xx = np.ogrid[: labels.shape[0], : labels.shape[1]]
        rock = (yy - y) ** 2 + (xx - x) ** 2 <= r * r
        relative[rock] += 0.03 + 0.005 * k
        contrast[rock] += -1.0 if k % 2 else 1.0
        labels[rock & (xx < x + (k - 1) * 3)] = k + 1
    relative[rng.random(labels.shape) < 0.05] = np.nan
    noise = np.full(labels.shape[0], 0.003)
    settings = {"max_noise_m": 0.0075, "min_height_m": 0.008, "max_steps": 12, "max_gain": 3.0}
    cases = [
        {"fraction": 0.5, "min_object_px": 150, "core_sigmas": 5.0, "min_contrast": 0.25},
        {"fraction": 0.25, "min_object_px": 60, "core_sigmas": 2.5, "min_contrast": 0.45},
        {"fraction": 0.1, "min_object_px": 150, "core_sigmas": 1.0, "min_contrast": 0.15},
    ]
    shared: dict = {}
    alone = with_measures = labels
    total = 0
    for case in cases:
        alone, _ = _grow(alone, contrast, relative, noise, **settings, **case)
        with_measures, grown = _grow(
            with_measures, contrast, relative, noise, **settings, **case, _measures=shared
        )
        np.testing.assert_array_equal(with_measures, alone)
        again = _measure(alone, contrast, relative, int(alone.max()))
        for key, values in again.items():
            # the objects' (label 0, the ground, is never grown nor read)
            np.testing.assert_array_equal(shared[key][1:], values[1:])
        total += grown
    assert total > 0


def test_reach_steps_equal_rounds_of_a_dilation_within_the_free_pixels():
    # the twin: the loop of 3x3 dilations the compiled breadth-first pass replaced
    rng = np.random.default_rng(6)
    for _ in range(60):
        shape = tuple(rng.integers(1, 40, 2))
        obj = rng.random(shape) < 0.03
        free = (rng.random(shape) < rng.uniform(0.3, 0.9)) & ~obj
        steps = int(rng.integers(1, 15))
        twin = obj
        for _ in range(steps):
            near = cv2.dilate(twin.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
            more = twin | (free & near)
            if np.count_nonzero(more) == np.count_nonzero(twin):
                break
            twin = more
        reached = obj.copy()
        _reach_steps(reached, free, steps)
        np.testing.assert_array_equal(reached, twin)


def test_window_masks_equal_the_numpy_comparisons():
    # the twins: the whole-window comparisons the pass replaced (float64 scalars against
    # float32 maps compare in float64; NaN heights are never free)
    rng = np.random.default_rng(7)
    for _ in range(30):
        shape = tuple(rng.integers(1, 30, 2))
        box = rng.integers(0, 4, shape).astype(np.int32)
        heights = rng.normal(0.01, 0.01, shape).astype(np.float32)
        heights[rng.random(shape) < 0.1] = np.nan
        mean = rng.normal(0, 0.5, shape).astype(np.float32)
        level = np.float64(rng.uniform(0, 0.02))
        side = np.float64(rng.choice([-1.0, 1.0]))
        top = int(rng.integers(0, shape[0] + 1))
        obj = np.empty(shape, bool)
        free = np.empty(shape, bool)
        _window_masks(box, heights, mean, 2, level, side, 0.25, top, obj, free)
        with np.errstate(invalid="ignore"):
            expected = (box == 0) & (heights > level)
        expected &= side * mean >= 0.25
        expected[:top] = False
        np.testing.assert_array_equal(obj, box == 2)
        np.testing.assert_array_equal(free, expected)


def _measure_twin(labels, contrast, relative, count):
    # _measure as it was before its compiled pass: whole-frame masks and gathers
    from stages._heights import _percentiles_by_label
    from stages._regions import _label_areas, _object_boxes

    inside = labels > 0
    judged = inside & np.isfinite(relative)
    core = _percentiles_by_label(
        relative[judged].astype(np.float32), labels[judged], count + 1, (75.0,)
    )[0]
    side = np.sign(
        _percentiles_by_label(
            contrast[inside].astype(np.float32), labels[inside], count + 1, (50.0,)
        )[0]
    )
    core[~np.isfinite(core)] = -np.inf
    return {
        "sizes": _label_areas(labels, count + 1),
        "core": core,
        "side": side,
        "boxes": _object_boxes(labels, count),
    }


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_measure_equals_its_whole_frame_twin(dtype):
    rng = np.random.default_rng(8)
    for _ in range(20):
        shape = tuple(rng.integers(1, 40, 2))
        labels = rng.integers(0, 6, shape).astype(np.int32)
        labels[rng.random(shape) < 0.4] = 0
        count = int(labels.max())
        relative = rng.normal(0, 0.02, shape).astype(dtype)
        relative[rng.random(shape) < 0.2] = np.nan
        contrast = rng.normal(0, 1, shape).astype(dtype)
        got = _measure(labels, contrast, relative, count)
        want = _measure_twin(labels, contrast, relative, count)
        for key in ("sizes", "core", "side", "boxes"):
            np.testing.assert_array_equal(got[key], want[key])
