from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.metrics import (
    descriptor_errors,
    disparity_errors,
    match_objects,
    pool_disparity_errors,
    pool_segmentation_scores,
    relation_agreement,
    segmentation_scores,
    true_occlusions,
    wilson_interval,
)


def _truth_disparity(shape=(40, 40), seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(5.0, 40.0, size=shape).astype(np.float32)


def _rock_labels(shape=(64, 64), boxes=()):
    """Label image with rectangular rocks ``(y0, y1, x0, x1)`` numbered 1..n."""
    labels = np.zeros(shape, dtype=np.int32)
    for k, (y0, y1, x0, x1) in enumerate(boxes, start=1):
        labels[y0:y1, x0:x1] = k
    return labels


# ------------------------------------------------------------------------------ depth
def test_perfect_disparity_has_no_error():
    truth = _truth_disparity()
    e = disparity_errors(truth.copy(), truth)
    assert e["bad1"] == e["bad2"] == e["epe"] == 0.0
    assert e["density"] == 1.0
    assert e["n_px"] == truth.size


def test_quarter_of_pixels_off_by_one_and_a_half():
    truth = _truth_disparity()
    pred = truth.copy()
    pred[:20, :20] += 1.5  # a quarter of the 40x40 frame
    e = disparity_errors(pred, truth)
    assert e["bad1"] == pytest.approx(0.25)
    assert e["bad2"] == 0.0
    assert e["epe"] == pytest.approx(0.25 * 1.5, rel=1e-5)


def test_invalid_predictions_count_as_bad_but_not_in_epe():
    truth = _truth_disparity()
    pred = truth.copy()
    pred[:10, :] = np.nan  # a quarter invalid
    e = disparity_errors(pred, truth)
    assert e["bad1"] == e["bad2"] == pytest.approx(0.25)
    assert e["density"] == pytest.approx(0.75)
    assert e["epe"] == 0.0


def test_occluded_and_invalid_truth_pixels_are_not_scored():
    truth = _truth_disparity()
    truth[0, :] = np.nan
    occluded = np.zeros(truth.shape, dtype=bool)
    occluded[:, :4] = True
    pred = np.where(occluded, np.nan, truth)  # wrong only where the truth is occluded
    e = disparity_errors(pred, truth, valid_truth=~occluded)
    assert e["bad1"] == 0.0 and e["density"] == 1.0
    assert e["n_px"] == 39 * 36


def test_nothing_scored_gives_nan_rates():
    truth = np.full((8, 8), np.nan, dtype=np.float32)
    e = disparity_errors(truth.copy(), truth)
    assert math.isnan(e["bad2"]) and math.isnan(e["epe"]) and e["n_px"] == 0


def test_pooled_disparity_is_pixel_weighted():
    truth = _truth_disparity()
    bad = truth + 3.0
    small_truth = truth[:20, :20]
    pooled = pool_disparity_errors(
        [disparity_errors(bad, truth), disparity_errors(small_truth, small_truth)]
    )
    # 1600 bad pixels, 400 good ones
    assert pooled["bad2"] == pytest.approx(1600 / 2000)
    assert pooled["epe"] == pytest.approx(3.0 * 1600 / 2000, rel=1e-5)


@settings(max_examples=30, deadline=None)
@given(
    offset=st.floats(-4.0, 4.0).filter(lambda o: abs(abs(o) - 1) > 1e-3 and abs(abs(o) - 2) > 1e-3)
)
def test_constant_offset_property(offset):
    truth = _truth_disparity((12, 12)).astype(np.float64)
    e = disparity_errors(truth + offset, truth)
    assert e["bad1"] == float(abs(offset) > 1)
    assert e["bad2"] == float(abs(offset) > 2)
    assert e["epe"] == pytest.approx(abs(offset), abs=1e-9)


def test_disparity_input_errors():
    truth = _truth_disparity()
    with pytest.raises(ValueError, match="same shape"):
        disparity_errors(truth[:10], truth)
    with pytest.raises(TypeError, match="numpy ndarray"):
        disparity_errors(truth.tolist(), truth)
    with pytest.raises(TypeError, match="valid_truth"):
        disparity_errors(truth, truth, valid_truth=np.ones(truth.shape, dtype=np.uint8))


# ------------------------------------------------------------------------ segmentation
BOXES = [(5, 15, 5, 15), (5, 15, 30, 42), (30, 45, 10, 20), (40, 60, 40, 60)]


def test_perfect_segmentation_scores_one():
    truth = _rock_labels(boxes=BOXES)
    s = segmentation_scores(truth.copy(), truth)
    assert s["precision"] == s["recall"] == s["f1"] == s["mean_iou"] == 1.0
    assert (s["tp"], s["fp"], s["fn"]) == (4, 0, 0)


@settings(max_examples=20, deadline=None)
@given(perm_seed=st.integers(0, 2**32 - 1))
def test_label_ids_do_not_matter(perm_seed):
    truth = _rock_labels(boxes=BOXES)
    rng = np.random.default_rng(perm_seed)
    new_ids = np.concatenate([[0], rng.choice(np.arange(1, 1000), size=4, replace=False)])
    pred = new_ids[truth].astype(np.int32)
    s = segmentation_scores(pred, truth)
    assert s["f1"] == 1.0
    m = match_objects(pred, truth)
    assert sorted(zip(m.true_ids.tolist(), m.pred_ids.tolist(), strict=True)) == [
        (k, int(new_ids[k])) for k in range(1, 5)
    ]


def test_missing_object_lowers_recall():
    truth = _rock_labels(boxes=BOXES)
    pred = truth.copy()
    pred[pred == 3] = 0
    s = segmentation_scores(pred, truth)
    assert s["recall"] == pytest.approx(3 / 4)
    assert s["precision"] == 1.0
    assert s["f1"] == pytest.approx(2 * 3 / (2 * 3 + 1))


def test_split_object_lowers_precision():
    truth = _rock_labels(boxes=BOXES)
    pred = truth.copy()
    # rock 4 (20x20) split 60/40 into objects 4 and 9: the larger part still matches (IoU 0.6)
    pred[40:60, 52:60] = 9
    s = segmentation_scores(pred, truth)
    assert s["recall"] == 1.0
    assert s["precision"] == pytest.approx(4 / 5)
    assert s["mean_iou"] == pytest.approx((3 + 0.6) / 4)


def test_half_split_loses_the_match_below_threshold():
    truth = _rock_labels(boxes=[(0, 10, 0, 10)])
    pred = truth.copy()
    pred[:, 5:10] = 2
    pred[:, :5] = 1
    pred[0, 0] = 0  # object 1 now has IoU 49/100 < 0.5
    pred[0, 5] = 0
    s = segmentation_scores(pred, truth)
    assert (s["tp"], s["fp"], s["fn"]) == (0, 2, 1)


def test_tiny_truth_rocks_are_ignored_both_ways():
    truth = _rock_labels(boxes=[*BOXES, (50, 54, 5, 10)])  # rock 5: 20 px < 30
    pred = truth.copy()
    s = segmentation_scores(pred, truth)  # finding the tiny rock is not a false positive
    assert (s["tp"], s["fp"], s["fn"]) == (4, 0, 0)
    pred[truth == 5] = 0
    s = segmentation_scores(pred, truth)  # missing it is not a false negative
    assert (s["tp"], s["fp"], s["fn"]) == (4, 0, 0)
    pred[50:52, 5:9] = 7  # a partial detection of the tiny rock (IoU 8/20 < 0.5)
    m = match_objects(pred, truth)
    assert m.fp == 0 and m.ignored_pred_ids.tolist() == [7]
    assert m.ignored_true_ids.tolist() == [5]


def test_false_positive_on_background_and_no_truth():
    truth = np.zeros((32, 32), dtype=np.int32)
    pred = _rock_labels((32, 32), boxes=[(2, 12, 2, 12)])
    s = segmentation_scores(pred, truth)
    assert (s["tp"], s["fp"], s["fn"]) == (0, 1, 0)
    assert s["precision"] == 0.0 and math.isnan(s["recall"])
    empty = segmentation_scores(truth, truth)
    assert math.isnan(empty["precision"]) and empty["fp"] == 0


def test_pooled_segmentation_sums_counts():
    truth = _rock_labels(boxes=BOXES)
    missing = truth.copy()
    missing[missing == 1] = 0
    pooled = pool_segmentation_scores(
        [segmentation_scores(truth, truth), segmentation_scores(missing, truth)]
    )
    assert pooled["recall"] == pytest.approx(7 / 8)
    assert pooled["mean_iou"] == 1.0


def test_label_input_errors():
    truth = _rock_labels(boxes=BOXES)
    with pytest.raises(TypeError, match="integer label image"):
        match_objects(truth.astype(np.float32), truth)
    with pytest.raises(ValueError, match=">= 0"):
        match_objects(truth - 1, truth)
    with pytest.raises(ValueError, match="iou_threshold"):
        match_objects(truth, truth, iou_threshold=0)


# ------------------------------------------------------------------------- descriptors
def _rock_columns(n=5):
    return {
        "height_m": np.linspace(0.02, 0.3, n),
        "height_max_m": np.linspace(0.02, 0.3, n),
        "width_m": np.linspace(0.05, 0.5, n),
        "range_m": np.linspace(1.0, 3.0, n),
        "size_class": np.array(["sample", "sample", "obstacle", "obstacle", "obstacle"][:n]),
    }


def test_perfect_descriptors_have_zero_error():
    truth = _rock_columns()
    e = descriptor_errors(dict(truth), truth)
    assert e["height_abs_err_median_m"] == 0.0 and e["width_rel_err_p90"] == 0.0
    assert e["class_accuracy"] == 1.0 and e["n_rocks"] == 5
    assert e["near_n_rocks"] == 3  # ranges 1.0, 1.5, 2.0


def test_descriptor_errors_known_values():
    truth = _rock_columns()
    pred = {k: np.array(v, copy=True) for k, v in truth.items()}
    pred["height_max_m"] = truth["height_m"] + np.array([0.01, -0.01, 0.02, 0.0, 0.05])
    pred["width_m"] = truth["width_m"] * 1.1
    pred["range_m"] = truth["range_m"] * np.array([1.0, 1.0, 1.0, 0.9, np.nan])
    pred["size_class"] = np.array(["sample", "obstacle", "obstacle", "obstacle", "obstacle"])
    e = descriptor_errors(pred, truth)
    assert e["height_abs_err_median_m"] == pytest.approx(0.01)
    assert e["width_rel_err_median"] == pytest.approx(0.1)
    assert e["range_rel_err_median"] == pytest.approx(0.0)  # NaN left out: [0, 0, 0, 0.1]
    assert e["class_accuracy"] == pytest.approx(4 / 5)
    assert e["near_class_accuracy"] == pytest.approx(2 / 3)
    assert e["near_height_abs_err_p90_m"] == pytest.approx(np.percentile([0.01, 0.01, 0.02], 90))


def test_descriptor_errors_border_breakdown():
    truth = _rock_columns()  # ranges 1.0, 1.5, 2.0 within 2 m, then 2.5, 3.0
    pred = {k: np.array(v, copy=True) for k, v in truth.items()}
    pred["width_m"] = truth["width_m"] * np.array([1.0, 0.5, 1.2, 1.0, 1.0])
    pred["size_class"] = np.array(["sample", "sample", "sample", "obstacle", "obstacle"])
    headline = descriptor_errors(pred, truth)
    assert not any(k.startswith(("near_interior_", "near_border_")) for k in headline)
    truth["touches_border"] = np.array([False, True, False, True, False])
    e = descriptor_errors(pred, truth)
    assert {k: v for k, v in e.items() if k in headline} == headline  # headline unchanged
    assert e["near_border_n_rocks"] == 1 and e["near_interior_n_rocks"] == 2
    assert e["near_border_width_rel_err_median"] == pytest.approx(0.5)
    assert e["near_interior_width_rel_err_median"] == pytest.approx(0.1)  # 0 and 0.2
    assert e["near_interior_class_accuracy"] == pytest.approx(1 / 2)
    truth["touches_border"] = np.array([0.0, 1.0, np.nan, 0.0, 0.0])  # unknown: no breakdown
    assert "near_border_n_rocks" not in descriptor_errors(pred, truth)


def test_descriptor_errors_decided_class_leaves_the_borderline_rocks_out():
    truth = _rock_columns()  # classes sample, sample, obstacle x 3; the first 3 within 2 m
    pred = {k: np.array(v, copy=True) for k, v in truth.items()}
    # rocks 0 and 3 borderline; wrong: 0 and 3 (borderline) and 2 (decided)
    pred["size_class"] = np.array(["obstacle", "sample", "sample", "sample", "obstacle"])
    headline = descriptor_errors(pred, truth)
    assert not any("borderline" in k or "decided" in k for k in headline)
    pred["size_class_borderline"] = np.array([True, False, False, True, False])
    e = descriptor_errors(pred, truth)
    assert {k: v for k, v in e.items() if k in headline} == headline  # headline unchanged
    assert e["class_accuracy"] == pytest.approx(2 / 5)
    assert e["borderline_fraction"] == pytest.approx(2 / 5)
    assert e["decided_class_accuracy"] == pytest.approx(2 / 3)  # rocks 1, 2, 4
    assert e["decided_n_rocks"] == 3
    assert e["near_borderline_fraction"] == pytest.approx(1 / 3)
    assert e["near_decided_class_accuracy"] == pytest.approx(1 / 2)  # rocks 1, 2
    assert e["near_decided_n_rocks"] == 2
    # 0/1 floats as the evaluation reads them from Parquet
    pred["size_class_borderline"] = np.array([1.0, 0.0, 0.0, 1.0, 0.0])
    assert descriptor_errors(pred, truth) == e
    # every rock borderline: nothing decided
    pred["size_class_borderline"] = np.ones(5, dtype=bool)
    e = descriptor_errors(pred, truth)
    assert e["borderline_fraction"] == 1.0 and e["decided_n_rocks"] == 0
    assert math.isnan(e["decided_class_accuracy"])
    # unknown (descriptors of a describe without the column): no decided figures
    pred["size_class_borderline"] = np.array([0.0, np.nan, 0.0, 1.0, 0.0])
    assert descriptor_errors(pred, truth) == headline
    with pytest.raises(ValueError, match="size_class_borderline"):
        descriptor_errors({**pred, "size_class_borderline": np.zeros(4)}, truth)


def test_descriptor_errors_no_pairs_and_bad_input():
    empty = {k: v[:0] for k, v in _rock_columns().items()}
    e = descriptor_errors(empty, empty)
    assert e["n_rocks"] == 0 and math.isnan(e["height_abs_err_median_m"])
    with pytest.raises(ValueError, match="height_max_m"):
        descriptor_errors({"height_m": []}, _rock_columns())


# --------------------------------------------------------------------------- relations
def test_relation_agreement_against_truth_positions():
    rel = np.array(["left_of", "right_of", "in_front_of", "behind", "adjacent", "left_of"])
    subject = {
        "x_m": np.array([0.0, 1.0, 0.0, 0.0, 0.0, 2.0]),
        "y_m": np.array([0, 0, 1, 3, 0, 0.0]),
    }
    object_ = {
        "x_m": np.array([1.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
        "y_m": np.array([0, 0, 2, 2, 0, 0.0]),
    }
    a = relation_agreement(rel, subject, object_)
    assert a["n_checked"] == 5 and a["n_unchecked"] == 1
    assert a["agreement"] == pytest.approx(4 / 5)
    assert a["agreement_left_of"] == 0.5


def test_true_occlusions_from_range_map():
    labels = np.zeros((20, 20), dtype=np.int32)
    labels[5:15, 2:10] = 1
    labels[5:15, 10:18] = 2
    rng = np.where(labels == 1, 1.0, np.where(labels == 2, 2.0, 5.0))
    assert true_occlusions(labels, rng) == {(1, 2)}
    rel = np.array(["occludes", "occludes"])
    pos = {"x_m": np.zeros(2), "y_m": np.zeros(2)}
    a = relation_agreement(rel, pos, pos, occludes_truth=np.array([True, False]))
    assert a["agreement"] == 0.5
    assert relation_agreement(rel, pos, pos)["n_checked"] == 0


@st.composite
def _label_images(draw):
    """Two 24x24 label images of up to 6 random (possibly overlapping) rectangles each."""
    images = []
    for _ in range(2):
        labels = np.zeros((24, 24), dtype=np.int32)
        for k in range(1, draw(st.integers(0, 6)) + 1):
            y0, x0 = draw(st.integers(0, 20)), draw(st.integers(0, 20))
            h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
            labels[y0 : y0 + h, x0 : x0 + w] = k
        images.append(labels)
    return images


@settings(max_examples=60, deadline=None)
@given(images=_label_images())
def test_matching_invariants(images):
    pred, truth = images
    m = match_objects(pred, truth, min_true_px=0)
    assert len(set(m.pred_ids.tolist())) == m.tp == len(set(m.true_ids.tolist()))
    assert np.all(m.iou >= 0.5)
    for p, t, iou in zip(m.pred_ids, m.true_ids, m.iou, strict=True):
        inter = np.count_nonzero((pred == p) & (truth == t))
        union = np.count_nonzero((pred == p) | (truth == t))
        assert iou == pytest.approx(inter / union)
    assert m.n_pred == len(np.unique(pred[pred > 0])) and m.n_true == len(
        np.unique(truth[truth > 0])
    )
    swapped = match_objects(truth, pred, min_true_px=0)
    assert swapped.tp == m.tp  # matching at IoU >= 0.5 does not depend on which side is truth
    assert segmentation_scores(truth, truth, min_true_px=0)["fp"] == 0


# --------------------------------------------------------------------------- intervals
def _wilson_roots(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson bounds by another route: the roots p of (p_hat - p)^2 = z^2 p (1 - p) / n,
    with z from scipy rather than statistics.NormalDist."""
    from scipy.stats import norm

    z = norm.ppf(1 - (1 - confidence) / 2)
    p_hat, n = successes / trials, trials
    a, b, c = 1 + z**2 / n, -(2 * p_hat + z**2 / n), p_hat**2
    disc = math.sqrt(b * b - 4 * a * c)
    return (-b - disc) / (2 * a), (-b + disc) / (2 * a)


@pytest.mark.parametrize(
    ("successes", "trials", "expected"),
    [
        # Newcombe (1998), Statistics in Medicine 17:857, Table I, method 3 (score, no
        # continuity correction), rounded to 4 decimals there
        (81, 263, (0.2553, 0.3662)),
        (15, 148, (0.0624, 0.1605)),
        (0, 20, (0.0, 0.1611)),
        (1, 29, (0.0061, 0.1718)),
    ],
)
def test_wilson_interval_published_values(successes, trials, expected):
    low, high = wilson_interval(successes, trials)
    assert (round(low, 4), round(high, 4)) == expected


@pytest.mark.parametrize(("successes", "trials"), [(54, 58), (1, 2), (3, 7), (99, 100)])
def test_wilson_interval_solves_the_score_equation(successes, trials):
    assert wilson_interval(successes, trials) == pytest.approx(
        _wilson_roots(successes, trials), rel=1e-9
    )


def test_wilson_interval_closed_forms_at_the_ends():
    z = 1.959963984540054  # the 97.5 % normal quantile
    for n in (1, 10, 58):
        assert wilson_interval(0, n) == (0.0, pytest.approx(z**2 / (n + z**2)))
        assert wilson_interval(n, n) == (pytest.approx(n / (n + z**2)), 1.0)
    low, high = wilson_interval(1, 2)  # symmetric about 1/2
    assert low + high == pytest.approx(1.0)
    assert (round(100 * low, 1), round(100 * high, 1)) == (9.5, 90.5)


def test_wilson_interval_of_the_lab_near_class_accuracy():
    # 54 of 58 near rocks classed right: "93.1 %" is 83.6-97.3 % at 95 %
    low, high = wilson_interval(54, 58)
    assert (round(100 * low, 1), round(100 * high, 1)) == (83.6, 97.3)


def test_wilson_interval_without_trials_and_with_float_counts():
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    assert wilson_interval(54.0, 58.0) == wilson_interval(54, 58)  # pooled counts are floats
    assert wilson_interval(np.int64(54), np.int64(58)) == wilson_interval(54, 58)


def test_wilson_interval_confidence():
    narrow, wide = wilson_interval(54, 58, confidence=0.8), wilson_interval(54, 58, confidence=0.99)
    assert wide[0] < narrow[0] < narrow[1] < wide[1]
    assert wilson_interval(54, 58, confidence=0.9) == pytest.approx(
        _wilson_roots(54, 58, 0.9), rel=1e-9
    )


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        ((-1, 10), {}, ValueError, "successes must be a whole number >= 0, got -1"),
        ((1, -10), {}, ValueError, "trials must be a whole number >= 0, got -10"),
        ((11, 10), {}, ValueError, "at most trials, got 11 successes of 10 trials"),
        ((0.5, 10), {}, ValueError, "not a rate"),
        ((float("nan"), 10), {}, ValueError, "whole number"),
        ((1, 10), {"confidence": 0.0}, ValueError, r"confidence must be in \(0, 1\), got 0.0"),
        ((1, 10), {"confidence": 1.0}, ValueError, r"confidence must be in \(0, 1\)"),
        ((1, 10), {"confidence": 95}, ValueError, "e.g. 0.95 for a 95 % interval"),
        (("1", 10), {}, TypeError, "successes must be a count"),
        ((True, 10), {}, TypeError, "successes must be a count"),
        ((1, 10), {"confidence": "0.95"}, TypeError, "confidence must be a number"),
    ],
)
def test_wilson_interval_input_errors(args, kwargs, error, match):
    with pytest.raises(error, match=match):
        wilson_interval(*args, **kwargs)


@settings(max_examples=200, deadline=None)
@given(
    trials=st.integers(1, 10_000),
    share=st.floats(0.0, 1.0),
    confidence=st.floats(0.5, 0.999),
    scale=st.integers(2, 10),
)
def test_wilson_interval_properties(trials, share, confidence, scale):
    successes = round(share * trials)
    low, high = wilson_interval(successes, trials, confidence=confidence)
    assert 0.0 <= low <= successes / trials <= high <= 1.0
    assert low < high
    # the same proportion on more trials is known more narrowly
    more = wilson_interval(scale * successes, scale * trials, confidence=confidence)
    assert more[1] - more[0] < high - low
    # failures are successes seen the other way round
    flipped = wilson_interval(trials - successes, trials, confidence=confidence)
    assert flipped[0] == pytest.approx(1 - high, abs=1e-12)
    assert flipped[1] == pytest.approx(1 - low, abs=1e-12)
