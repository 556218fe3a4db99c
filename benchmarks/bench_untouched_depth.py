"""Can depth find the untouched rocks? Their disparity bump against the stereo noise.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_untouched_depth.py runs/eval/lava
    PYTHONPATH=. .venv/bin/python benchmarks/bench_untouched_depth.py runs/eval/lava \
        /tmp/val7/lava_s2 --frames 6 --seed 1

A run's *untouched* rocks are the missed truth rocks without a single object pixel on them,
found as ``bench_misses.py`` finds them (:func:`bench_misses.classify_misses` on the run's
frames segmented again with the current code and the catalog's settings). On lava they are
most of the misses, low rocks with a face near the ground's gray. This script asks whether a
depth rule could find them, with the truth rock's exact mask given, and prints one row per
run:

* ``rocks`` -- the untouched rocks;
* ``bump`` -- their median true disparity bump (px): the median of the truth disparity over
  the rock minus the median over its ring of ground (the ground pixels 3 to 7 px from the
  rock, other rocks left out), each relative to the run's ground plane;
* ``relief`` -- the ground's own relief: the robust spread (1.4826 x MAD, px) of that same
  true bump over the ground patches below, what a perfect disparity would have to beat;
* ``noise`` -- the image noise: the standard deviation (gray levels, over the frames'
  ground pixels) of the reference image minus the other image warped onto it by the true
  disparity (bilinear), i.e. what no disparity can explain;
* ``SNR`` -- the median best-case signal-to-noise of the bump: the bump over the
  Cramer-Rao-style bound ``sqrt(s2 / sum(gm**2) + s2 / sum(gr**2))`` on the precision with
  which any matcher measures one disparity offset over the rock's pixels and one over its
  ring, where ``s2`` is the frame's noise variance and ``gm``, ``gr`` the horizontal gray
  gradients (mean of both images, mean removed) on the rock and on the ring. It assumes
  white noise and the exact mask, so it is an upper bound for any rule;
* ``>3.3`` -- the fraction of rocks with that SNR above 3.3 (one-sided 1 in 2000 false
  alarms per test under Gaussian noise, the least a rule tested on thousands of ground
  patches needs);
* then, for two height fields, the rocks' bump score against ten ground patches per rock of
  the rock's exact shape (moved by up to 15 rows and anywhere along the row, at least 3 px
  from any truth rock, the right border kept clear for the match; a seeded generator, so
  reruns agree): ``AUC`` (the chance that a rock scores above a patch; a score that cannot
  be measured ranks lowest) and ``R@1%`` (the rocks' recall at the score exceeded by 1 % of
  the patches). The score is the median height (m) over the mask minus the median over its
  ring, of (a) ``run``: the run's height product, and (b) ``zncc5``: the height of a fine
  5x5 ZNCC match with a parabola peak, searched +-2 px around the run's disparity (the ground
  plane's where the run has none; NaN where the window's gray spread is below 1 level, the
  peak ZNCC below 0.3 or the match leaves the image). A score needs at least 30 % of the
  mask's pixels and 5 of the ring's finite; ``n/a`` is the share of rocks without one (they
  rank lowest: a rule cannot find them. Leaving the unmeasured rocks and patches out instead
  gives AUCs 0.04 to 0.11 higher on the lava runs, 0.64 to 0.69, and the same zero recalls).

On lava (catalog seed, seeds 2 and 3) this says why depth rules stop short of the untouched
rocks: their bump, about 0.19 px, is six times the ground's relief but only about three
bounds, fewer than half clear 3.3 even for an ideal matcher on the exact mask, and a real
window matcher (zncc5) tells them from ground patches no better than the run's own height.

All frames are measured by default, about 6 s of CPU per 12-frame lava run on one core
(the re-segmentation and the fine match); ``--frames N`` measures only the first N frames of
each run. The CPU seconds of each run are printed after its row.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy.stats import rankdata

from stages.geometry import height_from_disparity, plane_disparity_coefficients
from stages.segment import segment_image

if TYPE_CHECKING:
    from _rundir import FinishedRun, RunFrame

__all__ = ["fine_disparity", "main", "patch_auc", "recall_at"]

_RING_IN = 2  # ring: dilated by 7 px minus dilated by 2 px (3 to 7 px from the mask)
_RING_OUT = 7
_PATCHES = 10  # ground patches per rock
_PATCH_TRIES = 300
_PATCH_ROWS = 15  # a patch moves up to this many rows (range and ground slope stay alike)
_ROCK_CLEARANCE = 3  # a patch keeps this far from every truth rock
_MIN_FINITE = 0.3  # a bump needs this share of the mask's pixels finite
_SNR_FOUND = 3.3
_FPR = 0.01


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _ring(mask: np.ndarray, ground: np.ndarray) -> np.ndarray:
    m8 = mask.view(np.uint8)
    outer = cv2.dilate(m8, _disk(_RING_OUT)).view(bool)
    inner = cv2.dilate(m8, _disk(_RING_IN)).view(bool)
    return outer & ~inner & ground


def _bump(values: np.ndarray, mask: np.ndarray, ring: np.ndarray) -> float:
    """Median of ``values`` over ``mask`` minus over ``ring`` (finite pixels), NaN when too
    few are finite."""
    inside = values[mask]
    inside = inside[np.isfinite(inside)]
    around = values[ring]
    around = around[np.isfinite(around)]
    if inside.size < max(5, _MIN_FINITE * mask.sum()) or around.size < 5:
        return float("nan")
    return float(np.median(inside) - np.median(around))


def fine_disparity(
    reference: np.ndarray,
    other: np.ndarray,
    centre: np.ndarray,
    *,
    win: int = 5,
    band: int = 2,
    min_std: float = 1.0,
    min_peak: float = 0.3,
) -> np.ndarray:
    """Disparity of a small-window ZNCC match in a narrow band around a centre disparity.

    Parameters
    ----------
    reference, other : (M, N) ndarray of uint8 or float
        The right (reference) and left images: column ``x`` of ``reference`` is column
        ``x + d`` of ``other``.
    centre : (M, N) ndarray of float
        Finite centre disparity per pixel (px); the search covers integer disparities
        ``round(centre) - band .. round(centre) + band``.
    win : int
        Odd window side (px).
    band : int
        Search half-width (px).
    min_std, min_peak : float
        A pixel is NaN when its window's gray spread is below ``min_std`` levels or its best
        ZNCC below ``min_peak``.

    Returns
    -------
    (M, N) ndarray of float32
        The best integer disparity plus a parabola's offset (clipped to +-0.5) through the
        ZNCC at it and its two neighbours; NaN where invalid or where the match leaves
        the image.
    """
    if win % 2 != 1 or win < 3:
        raise ValueError(f"win must be an odd window side >= 3, got {win}; give e.g. 5")
    ref = reference.astype(np.float32)
    oth = other.astype(np.float32)
    h, w = ref.shape
    if not np.isfinite(centre).all():
        raise ValueError("centre must be finite everywhere; fill its gaps (e.g. the plane's)")
    c0 = np.rint(centre).astype(np.int32)
    offsets = np.arange(-band - 1, band + 2)  # one more each side for the parabola
    scores = np.full((offsets.size, h, w), -2.0, np.float32)
    ksize = (win, win)

    def mean(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, ksize, normalize=True, borderType=cv2.BORDER_REFLECT)

    mean_r = mean(ref)
    std_r = np.sqrt(np.maximum(mean(ref * ref) - mean_r * mean_r, 0))
    flat_index = np.arange(h * w)
    for d in range(max(int(c0.min()) + offsets[0], 0), int(c0.max()) + offsets[-1] + 1):
        shifted = np.zeros_like(oth)
        shifted[:, : w - d] = oth[:, d:]
        mean_o = mean(shifted)
        std_o = np.sqrt(np.maximum(mean(shifted * shifted) - mean_o * mean_o, 0))
        ncc = (mean(ref * shifted) - mean_r * mean_o) / np.maximum(std_r * std_o, 1e-6)
        slot = (d - c0 - offsets[0]).ravel()
        use = (slot >= 0) & (slot < offsets.size)
        scores.reshape(offsets.size, -1)[slot[use], flat_index[use]] = ncc.ravel()[use]
    best = np.argmax(scores[1:-1], axis=0) + 1
    peak = np.take_along_axis(scores, best[None], axis=0)[0]
    before = np.take_along_axis(scores, best[None] - 1, axis=0)[0]
    after = np.take_along_axis(scores, best[None] + 1, axis=0)[0]
    curvature = before - 2 * peak + after
    concave = curvature < 0
    shift = np.where(concave, 0.5 * (before - after) / np.where(concave, curvature, -1), 0)
    disparity = (c0 + offsets[best] + np.clip(shift, -0.5, 0.5)).astype(np.float32)
    cols = np.arange(w)[None, :]
    bad = (std_r < min_std) | (peak < min_peak) | (cols + c0 + band + 1 + win // 2 >= w)
    disparity[bad] = np.nan
    return disparity


def patch_auc(positives: np.ndarray, negatives: np.ndarray) -> float:
    """Chance that a positive scores above a negative (ties count half; NaN ranks lowest)."""
    pos = np.nan_to_num(np.asarray(positives, np.float64), nan=-np.inf)
    neg = np.nan_to_num(np.asarray(negatives, np.float64), nan=-np.inf)
    if pos.size == 0 or neg.size == 0:
        return float("nan")
    ranks = rankdata(np.concatenate([pos, neg]))
    wins = ranks[: pos.size].sum() - pos.size * (pos.size + 1) / 2
    return float(wins / (pos.size * neg.size))


def recall_at(positives: np.ndarray, negatives: np.ndarray, fpr: float) -> float:
    """Share of positives above the score that a share ``fpr`` of the negatives exceeds."""
    pos = np.nan_to_num(np.asarray(positives, np.float64), nan=-np.inf)
    neg = np.nan_to_num(np.asarray(negatives, np.float64), nan=-np.inf)
    if pos.size == 0 or neg.size == 0:
        return float("nan")
    return float(np.mean(pos > np.quantile(neg, 1 - fpr)))


@dataclass
class _Tally:
    """Per-run measurements, one entry per untouched rock or ground patch."""

    bump: list[float] = field(default_factory=list)
    snr: list[float] = field(default_factory=list)
    noise_var: list[float] = field(default_factory=list)
    relief: list[float] = field(default_factory=list)
    rock_scores: dict[str, list[float]] = field(default_factory=lambda: {"run": [], "zncc5": []})
    patch_scores: dict[str, list[float]] = field(default_factory=lambda: {"run": [], "zncc5": []})


def _patches(
    mask: np.ndarray, *, free: np.ndarray, right_margin: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """Up to ``_PATCHES`` copies of ``mask`` moved onto ground (all pixels ``free``), with
    room for the ring inside the image and for the match at the right border."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    out = []
    for _ in range(_PATCH_TRIES):
        if len(out) >= _PATCHES:
            break
        ny = ys + int(rng.integers(-_PATCH_ROWS, _PATCH_ROWS + 1))
        nx = xs + int(rng.integers(-w, w))
        edge = _RING_OUT + 1
        if ny.min() < edge or nx.min() < edge or ny.max() >= h - edge:
            continue
        if nx.max() >= w - edge - right_margin or not free[ny, nx].all():
            continue
        patch = np.zeros_like(mask)
        patch[ny, nx] = True
        out.append(patch)
    return out


