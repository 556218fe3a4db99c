"""Numba kernels: the median absolute deviation of float32 values by selection; a median filter.

Private helper of :mod:`stages._heights` (``_robust_sigma``: the ground's height noise of
the depth rules, three times a frame over 50-250 thousand heights) and of
:mod:`stages.depth` (``median32``: the frame's median range, over ~250 thousand values).
``np.median`` selects three order statistics (the two middle ones and, for NaN, the last),
(twice for a MAD) each by an introselect over the whole array; counting the values' top
bits and selecting among the few in the middle buckets costs a fraction. The arithmetic is
``np.median``'s in float32: the mean of the two middle values is their float32 sum halved,
the deviations are float32 differences (``tests/stages/test_select.py`` compares it with numpy).

Also ``median_filter_nearest32``, the coarse median of :func:`stages._heights.local_ground`
(twice a frame): a sliding histogram of the values' ranks instead of ``np.partition`` over
every window (the test compares their bits); ``median_u8``, an object's median gray.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["median32", "median_abs_deviation32", "median_filter_nearest32", "median_u8"]


@njit(cache=True)
def _kth(a, k):  # pragma: no cover - numba
    """The k-th smallest of ``a`` (reordered: everything before ``k`` is <= it)."""
    lo, hi = 0, a.size - 1
    while lo < hi:
        mid = (lo + hi) // 2
        # median of three as the pivot, sorted into lo, mid, hi
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break  # between the two halves: equal to the pivot
    return a[k]


@njit(cache=True)
def _bucket(bits):  # pragma: no cover - numba
    """Top 16 bits of a float32's order-preserving key, 0..65535 (negative floats get their
    magnitude bits flipped; no branch)."""
    return ((bits ^ ((bits >> 31) & np.int32(0x7FFFFFFF))) >> 16) + 32768


@njit(cache=True)
def _gather(values, first, last, size):  # pragma: no cover - numba
    """The ``size`` values whose buckets lie in ``first..last``, in their order."""
    bits = values.view(np.int32)
    kept = np.empty(size, np.float32)
    j = 0
    for i in range(values.size):
        b = _bucket(bits[i])
        if b >= first and b <= last:
            kept[j] = values[i]
            j += 1
    return kept


@njit(cache=True)
def _bucket_range(bits):  # pragma: no cover - numba
    """The smallest and largest bucket of the values (a branch-free, vectorised pass)."""
    lo, hi = np.int32(65535), np.int32(0)
    for i in range(bits.size):
        b = _bucket(bits[i])
        lo = min(lo, b)
        hi = max(hi, b)
    return lo, hi


@njit(cache=True)
def _median(values):  # pragma: no cover - numba
    """``np.median`` of finite float32 values.

    One counting pass over the top 16 bits of the values' order-preserving keys finds the
    buckets of the two middle ranks (no data-dependent branches: a quickselect over the
    whole array mispredicts half of its comparisons); a quickselect finishes in the few
    values of those buckets. The counts span only the buckets between the smallest and the
    largest value (a few thousand): zeroing and scanning all 65536 cost ~50 us a call, more
    than the counting of 10 000 values.
    """
    n = values.size
    bits = values.view(np.int32)
    lo, hi = _bucket_range(bits)
    counts = np.zeros(hi - lo + 1, np.int32)  # n < 2**31: half the zeroing of int64
    for i in range(n):
        counts[_bucket(bits[i]) - lo] += 1
    upper_rank = n // 2
    lower_rank = upper_rank if n % 2 else upper_rank - 1
    first, last, below, seen = -1, -1, 0, 0
    for b in range(counts.size):
        if first < 0 and seen + counts[b] > lower_rank:
            first, below = b, seen
        if seen + counts[b] > upper_rank:
            last = b
            break
        seen += counts[b]
    size = 0
    for b in range(first, last + 1):
        size += counts[b]
    kept = _gather(values, first + lo, last + lo, size)
    upper = _kth(kept, upper_rank - below)
    if n % 2:
        return upper
    # after the selection every value before the upper rank is at most it
    lower = kept[0]
    for i in range(1, upper_rank - below):
        if kept[i] > lower:
            lower = kept[i]
    return (lower + upper) / np.float32(2.0)


@njit(cache=True)
def _mad(values):  # pragma: no cover - numba
    middle = _median(values)
    deviations = np.empty_like(values)
    for i in range(values.size):
        deviations[i] = abs(values[i] - middle)
    return _median(deviations)


_SHIFT = 4  # 16 ranks a block of the rank histogram


@njit(cache=True)
def _rank_median_filter(ranks, size):  # pragma: no cover - numba
    """Each pixel's middle rank of its ``size`` x ``size`` window (edges repeated), from a
    two-level histogram of the ranks slid along each row (Huang): 2 * ``size`` updates a
    pixel, and the middle's block of 16 ranks moves a few blocks from the last one's."""
    rows, cols = ranks.shape
    half = size // 2
    middle = (size * size) // 2
    fine = np.zeros(rows * cols, np.int32)
    coarse = np.zeros((rows * cols >> _SHIFT) + 1, np.int32)
    out = np.empty((rows, cols), np.int64)
    for r in range(rows):
        for c in range(-half, half + 1):
            cc = min(max(c, 0), cols - 1)
            for dr in range(-half, half + 1):
                k = ranks[min(max(r + dr, 0), rows - 1), cc]
                fine[k] += 1
                coarse[k >> _SHIFT] += 1
        # below: the window's ranks in the blocks before ``block``
        block, below = 0, 0
        for c in range(cols):
            if c > 0:
                leaving = max(c - half - 1, 0)
                entering = min(c + half, cols - 1)
                for dr in range(-half, half + 1):
                    rr = min(max(r + dr, 0), rows - 1)
                    k = ranks[rr, leaving]
                    fine[k] -= 1
                    coarse[k >> _SHIFT] -= 1
                    below -= (k >> _SHIFT) < block
                    k = ranks[rr, entering]
                    fine[k] += 1
                    coarse[k >> _SHIFT] += 1
                    below += (k >> _SHIFT) < block
            while below > middle:
                block -= 1
                below -= coarse[block]
            while below + coarse[block] <= middle:
                below += coarse[block]
                block += 1
            k = block << _SHIFT
            count = below
            while count + fine[k] <= middle:
                count += fine[k]
                k += 1
            out[r, c] = k
        # empty the histogram for the next row: remove the last window
        for cc in range(cols - 1 - half, cols + half):
            for dr in range(-half, half + 1):
                k = ranks[min(max(r + dr, 0), rows - 1), min(max(cc, 0), cols - 1)]
                fine[k] -= 1
                coarse[k >> _SHIFT] -= 1
    return out


def median_filter_nearest32(image: np.ndarray, *, size: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(image, size, mode="nearest")`` of float32 values.

    The values are replaced by their distinct ranks (an argsort; equal values in any order)
    and a sliding histogram of ranks picks each window's middle rank, whose value is the
    window's middle value. Equal finite float32 values have equal bits except 0.0 and -0.0
    (a selection may return either): without NaN and negative zeros, which the caller
    checks, the result has the bits of a selection among the window's values. ~0.25 ms for
    the frame's coarse ground (~60 x 60 pixels, 9 x 9 windows) against ~0.9 ms for
    ``np.partition`` over a copy of the sliding windows.

    Parameters
    ----------
    image : (M, N) ndarray of float32
        Finite, no ``-0.0``; not modified.
    size : int
        Odd, ``>= 1``: the window's side.

    Returns
    -------
    filtered : (M, N) ndarray of float32
    """
    if image.dtype != np.float32 or image.ndim != 2:
        raise ValueError(
            f"image must be a 2-D float32 array, got {image.ndim}-D {image.dtype}"
        )
    if size < 1 or size % 2 == 0:
        raise ValueError(f"size must be odd and >= 1, got {size}")
    flat = image.ravel()
    order = np.argsort(flat)
    ranks = np.empty(flat.size, np.int64)
    ranks[order] = np.arange(flat.size)
    middle = _rank_median_filter(ranks.reshape(image.shape), size)
    return flat[order][middle]


