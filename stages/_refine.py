"""Ground-sheared refinement of a disparity map: precise ground, rocks kept apart.

Why. A window on the ground seen by a forward-looking camera spans rows whose disparities
differ (about 0.07 px per row in the built-in archives: 2 px over a 31-row window), so a
rectangular window mixes disparities and its match is noisy and biased. Matching *relative to
the fitted ground plane* removes that: the other image is resampled at ``x + g(x, y) + q +
delta`` (``g`` the plane's disparity, ``q`` a coarse per-pixel offset from the first pass,
``delta`` the swept residual), so on the ground every pixel of a window lines up for the same
``delta`` and a tall window averages sensor noise without mixing disparities (Mojave: ground
error 3x smaller). A rock stands above the plane; a tall window there would pull it towards
the ground, so a pixel is refined with the tall window only where both the first pass and the tall
window's result lie within ``ground_band`` px of the plane (it *is* ground), otherwise with
the small window (a rock, or anything off the plane), otherwise it keeps its first-pass value.

Status: opt-in (``depth.ground_refine``, default off). It lowers the ground's height noise
about 2.5x (``bench_depth_heights.py --frames 3 --set ground_refine=true``, depth v5:
ground_sd mojave 0.82 -> 0.34 cm, lava 0.70 -> 0.41 cm, EPE 0.169 -> 0.122 px), but it
pulls the tops of low rocks onto the plane (rock_top mojave 1.27 -> 1.85 cm, lava 0.78 ->
1.31 cm: the small rocks of the built-in archives stand only about 0.25 px of disparity
above their surroundings, within ``ground_band``), and segmentation collapses on mojave and
lava (object F1 0.907 -> 0.10 and 0.673 -> 0.08 with ``bench_segment.py --depth stage``,
4 frames, the depth defaults overridden). What misfires: the segment stage measures the
ground's noise per frame (2.9 mm on mojave seed 0 instead of 8.3 mm), which puts the frame
in its *precise* regime, where every pixel more than 4 sigma (11.5 mm) above its local
ground is object (rule R1). The matcher's foreground fattening survives the refinement: the
ground just above a rock in the image (farther, within 4 px) carries the rock's disparity,
+21 mm median (+39 mm without the refinement), so R1 adds a halo (6256 px on that frame)
and the objects grow to 1.5-3x their true size (IoU < 0.5). With the true heights the same
rules work (their halo is absent). Crisp edges alone are not enough, though: with the truth's
disparity put in on the ground within 24 px of every rock (an oracle of a perfect edge
filter; ``benchmarks/bench_depth_edges.py --segment --truth-near 24 RUNDIR`` on 12-frame
catalog runs made with ``--set depth.ground_refine=true``) object F1 is mojave 0.119 ->
0.658 and lava 0.172 -> 0.648, with the rocks' own pixels true as well (``--truth-rocks``)
0.764 and 0.791, against 0.898 and 0.776 without the refinement: in the precise regime the
rules also need the rocks' full heights (the refinement and the windows pull them down) and
find false rocks far from any edge. The whole frame true gives 0.934 and 0.789, so the
refinement needs rules for its precise-regime heights before it can be the default.

How. For each ``delta`` in ``[-reach, reach]`` (``step`` apart) the other image is resampled
(linear interpolation, ``cv2.remap``) and the ZNCC of every pixel's window is computed from
box filters; the best ``delta`` with a parabola through its neighbours gives the refined
disparity. A result needs an interior peak of ZNCC at least ``min_ncc``. Pixels invalid in
the first pass stay invalid (the refinement never adds matches: the left-right check and
the distinctness test of the first pass stay in force).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

__all__ = ["fit_disparity_plane", "refine_against_ground"]


def _coerce_window(window: Any, name: str) -> tuple[int, int]:
    values = [window, window] if isinstance(window, int | np.integer) else list(window)
    shape = tuple(int(v) for v in values)
    if len(shape) != 2 or any(v < 3 or v % 2 == 0 or v > 63 for v in shape):
        raise ValueError(f"{name} must be odd (rows, columns) in [3, 63], got {window!r}")
    return shape[0], shape[1]


def fit_disparity_plane(
    disparity: np.ndarray, *, inlier_px: float = 1.0, stride: int = 3
) -> np.ndarray | None:
    """Robust least-squares plane ``d = alpha x + beta y + gamma`` through valid disparities.

    Parameters
    ----------
    disparity : (M, N) ndarray of float32
        NaN invalid.
    inlier_px : float
        Residual band (px) of the iterated refits, > 0.
    stride : int
        Every ``stride``-th row and column enters the fit (speed), >= 1.

    Returns
    -------
    (3,) ndarray of float64 or None
        ``(alpha, beta, gamma)``; None with fewer than 10 valid samples.
    """
    d = np.asarray(disparity, dtype=np.float64)[::stride, ::stride]
    ys, xs = np.nonzero(np.isfinite(d))
    if ys.size < 10:
        return None
    values = d[ys, xs]
    design = np.column_stack([xs * stride, ys * stride, np.ones(xs.size)]).astype(np.float64)
    # start from the median level, widen-then-narrow bands absorb the rocks
    coef = np.array([0.0, 0.0, float(np.median(values))])
    for band in (8.0 * inlier_px, 4.0 * inlier_px, 2.0 * inlier_px, inlier_px, inlier_px):
        keep = np.abs(design @ coef - values) <= band
        if np.count_nonzero(keep) < 10:
            break
        coef, *_ = np.linalg.lstsq(design[keep], values[keep], rcond=None)
    return coef


def _box(a: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    return cv2.boxFilter(a, -1, (window[1], window[0]), borderType=cv2.BORDER_REFLECT)


def _sweep(
    ref: np.ndarray,
    oth: np.ndarray,
    base: np.ndarray,
    window: tuple[int, int],
    offsets: np.ndarray,
    min_ncc: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Best disparity ``base + delta`` (subpixel) per pixel and whether it is accepted."""
    h, w = ref.shape
    grid_x = np.arange(w, dtype=np.float32)[None, :] + base
    grid_y = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, axis=1)
    mean_r = _box(ref, window)
    var_r = _box(ref * ref, window) - mean_r * mean_r
    scores = np.empty((offsets.size, h, w), np.float32)
    for i, delta in enumerate(offsets):
        warped = cv2.remap(
            oth, grid_x + np.float32(delta), grid_y, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )  # fmt: skip
        mean_o = _box(warped, window)
        var_o = _box(warped * warped, window) - mean_o * mean_o
        cov = _box(ref * warped, window) - mean_r * mean_o
        scores[i] = cov / np.sqrt(np.maximum(var_r * var_o, 1e-6))
    n = offsets.size
    best = np.argmax(scores, axis=0)
    centre = np.clip(best, 1, n - 2)[None]
    c0 = np.take_along_axis(scores, centre, 0)[0]
    cm = np.take_along_axis(scores, centre - 1, 0)[0]
    cp = np.take_along_axis(scores, centre + 1, 0)[0]
    curvature = cm - 2.0 * c0 + cp
    concave = curvature < 0
    vertex = np.where(concave, 0.5 * (cm - cp) / np.where(concave, curvature, -1.0), 0.0)
    step = float(offsets[1] - offsets[0])
    result = base + offsets[centre[0]] + np.clip(vertex, -0.5, 0.5) * step
    accepted = (best > 0) & (best < n - 1) & (c0 >= min_ncc) & (var_r > 0)
    return result.astype(np.float32), accepted