def _measure_frame(
    frame: RunFrame, run: FinishedRun, params: dict, rng: np.random.Generator, tally: _Tally
) -> None:
    """Add the frame's untouched rocks and their ground patches to ``tally``."""
    from bench_misses import classify_misses  # sibling script (benchmarks/ is on sys.path)

    cam = run.camera
    image = frame.product(cam.reference)
    other = frame.product("left")
    disparity = frame.product("disparity")
    height = frame.product("height")
    plane = frame.product("ground_plane")
    true = frame.truth["labels"]
    true_disp = frame.truth["disparity"].astype(np.float32)
    pred = segment_image(image, height=height, disparity=disparity, **params).labels
    rows = classify_misses(pred, true, image, frame.truth["range"])
    untouched = [row["rock"] for row in rows if row["class"] == "untouched"]
    if not untouched:
        return
    h, w = image.shape
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    alpha, beta, gamma = plane_disparity_coefficients(plane, camera=cam, shape=(h, w))
    plane_disp = (alpha * xx + beta * yy + gamma).astype(np.float32)
    relief = true_disp - plane_disp

    # the image noise: what the true disparity cannot explain, on the ground
    ref = image.astype(np.float32)
    warped = cv2.remap(other.astype(np.float32), xx + np.nan_to_num(true_disp), yy,
                       cv2.INTER_LINEAR)
    ground = true == 0
    seen = ground & np.isfinite(true_disp) & (xx + true_disp < w - 3)
    noise_var = float((ref - warped)[seen].var())
    tally.noise_var.append(noise_var)
    gx = 0.5 * (np.gradient(ref, axis=1) + np.gradient(warped, axis=1))

    centre = np.where(np.isfinite(disparity) & (disparity > 0), disparity, plane_disp)
    fields = {
        "run": height,
        "zncc5": height_from_disparity(fine_disparity(image, other, centre), plane, camera=cam),
    }
    free = ~cv2.dilate((true > 0).view(np.uint8), _disk(_ROCK_CLEARANCE)).view(bool)
    right_margin = int(np.ceil(np.nanmax(true_disp))) + 3
    for rock in untouched:
        mask = true == rock
        ring = _ring(mask, ground)
        bump = _bump(relief, mask, ring)
        gm = gx[mask] - gx[mask].mean()
        gr = gx[ring] - gx[ring].mean() if ring.any() else np.zeros(1, np.float32)
        bound = np.sqrt(noise_var / max(float(gm @ gm), 1e-12)
                        + noise_var / max(float(gr @ gr), 1e-12))
        tally.bump.append(bump)
        tally.snr.append(bump / bound)
        for name, values in fields.items():
            tally.rock_scores[name].append(_bump(values, mask, ring))
        for patch in _patches(mask, free=free, right_margin=right_margin, rng=rng):
            patch_ring = _ring(patch, ground)
            tally.relief.append(_bump(relief, patch, patch_ring))
            for name, values in fields.items():
                tally.patch_scores[name].append(_bump(values, patch, patch_ring))


