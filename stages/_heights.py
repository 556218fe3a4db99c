"""Height maps for the depth rules: smoothing, local ground (R0), noise, per-object percentiles.

What the rules of :mod:`stages._depth_rules` (regimes, R1/R2, R0b, R3b) and
:mod:`stages._height_vote` (the noisy regime's vote, R2-R2d) share: the NaN-aware 5x5
median of the heights (:func:`smooth_height`), the coarse local ground they are read
against (:func:`local_ground`, rule R0), the robust (MAD) noise of a set of heights,
nearest-rank percentiles per labelled object, and :class:`DepthRuleStats`, the per-frame
record every regime fills.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit
from scipy.ndimage import median_filter

from ._select import median_abs_deviation32, median_filter_nearest32

__all__ = [
    "check_height_inputs",
    "DepthRuleStats",
    "smooth_height",
    "local_ground",
    "relative_height",
]


@dataclass
class DepthRuleStats:
    """How many pixels each depth rule changed (for the per-frame figures)."""

    raised_added_px: int = 0
    flat_removed_px: int = 0
    depth_valid_fraction: float = 0.0
    raise_threshold_m: float = float("nan")
    flat_threshold_m: float = float("nan")
    ground_sigma_m: float = float("nan")
    notes: list[str] = field(default_factory=list)


def smooth_height(height: np.ndarray, *, window: int = 5) -> np.ndarray:
    """NaN-aware median of the height map.

    Parameters
    ----------
    height : (M, N) ndarray of float32
        Metres above ground, NaN where invalid.
    window : {1, 3, 5}
        Median window; 1 returns the input.

    Returns
    -------
    smoothed : (M, N) ndarray of float32
        NaN where the input is NaN; elsewhere the median of the window with invalid
        neighbours counted as ground (0), which biases isolated spikes down, never up.
    """
    if window not in (1, 3, 5):
        raise ValueError(f"window must be 1, 3 or 5 (OpenCV float median), got {window}")
    height = np.asarray(height, dtype=np.float32)
    if window == 1:
        return height
    valid, filled = _filled(height)
    smoothed = cv2.medianBlur(filled, window)
    _set_invalid(smoothed, valid, np.float32(np.nan))
    return smoothed


def local_ground(height: np.ndarray, *, window_px: int = 72) -> np.ndarray:
    """Large-scale ground level of a height map: a coarse NaN-aware median.

    Parameters
    ----------
    height : (M, N) ndarray of float32
        Metres above the fitted plane, NaN where invalid.
    window_px : int
        ``>= 9``; side of the median window in pixels. Objects narrower than half of it do
        not lift the estimate.

    Returns
    -------
    ground : (M, N) ndarray of float32
        Finite everywhere (0, the plane, where no valid height is near).
    """
    if window_px < 9:
        raise ValueError(f"window_px must be >= 9, got {window_px}")
    # invalid pixels vote for the plane itself: the fit already describes the ground
    return _ground_of_filled(_filled(height)[1], window_px=window_px)


def _ground_of_filled(filled: np.ndarray, *, window_px: int) -> np.ndarray:
    """:func:`local_ground` of a float32 height map whose invalid pixels are 0 already."""
    rows, cols = filled.shape
    factor = max(1, window_px // 9)
    small_shape = (max(1, rows // factor), max(1, cols // factor))
    small = cv2.resize(filled, small_shape[::-1], interpolation=cv2.INTER_AREA)
    coarse = _median_filter_nearest(small, size=min(9, *small_shape))
    return cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_LINEAR)


def relative_height(height: np.ndarray, *, smoothing_px: int, ground_window_px: int) -> np.ndarray:
    """Smoothed heights above the local ground (R0 of :mod:`stages._depth_rules`).

    ``smooth_height(height, window=smoothing_px)`` minus its :func:`local_ground`; NaN
    exactly where the smoothed map is NaN (the local ground is finite everywhere).

    Parameters
    ----------
    height : (M, N) ndarray of float32
        Metres above the fitted plane, NaN where invalid.
    smoothing_px : {1, 3, 5}
        Median window of the height map.
    ground_window_px : int
        ``>= 9``; window of the local ground level.

    Returns
    -------
    (M, N) ndarray of float32
    """
    if smoothing_px not in (1, 3, 5):
        raise ValueError(
            "smoothing_px (segment's height_smoothing_px) must be 1, 3 or 5 (OpenCV's float "
            f"median), got {smoothing_px}"
        )
    if ground_window_px < 9:
        raise ValueError(f"ground_window_px must be >= 9 (px), got {ground_window_px}")
    height = np.asarray(height, dtype=np.float32)
    valid, filled = _filled(height)
    if smoothing_px > 1:
        # the smoothed map with its invalid pixels at 0: the local ground's own input
        filled = cv2.medianBlur(filled, smoothing_px)
        _set_invalid(filled, valid, np.float32(0.0))
    ground = _ground_of_filled(filled, window_px=ground_window_px)
    # ``smooth_height(...) - local_ground(smooth_height(...))`` in one pass: the smoothed
    # map is the filled one where valid, NaN elsewhere (the input itself when not smoothed)
    relative = np.empty(height.shape, np.float32)
    _relative_pass(filled, valid, height, smoothing_px == 1, ground, relative)
    return relative


def _filled(height: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.isfinite(height)`` and ``height`` as float32 with 0 where not finite (one
    compiled pass instead of ``np.where``'s three)."""
    valid = np.empty(height.shape, bool)
    filled = np.empty(height.shape, np.float32)
    _fill_pass(height, valid, filled)
    return valid, filled


