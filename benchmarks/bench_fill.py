"""Rectification fill: depth and segmentation on frames with black wedges along the border.

A scientist's rectified pairs carry black (0) fill where no camera pixel maps, at another
place in each image. This benchmark cuts such wedges into the frames of finished runs of
built-in archives -- a triangle in the top-left corner, ``--reach`` px deep in the right
image and ``--reach + --skew`` px in the left, and a strip of ``--strip`` px along the
right border of both -- and measures, on the reference image's pixels:

* depth: bad-2 (share of matched pixels off by more than 2 px from the truth) and the
  share matched, by distance from the fill's edge, for the matcher on the wedged images as
  they come (what the depth stage did before :mod:`stages._fill`) and for the depth stage
  (:func:`stages.depth.run_depth`: the fill smoothly extended for matching, no disparity
  on it); and how many fill pixels got a disparity;
* segmentation (the current segment stage on the depth stage's products): pixels of
  objects on the fill, and object F1 against the truth with the fill's rocks cut out,
  next to F1 of the same frames without wedges (their own depth products).

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_fill.py runs/eval/mojave [--frames 6]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np
from _rundir import open_run

from pipeline.metrics import pool_segmentation_scores, segmentation_scores
from pipeline.stage import FrameContext
from stages import depth
from stages.segment import segment_image

__all__ = ["BANDS", "main", "wedges"]

BANDS: tuple[tuple[int, int], ...] = ((0, 3), (3, 6), (6, 10), (10, 20), (20, 40))
"""Distance bands from the fill's edge, px."""


def wedges(shape: tuple[int, int], *, reach: int, skew: int, strip: int):
    """The right and left images' fill masks (``(M, N)`` bool each)."""
    ys, xs = np.indices(shape)
    right = (xs + ys < reach) | (xs >= shape[1] - strip)
    left = (xs + ys < reach + skew) | (xs >= shape[1] - strip)
    return right, left


def _bad2_by_band(disparity, truth, distance, fill):
    out = []
    for lo, hi in BANDS:
        sel = ~fill & (distance > lo) & (distance <= hi)
        found = np.isfinite(disparity[sel])
        err = np.abs(disparity[sel][found] - truth[sel][found])
        out.append((found.mean() if sel.any() else np.nan, (err > 2).mean() if err.size else 0))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundir")
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--reach", type=int, default=90)
    parser.add_argument("--skew", type=int, default=10)
    parser.add_argument("--strip", type=int, default=30)
    args = parser.parse_args()
    run = open_run(args.rundir)
    if run.camera.reference != "right":
        parser.error("the benchmark cuts the wedges for a right-reference run")
    params = {**depth.STAGE.defaults(), **run.run["stages"]["depth"]["params"]}
    seg_params = run.segment_params()
    raw_bands, stage_bands, fill_matched = [], [], [0, 0]
    scores_fill, scores_plain, on_fill = [], [], 0
    for k, frame in enumerate(run.frames()):
        if k >= args.frames:
            break
        left, right = frame.product("left").copy(), frame.product("right").copy()
        truth = frame.truth
        fill_r, fill_l = wedges(right.shape, reach=args.reach, skew=args.skew, strip=args.strip)
        right[fill_r], left[fill_l] = 0, 0
        distance = cv2.distanceTransform((~fill_r).astype(np.uint8), cv2.DIST_L2, 3)
        ctx = FrameContext(frame_id=frame.frame_id, archive=run.archive, camera=run.camera)
        lo, hi = depth.resolve_disparity_range(run.camera, right.shape, params)
        band = depth.resolve_row_band(run.camera, right.shape, params)
        gradient = depth.resolve_row_gradient(run.camera, right.shape, params)
        # the stage's own matching call, on the wedged images as they come
        raw = depth._match(right, left, lo, hi, band, params, gradient)[0].disparity
        staged = depth.run_depth({"left": left, "right": right}, frame=ctx, params=params)
        disparity = staged.arrays["disparity"]
        raw_bands.append(_bad2_by_band(raw, truth["disparity"], distance, fill_r))
        stage_bands.append(_bad2_by_band(disparity, truth["disparity"], distance, fill_r))
        fill_matched[0] += int(np.isfinite(raw[fill_r]).sum())
        fill_matched[1] += int(np.isfinite(disparity[fill_r]).sum())
        labels = segment_image(
            right, height=staged.arrays["height"], disparity=disparity, **seg_params
        ).labels
        on_fill += int(np.count_nonzero(labels[fill_r]))
        cut_truth = np.where(fill_r, 0, truth["labels"])
        scores_fill.append(segmentation_scores(labels, cut_truth))
        plain = segment_image(
            frame.product("right"),
            height=frame.product("height"),
            disparity=frame.product("disparity"),
            **seg_params,
        ).labels
        scores_plain.append(segmentation_scores(plain, truth["labels"]))
    wedge = f"{args.reach}/{args.reach + args.skew} px"
    print(f"{run.archive}: {len(raw_bands)} frames, wedge {wedge}, strip {args.strip} px")
    print("px from the fill   matched raw / stage   bad-2 raw / stage")
    for b, (lo, hi) in enumerate(BANDS):
        raw_m = np.nanmean([f[b][0] for f in raw_bands])
        st_m = np.nanmean([f[b][0] for f in stage_bands])
        raw_b = np.mean([f[b][1] for f in raw_bands])
        st_b = np.mean([f[b][1] for f in stage_bands])
        print(f"{lo:3d}-{hi:<3d}              {raw_m:5.2f} / {st_m:5.2f}        "
              f"{raw_b:6.3f} / {st_b:6.3f}")  # fmt: skip
    print(f"fill pixels with a disparity: raw {fill_matched[0]}, stage {fill_matched[1]}")
    with_fill = pool_segmentation_scores(scores_fill)
    without = pool_segmentation_scores(scores_plain)
    print(f"segmentation: object pixels on the fill {on_fill}; F1 with wedges "
          f"{with_fill['f1']:.3f} (P {with_fill['precision']:.3f} R {with_fill['recall']:.3f}), "
          f"same frames without {without['f1']:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