# (upper label, lower label, width) per column; a row's cells are right-aligned under them
_COLUMNS = (
    ("", "archive", -9),
    ("", "rocks", 5),
    ("bump", "(px)", 6),
    ("relief", "(px)", 6),
    ("noise", "(gray)", 6),
    ("SNR", "median", 6),
    ("SNR", ">3.3", 5),
    ("ground", "patches", 7),
    ("run", "AUC", 6),
    ("run", "R@1%", 5),
    ("run", "n/a", 5),
    ("zncc5", "AUC", 6),
    ("zncc5", "R@1%", 5),
    ("zncc5", "n/a", 5),
)


def _line(cells: list[str]) -> str:
    return " ".join(
        f"{cell:{'<' if width < 0 else '>'}{abs(width)}s}"
        for cell, (_, _, width) in zip(cells, _COLUMNS, strict=True)
    )


def _row(archive: str, tally: _Tally) -> str:
    relief = np.asarray(tally.relief)
    relief = relief[np.isfinite(relief)]
    spread = np.nan
    if relief.size:
        spread = 1.4826 * float(np.median(np.abs(relief - np.median(relief))))
    snr = np.asarray(tally.snr)
    cells = [
        archive,
        f"{len(tally.bump):d}",
        f"{np.nanmedian(tally.bump):.3f}",
        f"{spread:.3f}",
        f"{np.sqrt(np.mean(tally.noise_var)):.2f}",
        f"{np.nanmedian(snr):.2f}",
        f"{np.mean(np.nan_to_num(snr, nan=-np.inf) > _SNR_FOUND):.2f}",
        f"{len(tally.relief):d}",
    ]
    for name in ("run", "zncc5"):
        pos, neg = tally.rock_scores[name], tally.patch_scores[name]
        cells += [
            f"{patch_auc(pos, neg):.3f}",
            f"{recall_at(pos, neg, _FPR):.2f}",
            f"{np.mean(~np.isfinite(pos)):.2f}",
        ]
    return _line(cells)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="All frames by default (about 6 s of CPU per 12-frame lava run); --frames N "
        "subsamples to the first N frames of each run.",
    )
    parser.add_argument("rundirs", nargs="+", help="finished run directories of built-in archives")
    parser.add_argument("--frames", type=int, default=0, metavar="N",
                        help="measure the first N frames of each run only (0: all)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the ground patches' placement (per run)")
    args = parser.parse_args()
    if args.frames < 0:
        parser.error(f"--frames must be 0 (all) or a positive count, got {args.frames}")
    from _rundir import open_run  # sibling module (benchmarks/ is on sys.path)

    print(_line([upper for upper, _, _ in _COLUMNS]))
    print(_line([lower for _, lower, _ in _COLUMNS]) + "  run directory (CPU)")
    for rundir in args.rundirs:
        start = time.process_time()
        run = open_run(rundir)
        if run.camera.reference != "right":
            raise ValueError(
                f"run {rundir!r} has reference camera {run.camera.reference!r}; this benchmark "
                "matches the left image onto the right one, give a run with reference 'right'"
            )
        params = run.segment_params()
        rng = np.random.default_rng(args.seed)
        tally = _Tally()
        for index, frame in enumerate(run.frames()):
            if args.frames and index >= args.frames:
                break
            _measure_frame(frame, run, params, rng, tally)
        if not tally.bump:
            print(f"{run.archive:9s}     0  (no untouched rocks)  {rundir}")
            continue
        print(f"{_row(run.archive, tally)}  {rundir} ({time.process_time() - start:.0f} s)")


if __name__ == "__main__":
    main()
