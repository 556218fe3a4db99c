"""Images in and out of stereo matching: input checks, the prefilter, speckle removal and
OpenCV's StereoSGBM.

Helpers of :mod:`stages._stereo` (the matcher) and :mod:`stages._stereo_tiles`; the
evaluation's baseline (:mod:`pipeline._baselines`) runs :func:`sgbm_disparity`.

Input checks. Matching takes rectified uint8 gray images of one shape (other integer images
in [0, 255] are converted) and an integer disparity range at least 3 disparities wide;
anything else raises a ValueError or TypeError that says what was expected.

Prefilter (opt-in). With ``prefilter`` > 0, ``adaptive`` and ``sgm`` match high-passed
images: each image minus its ``prefilter`` x ``prefilter`` box mean, times 2, rounded to
integer gray levels around 128 (:func:`prefilter_image`). Why: ZNCC removes a window's mean
but not a brightness *gradient* across it; under lamps the slow shading of a nearly uniform
floor can dominate a window's variance, so the curve is a broad hump and the peak is not
distinct although fine texture is there. Measured on the 12-frame catalogs: ``sgm`` on
dunes bad-2 23.1 -> 20.9 % with 15 px; lab 25.3 -> 21.7 % with the old 51x63 windows but
no gain with the wide 63x255 window (EPE 0.45 -> 0.49); mojave and lava bad-2 within
0.1 % but segmentation F1 about 0.7 points lower. Hence off by default. The arithmetic is
exact integer, so tiles still match the whole frame bit for bit.

Speckles (:func:`remove_speckles`). All methods finish by removing speckles: 4-connected
regions of at most ``speckle_size`` pixels whose neighbouring disparities differ by at most
``speckle_range`` px are isolated islands of (usually wrong) matches and are invalidated.

OpenCV's StereoSGBM (:func:`sgbm_disparity`), with the right image as reference: the
``opencv-sgbm`` method and the evaluation's baseline.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numba import njit

__all__ = ["prefilter_image", "remove_speckles", "speckle_mask", "sgbm_disparity"]


# ----------------------------------------------------------------------------- validation


def _coerce_image(image: Any, name: str) -> np.ndarray:
    array = np.asarray(image)
    if array.ndim != 2:
        raise ValueError(f"{name} must be a 2-D gray image, got shape {array.shape}")
    if array.dtype == np.uint8:
        return array
    if not np.issubdtype(array.dtype, np.integer):
        raise TypeError(
            f"{name} must be an integer gray image (uint8), got dtype {array.dtype}; "
            "convert with np.clip(image, 0, 255).astype(np.uint8)"
        )
    if array.size and (array.min() < 0 or array.max() > 255):
        raise ValueError(
            f"{name} gray levels must be in [0, 255], got [{array.min()}, {array.max()}]"
        )
    return array.astype(np.uint8)


def _coerce_pair(reference: Any, other: Any) -> tuple[np.ndarray, np.ndarray]:
    ref = _coerce_image(reference, "reference")
    oth = _coerce_image(other, "other")
    if ref.shape != oth.shape:
        raise ValueError(
            f"reference and other images must have the same shape, got {ref.shape} and "
            f"{oth.shape}; the pair must be rectified to a common size"
        )
    return ref, oth


def _coerce_range(min_disparity: Any, max_disparity: Any) -> tuple[int, int]:
    for name, value in (("min_disparity", min_disparity), ("max_disparity", max_disparity)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise TypeError(f"{name} must be an int, got {type(value).__name__} {value!r}")
    lo, hi = int(min_disparity), int(max_disparity)
    if hi - lo < 2:
        raise ValueError(
            f"max_disparity must exceed min_disparity by at least 2 (a peak needs two "
            f"neighbours), got min_disparity={lo}, max_disparity={hi}"
        )
    if max(abs(lo), abs(hi)) > 2000:
        raise ValueError(f"|disparity| must stay below 2000 px, got range [{lo}, {hi}]")
    return lo, hi


def _is_int(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


def _check_prefilter_size(name: str, value: Any, *, off: str = "") -> None:
    """The prefilter's box side: an odd int in [3, 63] (``off`` names the disabling value)."""
    if not (_is_int(value) and 3 <= value <= 63 and value % 2 == 1):
        raise ValueError(f"{name} must be {off}an odd int in [3, 63], got {value!r}")


# ------------------------------------------------------------------- pre- and post-processing


def prefilter_image(image: np.ndarray, *, size: int) -> np.ndarray:
    """High-pass a gray image: ``128 + 2 (image - box mean)``, rounded, clipped to uint8.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Gray image.
    size : int
        Odd box side in px, 3 to 63; the border is mirrored (``cv2.BORDER_REFLECT``).

    Returns
    -------
    (M, N) ndarray of uint8
        Integer arithmetic throughout (box sums from an int64 integral image, round half
        up), so a pixel's value depends only on its ``size`` x ``size`` neighbourhood, bit
        for bit, wherever the image is cut.
    """
    img = _coerce_image(image, "image")
    _check_prefilter_size("size", size)
    half = int(size) // 2
    padded = np.pad(img, half, mode="symmetric")  # = cv2.BORDER_REFLECT
    return _high_pass(padded, int(size))


