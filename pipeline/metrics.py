"""Scores of arroyo's products against ground truth: pure functions, arrays in, numbers out.

Conventions (the answer to "what exactly does bad-2 mean here"):

* **Depth** is scored on the *non-occluded* truth pixels (the "noc" convention of the stereo
  benchmarks): pixels whose truth disparity is finite and > 0 and that the other camera sees.
  An occluded pixel has no correct match, so no method can be right or wrong there. A
  prediction that is NaN (invalid) on a scored pixel counts as bad for bad-1 and bad-2 and
  lowers the density; the end-point error is averaged only where both are valid.
* **Segmentation** matches predicted objects to truth rocks one-to-one at IoU >= 0.5 (above
  0.5 a match is unique anyway; exact ties at 0.5 are resolved by a maximum matching). Only
  truth rocks with at least ``min_true_px`` visible pixels count. A predicted object that
  matches an ignored (too small) rock, or lies for at least half of its area on ignored rocks,
  is neither a true nor a false positive: it found a real rock the benchmark chose not to
  grade.
* **Descriptors** are compared on matched (predicted, truth) rock pairs; errors pool over all
  pairs (medians do not average across frames).
* **Relations** are checked against the truth geometry of the matched rocks (see
  :func:`relation_agreement`).
* **Intervals**: a proportion over a count (precision, recall, class accuracy, agreement)
  comes with its Wilson score interval (:func:`wilson_interval`), which stays inside [0, 1]
  and keeps a sensible width at 0 or n successes, where the normal approximation collapses.

Each per-frame result carries the counts it came from, so the ``pool_*`` functions combine
frames exactly (a pooled bad-2 rate is over all pixels, not a mean of per-frame rates).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from numbers import Real
from statistics import NormalDist

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = [
    "ObjectMatches",
    "disparity_errors",
    "pool_disparity_errors",
    "match_objects",
    "segmentation_scores",
    "pool_segmentation_scores",
    "descriptor_errors",
    "true_occlusions",
    "relation_agreement",
    "CHECKED_RELATIONS",
    "wilson_interval",
]

#: Relations :func:`relation_agreement` checks; ``adjacent`` is not checked (its gap tolerance
#: is a parameter of the describe stage and the truth has no notion of it).
CHECKED_RELATIONS: tuple[str, ...] = ("left_of", "right_of", "in_front_of", "behind", "occludes")


# --------------------------------------------------------------------------- coercion helpers
def _coerce_image(name: str, value: object, *, kind: str) -> np.ndarray:
    """A 2-D array; ``kind`` 'float' converts to float64, 'label' checks non-negative ints."""
    if not isinstance(value, np.ndarray):
        raise TypeError(f"{name} must be a numpy ndarray, got {type(value).__name__}")
    if value.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (M, N) array, got shape {value.shape}")
    if kind == "float":
        if not (np.issubdtype(value.dtype, np.floating) or np.issubdtype(value.dtype, np.integer)):
            raise TypeError(f"{name} must hold numbers (float), got dtype {value.dtype}")
        return value.astype(np.float64, copy=False)
    if not np.issubdtype(value.dtype, np.integer):
        raise TypeError(
            f"{name} must be an integer label image (0 = background), got dtype {value.dtype}; "
            "cast it with .astype(np.int32)"
        )
    if value.size and value.min() < 0:
        raise ValueError(f"{name} must have labels >= 0 (0 = background), got {value.min()}")
    return value.astype(np.int64, copy=False)


def _coerce_same_shape(a: np.ndarray, b: np.ndarray, names: str) -> None:
    if a.shape != b.shape:
        raise ValueError(f"{names} must have the same shape, got {a.shape} and {b.shape}")


def _ratio(num: float, den: float) -> float:
    return float(num) / float(den) if den > 0 else float("nan")


# --------------------------------------------------------------------------------- depth
def disparity_errors(
    pred: np.ndarray, truth: np.ndarray, *, valid_truth: np.ndarray | None = None
) -> dict[str, float]:
    """Stereo benchmark errors of a disparity map against the truth.

    Parameters
    ----------
    pred : (M, N) ndarray of float
        Predicted disparity in pixels, NaN where invalid.
    truth : (M, N) ndarray of float
        True disparity in pixels; pixels where it is not finite or not > 0 are not scored.
    valid_truth : (M, N) ndarray of bool, optional
        Pixels to score in addition to the finiteness rule; pass ``~occluded`` for the
        non-occluded ("noc") convention used by ``arroyo evaluate``.

    Returns
    -------
    errors : dict of str to float
        ``bad1``, ``bad2``: share of scored pixels whose prediction is off by more than 1 / 2
        px, invalid predictions counting as bad; ``epe``: mean absolute error over scored pixels
        with a valid prediction; ``density``: share of scored pixels with a valid prediction;
        ``n_px``, ``n_valid``, ``n_bad1``, ``n_bad2``, ``abs_err_sum``: the counts behind them
        (for :func:`pool_disparity_errors`). Rates are NaN when no pixel is scored.
    """
    p = _coerce_image("pred", pred, kind="float")
    t = _coerce_image("truth", truth, kind="float")
    _coerce_same_shape(p, t, "pred and truth")
    scored = np.isfinite(t) & (t > 0)
    if valid_truth is not None:
        if not isinstance(valid_truth, np.ndarray) or valid_truth.dtype != np.bool_:
            raise TypeError(
                "valid_truth must be a boolean ndarray (True = score this pixel), got "
                f"{type(valid_truth).__name__} {getattr(valid_truth, 'dtype', '')}"
            )
        _coerce_same_shape(valid_truth, t, "valid_truth and truth")
        scored &= valid_truth
    err = np.abs(p[scored] - t[scored])
    valid = np.isfinite(err)
    counts = {
        "n_px": float(err.size),
        "n_valid": float(np.count_nonzero(valid)),
        # NaN comparisons are False, so "not within tolerance" counts invalid pixels as bad
        "n_bad1": float(err.size - np.count_nonzero(err <= 1.0)),
        "n_bad2": float(err.size - np.count_nonzero(err <= 2.0)),
        "abs_err_sum": float(err[valid].sum()),
    }
    return _disparity_rates(counts)


def _disparity_rates(counts: Mapping[str, float]) -> dict[str, float]:
    n_px, n_valid = counts["n_px"], counts["n_valid"]
    return {
        "bad1": _ratio(counts["n_bad1"], n_px),
        "bad2": _ratio(counts["n_bad2"], n_px),
        "epe": _ratio(counts["abs_err_sum"], n_valid),
        "density": _ratio(n_valid, n_px),
        **{k: float(counts[k]) for k in ("n_px", "n_valid", "n_bad1", "n_bad2", "abs_err_sum")},
    }


def pool_disparity_errors(per_frame: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Combine results of :func:`disparity_errors` over frames, pixel-weighted.

    Parameters
    ----------
    per_frame : iterable of dict
        Results of :func:`disparity_errors`.

    Returns
    -------
    errors : dict of str to float
        Same keys as :func:`disparity_errors`, over all pixels of all frames.
    """
    keys = ("n_px", "n_valid", "n_bad1", "n_bad2", "abs_err_sum")
    total = dict.fromkeys(keys, 0.0)
    for result in per_frame:
        for k in keys:
            total[k] += float(result[k])
    return _disparity_rates(total)


