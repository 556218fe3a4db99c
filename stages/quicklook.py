"""Quicklook PNGs per frame, drawn with OpenCV (a few milliseconds per image).

``quicklooks/<frame_id>/objects.png``
    Reference (right) image with each object's outline and id (the study's Fig. 10).
``quicklooks/<frame_id>/range_contours.png``
    Lines of equal range every ``range_step_m`` metres, labelled in metres, over the
    reference image (Fig. 14 and 17). Range is smoothed by a NaN-aware Gaussian (sigma
    1.5 px) without the pixels under half its 0.5th or over twice its 99.5th percentile
    (version 4: a few wrong matches at 170 m had widened the step to 5 m) and quantised to
    ``floor(range / step)``; the line pixels are where the quantised level changes between
    4-neighbours, so no contour runs along the image border.
``quicklooks/<frame_id>/residual.png``
    Left minus right beside left minus pseudo-left (Fig. 15 and 18), both on the same gray
    scale (mid-gray = 0); undefined residual pixels are dark blue. With the camera's
    reference ``left`` the residual is right minus pseudo-right, beside right minus left.

With ``every = N`` (> 1) only about one frame in N gets quicklooks: those whose frame id's
CRC-32 is a multiple of N, so the choice does not depend on which frames a run selects or in
which order they finish (``arroyo report`` draws the others from the products). The three
PNGs cost ~14 ms of CPU per 500x500 frame: ~6.5 ms drawing, ~7.5 ms encoding (:mod:`stages._png`).
"""

from __future__ import annotations

import functools
import math
import zlib
from typing import Any

import cv2
import numpy as np
from numba import njit
from scipy import ndimage

from pipeline.stage import FrameContext, Param, Product, Stage, StageResult

from ._png import encode_png

__all__ = [
    "STAGE",
    "objects_image",
    "range_contours_image",
    "residual_image",
    "residual_labels",
    "encode_png",
    "draws_frame",
    "run_quicklook",
]

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_MAX_LEVELS = 30
_PANEL_GAP_PX = 4
_UNDEFINED_BGR = (90, 20, 0)
# Tableau-like palette (BGR), cycled by object id so neighbours usually differ
_PALETTE = (
    (180, 119, 31),
    (14, 127, 255),
    (44, 160, 44),
    (40, 39, 214),
    (189, 103, 148),
    (75, 86, 140),
    (194, 119, 227),
    (34, 189, 188),
    (207, 190, 23),
)


def _coerce_image(name: str, image: np.ndarray) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (M, N) gray image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float64)), 0, 255).astype(np.uint8)
    return a