@njit(cache=True)
def _high_pass(padded, size):  # pragma: no cover - numba
    """``clip(128 + floor((4 (n I - S) + n) / (2 n)), 0, 255)`` of the unpadded pixels:
    ``S`` the box sum (int64 integral image of the padded uint8 image), ``n = size**2``,
    i.e. 2 (I - S / n) rounded half up, all in integers."""
    k = size
    n = k * k
    half = k // 2
    ph, pw = padded.shape
    h = ph - k + 1
    w = pw - k + 1
    integral = np.zeros((ph + 1, pw + 1), np.int64)
    for y in range(ph):
        row = np.int64(0)
        above = integral[y]
        out = integral[y + 1]
        src = padded[y]
        for x in range(pw):
            row += np.int64(src[x])
            out[x + 1] = above[x + 1] + row
    high = np.empty((h, w), np.uint8)
    for y in range(h):
        top = integral[y]
        bottom = integral[y + k]
        centre = padded[y + half]
        for x in range(w):
            box = bottom[x + k] - top[x + k] - bottom[x] + top[x]
            value = (4 * (n * np.int64(centre[x + half]) - box) + n) // (2 * n) + 128
            high[y, x] = min(255, max(0, value))
    return high


@njit(cache=True)
def _fixed_point(disparity, invalid_code):  # pragma: no cover - numba
    """int16 disparity in 1/16 px (round half to even, as ``np.round``), ``invalid_code``
    where not finite: OpenCV's speckle filter's input, in one pass."""
    h, w = disparity.shape
    fixed = np.empty((h, w), np.int16)
    for y in range(h):
        for x in range(w):
            d = disparity[y, x]
            fixed[y, x] = np.int16(np.rint(d * np.float32(16))) if np.isfinite(d) else invalid_code
    return fixed


@njit(cache=True)
def _removed(disparity, marked, invalid_code):  # pragma: no cover - numba
    """Finite pixels that the speckle filter marked invalid."""
    h, w = disparity.shape
    removed = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            removed[y, x] = np.isfinite(disparity[y, x]) and marked[y, x] == invalid_code
    return removed


def speckle_mask(disparity: np.ndarray, *, max_size: int, max_diff: float) -> np.ndarray:
    """(M, N) bool: the finite pixels of ``disparity`` (float32; NaN or +-inf invalid)
    that :func:`remove_speckles` removes, without forming the cleaned map."""
    invalid_code = np.int16(-32768)
    marked = _fixed_point(disparity, invalid_code)
    cv2.filterSpeckles(marked, int(invalid_code), int(max_size), max(1, round(max_diff * 16)))
    return _removed(disparity, marked, invalid_code)


def remove_speckles(
    disparity: np.ndarray, *, max_size: int, max_diff: float
) -> tuple[np.ndarray, np.ndarray]:
    """Invalidate small connected islands of disparity.

    Parameters
    ----------
    disparity : (M, N) ndarray of float32
        Pixels, NaN invalid, ``|d| < 2000``.
    max_size : int
        Regions of at most this many pixels (4-connected) are removed.
    max_diff : float
        Neighbours whose disparities differ by at most this (px, resolved to 1/16) belong
        to the same region.

    Returns
    -------
    cleaned : (M, N) ndarray of float32
        ``disparity`` with the speckles set to NaN.
    removed : (M, N) ndarray of bool
        The pixels that were removed.
    """
    d = np.ascontiguousarray(disparity, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"disparity must be 2-D, got shape {d.shape}")
    removed = speckle_mask(d, max_size=max_size, max_diff=max_diff)
    cleaned = np.where(removed, np.nan, d).astype(np.float32)
    return cleaned, removed


def sgbm_disparity(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int,
    max_disparity: int,
    block_size: int = 5,
) -> np.ndarray:
    """OpenCV StereoSGBM disparity with the *right* image as reference (the baseline).

    OpenCV's matcher takes the left image as reference (left ``x`` matches right ``x - d``).
    Mirroring both images turns the right image into a left-reference image with the same
    positive disparities, so ``compute(flip(right), flip(left))`` flipped back is the
    right-reference disparity (right ``x`` matches left ``x + d``).

    Parameters
    ----------
    left, right : (M, N) ndarray of uint8
        Rectified gray pair.
    min_disparity, max_disparity : int
        Search range; OpenCV searches a multiple of 16 disparities from ``min_disparity``.
    block_size : int
        Odd matching block size; penalties P1 = 8 b^2, P2 = 32 b^2 (OpenCV's usual choice).

    Returns
    -------
    disparity : (M, N) ndarray of float32
        Right-reference disparity in px (1/16 px steps), NaN where OpenCV gives none.
    """
    right_u8, left_u8 = _coerce_pair(right, left)
    lo, hi = _coerce_range(min_disparity, max_disparity)
    count = int(np.ceil((hi - lo + 1) / 16.0)) * 16
    matcher = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=lo, numDisparities=count, blockSize=block_size,
        P1=8 * block_size**2, P2=32 * block_size**2, disp12MaxDiff=1,
        uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )  # fmt: skip
    raw = matcher.compute(
        np.ascontiguousarray(right_u8[:, ::-1]), np.ascontiguousarray(left_u8[:, ::-1])
    )[:, ::-1]
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < lo * 16] = np.nan
    return np.ascontiguousarray(disparity)