# --------------------------------------------------------------------------- segmentation
@dataclass(frozen=True)
class ObjectMatches:
    """One-to-one matches between predicted objects and truth rocks of one frame.

    Attributes
    ----------
    pred_ids, true_ids : (K,) ndarray of int64
        Matched pairs (true positives): predicted object ``pred_ids[i]`` is truth rock
        ``true_ids[i]``. Only graded truth rocks appear here.
    iou : (K,) ndarray of float64
        Intersection over union of each pair.
    n_true : int
        Graded truth rocks (at least ``min_true_px`` visible pixels).
    n_pred : int
        Predicted objects that are graded (not ignored).
    ignored_true_ids, ignored_pred_ids : ndarray of int64
        Truth rocks too small to grade, and predicted objects ignored because they found one.
    """

    pred_ids: np.ndarray
    true_ids: np.ndarray
    iou: np.ndarray
    n_true: int
    n_pred: int
    ignored_true_ids: np.ndarray
    ignored_pred_ids: np.ndarray

    @property
    def tp(self) -> int:
        return int(self.pred_ids.size)

    @property
    def fp(self) -> int:
        return self.n_pred - self.tp

    @property
    def fn(self) -> int:
        return self.n_true - self.tp

    def scores(self) -> dict[str, float]:
        """The scores of :func:`segmentation_scores` for these matches."""
        return _segmentation_rates(self.tp, self.fp, self.fn, float(self.iou.sum()))