def refine_against_ground(
    reference: np.ndarray,
    other: np.ndarray,
    disparity: np.ndarray,
    *,
    plane: np.ndarray,
    tall_window: Any = (15, 41),
    small_window: Any = (7, 11),
    reach: float = 1.0,
    step: float = 0.25,
    ground_band: float = 0.3,
    min_ncc: float = 0.3,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine a first-pass disparity by matching relative to the ground plane.

    Parameters
    ----------
    reference, other : (M, N) ndarray of uint8
        The matched pair (reference ``x`` is at ``x + d`` in ``other``).
    disparity : (M, N) ndarray of float32
        First-pass disparity, NaN invalid; only valid pixels are refined.
    plane : (3,) ndarray of float
        ``(alpha, beta, gamma)``: ground disparity ``alpha x + beta y + gamma``
        (:func:`fit_disparity_plane`).
    tall_window, small_window : int or (int, int)
        Odd (rows, columns) of the ground window and of the off-ground window.
    reach, step : float
        Residuals ``-reach .. reach`` px around the first pass's coarse offset, ``step``
        apart (``reach >= 2 step > 0``).
    ground_band : float
        A tall-window result within this many px of the plane counts as ground.
    min_ncc : float in [-1, 1]
        Least ZNCC of an accepted refinement.

    Returns
    -------
    refined : (M, N) ndarray of float32
        NaN where ``disparity`` is NaN.
    source : (M, N) ndarray of int8
        0 first pass kept (or invalid), 1 tall (ground) window, 2 small window.
    """
    ref = np.asarray(reference)
    oth = np.asarray(other)
    d = np.asarray(disparity, dtype=np.float32)
    if ref.ndim != 2 or ref.shape != oth.shape or ref.shape != d.shape:
        raise ValueError(
            f"reference, other and disparity must be 2-D of one shape, got {ref.shape}, "
            f"{oth.shape}, {d.shape}"
        )
    coef = np.asarray(plane, dtype=np.float64)
    if coef.shape != (3,) or not np.all(np.isfinite(coef)):
        raise ValueError(f"plane must be 3 finite coefficients (alpha, beta, gamma), got {plane!r}")
    tall = _coerce_window(tall_window, "tall_window")
    small = _coerce_window(small_window, "small_window")
    if not (step > 0 and reach >= 2 * step):
        raise ValueError(f"need step > 0 and reach >= 2 step, got reach={reach}, step={step}")
    if not -1.0 <= min_ncc <= 1.0 or ground_band < 0:
        raise ValueError(f"need min_ncc in [-1, 1], ground_band >= 0; got {min_ncc}, {ground_band}")
    h, w = d.shape
    yy, xx = np.indices((h, w), dtype=np.float64)
    ground = (coef[0] * xx + coef[1] * yy + coef[2]).astype(np.float32)
    valid = np.isfinite(d)
    # coarse offset of the first pass from the plane: 0 on the ground (the window follows the
    # plane exactly), else the median of its neighbourhood in half-pixel steps
    above = np.where(valid, d - ground, 0.0).astype(np.float32)
    coarse = cv2.medianBlur(above, 5)
    coarse = np.where(np.abs(coarse) < 0.75, 0.0, np.round(coarse * 2.0) / 2.0)
    base = (ground + coarse).astype(np.float32)
    offsets = np.arange(-reach, reach + 1e-9, step, dtype=np.float64)
    ref_f = ref.astype(np.float32)
    oth_f = oth.astype(np.float32)
    tall_d, tall_ok = _sweep(ref_f, oth_f, base, tall, offsets, min_ncc)
    small_d, small_ok = _sweep(ref_f, oth_f, base, small, offsets, min_ncc)
    # ground: both the first pass and the tall window put the pixel on the plane (the tall
    # window alone pulls low rocks' tops onto it)
    near = (np.abs(tall_d - ground) < ground_band) & (np.abs(d - ground) < ground_band)
    on_ground = valid & tall_ok & near
    off_ground = valid & ~on_ground & small_ok
    refined = np.where(on_ground, tall_d, np.where(off_ground, small_d, d)).astype(np.float32)
    source = np.zeros((h, w), np.int8)
    source[on_ground] = 1
    source[off_ground] = 2
    return refined, source