@njit(cache=True)
def _median_u8(values):  # pragma: no cover - numba
    counts = np.zeros(256, np.int64)
    for v in values:
        counts[v] += 1
    n = values.size
    upper_rank = n // 2
    lower_rank = upper_rank if n % 2 else upper_rank - 1
    lower, seen = -1, 0
    for level in range(256):
        seen += counts[level]
        if lower < 0 and seen > lower_rank:
            lower = level
        if seen > upper_rank:
            return (lower + level) / 2.0
    return np.nan  # unreachable: n >= 1


def median_u8(values: np.ndarray) -> float:
    """``float(np.median(values))`` of uint8 values, by a 256-level count.

    ``np.median`` of a few hundred gray levels costs ~10 us, mostly its overhead; the rules
    that read an object's and its ground ring's median gray (R6, R6b) call it per object.
    The result is the same float: the two middle levels' sum halved, exact in float64.

    Parameters
    ----------
    values : (K,) ndarray of uint8
        ``K >= 1``; not modified.

    Returns
    -------
    median : float
    """
    if values.dtype != np.uint8 or values.ndim != 1 or values.size == 0:
        raise ValueError(
            f"values must be a non-empty 1-D uint8 array, got {values.ndim}-D "
            f"{values.dtype} of size {values.size}"
        )
    return float(_median_u8(values))


def median32(values: np.ndarray) -> np.float32:
    """``np.median(values)`` of finite float32 values, the same float32.

    Parameters
    ----------
    values : (K,) ndarray of float32
        Finite, ``K >= 1``; not modified.

    Returns
    -------
    median : numpy.float32
    """
    _check_values(values)
    return np.float32(_median(np.ascontiguousarray(values)))


def median_abs_deviation32(values: np.ndarray) -> np.float32:
    """``np.median(np.abs(values - np.median(values)))`` of finite float32 values.

    Parameters
    ----------
    values : (K,) ndarray of float32
        Finite, ``K >= 1``.

    Returns
    -------
    mad : numpy.float32
    """
    _check_values(values)
    return np.float32(_mad(np.ascontiguousarray(values)))


def _check_values(values: np.ndarray) -> None:
    if values.dtype != np.float32 or values.ndim != 1 or values.size == 0:
        raise ValueError(
            f"values must be a non-empty 1-D float32 array, got {values.ndim}-D "
            f"{values.dtype} of size {values.size}"
        )