def _present_ids(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ids > 0 present in ``labels`` and a dense index image (0 = background, 1..n = ids)."""
    counts = np.bincount(labels.ravel())
    ids = np.flatnonzero(counts)
    ids = ids[ids > 0]
    lookup = np.zeros(counts.size, dtype=np.int64)
    lookup[ids] = np.arange(1, ids.size + 1)
    return ids, lookup[labels]


def _one_to_one(iou: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Most pairs with IoU >= threshold, each object used once; ties broken by total IoU.

    Above IoU 0.5 a match is unique anyway; at exactly 0.5 an object can have two candidates
    (a rock split in equal halves), and a maximum matching keeps the count independent of
    label order and of which side is the truth.
    """
    rows = np.flatnonzero((iou >= threshold).any(axis=1))
    cols = np.flatnonzero((iou >= threshold).any(axis=0))
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    sub = iou[np.ix_(rows, cols)]
    candidate = sub >= threshold
    # a pair is worth more than any IoU total, so the count is maximised first
    weight = np.where(candidate, min(sub.shape) + 1.0 + sub, 0.0)
    r, c = linear_sum_assignment(weight, maximize=True)
    keep = candidate[r, c]
    return rows[r[keep]].astype(np.int64), cols[c[keep]].astype(np.int64)


def match_objects(
    pred_labels: np.ndarray,
    true_labels: np.ndarray,
    *,
    iou_threshold: float = 0.5,
    min_true_px: int = 30,
) -> ObjectMatches:
    """Match predicted objects to truth rocks one-to-one by intersection over union.

    Parameters
    ----------
    pred_labels : (M, N) ndarray of int
        Predicted instance labels, 0 = background, k > 0 = object k (need not be dense).
    true_labels : (M, N) ndarray of int
        Truth instance labels, same convention.
    iou_threshold : float
        Minimum IoU of a match, in (0, 1]; 0.5 by default.
    min_true_px : int
        Truth rocks with fewer visible pixels are not graded (see module docstring), >= 0.

    Returns
    -------
    matches : ObjectMatches
        The true-positive pairs and the counts for precision and recall.
    """
    pred = _coerce_image("pred_labels", pred_labels, kind="label")
    true = _coerce_image("true_labels", true_labels, kind="label")
    _coerce_same_shape(pred, true, "pred_labels and true_labels")
    if not isinstance(iou_threshold, int | float) or not 0 < iou_threshold <= 1:
        raise ValueError(f"iou_threshold must be a number in (0, 1], got {iou_threshold!r}")
    if isinstance(min_true_px, bool) or not isinstance(min_true_px, int) or min_true_px < 0:
        raise ValueError(f"min_true_px must be an int >= 0, got {min_true_px!r}")

    pred_ids, pred_idx = _present_ids(pred)
    true_ids, true_idx = _present_ids(true)
    n_p, n_t = pred_ids.size + 1, true_ids.size + 1
    # contingency table: inter[i, j] = pixels of dense pred object i on dense truth rock j
    inter = np.bincount((pred_idx * n_t + true_idx).ravel(), minlength=n_p * n_t)
    inter = inter.reshape(n_p, n_t).astype(np.float64)
    area_p, area_t = inter.sum(axis=1), inter.sum(axis=0)
    inter, area_p, area_t = inter[1:, 1:], area_p[1:], area_t[1:]
    union = area_p[:, None] + area_t[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)

    graded_t = area_t >= min_true_px
    pairs_p_arr, pairs_t_arr = _one_to_one(iou, iou_threshold)
    tp_mask = graded_t[pairs_t_arr]
    on_ignored = inter[:, ~graded_t].sum(axis=1)
    ignored_p = (on_ignored >= 0.5 * area_p) & (area_p > 0)
    ignored_p[pairs_p_arr[~tp_mask]] = True
    # a match with a graded rock outranks the "mostly on small rocks" rule
    ignored_p[pairs_p_arr[tp_mask]] = False
    tp_p, tp_t = pairs_p_arr[tp_mask], pairs_t_arr[tp_mask]
    return ObjectMatches(
        pred_ids=pred_ids[tp_p],
        true_ids=true_ids[tp_t],
        iou=iou[tp_p, tp_t],
        n_true=int(np.count_nonzero(graded_t)),
        n_pred=int(pred_ids.size - np.count_nonzero(ignored_p)),
        ignored_true_ids=true_ids[~graded_t],
        ignored_pred_ids=pred_ids[ignored_p],
    )


def segmentation_scores(
    pred_labels: np.ndarray,
    true_labels: np.ndarray,
    *,
    iou_threshold: float = 0.5,
    min_true_px: int = 30,
) -> dict[str, float]:
    """Object precision, recall, F1 and mean IoU of a label image against the truth.

    Parameters
    ----------
    pred_labels, true_labels : (M, N) ndarray of int
        Instance labels, 0 = background.
    iou_threshold : float
        Minimum IoU of a match, in (0, 1].
    min_true_px : int
        Truth rocks with fewer visible pixels are not graded.

    Returns
    -------
    scores : dict of str to float
        ``precision`` = tp / (tp + fp), ``recall`` = tp / (tp + fn), ``f1``, ``mean_iou`` (of the
        matched pairs), and the counts ``tp``, ``fp``, ``fn``, ``iou_sum``. A rate whose
        denominator is 0 is NaN (no predictions: precision undefined, and fp = 0 says so).
    """
    return match_objects(
        pred_labels, true_labels, iou_threshold=iou_threshold, min_true_px=min_true_px
    ).scores()


def _segmentation_rates(tp: float, fp: float, fn: float, iou_sum: float) -> dict[str, float]:
    precision, recall = _ratio(tp, tp + fp), _ratio(tp, tp + fn)
    return {
        "precision": precision,
        "recall": recall,
        "f1": _ratio(2 * tp, 2 * tp + fp + fn),
        "mean_iou": _ratio(iou_sum, tp),
        "tp": float(tp),
        "fp": float(fp),
        "fn": float(fn),
        "iou_sum": float(iou_sum),
    }


def pool_segmentation_scores(per_frame: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Combine results of :func:`segmentation_scores` over frames (object counts summed).

    Parameters
    ----------
    per_frame : iterable of dict
        Results of :func:`segmentation_scores`.

    Returns
    -------
    scores : dict of str to float
        Same keys as :func:`segmentation_scores`, over all objects of all frames.
    """
    tp = fp = fn = iou_sum = 0.0
    for r in per_frame:
        tp, fp, fn = tp + r["tp"], fp + r["fp"], fn + r["fn"]
        iou_sum += r["iou_sum"]
    return _segmentation_rates(tp, fp, fn, iou_sum)


# ----------------------------------------------------------------------------- descriptors
def _coerce_column(columns: Mapping[str, object], name: str, where: str, n: int | None):
    if name not in columns:
        raise ValueError(f"{where} needs a column {name!r}; got columns {sorted(columns)}")
    col = np.asarray(columns[name])
    if col.ndim != 1 or (n is not None and col.size != n):
        raise ValueError(
            f"{where}[{name!r}] must be a 1-D array of the matched pairs"
            + (f" (length {n})" if n is not None else "")
            + f", got shape {col.shape}"
        )
    return col


def _quantiles(values: np.ndarray, prefix: str, unit: str) -> dict[str, float]:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {f"{prefix}_median{unit}": float("nan"), f"{prefix}_p90{unit}": float("nan")}
    med, p90 = np.percentile(finite, [50, 90])
    return {f"{prefix}_median{unit}": float(med), f"{prefix}_p90{unit}": float(p90)}


def descriptor_errors(
    pred: Mapping[str, object], truth: Mapping[str, object], *, near_range_m: float = 2.0
) -> dict[str, float]:
    """Errors of per-rock descriptors on matched (predicted, truth) rock pairs.

    Parameters
    ----------
    pred : mapping of str to (K,) array
        Descriptor columns of the matched predicted objects, row i matching truth row i:
        ``height_max_m``, ``height_m`` (the study's height of the farthest perceivable point),
        ``width_m``, ``range_m`` (float, NaN where unknown) and ``size_class``
        ({'sample', 'obstacle'}); optionally ``size_class_borderline`` (bool, or 0/1
        floats): the measurement could not decide the class (the describe column).
    truth : mapping of str to (K,) array
        Truth rock columns: ``height_m`` (highest point above ground), ``width_m``,
        ``range_m``, ``size_class``; optionally ``touches_border`` (bool, or 0/1 floats):
        the rock's visible region reaches the image border, so only part of it is seen.
    near_range_m : float
        Also report every error restricted to rocks whose truth range is at most this (m).

    Returns
    -------
    errors : dict of str to float
        ``height_abs_err_{median,p90}_m`` (``height_max_m`` against the truth height),
        ``study_height_abs_err_{median,p90}_m`` (``height_m`` against the same truth: the
        study's height is of the farthest visible point, so it can only be lower),
        ``width_rel_err_{median,p90}``, ``range_rel_err_{median,p90}`` (|pred - truth| / truth),
        ``class_accuracy``, ``n_rocks``; then the same keys prefixed ``near_`` for rocks within
        ``near_range_m``. NaN predictions are left out of the quantiles (``n_rocks`` counts
        pairs, so compare with it); all NaN when there are no pairs. With a finite truth
        ``touches_border`` column, a breakdown of the ``near_`` rocks follows: the same keys
        prefixed ``near_interior_`` (rocks seen whole) and ``near_border_`` (rocks cut by
        the image border, whose truth width and class are of the whole rock while only a
        part of it can be measured). With a finite pred ``size_class_borderline`` column,
        every block (prefix ``''``, ``near_``, ...) also has ``borderline_fraction`` (share
        of its rocks whose class is borderline), ``decided_class_accuracy`` (class accuracy
        over the others) and ``decided_n_rocks`` (their count). The headline keys do not
        change.
    """
    if not isinstance(pred, Mapping) or not isinstance(truth, Mapping):
        raise TypeError(
            "pred and truth must be mappings of column name to 1-D arrays (e.g. dicts or "
            f"pyarrow tables converted with .to_pydict()), got {type(pred).__name__} and "
            f"{type(truth).__name__}"
        )
    if not isinstance(near_range_m, int | float) or not near_range_m > 0:
        raise ValueError(f"near_range_m must be a number > 0, got {near_range_m!r}")
    t_range = _coerce_column(truth, "range_m", "truth", None).astype(np.float64)
    n = t_range.size
    cols = {
        "p_hmax": _coerce_column(pred, "height_max_m", "pred", n).astype(np.float64),
        "p_h": _coerce_column(pred, "height_m", "pred", n).astype(np.float64),
        "p_w": _coerce_column(pred, "width_m", "pred", n).astype(np.float64),
        "p_r": _coerce_column(pred, "range_m", "pred", n).astype(np.float64),
        "p_c": _coerce_column(pred, "size_class", "pred", n).astype(str),
        "t_h": _coerce_column(truth, "height_m", "truth", n).astype(np.float64),
        "t_w": _coerce_column(truth, "width_m", "truth", n).astype(np.float64),
        "t_r": t_range,
        "t_c": _coerce_column(truth, "size_class", "truth", n).astype(str),
    }
    if "size_class_borderline" in pred:
        borderline = _coerce_column(pred, "size_class_borderline", "pred", n).astype(np.float64)
        if np.isfinite(borderline).all():  # NaN: a run from before the column (describe < 11)
            cols["p_b"] = borderline != 0
    out = _descriptor_block(cols, np.ones(n, dtype=bool), "")
    near = t_range <= near_range_m
    out.update(_descriptor_block(cols, near, "near_"))
    if "touches_border" in truth:
        border = _coerce_column(truth, "touches_border", "truth", n).astype(np.float64)
        if np.isfinite(border).all():
            out.update(_descriptor_block(cols, near & (border == 0), "near_interior_"))
            out.update(_descriptor_block(cols, near & (border != 0), "near_border_"))
    return out


def _descriptor_block(c: dict[str, np.ndarray], keep: np.ndarray, prefix: str) -> dict[str, float]:
    def rel(p: np.ndarray, t: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(p - t) / np.abs(t)

    s = {k: v[keep] for k, v in c.items()}
    out: dict[str, float] = {}
    out.update(_quantiles(np.abs(s["p_hmax"] - s["t_h"]), f"{prefix}height_abs_err", "_m"))
    out.update(_quantiles(np.abs(s["p_h"] - s["t_h"]), f"{prefix}study_height_abs_err", "_m"))
    out.update(_quantiles(rel(s["p_w"], s["t_w"]), f"{prefix}width_rel_err", ""))
    out.update(_quantiles(rel(s["p_r"], s["t_r"]), f"{prefix}range_rel_err", ""))
    n = int(keep.sum())
    out[f"{prefix}class_accuracy"] = _ratio(int(np.count_nonzero(s["p_c"] == s["t_c"])), n)
    out[f"{prefix}n_rocks"] = float(n)
    if "p_b" in s:
        decided = ~s["p_b"]
        n_decided = int(np.count_nonzero(decided))
        right = np.count_nonzero((s["p_c"] == s["t_c"]) & decided)
        out[f"{prefix}borderline_fraction"] = _ratio(n - n_decided, n)
        out[f"{prefix}decided_class_accuracy"] = _ratio(int(right), n_decided)
        out[f"{prefix}decided_n_rocks"] = float(n_decided)
    return out


# ------------------------------------------------------------------------------ relations
def true_occlusions(
    true_labels: np.ndarray, true_range: np.ndarray, *, min_boundary_px: int = 3
) -> set[tuple[int, int]]:
    """Which truth rock occludes which, from the truth labels and range map.

    Along every boundary between two rocks' visible regions (4-neighbour pixel pairs), the rock
    whose surface is nearer there occludes the other. A pair is reported when the nearer-side
    votes outnumber the others and the shared boundary has at least ``min_boundary_px`` pixel
    pairs.

    Parameters
    ----------
    true_labels : (M, N) ndarray of int
        Truth instance labels, 0 = ground.
    true_range : (M, N) ndarray of float
        Truth range (m) in the same geometry.
    min_boundary_px : int
        Shortest shared boundary that counts, >= 1.

    Returns
    -------
    pairs : set of (int, int)
        ``(occluder_id, occluded_id)``.
    """
    labels = _coerce_image("true_labels", true_labels, kind="label")
    rng = _coerce_image("true_range", true_range, kind="float")
    _coerce_same_shape(labels, rng, "true_labels and true_range")
    if isinstance(min_boundary_px, bool) or not isinstance(min_boundary_px, int):
        raise TypeError(f"min_boundary_px must be an int, got {min_boundary_px!r}")
    if min_boundary_px < 1:
        raise ValueError(f"min_boundary_px must be >= 1, got {min_boundary_px}")
    near, far = [], []
    for a_lab, b_lab, a_rng, b_rng in (
        (labels[:, :-1], labels[:, 1:], rng[:, :-1], rng[:, 1:]),
        (labels[:-1, :], labels[1:, :], rng[:-1, :], rng[1:, :]),
    ):
        edge = (
            (a_lab != b_lab) & (a_lab > 0) & (b_lab > 0) & np.isfinite(a_rng) & np.isfinite(b_rng)
        )
        a, b, ra, rb = a_lab[edge], b_lab[edge], a_rng[edge], b_rng[edge]
        near.append(np.where(ra < rb, a, b))
        far.append(np.where(ra < rb, b, a))
    near_ids, far_ids = np.concatenate(near), np.concatenate(far)
    if near_ids.size == 0:
        return set()
    votes: dict[tuple[int, int], int] = {}
    pairs, counts = np.unique(np.stack([near_ids, far_ids], axis=1), axis=0, return_counts=True)
    for (a, b), k in zip(pairs.tolist(), counts.tolist(), strict=True):
        votes[(a, b)] = k
    result = set()
    for (a, b), k in votes.items():
        against = votes.get((b, a), 0)
        if k > against and k + against >= min_boundary_px:
            result.add((a, b))
    return result


def relation_agreement(
    relation: np.ndarray,
    subject: Mapping[str, object],
    object_: Mapping[str, object],
    *,
    occludes_truth: np.ndarray | None = None,
) -> dict[str, float]:
    """Share of scene-graph edges that agree with the truth geometry of their rocks.

    Each edge ``subject relation object`` is checked on the truth rocks the two predicted
    objects matched: ``left_of`` / ``right_of`` compare the truth ground x (``x_m``),
    ``in_front_of`` / ``behind`` the truth ground y (``y_m``, forward; in front = nearer,
    smaller y); ``occludes`` must be true in ``occludes_truth`` (from :func:`true_occlusions`).
    Strict comparisons: the describe stage puts no edge on near-ties, so a truth tie is a
    disagreement. ``adjacent`` edges (and ``occludes`` when ``occludes_truth`` is None) are
    not checked.

    Parameters
    ----------
    relation : (E,) ndarray of str
        Relation of each edge.
    subject, object_ : mapping of str to (E,) array of float
        Truth ground position of the subject's and the object's rock: ``x_m``, ``y_m``.
    occludes_truth : (E,) ndarray of bool, optional
        Whether the truth subject rock occludes the truth object rock, per edge.

    Returns
    -------
    agreement : dict of str to float
        ``agreement`` (share of checked edges that agree, NaN when none), ``n_checked``,
        ``n_agree``, ``n_unchecked``, and ``agreement_<relation>`` per relation kind present.
    """
    rel = np.asarray(relation).astype(str)
    if rel.ndim != 1:
        raise ValueError(f"relation must be a 1-D array of edges, got shape {rel.shape}")
    n = rel.size
    sx = _coerce_column(subject, "x_m", "subject", n).astype(np.float64)
    sy = _coerce_column(subject, "y_m", "subject", n).astype(np.float64)
    ox = _coerce_column(object_, "x_m", "object_", n).astype(np.float64)
    oy = _coerce_column(object_, "y_m", "object_", n).astype(np.float64)
    checks = {
        "left_of": sx < ox,
        "right_of": sx > ox,
        "in_front_of": sy < oy,
        "behind": sy > oy,
    }
    if occludes_truth is not None:
        occ = np.asarray(occludes_truth)
        if occ.dtype != np.bool_ or occ.shape != (n,):
            raise ValueError(
                f"occludes_truth must be a boolean array of shape ({n},), got "
                f"{occ.dtype} {occ.shape}"
            )
        checks["occludes"] = occ
    checked = np.zeros(n, dtype=bool)
    agree = np.zeros(n, dtype=bool)
    out: dict[str, float] = {}
    for name, ok in checks.items():
        is_rel = rel == name
        checked |= is_rel
        agree |= is_rel & ok
        if is_rel.any():
            out[f"agreement_{name}"] = _ratio(int(np.count_nonzero(is_rel & ok)), int(is_rel.sum()))
    n_checked, n_agree = int(checked.sum()), int(agree.sum())
    return {
        "agreement": _ratio(n_agree, n_checked),
        "n_checked": float(n_checked),
        "n_agree": float(n_agree),
        "n_unchecked": float(n - n_checked),
        **out,
    }


# ------------------------------------------------------------------------------ intervals
def _coerce_count(name: str, value: object) -> float:
    """A whole number >= 0 (int, or a float holding one, as the pooled counts are)."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise TypeError(f"{name} must be a count (int), got {type(value).__name__} {value!r}")
    count = float(value)
    if not math.isfinite(count) or count < 0 or count != math.floor(count):
        raise ValueError(
            f"{name} must be a whole number >= 0, got {value!r}; pass the count of rocks, "
            "objects or edges, not a rate"
        )
    return count


def wilson_interval(
    successes: int | float, trials: int | float, *, confidence: float = 0.95
) -> tuple[float, float]:
    """Wilson score interval of a proportion ``successes / trials``.

    Unlike the normal ("Wald") interval it stays inside [0, 1] and does not collapse to a
    point at 0 or ``trials`` successes, so it suits the small counts of an evaluation
    (58 rocks within 2 m, 54 classed right: 93.1 %, 95 % interval 83.6-97.3 %).

    Parameters
    ----------
    successes : int or float
        Number of successes, a whole number in [0, trials] (a float holding a whole number,
        such as the pooled counts of :func:`pool_segmentation_scores`, is accepted).
    trials : int or float
        Number of trials, a whole number >= 0.
    confidence : float
        Coverage of the interval, in (0, 1); 0.95 by default.

    Returns
    -------
    low, high : float
        The interval's bounds, ``0 <= low <= successes / trials <= high <= 1``; ``low`` is
        exactly 0 at 0 successes and ``high`` exactly 1 at ``trials`` successes. Both NaN
        when ``trials`` is 0 (no proportion to bound).
    """
    s = _coerce_count("successes", successes)
    n = _coerce_count("trials", trials)
    if s > n:
        raise ValueError(
            f"successes must be at most trials, got {successes!r} successes of {trials!r} "
            "trials; pass (successes, trials) in that order"
        )
    if isinstance(confidence, bool) or not isinstance(confidence, Real):
        raise TypeError(f"confidence must be a number in (0, 1), got {confidence!r}")
    if not 0 < float(confidence) < 1:
        raise ValueError(
            f"confidence must be in (0, 1), got {confidence!r}; e.g. 0.95 for a 95 % interval"
        )
    if n == 0:
        return float("nan"), float("nan")
    z = NormalDist().inv_cdf(0.5 + float(confidence) / 2)
    p = s / n
    z2n = z * z / n
    centre = (p + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * math.sqrt(p * (1 - p) / n + z2n / (4 * n))
    # rounding must neither put p outside nor a bound outside [0, 1]
    low = 0.0 if s == 0 else min(max(centre - half, 0.0), p)
    high = 1.0 if s == n else max(min(centre + half, 1.0), p)
    return float(low), float(high)
