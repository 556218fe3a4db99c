"""Numba kernels of the describe stage, each the same floats as the numpy code it replaced.

``median64`` / ``percentile64`` (``np.median`` / ``np.percentile`` of small arrays),
``footprint_spreads`` / ``projection_spreads`` (:func:`stages._footprint.footprint_dimensions`),
``boundary_jump_counts`` (:func:`stages._descriptors.background_jump_fraction`),
``huber_weights`` (the reweighting of :func:`stages._ground.fit_disparity_surface`, whose
products and solves stay numpy's BLAS/LAPACK) and ``back_project``
(:func:`stages._ground.pixel_points`): elementwise arithmetic in numpy's order (no FMA),
order statistics by selection.

Private helpers of the describe stage (:mod:`stages._ground`, :mod:`stages._descriptors`),
which takes thousands of medians and a percentile per object of arrays of tens to a few
thousand values: the generic numpy functions spend most of that time in argument handling
(``np.percentile`` ~60 us a call, a partition-based median ~6 us). Order statistics are
exact whichever way they are selected, so only the arithmetic after the selection has to
be numpy's, and it is written out operation by operation here:
``np.median`` takes the mean of the two middle values as ``(0.0 + lower + upper) / 2``
(np.mean's sum starts from +0.0), NaN when any value is NaN; ``np.percentile`` (method
``'linear'``, a Python number ``q``) interpolates at the virtual index ``(n - 1) q / 100``
as ``numpy.lib._function_base_impl._lerp`` does. ``tests/stages/test_small_stats.py``
compares both with numpy.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._select import _kth

__all__ = [
    "median64",
    "percentile64",
    "projection_spreads",
    "footprint_spreads",
    "boundary_jump_counts",
    "huber_weights",
    "back_project",
]


@njit(cache=True)
def _has_nan(a):  # pragma: no cover - numba
    for i in range(a.size):
        if math.isnan(a[i]):
            return True
    return False


@njit(cache=True)
def _next_above(a, k):  # pragma: no cover - numba
    """The smallest of ``a[k:]`` (after ``_kth(a, k - 1)``: the k-th smallest)."""
    value = a[k]
    for i in range(k + 1, a.size):
        if a[i] < value:
            value = a[i]
    return value


@njit(cache=True)
def _median64(a):  # pragma: no cover - numba
    """``np.median`` of a non-empty float64 array (reordered in place)."""
    n = a.size
    if _has_nan(a):
        return np.nan
    half = n // 2
    upper = _kth(a, half)
    if n % 2:
        return 0.0 + upper
    # after the selection every value before ``half`` is at most ``upper``
    lower = a[0]
    for i in range(1, half):
        if a[i] > lower:
            lower = a[i]
    return (0.0 + lower + upper) / 2.0


@njit(cache=True)
def _percentile64(a, fraction):  # pragma: no cover - numba
    """``np.percentile(a, q)`` of a non-empty float64 array, ``fraction = q / 100``
    (reordered in place), and whether numpy must decide instead (a zero was selected: which
    of +0.0 and -0.0 depends on numpy's own selection)."""
    n = a.size
    if _has_nan(a):
        return np.nan, False
    virtual = (n - 1) * fraction
    if virtual >= n - 1:  # numpy takes the last value twice, at index -1 (gamma from it)
        below = above = _kth(a, n - 1)
        gamma = virtual - (-1.0)
    else:
        previous = int(math.floor(virtual))
        below = _kth(a, previous)
        above = _next_above(a, previous + 1)
        gamma = virtual - previous
    if below == 0.0 or above == 0.0:
        return np.nan, True
    diff = above - below
    if gamma >= 0.5:
        return above - diff * (1.0 - gamma), False
    return below + diff * gamma, False


def median64(values: np.ndarray) -> np.float64:
    """``np.median(values)`` of a non-empty real array, as float64 (the same value).

    Parameters
    ----------
    values : ndarray of float or int
        Any shape, K >= 1 values (flattened); not modified. Integers are taken as float64
        (exact below 2**53).

    Returns
    -------
    numpy.float64
        NaN when a value is NaN.
    """
    a = np.array(values, dtype=np.float64).ravel()  # a copy: the selection reorders it
    if a.size == 0:
        raise ValueError("values must hold at least one value, got an empty array")
    return np.float64(_median64(a))


def percentile64(values: np.ndarray, q: float) -> float:
    """``float(np.percentile(values, q))`` of a non-empty real array (method 'linear').

    Parameters
    ----------
    values : ndarray of float or int
        Any shape, K >= 1 values (flattened); not modified.
    q : int or float
        Percentile in [0, 100], a Python number (numpy's arithmetic for a weak scalar ``q``).

    Returns
    -------
    float
        NaN when a value is NaN.
    """
    if not 0 <= q <= 100:
        raise ValueError(f"q must be a percentile in [0, 100], got {q!r}")
    a = np.array(values, dtype=np.float64).ravel()
    if a.size == 0:
        raise ValueError("values must hold at least one value, got an empty array")
    # np.true_divide(q, 100): the float64 quotient
    value, zero = _percentile64(a, float(np.true_divide(q, 100)))
    return float(np.percentile(values, q)) if zero else value


@njit(cache=True)
def _projection_spreads(x, y, cos, sin):  # pragma: no cover - numba
    spread = np.empty(cos.size)
    for j in range(cos.size):
        c, s = cos[j], sin[j]
        low = high = x[0] * c + y[0] * s
        for i in range(1, x.size):
            p = x[i] * c + y[i] * s  # two products and a sum, as numpy's ufuncs (no FMA)
            if p > high:
                high = p
            elif p < low:
                low = p
        spread[j] = high - low
    return spread


def projection_spreads(
    x: np.ndarray, y: np.ndarray, cos: np.ndarray, sin: np.ndarray
) -> np.ndarray:
    """Spread (max - min) of the points' projections on each direction: ``proj.max(axis=0)
    - proj.min(axis=0)`` of ``proj = x[:, None] * cos[None, :] + y[:, None] * sin[None, :]``,
    the same floats, without the (K, D) array.

    Parameters
    ----------
    x, y : (K,) ndarray of float64
        Finite coordinates, K >= 1.
    cos, sin : (D,) ndarray of float64
        The directions' cosines and sines.

    Returns
    -------
    (D,) ndarray of float64
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape or x.size == 0:
        raise ValueError(
            f"x and y must be equal non-empty 1-D arrays, got shapes {x.shape}, {y.shape}"
        )
    return _projection_spreads(
        x,
        y,
        np.ascontiguousarray(cos, dtype=np.float64),
        np.ascontiguousarray(sin, dtype=np.float64),
    )


@njit(cache=True)
def _boundary_jump_counts(mask, background, disparity, jump_px):  # pragma: no cover - numba
    total = hidden = 0
    rows, cols = mask.shape
    for i in range(rows):
        for j in range(cols):
            if not mask[i, j]:
                continue
            d_in = disparity[i, j]
            if not math.isfinite(d_in):
                continue
            for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                y, x = i + di, j + dj
                if y < 0 or y >= rows or x < 0 or x >= cols or not background[y, x]:
                    continue
                d_out = disparity[y, x]
                if not math.isfinite(d_out):
                    continue
                total += 1
                if d_out - d_in > jump_px:
                    hidden += 1
    return total, hidden


def boundary_jump_counts(
    mask: np.ndarray, background: np.ndarray, disparity: np.ndarray, *, jump_px: float
) -> tuple[int, int]:
    """4-neighbour pairs (inside ``mask``, outside in ``background``) with both disparities
    finite, and how many of them have the outside one more than ``jump_px`` larger.

    Parameters
    ----------
    mask, background : (M, N) ndarray of bool
    disparity : (M, N) ndarray of float64
        NaN where invalid.
    jump_px : float

    Returns
    -------
    total, hidden : int
    """
    m = np.ascontiguousarray(mask, dtype=bool)
    if not (m.shape == np.shape(background) == np.shape(disparity)) or m.ndim != 2:
        raise ValueError(
            f"mask, background and disparity must be equal 2-D arrays, got shapes {m.shape}, "
            f"{np.shape(background)}, {np.shape(disparity)}"
        )
    total, hidden = _boundary_jump_counts(
        m,
        np.ascontiguousarray(background, dtype=bool),
        np.ascontiguousarray(disparity, dtype=np.float64),
        float(jump_px),
    )
    return int(total), int(hidden)


@njit(cache=True)
def _huber_weights(measured, fitted, huber_k, reject_k, reject):  # pragma: no cover - numba
    n = measured.size
    resid = np.empty(n)
    for i in range(n):
        resid[i] = abs(measured[i] - fitted[i])
    sigma = 1.4826 * _median64(resid.copy()) + 1e-9
    scale = huber_k * sigma
    limit = reject_k * sigma
    weights = np.empty(n)
    for i in range(n):
        ratio = resid[i] / scale
        # np.maximum(1.0, ratio): NaN propagates
        weights[i] = 1.0 / (ratio if (ratio > 1.0 or ratio != ratio) else 1.0)
        if reject and resid[i] > limit:
            weights[i] = 0.0
    return weights


def huber_weights(
    measured: np.ndarray, fitted: np.ndarray, *, huber_k: float, reject_k: float, reject: bool
) -> np.ndarray:
    """The reweighting step of a robust fit, numpy's arithmetic in one pass:
    ``resid = |measured - fitted|``, ``sigma = 1.4826 median(resid) + 1e-9``, weights
    ``1 / max(1, resid / (huber_k sigma))``, and 0 where ``resid > reject_k sigma`` when
    ``reject``.

    Parameters
    ----------
    measured, fitted : (K,) ndarray of float64
        K >= 1.
    huber_k, reject_k : float
    reject : bool

    Returns
    -------
    (K,) ndarray of float64
    """
    measured = np.ascontiguousarray(measured, dtype=np.float64)
    fitted = np.ascontiguousarray(fitted, dtype=np.float64)
    if measured.ndim != 1 or measured.shape != fitted.shape or measured.size == 0:
        raise ValueError(
            f"measured and fitted must be equal non-empty 1-D arrays, got shapes "
            f"{measured.shape}, {fitted.shape}"
        )
    return _huber_weights(measured, fitted, float(huber_k), float(reject_k), bool(reject))


@njit(cache=True)
def _back_project(rows, cols, disparity, k_m_px, focal_px, cx, cy):  # pragma: no cover
    out = np.empty((disparity.size, 3))
    for i in range(disparity.size):
        d = disparity[i]
        if not d > 0:  # NaN too
            d = np.nan
        z = k_m_px / d
        out[i, 0] = (float(cols[i]) - cx) * z / focal_px
        out[i, 1] = (float(rows[i]) - cy) * z / focal_px
        out[i, 2] = z
    return out


def back_project(
    rows: np.ndarray,
    cols: np.ndarray,
    disparity: np.ndarray,
    *,
    k_m_px: float,
    focal_px: float,
    cx: float,
    cy: float,
) -> np.ndarray:
    """Camera-frame points ``(K, 3)``: ``z = k_m_px / d`` (NaN where ``d`` is not > 0),
    ``x = (col - cx) z / f``, ``y = (row - cy) z / f``, numpy's operations in numpy's order
    (:func:`stages._ground.pixel_points`).

    Parameters
    ----------
    rows, cols : (K,) ndarray of int or float
    disparity : (K,) ndarray of float64
    k_m_px, focal_px, cx, cy : float
    """
    d = np.ascontiguousarray(disparity, dtype=np.float64)
    r = np.ascontiguousarray(rows)
    c = np.ascontiguousarray(cols)
    if d.ndim != 1 or r.shape != d.shape or c.shape != d.shape:
        raise ValueError(
            f"rows, cols and disparity must be equal 1-D arrays, got shapes {r.shape}, "
            f"{c.shape}, {d.shape}"
        )
    return _back_project(r, c, d, float(k_m_px), float(focal_px), float(cx), float(cy))


@njit(cache=True)
def _mad_inliers(values, keep):  # pragma: no cover - numba
    """Clear ``keep`` where a kept value lies more than 4 scaled MADs (+1e-12) from the kept
    values' median: ``_footprint.footprint_dimensions``' numpy steps, value for value."""
    kept = np.empty(values.size)
    n = 0
    for i in range(values.size):
        if keep[i]:
            kept[n] = values[i]
            n += 1
    if n == 0:
        return
    centre = _median64(kept[:n].copy())
    deviation = np.empty(n)
    for i in range(n):
        deviation[i] = abs(kept[i] - centre)
    mad = 1.4826 * _median64(deviation.copy())
    limit = 4.0 * mad + 1e-12
    j = 0
    for i in range(values.size):
        if keep[i]:
            if not deviation[j] <= limit:
                keep[i] = False
            j += 1


@njit(cache=True)
def _footprint_spreads(x, y, cos, sin):  # pragma: no cover - numba
    keep = np.empty(x.size, np.bool_)
    for i in range(x.size):
        keep[i] = math.isfinite(x[i]) and math.isfinite(y[i])
    _mad_inliers(x, keep)
    _mad_inliers(y, keep)
    n = 0
    for i in range(x.size):
        n += keep[i]
    if n < 2:
        return np.empty(0)
    xs, ys = np.empty(n), np.empty(n)
    j = 0
    for i in range(x.size):
        if keep[i]:
            xs[j], ys[j] = x[i], y[i]
            j += 1
    return _projection_spreads(xs, ys, cos, sin)


def footprint_spreads(
    x: np.ndarray, y: np.ndarray, cos: np.ndarray, sin: np.ndarray
) -> np.ndarray:
    """:func:`projection_spreads` of the finite points within 4 scaled MADs (1.4826 MAD,
    +1e-12) of the median in x, then of those in y: the spreads
    :func:`stages._footprint.footprint_dimensions` measures, the same floats.

    Parameters
    ----------
    x, y : (K,) ndarray of float64
        Ground coordinates; NaN entries are ignored.
    cos, sin : (D,) ndarray of float64

    Returns
    -------
    (D,) ndarray of float64
        Empty when fewer than two points remain.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"x and y must be equal 1-D arrays, got shapes {x.shape}, {y.shape}")
    return _footprint_spreads(
        x,
        y,
        np.ascontiguousarray(cos, dtype=np.float64),
        np.ascontiguousarray(sin, dtype=np.float64),
    )
