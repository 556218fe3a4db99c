"""Depth edges: the matcher's foreground fattening against the truth, and what it does to R1.

Profile (always). The disparity of finished ``arroyo run`` directories minus the truth's,
occluded pixels left out, by distance from the nearest truth rock: ground pixels by bands of
distance (px) outside it and by where that rock lies (*below*: the ground is farther than
the rock, above it in the image; *above*: the ground is nearer; *beside*), rock pixels by
distance inside the rock's edge. Each cell: median error (px) / share off by more than
0.25 px (about 5-10 mm of height at the built-in archives' ranges, the segment stage's R1
threshold is 11.5 mm in its precise regime). Ground far from rocks is the reference.

Segmentation (``--segment``). Segments the frames again as ``bench_segment.py --rundir``
does (current code, the catalog's current segment params) and prints pooled object
precision / recall / F1 with the ground height noise the segment stage measured (median
over frames, and how many frames fell in its *precise* regime, noise <= 5 mm, where rule
R1 turns raised pixels into rock). ``--truth-near PX`` first replaces, in memory, the
disparity of ground pixels within PX px of a truth rock by the truth (``--truth-rocks``:
also every rock pixel; ``--truth-near 0 --truth-rocks``: rocks only; a large PX: the whole
frame) and recomputes the height over the run's fitted ground plane: an oracle of perfect
depth edges, the most any edge post-filter could give.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_edges.py runs/eval/mojave runs/eval/lava
    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_edges.py --segment --truth-near 24 \\
        --truth-rocks runs/eval/mojave
"""

from __future__ import annotations

import argparse

import numpy as np
from _rundir import open_run  # sibling module (benchmarks/ is on sys.path)
from scipy.ndimage import distance_transform_edt

from pipeline.metrics import pool_segmentation_scores, segmentation_scores
from stages import segment as segment_stage
from stages._depth_rules import _NOISY_SIGMA_M
from stages.geometry import height_above_plane

GROUND_BANDS = ((1, 2), (3, 4), (5, 8), (9, 12), (13, 16), (17, 24), (25, 40))
ROCK_BANDS = ((1, 1), (2, 2), (3, 4), (5, 8))
SIDES = ("below", "above", "beside")
OFF_PX = 0.25