@njit(cache=True)
def _fill_pass(height, valid, filled):  # pragma: no cover - numba
    rows, cols = height.shape
    for y in range(rows):
        for x in range(cols):
            value = height[y, x]
            ok = np.isfinite(value)
            valid[y, x] = ok
            filled[y, x] = np.float32(value) if ok else np.float32(0.0)


@njit(cache=True)
def _set_invalid(values, valid, fill):  # pragma: no cover - numba
    """``values[~valid] = fill``, in place."""
    rows, cols = values.shape
    for y in range(rows):
        for x in range(cols):
            if not valid[y, x]:
                values[y, x] = fill


@njit(cache=True)
def _relative_pass(filled, valid, source, keep_invalid, ground, out):  # pragma: no cover
    """``out = smoothed - ground`` in float32, ``smoothed`` being ``filled`` where valid and
    elsewhere NaN (or ``source``'s own value when ``keep_invalid``: an unsmoothed map)."""
    rows, cols = out.shape
    nan = np.float32(np.nan)
    for y in range(rows):
        for x in range(cols):
            if valid[y, x]:
                value = filled[y, x]
            elif keep_invalid:
                value = source[y, x]
            else:
                value = nan
            out[y, x] = value - ground[y, x]


def _median_filter_nearest(image: np.ndarray, *, size: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(image, size, mode='nearest')``, faster for odd sizes.

    A median picks one of the window's values, so selecting it with ``np.partition`` over
    all windows at once gives the same array; scipy's rank filter is slow on floats.
    """
    if size % 2 == 0 or image.ndim != 2:
        return median_filter(image, size=size, mode="nearest")
    if (
        image.dtype == np.float32
        and np.isfinite(image).all()
        and not (np.signbit(image) & (image == 0)).any()
    ):
        # ranks in a sliding histogram: a third of the cost of the selections below;
        # a selection may return either of 0.0 and -0.0, the ranks one of them: none here
        return median_filter_nearest32(image, size=size)
    half = size // 2
    padded = np.pad(image, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (size, size))
    flat = windows.reshape(image.shape[0], image.shape[1], size * size)
    middle = (size * size) // 2
    return np.partition(flat, middle, axis=-1)[..., middle].astype(image.dtype, copy=False)


def _ground_heights(relative: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``relative[np.isfinite(relative) & ~mask]`` (2-D arrays of one shape) in one compiled
    pass: the heights whose MAD is the ground's noise."""
    values = np.empty(relative.size, relative.dtype)
    return values[: _ground_pass(relative, mask, values)]


@njit(cache=True)
def _ground_pass(relative, mask, values):  # pragma: no cover - numba
    rows, cols = relative.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            value = relative[y, x]
            if np.isfinite(value) and not mask[y, x]:
                values[n] = value
                n += 1
    return n


def _fraction(mask: np.ndarray) -> float:
    """``float(mask.mean())`` of a non-empty boolean mask, without its float64 copy: the
    mean adds 0s and 1s exactly, so the count over the size is the same float."""
    return int(np.count_nonzero(mask)) / mask.size  # (a numpy int would give np.float64)


def _robust_sigma(values: np.ndarray) -> float:
    if values.size < 10:
        return 0.0
    if values.dtype == np.float32 and values.ndim == 1 and np.isfinite(values).all():
        # the same float32 value by selection, at half the cost of two np.median
        return float(1.4826 * median_abs_deviation32(values))
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def _percentile_by_label(
    values: np.ndarray, labels: np.ndarray, count: int, percentile: float
) -> np.ndarray:
    """Nearest-rank (lower) ``percentile`` of ``values`` per label 0..count-1 (+inf if empty)."""
    return _percentiles_by_label(values, labels, count, (percentile,))[0]


def _percentiles_by_label(
    values: np.ndarray, labels: np.ndarray, count: int, percentiles: tuple[float, ...]
) -> np.ndarray:
    """Nearest-rank percentiles per label, shape ``(len(percentiles), count)``; one sort."""
    result = np.full((len(percentiles), count), np.inf)
    if values.size == 0:
        return result
    if values.dtype == np.float32 and labels.min() >= 0 and np.isfinite(values).all():
        return _float32_percentiles_by_label(values, labels, count, percentiles, result)
    values = np.asarray(values, dtype=np.float64)
    low, high = float(values.min()), float(values.max())
    if np.isfinite(low) and np.isfinite(high):
        # one sort of a combined key (label, then value) instead of a lexsort: 7x faster;
        # a label's keys span less than one unit, so labels never interleave
        order = np.argsort(labels * (high - low + 1.0) + (values - low))
    else:
        order = np.lexsort((values, labels))
    sorted_labels, sorted_values = labels[order], values[order]
    starts = np.searchsorted(sorted_labels, np.arange(count), side="left")
    stops = np.searchsorted(sorted_labels, np.arange(count), side="right")
    sizes = stops - starts
    present = sizes > 0
    for row, percentile in zip(result, percentiles, strict=True):
        # nearest-rank percentile: cheap and exact enough for a vote
        rank = starts + np.floor((percentile / 100.0) * (sizes - 1)).astype(np.int64)
        row[present] = sorted_values[rank[present]]
    return result


# float32 bits made order-preserving as int32: negative floats get their magnitude bits
# flipped (the same transform undoes it)
_MAGNITUDE_BITS = np.int32(0x7FFFFFFF)
_OFFSET = np.int64(2**31)


def _ordered_bits(bits: np.ndarray) -> np.ndarray:
    return bits ^ ((bits >> 31) & _MAGNITUDE_BITS)


def _float32_percentiles_by_label(
    values: np.ndarray,
    labels: np.ndarray,
    count: int,
    percentiles: tuple[float, ...],
    result: np.ndarray,
) -> np.ndarray:
    """:func:`_percentiles_by_label` of finite float32 values, labels ``>= 0``: one sort
    of int64 keys, the label in the upper 32 bits and the value's order-preserving bits in
    the lower ones (a radix sort, a third of the time of the float64 argsort); the kept
    bits are the values themselves."""
    keys = (labels.astype(np.int64) << 32) + _ordered_bits(values.view(np.int32)) + _OFFSET
    keys.sort()
    edges = np.searchsorted(keys, np.arange(count + 1, dtype=np.int64) << 32, side="left")
    starts, sizes = edges[:-1], np.diff(edges)
    present = sizes > 0
    for row, percentile in zip(result, percentiles, strict=True):
        rank = starts + np.floor((percentile / 100.0) * (sizes - 1)).astype(np.int64)
        kept = ((keys[rank[present]] & np.int64(0xFFFFFFFF)) - _OFFSET).astype(np.int32)
        row[present] = _ordered_bits(kept).view(np.float32)
    return result


def check_height_inputs(
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    row_noise: np.ndarray,
    *,
    noise_name: str = "row_noise",
) -> None:
    """Raise ValueError unless ``labels``, ``contrast`` and ``relative`` (heights above the
    local ground) share one (M, N) shape and ``row_noise`` holds one value per row, (M,):
    the inputs of the rules that read heights per row (R6c, R7e, R7f)."""
    if not labels.shape == contrast.shape == relative.shape:
        raise ValueError(
            f"labels {labels.shape}, contrast {contrast.shape} and relative {relative.shape} "
            "must have one shape"
        )
    if row_noise.shape != (labels.shape[0],):
        raise ValueError(
            f"{noise_name} must hold one value per row, shape ({labels.shape[0]},), got "
            f"{row_noise.shape}"
        )