def _check_shape(name: str, array: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(array)
    if a.shape != shape:
        raise ValueError(
            f"{name} must have the reference image's shape {shape}, got {a.shape}; pass the "
            "same frame's products"
        )
    return a


def _text(img: np.ndarray, text: str, org: tuple[int, int], color: tuple[int, ...]) -> None:
    scale = 0.35 if min(img.shape[:2]) < 300 else 0.45
    cv2.putText(img, text, org, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, _FONT, scale, color, 1, cv2.LINE_AA)


def objects_image(gray: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Reference image with object outlines and ids.

    Parameters
    ----------
    gray : (M, N) ndarray of uint8
    labels : (M, N) ndarray of int32
        0 = background.

    Returns
    -------
    (M, N, 3) ndarray of uint8
        BGR image.
    """
    g = _coerce_image("gray", gray)
    lab = _check_shape("labels", labels, g.shape)
    out = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    # (labels are >= 0 as the segment stage writes them: no copy then)
    positive = lab if lab.size == 0 or lab.min() >= 0 else np.where(lab > 0, lab, 0)
    if positive.dtype.kind not in "iu":  # find_objects takes integer labels of any width
        positive = positive.astype(np.int64)
    slices = ndimage.find_objects(positive)
    for index, sl in enumerate(slices, start=1):
        if sl is None:
            continue
        mask = (lab[sl] == index).astype(np.uint8)
        contours, _ = cv2.findContours(
            mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(sl[1].start, sl[0].start)
        )
        color = _PALETTE[index % len(_PALETTE)]
        cv2.drawContours(out, contours, -1, color, 1, cv2.LINE_8)
        # the most interior pixel stays inside concave or wrapped-around objects
        # (a zero border so the frame's edge counts as outside; copyMakeBorder is ~10x np.pad)
        padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        inner = cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]
        row, col = np.unravel_index(int(np.argmax(inner)), inner.shape)
        org = (int(col) + sl[1].start - 3, int(row) + sl[0].start + 4)
        _text(out, str(index), org, color)
    return out


def _smooth_nan(values: np.ndarray, sigma: float) -> np.ndarray:
    v = np.asarray(values, dtype=np.float32)
    finite = np.isfinite(v)
    num = cv2.GaussianBlur(np.where(finite, v, np.float32(0.0)), (0, 0), sigma)
    den = cv2.GaussianBlur(finite.astype(np.float32), (0, 0), sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        np.divide(num, den, out=num)
    num[den <= 0.5] = np.nan
    return num


def range_contours_image(
    gray: np.ndarray, range_m: np.ndarray, *, step_m: float = 0.25
) -> np.ndarray:
    """Lines of equal range, labelled in metres, over the reference image.

    Parameters
    ----------
    gray : (M, N) ndarray of uint8
    range_m : (M, N) ndarray of float32
        Metres, NaN where invalid.
    step_m : float
        Spacing of the levels, metres, > 0 (widened to keep at most 30 lines).

    Returns
    -------
    (M, N, 3) ndarray of uint8
        BGR image.
    """
    if not (isinstance(step_m, int | float) and math.isfinite(step_m) and step_m > 0):
        raise ValueError(f"step_m must be a finite number > 0, got {step_m!r}")
    g = _coerce_image("gray", gray)
    rng = np.asarray(_check_shape("range", range_m, g.shape), dtype=np.float32)
    out = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    # a few wrong matches (disparity near 0: ranges of 170 m in a 1.4-3.8 m frame) set the
    # span that widens the step, and a 1024x768 frame got 5.25 m contours, none across it
    smooth = _smooth_nan(_without_outliers(rng), 1.5)
    lo, hi = _finite_range(smooth)
    if not lo <= hi:  # no finite range at all
        return out
    step = float(step_m) * max(1, math.ceil((hi - lo) / step_m / _MAX_LEVELS))
    rows = np.empty(smooth.size, np.int64)
    cols = np.empty(smooth.size, np.int64)
    crossed = np.empty(smooth.size, np.int64)
    # float32 quotients, as numpy divides a float32 array by a Python float
    n = _crossings(smooth, np.float32(step), rows, cols, crossed)
    if n == 0:
        return out
    rows, cols, crossed = rows[:n], cols[:n], crossed[:n]
    # levels are small non-negative ints: a count per level finds them without sorting
    present = np.bincount(crossed)
    present[0] = 0
    levels = np.flatnonzero(present)
    span = max(int(levels.max() - levels.min()), 1)
    hues = ((levels - levels.min()) * 200 // span).astype(np.uint8)
    colors = cv2.applyColorMap(hues.reshape(-1, 1), cv2.COLORMAP_JET).reshape(-1, 3)
    rank = np.zeros(present.size, dtype=np.intp)
    rank[levels] = np.arange(levels.size)
    which = rank[crossed]
    out[rows, cols] = colors[which]
    _label_levels(out, rows, cols, which, [f"{lvl * step:.2f} m" for lvl in levels], colors)
    return out


_RANGE_QUANTILES = (0.5, 99.5)
"""Percentiles of a frame's range; a pixel under half the first or over twice the second is
left out of the contours (none of the built-in archives' pixels is)."""


def _without_outliers(range_m: np.ndarray) -> np.ndarray:
    """``range_m`` with NaN where it lies far outside the frame's bulk (the percentiles of
    one pixel in 31, 8,000 of a 500x500 frame: ~0.3 ms); ``range_m`` itself when nothing does."""
    flat = range_m.ravel()
    sample = flat[::31] if flat.size > 31_000 else flat
    sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        return range_m
    low, high = np.percentile(sample, _RANGE_QUANTILES)
    with np.errstate(invalid="ignore"):
        outside = (range_m < low / 2) | (range_m > 2 * high)
    if not outside.any():
        return range_m
    return np.where(outside, np.float32(np.nan), range_m)


@njit(cache=True)
def _finite_range(values):  # pragma: no cover - numba
    """Smallest and largest finite value (``inf, -inf`` when there is none)."""
    lo, hi = np.inf, -np.inf
    for v in values.ravel():
        if np.isfinite(v):
            lo = min(lo, v)
            hi = max(hi, v)
    return lo, hi


@njit(cache=True)
def _crossings(smooth, step, rows, cols, crossed):  # pragma: no cover - numba
    """The line pixels of :func:`range_contours_image` in raster order; returns their count.

    A pixel's level is ``floor(smooth / step)`` (float32), none where ``smooth`` is NaN or
    the level is negative. A pixel is on a line where its level differs from its right or
    lower neighbour's; ``crossed`` is the upper level of the crossing (the larger of the
    two when both neighbours differ), always >= 1. One pass instead of a dozen whole-grid
    numpy ones (``test_quicklook.py`` compares with them).
    """
    height, width = smooth.shape
    level = np.empty((height, width), np.int32)
    for y in range(height):
        for x in range(width):
            v = smooth[y, x]
            level[y, x] = np.int32(np.floor(v / step)) if np.isfinite(v) else -1
    n = 0
    for y in range(height):
        for x in range(width):
            a = level[y, x]
            if a < 0:
                continue
            upper = 0
            if x + 1 < width:
                b = level[y, x + 1]
                if b >= 0 and b != a:
                    upper = max(upper, a, b)
            if y + 1 < height:
                b = level[y + 1, x]
                if b >= 0 and b != a:
                    upper = max(upper, a, b)
            if upper > 0:
                rows[n], cols[n], crossed[n] = y, x, upper
                n += 1
    return n


@functools.lru_cache(maxsize=16)
def _text_size(n_chars: int, scale: float) -> tuple[int, int]:
    (width, height), _ = cv2.getTextSize("0" * n_chars, _FONT, scale, 1)
    return width, height


def _label_levels(
    out: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    which: np.ndarray,
    texts: list[str],
    colors: np.ndarray,
) -> None:
    """Put each level's label on its line, at the first candidate column where it overlaps
    no label already placed (crowded far levels stay unlabelled rather than illegible)."""
    scale = 0.35 if min(out.shape[:2]) < 300 else 0.45
    width = out.shape[1]
    # fewer than 2**15 levels: a stable sort of int16 is a radix sort, ~10x numpy's default
    order = np.argsort(which.astype(np.int16), kind="stable")
    starts = np.searchsorted(which[order], np.arange(len(texts) + 1))
    placed: list[tuple[int, int, int, int]] = []
    # one size for all labels (they share a format); getTextSize is slow, so it is cached
    tw, th = _text_size(len(max(texts, key=len)), scale)
    x_max, y_min, y_max = max(width - tw, 0), th + 1, out.shape[0] - 1
    for index, text in enumerate(texts):
        members = order[starts[index] : starts[index + 1]]
        if members.size == 0:
            continue
        member_cols = cols[members]
        for anchor in (0.5, 0.3, 0.7, 0.12, 0.88):
            pick = members[int(np.argmin(np.abs(member_cols - anchor * width)))]
            # clipped as np.clip would (the upper bound wins when the bounds cross)
            x0 = min(max(int(cols[pick]) - tw // 2, 0), x_max)
            y1 = min(max(int(rows[pick]) - 2, y_min), y_max)
            box = (x0 - 2, y1 - th - 2, x0 + tw + 2, y1 + 3)
            if all(
                box[2] <= b[0] or b[2] <= box[0] or box[3] <= b[1] or b[3] <= box[1] for b in placed
            ):
                placed.append(box)
                # half-way to white: dark line colours stay legible on the black outline
                _text(out, text, (x0, y1), tuple(int(c) // 2 + 128 for c in colors[index]))
                break


@njit(cache=True)
def _diff_panel(diff, scale, undefined, out):  # pragma: no cover - numba
    """Paint ``out`` (M, N, 3) gray ``128 + scale * diff`` (float32 product, then sum,
    clipped to 0..255 and truncated, as numpy's float32 passes and ``astype(np.uint8)`` do)
    and ``undefined`` (B, G, R) where ``diff`` is not finite."""
    rows, cols = diff.shape
    for y in range(rows):
        for x in range(cols):
            d = diff[y, x]
            if np.isfinite(d):
                level = d * scale
                level = level + np.float32(128.0)
                level = min(max(level, np.float32(0.0)), np.float32(255.0))
                gray = np.uint8(level)
                out[y, x, 0] = gray
                out[y, x, 1] = gray
                out[y, x, 2] = gray
            else:
                out[y, x, 0] = undefined[0]
                out[y, x, 1] = undefined[1]
                out[y, x, 2] = undefined[2]


def residual_labels(reference: str) -> tuple[str, str]:
    """Titles of the residual image's panels for the camera's ``reference`` image.

    Parameters
    ----------
    reference : {'right', 'left'}

    Returns
    -------
    (str, str)
        ``("left - right", "left - pseudo-left")`` for ``'right'``, ``("right - left",
        "right - pseudo-right")`` for ``'left'``: the other image minus the reference
        before and after warping it by the disparity.
    """
    if reference not in ("right", "left"):
        raise ValueError(f"reference must be 'right' or 'left', got {reference!r}")
    other = "left" if reference == "right" else "right"
    return f"{other} - {reference}", f"{other} - pseudo-{other}"


def residual_image(
    left: np.ndarray, right: np.ndarray, residual: np.ndarray, *, reference: str = "right"
) -> np.ndarray:
    """The other image minus the reference beside the depth stage's residual, on one gray
    scale.

    Parameters
    ----------
    left, right : (M, N) ndarray of uint8
    residual : (M, N) ndarray of float32
        Left minus pseudo-left (reference ``'right'``) or right minus pseudo-right
        (``'left'``), NaN where undefined.
    reference : {'right', 'left'}
        The camera's reference image; names and orders the panels (:func:`residual_labels`).

    Returns
    -------
    (M, 2 N + 4, 3) ndarray of uint8
        BGR: left panel ``left - right`` (``right - left``), right panel the residual;
        mid-gray is 0, the scale maps the 99th percentile of ``|left - right|`` (on a 1-in-9
        pixel sample) to full contrast.
    """
    titles = residual_labels(reference)
    lf = _coerce_image("left", left).astype(np.float32)
    rt = _coerce_image("right", right).astype(np.float32)
    _check_shape("right", rt, lf.shape)
    res = np.asarray(_check_shape("residual", residual, lf.shape), dtype=np.float32)
    raw = lf - rt if reference == "right" else rt - lf
    # every 3rd pixel of every 3rd row is plenty for a display scale
    sample = np.abs(raw[::3, ::3]) if raw.size >= 900 else np.abs(raw)
    spread = float(np.percentile(sample, 99)) if raw.size else 0.0
    scale = 127.0 / max(spread, 1.0)
    h, w = lf.shape
    out = np.empty((h, 2 * w + _PANEL_GAP_PX, 3), dtype=np.uint8)
    out[:, w : w + _PANEL_GAP_PX] = 255  # the white gap; the panels are painted whole
    # float32 arithmetic, as numpy multiplies a float32 array by a Python float
    undefined = np.array(_UNDEFINED_BGR, np.uint8)
    _diff_panel(raw, np.float32(scale), undefined, out[:, :w])
    _diff_panel(res, np.float32(scale), undefined, out[:, w + _PANEL_GAP_PX :])
    _text(out, titles[0], (3, 12), (255, 255, 255))
    _text(out, titles[1], (w + _PANEL_GAP_PX + 3, 12), (255, 255, 255))
    return out


def draws_frame(frame_id: str, *, every: int) -> bool:
    """Whether a frame gets quicklooks when only about one frame in ``every`` does.

    Parameters
    ----------
    frame_id : str
    every : int
        >= 1; 1 draws every frame.
    """
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every must be an integer >= 1, got {every!r}; use 1 for all frames")
    return zlib.crc32(frame_id.encode()) % every == 0


def run_quicklook(
    inputs: dict[str, np.ndarray], *, frame: FrameContext, params: dict[str, Any]
) -> StageResult:
    """Stage entry point: three PNGs under ``quicklooks/<frame_id>/``."""
    if not params.get("enabled", True):
        return StageResult(notes=["quicklooks disabled"])
    every = params.get("every", 1)
    if not draws_frame(frame.frame_id, every=every):
        return StageResult(notes=[f"no quicklooks: drawn for about one frame in {every}"])
    prefix = f"quicklooks/{frame.frame_id}"
    reference = inputs[frame.camera.reference]
    step = params.get("range_step_m", 0.25)
    files = {
        f"{prefix}/objects.png": encode_png(objects_image(reference, inputs["labels"])),
        f"{prefix}/range_contours.png": encode_png(
            range_contours_image(reference, inputs["range"], step_m=step)
        ),
        f"{prefix}/residual.png": encode_png(
            residual_image(
                inputs["left"],
                inputs["right"],
                inputs["residual"],
                reference=frame.camera.reference,
            )
        ),
    }
    return StageResult(files=files)


STAGE = Stage(
    name="quicklook",
    version="4",
    inputs=("left", "right", "labels", "range", "residual"),
    outputs=(Product("quicklooks", kind="files"),),
    params=(
        Param("enabled", bool, True, "write quicklook PNGs"),
        Param(
            "every",
            int,
            1,
            "draw for about one frame in N (chosen by frame id); 1 = every frame",
            minimum=1,
        ),
        Param("range_step_m", float, 0.25, "spacing of the range contours, m", minimum=0.001),
    ),
    run=run_quicklook,
    doc="quicklook PNGs: object outlines, range contours, stereo residuals",
)