def _geometry(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance outside rocks, distance inside them (1 = edge pixel), side of the nearest rock."""
    outside, (iy, ix) = distance_transform_edt(labels == 0, return_indices=True)
    inside = distance_transform_edt(labels > 0)
    rows, cols = np.indices(labels.shape)
    dy, dx = iy - rows, ix - cols
    side = np.where(np.abs(dy) >= np.abs(dx), np.where(dy > 0, 0, 1), 2)
    return np.rint(outside).astype(int), np.rint(inside).astype(int), side


def _cell(errors: list[np.ndarray]) -> str:
    e = np.concatenate(errors) if errors else np.empty(0)
    if e.size == 0:
        return "      --     "
    return f"{np.median(e):+.3f}/{np.mean(np.abs(e) > OFF_PX):.2f}"


def profile(rundir: str, frames: int) -> None:
    run = open_run(rundir)
    ground: dict[tuple, list[np.ndarray]] = {}
    rock: dict[tuple, list[np.ndarray]] = {}
    far: list[np.ndarray] = []
    abs_sum, count = 0.0, 0
    for n, frame in enumerate(run.frames()):
        if n == frames:
            break
        truth = frame.truth
        error = frame.product("disparity") - truth["disparity"]
        ok = np.isfinite(error) & ~truth["occluded"]
        abs_sum += float(np.abs(error[ok]).sum())
        count += int(ok.sum())
        outside, inside, side = _geometry(truth["labels"])
        is_ground = ok & (truth["labels"] == 0)
        for lo, hi in GROUND_BANDS:
            band = is_ground & (outside >= lo) & (outside <= hi)
            for s, name in enumerate(SIDES):
                ground.setdefault((lo, hi, name), []).append(error[band & (side == s)])
        far.append(error[is_ground & (outside > GROUND_BANDS[-1][1])])
        for lo, hi in ROCK_BANDS:
            rock.setdefault((lo, hi), []).append(error[ok & (inside >= lo) & (inside <= hi)])
    used = min(frames, len(run.products["frame"])) if frames > 0 else len(run.products["frame"])
    print(
        f"{run.archive} ({used} frames, {rundir}): disparity error, median px / share off by "
        f"> {OFF_PX} px; EPE {abs_sum / max(count, 1):.4f} px"
    )
    print("  ground, px from rock " + " ".join(f"{f'{lo}-{hi}':>13s}" for lo, hi in GROUND_BANDS))
    for name in SIDES:
        cells = " ".join(f"{_cell(ground[(lo, hi, name)]):>13s}" for lo, hi in GROUND_BANDS)
        print(f"    rock {name:6s}          {cells}")
    print(f"    farther than {GROUND_BANDS[-1][1]} px    {_cell(far):>13s}")
    print("  rock, px inside      " + " ".join(f"{f'{lo}-{hi}':>13s}" for lo, hi in ROCK_BANDS))
    print("                       " + " ".join(f"{_cell(rock[b]):>13s}" for b in ROCK_BANDS))


def _oracle(frame, camera, truth_near: float, truth_rocks: bool):
    """Disparity and height with the truth put in near rock edges (None: the run's)."""
    disparity = frame.product("disparity")
    height = frame.product("height")
    if truth_near <= 0 and not truth_rocks:
        return disparity, height
    labels = frame.truth["labels"]
    truth = frame.truth["disparity"]
    replace = (labels == 0) & (distance_transform_edt(labels == 0) <= truth_near)
    if truth_rocks:
        replace |= labels > 0
    replace &= np.isfinite(disparity) & np.isfinite(truth)
    disparity = np.where(replace, truth, disparity).astype(np.float32)
    plane = frame.product("ground_plane")
    if np.all(np.isfinite(plane)):
        height = height_above_plane(camera.camera_points(disparity), plane).astype(np.float32)
    return disparity, height


def segment_scores(rundir: str, frames: int, truth_near: float, truth_rocks: bool) -> None:
    run = open_run(rundir)
    params = run.segment_params()
    results, sigmas = [], []
    for n, frame in enumerate(run.frames()):
        if n == frames:
            break
        disparity, height = _oracle(frame, run.camera, truth_near, truth_rocks)
        seg = segment_stage.segment_image(
            frame.product(run.camera.reference), height=height, disparity=disparity, **params
        )
        results.append(segmentation_scores(seg.labels, frame.truth["labels"]))
        sigmas.append(seg.depth.ground_sigma_m if seg.depth is not None else float("nan"))
    pooled = pool_segmentation_scores(results)
    sig = np.asarray(sigmas)
    oracle = f"truth within {truth_near:g} px of rocks" if truth_near > 0 else "no truth"
    oracle += " and on rocks" if truth_rocks else ""
    print(
        f"  segmentation ({oracle}): P {pooled['precision']:.3f} R {pooled['recall']:.3f} "
        f"F1 {pooled['f1']:.3f} (tp {pooled['tp']:.0f} fp {pooled['fp']:.0f} fn "
        f"{pooled['fn']:.0f}); ground noise median {1e3 * np.nanmedian(sig):.1f} mm, "
        f"{int(np.sum(sig <= _NOISY_SIGMA_M))}/{sig.size} frames precise "
        f"(<= {1e3 * _NOISY_SIGMA_M:g} mm)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("rundirs", nargs="+", help="finished arroyo run directories")
    parser.add_argument("--frames", type=int, default=0, help="first N frames only; 0 = all")
    parser.add_argument("--segment", action="store_true", help="also segment and score")
    parser.add_argument("--truth-near", type=float, default=0.0, help="--segment: oracle px")
    parser.add_argument("--truth-rocks", action="store_true", help="--segment: oracle on rocks")
    parser.add_argument("--no-profile", action="store_true", help="only --segment")
    args = parser.parse_args()
    frames = args.frames if args.frames > 0 else -1
    for rundir in args.rundirs:
        if not args.no_profile:
            profile(rundir, frames)
        if args.segment:
            if args.no_profile:
                print(rundir)
            segment_scores(rundir, frames, args.truth_near, args.truth_rocks)


if __name__ == "__main__":
    main()
