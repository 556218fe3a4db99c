"""Numba kernels of semi-global aggregation (Hirschmueller 2008) over a matching-cost volume.

Private helpers of :mod:`stages._stereo`. The cost volume has shape (H, W, D), lower is better.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__: list[str] = []  # private module; names used by stages._stereo

_DIRECTIONS_8 = np.array(
    [(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)], dtype=np.int64
)


@njit(cache=True)
def _min(values):  # pragma: no cover - numba
    """Least of ``values`` (at least one), as four running minima over interleaved entries.

    A minimum is exact in any order for these values (finite sums of costs, never -0),
    so the result is that of one running minimum; the four chains overlap instead of
    waiting on each other (LLVM does not vectorise this reduction, even with fastmath).
    """
    n = values.size
    b0 = values[0]
    b1 = b0
    b2 = b0
    b3 = b0
    i = 1
    while i + 4 <= n:
        v = values[i]
        b0 = v if v < b0 else b0
        v = values[i + 1]
        b1 = v if v < b1 else b1
        v = values[i + 2]
        b2 = v if v < b2 else b2
        v = values[i + 3]
        b3 = v if v < b3 else b3
        i += 4
    while i < n:
        v = values[i]
        b0 = v if v < b0 else b0
        i += 1
    b0 = b1 if b1 < b0 else b0
    b0 = b2 if b2 < b0 else b0
    return b3 if b3 < b0 else b0


@njit(cache=True, inline="always")
def _path_step(out, cost, pred, pred_min, p1, p2):  # pragma: no cover - numba
    """``out[j] = cost[j] + min(pred[j], pred[j -+ 1] + p1, pred_min + p2) - pred_min``.

    The minimum is taken in the same order of comparisons as one disparity at a time
    (centre, lower, upper neighbour, jump), written as selects so that the interior
    disparities vectorise; the ends, with one neighbour, are done apart.
    """
    n_disp = out.size
    jump = pred_min + p2
    m = pred[0]
    if n_disp > 1:
        upper = pred[1] + p1
        m = upper if upper < m else m
    m = jump if jump < m else m
    out[0] = cost[0] + m - pred_min
    for j in range(1, n_disp - 1):
        m = pred[j]
        lower = pred[j - 1] + p1
        m = lower if lower < m else m
        upper = pred[j + 1] + p1
        m = upper if upper < m else m
        m = jump if jump < m else m
        out[j] = cost[j] + m - pred_min
    if n_disp > 1:
        j = n_disp - 1
        m = pred[j]
        lower = pred[j - 1] + p1
        m = lower if lower < m else m
        m = jump if jump < m else m
        out[j] = cost[j] + m - pred_min


@njit(cache=True)
def _aggregate_direction(cost, total, dy, dx, p1, p2):  # pragma: no cover - numba
    """Add the path costs along direction (dy, dx) to ``total``."""
    h, w, n_disp = cost.shape
    previous = np.zeros((w, n_disp), np.float32)
    current = np.zeros((w, n_disp), np.float32)
    prev_min = np.zeros(w, np.float32)
    cur_min = np.zeros(w, np.float32)
    y_start, y_stop, y_step = (0, h, 1) if dy >= 0 else (h - 1, -1, -1)
    x_start, x_stop, x_step = (0, w, 1) if dx >= 0 else (w - 1, -1, -1)
    for y in range(y_start, y_stop, y_step):
        py = y - dy
        for x in range(x_start, x_stop, x_step):
            px = x - dx
            out = current[x]
            if 0 <= py < h and 0 <= px < w:
                if dy == 0:
                    _path_step(out, cost[y, x], current[px], cur_min[px], p1, p2)
                else:
                    _path_step(out, cost[y, x], previous[px], prev_min[px], p1, p2)
            else:
                out[:] = cost[y, x]
            cur_min[x] = _min(out)
            acc = total[y, x]
            for j in range(n_disp):
                acc[j] += out[j]
        previous, current = current, previous
        prev_min, cur_min = cur_min, prev_min


@njit(cache=True)
def aggregate(cost, p1, p2, n_paths, out=None):  # pragma: no cover - numba
    """Sum of path costs over 4 (horizontal, vertical) or 8 (plus diagonal) directions.

    ``out``, if given, is an array of ``cost``'s shape and dtype that receives the sums
    (zeroed first) instead of a new one, as for :func:`stages._ncc.ncc_cost_volume`.
    """
    if out is None:
        total = np.zeros(cost.shape, np.float32)
    else:
        total = out
        total[...] = 0
    for i in range(n_paths):
        _aggregate_direction(
            cost, total, _DIRECTIONS_8[i, 0], _DIRECTIONS_8[i, 1], np.float32(p1), np.float32(p2)
        )
    return total


@njit(cache=True)
def _left_best(left_index, left_value, cells, d_min):  # pragma: no cover - numba
    """Least aggregated cost's disparity index of every column ``xl`` of the other image,
    from one row of the volume, ``cells`` (W, D): ``S_left(xl, j) = S(xl - d_min - j, j)``
    over every reference column inside the image.

    Of equal costs the smallest index wins, as in a scan of increasing ``j`` with ``<``:
    here the reference columns are scanned in increasing order, so the index decreases
    along each ``xl``'s candidates and a later candidate wins ties (``<=``). The inner
    loop runs over contiguous disparities and vectorises.
    """
    w, n_disp = cells.shape
    left_index[:] = -1
    left_value[:] = np.inf
    for xr in range(w):
        base = xr + d_min  # xl = base + j
        j0 = max(0, -base)
        j1 = min(n_disp, w - base)
        if j1 <= j0:
            continue
        values = cells[xr, j0:j1]
        best_value = left_value[base + j0 : base + j1]
        best_index = left_index[base + j0 : base + j1]
        for i in range(j1 - j0):
            v = values[i]
            better = v <= best_value[i]
            best_value[i] = v if better else best_value[i]
            best_index[i] = j0 + i if better else best_index[i]


@njit(cache=True)
def select(total, d_min, hw, lr_tolerance):  # pragma: no cover - numba
    """Winner-take-all on aggregated costs, parabola subpixel, left-right check.

    Returns disparity (H, W) float32: NaN without data (window outside the image, peak at
    the end of the search range), -inf where the left-right check fails.

    The best index is the first one holding the least cost (:func:`_min`, then a search
    for it), the left-reference one comes from a row pass (:func:`_left_best`): the same
    indices as scanning each pixel's costs in increasing order with ``<``.
    """
    h, w, n_disp = total.shape
    disparity = np.full((h, w), np.nan, np.float32)
    left_index = np.empty(w, np.int64)
    left_value = np.empty(w, np.float32)
    for y in range(hw, h - hw):
        _left_best(left_index, left_value, total[y], d_min)
        for x in range(hw, w - hw):
            j0 = max(0, hw - x - d_min)
            j1 = min(n_disp, w - hw - x - d_min)
            if j1 - j0 < 3:
                continue
            cell = total[y, x]
            least = _min(cell[j0:j1])
            best = j0
            while cell[best] != least:
                best += 1
            best_value = cell[best]
            if best == j0 or best == j1 - 1:
                continue
            # Left-reference aggregated cost is the same volume re-indexed: S(xl - d, d).
            xl = x + d_min + best
            lr_best = left_index[xl]
            if abs(lr_best - best) > lr_tolerance:
                disparity[y, x] = -np.inf
                continue
            c_minus = cell[best - 1]
            c_plus = cell[best + 1]
            curvature = c_minus - 2.0 * best_value + c_plus
            offset = 0.0
            if curvature > 0:
                offset = min(0.5, max(-0.5, 0.5 * (c_minus - c_plus) / curvature))
            disparity[y, x] = np.float32(d_min + best + offset)
    return disparity
