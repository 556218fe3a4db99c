"""Why segmentation misses rocks: every missed truth rock of finished runs, sorted by cause.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_misses.py runs/eval/lava
    PYTHONPATH=. .venv/bin/python benchmarks/bench_misses.py runs/eval/lab runs/eval/mojave \
        --set neck_ratio=0      # segment_image keywords, as bench_segment.py --rundir

Each run's frames are segmented again with the current code (the run's depth products and
catalog settings, plus ``--set``), exactly as ``bench_segment.py --rundir`` does, and every
truth rock of at least 30 visible pixels that no object matches at IoU >= 0.5 falls in one
class, by the object that covers most of it:

* ``untouched`` -- no object pixel on the rock;
* ``shared`` -- that object also covers at least 30 % of another truth rock (two rocks
  merged into one object, neither reaching IoU 0.5);
* ``partial`` -- that object covers less than half the rock (a crescent, a lit half, a
  speck; ``pieces`` counts the objects on it);
* ``fat`` -- that object covers most of the rock but as much ground again (a shadow, a
  blurred rim).

Per class: the count, the median visible pixels, the median range and how many lie within
2 m, and the rock's gray contrast: its mean gray minus the median of a 4-pixel ring of
ground around it, in robust ground spreads (1.4826 x MAD of that ring). The matched rocks'
contrast is printed for comparison: it tells how far an intensity rule would have to reach
into the ground's own texture to find what is missed. Last, each class's *ceiling*: the
object F1 when every missed rock of that class is painted into the labels from the truth
(over everything, as a new object), all else kept -- an upper bound on what a rule that
fixes that class alone can gain, not a promise that such a rule exists.

A second table sorts the false objects (graded, unmatched) the same way, by the truth rock
under most of the object:

* ``ground`` -- less than a quarter of the object lies on truth rocks (texture, a shadow,
  an invented rock);
* ``on_missed`` -- the rock under it is missed (the object is its partial, fat or shared
  cover, counted above as a miss too);
* ``extra`` -- the rock under it is matched by another object (a second piece).

Its ceiling is the F1 when every false object of that class is erased, all else kept.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import cv2
import numpy as np

from pipeline.metrics import match_objects, pool_segmentation_scores, segmentation_scores
from stages.segment import segment_image

__all__ = ["classify_false_objects", "classify_misses", "main"]

_MIN_TRUE_PX = 30
_SHARED = 0.3
_RING_PX = 4
CLASSES = ("untouched", "shared", "partial", "fat")
FALSE_CLASSES = ("ground", "on_missed", "extra")
_ON_ROCKS = 0.25


def _contrast(image: np.ndarray, rock: np.ndarray, ground: np.ndarray) -> float:
    kernel = np.ones((2 * _RING_PX + 1, 2 * _RING_PX + 1), np.uint8)
    ring = cv2.dilate(rock.view(np.uint8), kernel).view(bool) & ground
    if not ring.any():
        return float("nan")
    values = image[ring].astype(np.float64)
    centre = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - centre)))
    return (float(image[rock].mean()) - centre) / max(spread, 1.0)


def classify_misses(
    pred: np.ndarray, true: np.ndarray, image: np.ndarray, rng: np.ndarray
) -> list[dict]:
    """One row per graded truth rock of a frame: its id, class ('matched' or a miss class),
    size, range, contrast and the number of objects on it."""
    matches = match_objects(pred, true, min_true_px=_MIN_TRUE_PX)
    matched = set(matches.true_ids.tolist())
    true_ids, true_px = np.unique(true[true > 0], return_counts=True)
    size = dict(zip(true_ids.tolist(), true_px.tolist(), strict=True))
    ground = true == 0
    rows = []
    for t, n in size.items():
        if n < _MIN_TRUE_PX:
            continue
        rock = true == t
        on = pred[rock]
        objects, counts = np.unique(on[on > 0], return_counts=True)
        if t in matched:
            kind = "matched"
        elif objects.size == 0:
            kind = "untouched"
        else:
            best = objects[np.argmax(counts)]
            covered = pred == best
            others, shared = np.unique(true[covered & ~rock & ~ground], return_counts=True)
            if any(c >= _SHARED * size[o] for o, c in zip(others, shared, strict=True)):
                kind = "shared"
            elif counts.max() < 0.5 * n:
                kind = "partial"
            else:
                kind = "fat"
        rows.append(
            {
                "rock": int(t),
                "class": kind,
                "px": n,
                "range_m": float(np.median(rng[rock])),
                "contrast": _contrast(image, rock, ground),
                "pieces": int(objects.size),
            }
        )
    return rows


def classify_false_objects(pred: np.ndarray, true: np.ndarray, image: np.ndarray) -> list[dict]:
    """One row per false object of a frame (graded, unmatched): its id, class, size and
    gray contrast against the ground around it."""
    matches = match_objects(pred, true, min_true_px=_MIN_TRUE_PX)
    matched_pred = set(matches.pred_ids.tolist())
    matched_true = set(matches.true_ids.tolist())
    ignored = set(matches.ignored_pred_ids.tolist())
    ground = true == 0
    rows = []
    for p in np.unique(pred[pred > 0]).tolist():
        if p in matched_pred or p in ignored:
            continue
        obj = pred == p
        under, counts = np.unique(true[obj], return_counts=True)
        on_rocks = counts[under > 0]
        if on_rocks.sum() < _ON_ROCKS * counts.sum():
            kind = "ground"
        else:
            rock = int(under[under > 0][np.argmax(on_rocks)])
            kind = "extra" if rock in matched_true else "on_missed"
        rows.append(
            {
                "object": int(p),
                "class": kind,
                "px": int(counts.sum()),
                "contrast": _contrast(image, obj, ground & ~obj),
            }
        )
    return rows


def _erased(pred: np.ndarray, objects: list[int]) -> np.ndarray:
    """``pred`` without the objects ``objects``."""
    return np.where(np.isin(pred, objects), 0, pred)


def _painted(pred: np.ndarray, true: np.ndarray, rocks: list[int]) -> np.ndarray:
    """``pred`` with the truth rocks ``rocks`` painted over it as new objects."""
    out = pred.astype(np.int32, copy=True)
    for offset, rock in enumerate(rocks, start=1):
        out[true == rock] = int(pred.max()) + offset
    return out


def _summary(rows: list[dict]) -> str:
    px = np.array([r["px"] for r in rows])
    rng = np.array([r["range_m"] for r in rows])
    contrast = np.abs([r["contrast"] for r in rows])
    q1, q2, q3 = np.nanpercentile(contrast, [25, 50, 75])
    return (
        f"{len(rows):5d} {np.median(px):8.0f} {np.median(rng):8.2f} {np.sum(rng < 2.0):6d}"
        f"   {q1:5.1f} {q2:5.1f} {q3:5.1f}"
    )


def _false_summary(rows: list[dict]) -> str:
    px = np.array([r["px"] for r in rows])
    contrast = np.abs([r["contrast"] for r in rows])
    q1, q2, q3 = np.nanpercentile(contrast, [25, 50, 75])
    return f"{len(rows):5d} {np.median(px):8.0f}   |contrast| {q1:5.1f} {q2:5.1f} {q3:5.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundirs", nargs="+", help="finished run directories of built-in archives")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    # sibling modules: benchmarks/ is on sys.path when this script runs (not when a test
    # imports classify_misses)
    from _overrides import keyword_overrides
    from _rundir import open_run

    overrides = keyword_overrides(args.set)
    print("archive   class      rocks  px(med) range(m)  <2m   |contrast| q1, median, q3 (spreads)")
    for rundir in args.rundirs:
        run = open_run(rundir)
        params = run.segment_params()
        params.update(overrides)
        by_class: dict[str, list[dict]] = defaultdict(list)
        painted: dict[str, list[dict]] = defaultdict(list)
        false_rows: dict[str, list[dict]] = defaultdict(list)
        for frame in run.frames():
            image = frame.product(run.camera.reference)
            pred = segment_image(
                image,
                height=frame.product("height"),
                disparity=frame.product("disparity"),
                **params,
            ).labels
            true = frame.truth["labels"]
            rows = classify_misses(pred, true, image, frame.truth["range"])
            for row in rows:
                by_class[row["class"]].append(row)
            for kind in CLASSES:
                rocks = [row["rock"] for row in rows if row["class"] == kind]
                painted[kind].append(segmentation_scores(_painted(pred, true, rocks), true))
            false_objects = classify_false_objects(pred, true, image)
            for row in false_objects:
                false_rows[row["class"]].append(row)
            for kind in FALSE_CLASSES:
                objects = [row["object"] for row in false_objects if row["class"] == kind]
                painted[kind].append(segmentation_scores(_erased(pred, objects), true))
        for kind in ("matched", *CLASSES):
            if by_class[kind]:
                ceiling = pool_segmentation_scores(painted[kind])["f1"] if kind in painted else 0
                column = f"   ceiling F1 {ceiling:.3f}" if kind != "matched" else ""
                print(f"{run.archive:9s} {kind:10s} {_summary(by_class[kind])}{column}")
        missed = [r for k in CLASSES for r in by_class[k]]
        if missed:
            print(f"{run.archive:9s} {'missed':10s} {_summary(missed)}")
        for kind in FALSE_CLASSES:
            if false_rows[kind]:
                ceiling = pool_segmentation_scores(painted[kind])["f1"]
                print(
                    f"{run.archive:9s} {'false ' + kind:18s} {_false_summary(false_rows[kind])}"
                    f"   ceiling F1 {ceiling:.3f}"
                )


if __name__ == "__main__":
    main()
