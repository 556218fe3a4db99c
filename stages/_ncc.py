"""Numba kernels of zero-mean normalised cross-correlation (ZNCC) stereo matching.

Private helpers of :mod:`stages._stereo`; see that module for the matching rules.

Layout and exactness. Images are int32 gray levels minus 128. Every window sum (of ``R``,
``R**2``, ``R*L``...) is an exact integer: box sums come from int64 integral images or
column sums (per-window image statistics, whole frame or row by row) and from sliding
int32 column/row sums of the products ``R[y, x] * L[y, x + d]`` (the row kernel), which
cannot overflow because centred products are at most 128**2 and a window of at most
255 x 255 px keeps every partial sum below 2**31 (255**2 * 128**2 < 1.1e9). Window sums of
gray levels (< 128 * 255**2 < 2**24) are stored as exact float32. Only the final ZNCC
division is floating point, and it is done with the same operations for a pixel whatever
the image or tile it sits in, so matching a tile gives
bit-identical results to matching the whole frame.

Per image row the kernel keeps, for every window (half-height ``hy``, half-width ``hw``) and
every disparity index ``j`` (disparity ``d = d_min + j``), the column sums ``cs[j, x]`` of
``R*L`` over the ``2 hy + 1`` window rows and the window sums ``hs[j, x]`` over ``2 hw + 1``
columns: O(1) work per pixel, disparity and window whatever the window size (box
filtering), no Python loop over pixels. Both matchers, :func:`adaptive_match` and the
``sgm`` method's :func:`ncc_cost_volume`, share these disparity-major (D, W) sums.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__: list[str] = []  # private module; names used by stages._stereo

NO_PEAK = np.float32(np.nan)
LR_REJECTED = np.float32(-np.inf)


@njit(cache=True, error_model="numpy")
def window_stats(image, hys, hxs, with_std=True):  # pragma: no cover - numba
    """Per-window sums, ``1 / sqrt(n*sum(v^2) - sum(v)^2)`` and standard deviations.

    ``image`` is a centred int32 image (H, W), ``hys, hxs`` the windows' half-heights and
    half-widths (K,). Returns three float32 arrays (K, H, W), zero where the window does not fit
    in the image or is flat; with ``with_std = False`` (the other image, whose texture no
    test reads) the third is (K, 0, 0). The sums are exact (integers below 2**24).
    """
    # The spread is an exact integer and never negative (Cauchy-Schwarz), so the root of a
    # flat window is 0 and its std 0 / n = 0 without a branch; only the inverse needs a
    # select. error_model="numpy" drops the zero-division check of 1 / root, which is
    # discarded there: the loop vectorises, with the same correctly rounded sqrt and
    # divisions as one pixel at a time.
    h, w = image.shape
    n_win = hys.size
    integral = np.zeros((h + 1, w + 1), np.int64)
    integral2 = np.zeros((h + 1, w + 1), np.int64)
    for y in range(h):
        row = np.int64(0)
        row2 = np.int64(0)
        for x in range(w):
            v = np.int64(image[y, x])
            row += v
            row2 += v * v
            integral[y + 1, x + 1] = integral[y, x + 1] + row
            integral2[y + 1, x + 1] = integral2[y, x + 1] + row2
    sums = np.zeros((n_win, h, w), np.float32)
    inv = np.zeros((n_win, h, w), np.float32)
    std = np.zeros((n_win, h, w) if with_std else (n_win, 0, 0), np.float32)
    for k in range(n_win):
        hy = hys[k]
        hx = hxs[k]
        n = (2 * hy + 1) * (2 * hx + 1)
        m = w - 2 * hx
        if m <= 0:
            continue
        for y in range(hy, h - hy):
            # one window per x: columns x .. x + 2 hx of the integral rows y - hy, y + hy + 1
            top = integral[y - hy]
            bottom = integral[y + hy + 1]
            top2 = integral2[y - hy]
            bottom2 = integral2[y + hy + 1]
            out_sums = sums[k, y, hx : w - hx]
            out_inv = inv[k, y, hx : w - hx]
            for x in range(m):
                x1 = x + 2 * hx + 1
                s = bottom[x1] - top[x1] - bottom[x] + top[x]
                s2 = bottom2[x1] - top2[x1] - bottom2[x] + top2[x]
                spread = n * s2 - s * s
                root = np.sqrt(np.float64(spread))
                out_sums[x] = s
                out_inv[x] = 1.0 / root if spread > 0 else 0.0
            if with_std:
                out_std = std[k, y, hx : w - hx]
                for x in range(m):
                    x1 = x + 2 * hx + 1
                    s = bottom[x1] - top[x1] - bottom[x] + top[x]
                    s2 = bottom2[x1] - top2[x1] - bottom2[x] + top2[x]
                    out_std[x] = np.sqrt(np.float64(n * s2 - s * s)) / n
    return sums, inv, std


@njit(cache=True)
def _parabola_offset(c_minus, c_0, c_plus):  # pragma: no cover - numba
    """Vertex offset in [-0.5, 0.5] of the parabola through three equally spaced samples."""
    curvature = c_minus - 2.0 * c_0 + c_plus
    if curvature == 0.0:
        return 0.0
    offset = 0.5 * (c_minus - c_plus) / curvature
    return min(0.5, max(-0.5, offset))


@njit(cache=True)
def _equiangular_offset(c_minus, c_0, c_plus):  # pragma: no cover - numba
    """Apex offset in [-0.5, 0.5] of the symmetric V (equal and opposite slopes) through
    three equally spaced samples around a maximum ``c_0``; 0 when all three are equal."""
    low = min(c_minus, c_plus)
    if c_0 <= low:
        return 0.0
    offset = 0.5 * (c_plus - c_minus) / (c_0 - low)
    return min(0.5, max(-0.5, offset))


@njit(cache=True)
def subpixel_offset(c_minus, c_0, c_plus, blend):  # pragma: no cover - numba
    """Peak offset in [-0.5, 0.5] from the ZNCC at the best disparity and its neighbours.

    ``blend = False``: the parabola's vertex. ``blend = True``: the mean of the parabola's
    vertex and the V's apex. A ZNCC peak is rounder than a V and sharper than a parabola, so
    the parabola pulls estimates towards the integer (pixel locking: -0.05 px at a true
    fraction of 0.3, +0.05 px at 0.7 on the mojave ground) and the V pushes them away by
    about as much; their mean is within 0.013 px of unbiased at every fraction there.
    """
    parabola = _parabola_offset(c_minus, c_0, c_plus)
    if not blend:
        return parabola
    return 0.5 * (parabola + _equiangular_offset(c_minus, c_0, c_plus))


# ------------------------------------------------------------------ row sums, (D, W) layout
#
# The matchers keep their per-row sums and curves disparity-major, ``a[j, x]``: the work
# that dominates (the ZNCC of every column, its peak and runner-up, the left-reference
# argmax) then runs over contiguous columns for one disparity at a time, so every column is
# an independent SIMD lane instead of a short serial search per pixel. Only the sliding
# window sum along the row is serial (one running sum per disparity).


@njit(cache=True)
def _update_column_sums_t(cs, ref, other, y_add, y_sub, d_min):  # pragma: no cover - numba
    """(D, W) column sums: add product row ``y_add``, remove row ``y_sub`` (skipped if < 0)."""
    n_disp, w = cs.shape
    ref_add = ref[y_add]
    oth_add = other[y_add]
    ref_sub = ref[max(y_sub, 0)]
    oth_sub = other[max(y_sub, 0)]
    for j in range(n_disp):
        d = d_min + j
        x0 = max(0, -d)
        x1 = min(w, w - d)
        if x1 <= x0:
            continue
        sums = cs[j, x0:x1]
        ra = ref_add[x0:x1]
        la = oth_add[x0 + d : x1 + d]
        if y_sub >= 0:
            rs = ref_sub[x0:x1]
            ls = oth_sub[x0 + d : x1 + d]
            for i in range(x1 - x0):
                sums[i] += ra[i] * la[i] - rs[i] * ls[i]
        else:
            for i in range(x1 - x0):
                sums[i] += ra[i] * la[i]


@njit(cache=True)
def _window_sums_t(hs, cs, hw):  # pragma: no cover - numba
    """(D, W) sums of the ``2 hw + 1`` wide window along each disparity's row."""
    # The window sum's change from x - 1 to x, cs[x + hw] - cs[x - hw - 1], is formed in a
    # vectorised pass; only the running total of those changes is serial (one add per
    # element), which halves the cost of a plain sliding sum.
    n_disp, w = cs.shape
    if w < 2 * hw + 1:
        return
    m = w - 2 * hw - 1
    for j in range(n_disp):
        column = cs[j]
        out = hs[j, hw + 1 : w - hw]
        acc = np.int32(0)
        for x in range(2 * hw + 1):
            acc += column[x]
        hs[j, hw] = acc
        ahead = column[2 * hw + 1 :]
        behind = column[:m]
        for i in range(m):
            out[i] = ahead[i] - behind[i]
        for i in range(m):
            acc += out[i]
            out[i] = acc


@njit(cache=True)
def _advance_column_sums_t(cs, ref, other, y, hy, d_min):  # pragma: no cover - numba
    """Bring the (D, W) column sums of one window height to row ``y`` (from row y - 1)."""
    if y == hy:
        cs[:, :] = 0
        for yy in range(2 * hy + 1):
            _update_column_sums_t(cs, ref, other, yy, -1, d_min)
    else:
        _update_column_sums_t(cs, ref, other, y + hy, y - hy - 1, d_min)


@njit(cache=True, inline="always")
def _ncc(hs, n, rs_row, ri_row, os_row, oi_row, x, j, d_min):  # pragma: no cover - numba
    """ZNCC of reference column ``x`` at disparity index ``j`` in the current row (hs (D, W))."""
    xo = x + d_min + j
    num = n * np.float64(hs[j, x]) - np.float64(rs_row[x]) * np.float64(os_row[xo])
    return np.float32(num * ri_row[x] * oi_row[xo])


@njit(cache=True)
def _row_scores(out, hs, n, hw, rs_row, ri_row, os_row, oi_row, d_min, as_cost):  # pragma: no cover
    """ZNCC (or, ``as_cost``, the cost ``(1 - ZNCC) / 2``) of every disparity and column of
    the current row, (D, W); -2 (cost: 0.5) where the window does not fit.

    ``n`` is the window's pixel count, ``hw`` its half-width. The float operations are the
    same, in the same order, as in :func:`_ncc`, so both give identical values; the cost is
    formed from the ZNCC in float64 and rounded to float32 once (halving is exact, so it
    equals ``0.5 - 0.5 * num * ...`` bit for bit).
    """
    n_disp, w = out.shape
    outside = 0.5 if as_cost else -2.0
    for j in range(n_disp):
        d = d_min + j
        x0 = max(hw, hw - d)
        x1 = min(w - hw, w - hw - d)
        if x1 <= x0:
            out[j, :] = outside
            continue
        out[j, :x0] = outside  # only where the window does not fit: the rest is written
        out[j, x1:] = outside
        row = out[j, x0:x1]
        sums = hs[j, x0:x1]
        r_sums = rs_row[x0:x1]
        r_inv = ri_row[x0:x1]
        o_sums = os_row[x0 + d : x1 + d]
        o_inv = oi_row[x0 + d : x1 + d]
        for i in range(x1 - x0):
            num = n * np.float64(sums[i]) - np.float64(r_sums[i]) * np.float64(o_sums[i])
            score = num * np.float64(r_inv[i]) * o_inv[i]
            row[i] = np.float32(0.5 - 0.5 * score) if as_cost else np.float32(score)


@njit(cache=True)
def _row_peaks(best_index, best_value, second, curves, x0, x1):  # pragma: no cover - numba
    """:func:`_peak` of the columns ``x0 .. x1 - 1`` of the row's curves (all disparities).

    Three passes over the (D, W) curves, each a branch-free update of contiguous columns:
    the maximum, the first index that reaches it, the best value more than one index
    away. Maxima are exact, so the results equal :func:`_peak`'s column by column.
    """
    n_disp = curves.shape[0]
    if x1 <= x0:
        return
    top = best_value[x0:x1]
    index = best_index[x0:x1]
    runner = second[x0:x1]
    top[:] = -np.inf
    for j in range(n_disp):
        row = curves[j, x0:x1]
        for i in range(x1 - x0):
            v = row[i]
            top[i] = v if v > top[i] else top[i]
    index[:] = n_disp
    for j in range(n_disp - 1, -1, -1):  # descending: the smallest index reaching it wins
        row = curves[j, x0:x1]
        jj = np.int32(j)  # as wide as the values: one vector of each per step
        for i in range(x1 - x0):
            index[i] = jj if row[i] == top[i] else index[i]
    runner[:] = -np.inf
    for j in range(n_disp):
        row = curves[j, x0:x1]
        jj = np.int32(j)
        for i in range(x1 - x0):
            v = row[i]
            far = (jj < index[i] - 1) | (jj > index[i] + 1)
            runner[i] = v if far and v > runner[i] else runner[i]


@njit(cache=True)
def _left_best(left_index, left_value, curves, hw, d_min):  # pragma: no cover - numba
    """Best disparity index of every column of the other image from the row's (D, W) curves.

    The left-reference curve is the reference one re-indexed, ``C_left(xl, j) =
    C_ref(xl - d_min - j, j)``, so one pass over the row's curves finds every argmax. Of
    equal values the largest index wins ('>=' over increasing j), as in the per-pixel
    check of :func:`adaptive_match`.
    """
    n_disp, w = curves.shape
    left_index[:] = -1
    left_value[:] = -np.inf
    for j in range(n_disp):
        d = d_min + j
        # the reference column xl - d and the left column xl both hold the whole window
        xl0 = max(hw, hw + d)
        xl1 = min(w - hw, w - hw + d)
        if xl1 <= xl0:
            continue
        values = curves[j, xl0 - d : xl1 - d]
        best_value = left_value[xl0:xl1]
        best_index = left_index[xl0:xl1]
        jj = np.int32(j)
        for i in range(xl1 - xl0):
            v = values[i]
            better = v >= best_value[i]
            best_value[i] = v if better else best_value[i]
            best_index[i] = jj if better else best_index[i]


@njit(cache=True)
def _border_curves(shifted, j_first, j_last, curves, hw, d_min, x0, x1):  # pragma: no cover
    """Curves of the columns ``x0 .. x1 - 1`` with the window shifted to fit, (D, W).

    Near the image's sides :func:`adaptive_match` moves a window that does not fit at a
    disparity to the nearest centre where it does (:func:`_shifted_centre`, at most ``hw``
    px away); its ZNCC is then ``curves[j, centre]``. Where no such centre exists the value
    is -inf, which no maximum picks. ``j_first``, ``j_last`` receive each column's valid
    index range ``[j_first, j_last)`` (contiguous: the centre moves monotonically with j).
    """
    # At index j the centre is x clamped to [a, b] (the columns where the window fits in
    # both images), valid within hw of x: a constant run, a copy of the curve row, and
    # another constant run, all contiguous slices.
    n_disp, w = curves.shape
    if x1 <= x0:
        return
    j_first[x0:x1] = n_disp
    j_last[x0:x1] = 0
    for j in range(n_disp):
        out = shifted[j]
        row = curves[j]
        out[x0:x1] = -np.inf
        a = max(hw, hw - d_min - j)
        b = min(w - 1 - hw, w - 1 - hw - d_min - j)
        if a > b:
            continue
        v0 = max(x0, a - hw)
        v1 = min(x1, b + hw + 1)
        if v1 <= v0:
            continue
        for x in range(v0, min(v1, a)):
            out[x] = row[a]
        c0 = max(v0, a)
        c1 = min(v1, b + 1)
        if c1 > c0:
            out[c0:c1] = row[c0:c1]
        for x in range(max(v0, b + 1), v1):
            out[x] = row[b]
        first = j_first[v0:v1]
        for i in range(v1 - v0):
            first[i] = min(first[i], j)
        j_last[v0:v1] = j + 1


@njit(cache=True, inline="always")
def _shifted_centre(x, j, hw, d_min, w):  # pragma: no cover - numba
    """Nearest window centre to column ``x`` where the window fits in both images at index j."""
    x_ref = min(max(x, hw), w - 1 - hw)
    return max(min(x_ref, w - 1 - hw - d_min - j), hw - d_min - j)


@njit(cache=True, fastmath={"nnan", "ninf", "nsz", "reassoc"})
def _max(curve, j0, j1):  # pragma: no cover - numba
    # A max is exact in any order, so letting LLVM vectorise it changes no result; the
    # slice indexed from 0 spares numba's negative-index wraparound, which blocked that.
    best = np.float32(-np.inf)
    if j1 <= j0:
        return best
    values = curve[j0:j1]
    for j in range(j1 - j0):
        best = max(best, values[j])
    return best


@njit(cache=True, inline="always")
def _peak(curve, j0, j1):  # pragma: no cover - numba
    """Best index (first maximum), best value, and best value more than one index away."""
    best_value = _max(curve, j0, j1)
    best = j0
    while curve[best] != best_value:
        best += 1
    second = max(_max(curve, j0, best - 1), _max(curve, best + 2, j1))
    return best, best_value, second


@njit(cache=True)
def _advance_stat_columns(col, col2, image, yc, hy):  # pragma: no cover - numba
    """Bring the column sums of ``v`` and ``v**2`` over the rows ``yc - hy .. yc + hy`` of
    ``image`` (W,) each, int64, to centre row ``yc`` (from ``yc - 1``; started at ``hy``)."""
    w = col.size
    if yc == hy:
        col[:] = 0
        col2[:] = 0
        for yy in range(2 * hy + 1):
            row = image[yy]
            for x in range(w):
                v = np.int64(row[x])
                col[x] += v
                col2[x] += v * v
        return
    add = image[yc + hy]
    sub = image[yc - hy - 1]
    for x in range(w):
        a = np.int64(add[x])
        b = np.int64(sub[x])
        col[x] += a - b
        col2[x] += a * a - b * b


@njit(cache=True, error_model="numpy")
def _row_stats(sums, inv, std, col, col2, hx, n, prefix, prefix2):  # pragma: no cover - numba
    """One row of :func:`window_stats` (window ``2 hx + 1`` wide, ``n`` pixels) from the
    column sums of :func:`_advance_stat_columns`: the same integers, the same float
    operations, so the same float32 values. ``std`` may be empty (not formed); ``prefix``,
    ``prefix2`` are (W + 1,) int64 scratch."""
    w = col.size
    m = w - 2 * hx
    sums[:] = 0
    inv[:] = 0
    if std.size:
        std[:] = 0
    if m <= 0:
        return
    prefix[0] = 0
    prefix2[0] = 0
    for x in range(w):
        prefix[x + 1] = prefix[x] + col[x]
        prefix2[x + 1] = prefix2[x] + col2[x]
    out_sums = sums[hx : w - hx]
    out_inv = inv[hx : w - hx]
    for x in range(m):
        s = prefix[x + 2 * hx + 1] - prefix[x]
        spread = n * (prefix2[x + 2 * hx + 1] - prefix2[x]) - s * s
        root = np.sqrt(np.float64(spread))
        out_sums[x] = s
        out_inv[x] = 1.0 / root if spread > 0 else 0.0
    if std.size:
        out_std = std[hx : w - hx]
        for x in range(m):
            s = prefix[x + 2 * hx + 1] - prefix[x]
            spread = n * (prefix2[x + 2 * hx + 1] - prefix2[x]) - s * s
            out_std[x] = np.sqrt(np.float64(spread)) / n


@njit(cache=True)
def _kept_range(row_start, row_end, hys, h):  # pragma: no cover - numba
    """Per window and centre row: first disparity index whose column sums are kept up to
    date, and the end of the indices whose window sums the rows it serves need.

    A window centred on row ``c`` serves row ``c`` (and, shifted vertically, the rows above
    the first centre or below the last one). The kept start must cover the lowest floor of
    those rows and of every later centre, because column sums are running sums: an index
    dropped once cannot be resumed. Hence a suffix minimum, non-decreasing down the image.
    (Column sums are kept up to the last index: the ceilings rise down the image.)
    """
    n_win = hys.size
    kept = np.zeros((n_win, h), np.int64)
    end = np.zeros((n_win, h), np.int64)
    for k in range(n_win):
        hy = hys[k]
        if 2 * hy + 1 > h:
            continue
        low = row_start[k, h - 1]
        for c in range(h - 1 - hy, hy - 1, -1):
            # the rows this centre serves
            y0 = 0 if c == hy else c
            y1 = h if c == h - 1 - hy else c + 1
            need = row_start[k, y0]
            top = row_end[k, y0]
            for y in range(y0, y1):
                need = min(need, row_start[k, y])
                top = max(top, row_end[k, y])
            low = min(low, need)
            kept[k, c] = low
            end[k, c] = top
    return kept, end


@njit(cache=True)
def adaptive_match(
    ref,
    other,
    d_lo,
    n_all,
    row_start,
    row_end,
    hys,
    hxs,
    min_texture,
    min_ncc,
    margins,
    lr_tolerance,
    blend,
):  # pragma: no cover - numba
    """Adaptive-window ZNCC matching with subpixel peak and left-right check.

    Parameters are centred int32 images (H, W), the first disparity and the number of
    disparities, the first and one past the last disparity index each window searches in
    each row, (K, H) each (the row's floor and ceiling, ``0 <= row_start``, ``row_start + 3
    <= row_end <= n_all``), the window half-heights and half-widths in increasing order
    (K,), the least texture (gray-level std), the least ZNCC, the least peak margin per
    window (K,), the left-right tolerance (px) and ``blend``, the subpixel estimator of
    :func:`subpixel_offset` (False: parabola; True: parabola and V averaged).

    The windows' statistics (:func:`window_stats`) are formed row by row as each window's
    centre row advances (:func:`_row_stats`), not as (K, H, W) arrays: the same values,
    without allocating and filling five frames per window that are read one row at a time.

    Returns
    -------
    disparity : (H, W) float32
        Subpixel disparity; NaN where no window gave a textured, distinct peak; -inf where
        a peak was found but every such window failed the left-right check.
    window : (H, W) int8
        Index of the accepted window, -1 where none.
    """
    h, w = ref.shape
    n_win = hys.size
    disparity = np.full((h, w), NO_PEAK, np.float32)
    window = np.full((h, w), -1, np.int8)
    cs = np.zeros((n_win, n_all, w), np.int32)
    hs = np.zeros((n_win, n_all, w), np.int32)
    all_curves = np.full((n_all, w), -2.0, np.float32)
    curve = np.empty(n_all, np.float32)
    row_best = np.zeros(w, np.int32)
    row_top = np.zeros(w, np.float32)
    row_second = np.zeros(w, np.float32)
    left_index = np.full(w, -1, np.int32)  # int32: vectorises with the float32 values
    left_value = np.full(w, -np.inf, np.float32)
    pending = np.empty(w, np.int64)
    all_shifted = np.full((n_all, w), -np.inf, np.float32)
    j_first = np.zeros(w, np.int64)
    j_last = np.zeros(w, np.int64)
    peak_seen = np.zeros(w, np.bool_)
    # Row of each window's centre: the pixel's row, or the nearest row where the window fits
    # (near the top and bottom the window is shifted vertically, by at most its half-height,
    # like the sideways shift below). The sums advance one row at a time from row hy.
    centre_row = np.full(n_win, -1, np.int64)
    kept_from, kept_end = _kept_range(row_start, row_end, hys, h)
    # The column sums must follow every row (they are running sums), but the window sums
    # along the row are only formed in rows where a textured pixel still needs the window:
    # the larger windows are needed by few rows where the small ones match nearly everywhere.
    sums_row = np.full(n_win, -1, np.int64)
    # each window's statistics at its centre row: reference sums, inverse roots and std,
    # other image's sums and inverse roots (see window_stats), and their column sums
    stat_rows = np.zeros((5, n_win, w), np.float32)
    stat_cols = np.zeros((4, n_win, w), np.int64)
    prefix = np.empty(w + 1, np.int64)
    prefix2 = np.empty(w + 1, np.int64)
    no_std = np.empty(0, np.float32)
    for y in range(h):
        for k in range(n_win):
            if 2 * hys[k] + 1 > h:
                continue
            yc = min(max(y, hys[k]), h - 1 - hys[k])
            if yc != centre_row[k]:
                j_keep = kept_from[k, yc]
                _advance_column_sums_t(cs[k, j_keep:], ref, other, yc, hys[k], d_lo + j_keep)
                centre_row[k] = yc
                sums_row[k] = -1  # window sums are formed on first need in the row
                n_k = (2 * hys[k] + 1) * (2 * hxs[k] + 1)
                _advance_stat_columns(stat_cols[0, k], stat_cols[1, k], ref, yc, hys[k])
                _advance_stat_columns(stat_cols[2, k], stat_cols[3, k], other, yc, hys[k])
                _row_stats(
                    stat_rows[0, k], stat_rows[1, k], stat_rows[2, k], stat_cols[0, k],
                    stat_cols[1, k], hxs[k], n_k, prefix, prefix2,
                )  # fmt: skip
                _row_stats(
                    stat_rows[3, k], stat_rows[4, k], no_std, stat_cols[2, k], stat_cols[3, k],
                    hxs[k], n_k, prefix, prefix2,
                )  # fmt: skip
        n_pending = 0
        for x in range(w):
            pending[n_pending] = x
            n_pending += 1
        peak_seen[:] = False
        # Window by window over the row's still-unmatched pixels. Where many pixels need a
        # window, its whole row of curves and their peaks are computed in vectorised passes
        # and the left-right check reads the row back (C_left(xl, d) = C_ref(xl - d, d));
        # otherwise the few pixels are evaluated one by one. Both give identical values.
        for k in range(n_win):
            hw = hxs[k]
            hy = hys[k]
            if n_pending == 0 or 2 * hy + 1 > h:
                break
            yc = centre_row[k]
            n = (2 * hy + 1) * (2 * hw + 1)
            # The window's search range in this row starts at its floor: the row arrays are
            # viewed from there, and d_min, n_disp below are the row's.
            js = row_start[k, y]
            je = row_end[k, y]
            d_min = d_lo + js
            n_disp = je - js
            curves = all_curves[js:je]
            shifted = all_shifted[js:je]
            hs_k = hs[k, js:je]
            rs_row = stat_rows[0, k]
            ri_row = stat_rows[1, k]
            std_row = stat_rows[2, k]
            os_row = stat_rows[3, k]
            oi_row = stat_rows[4, k]
            textured = 0
            kept = 0
            if w < 2 * hw + 1:
                break  # wider windows do not fit either
            for i in range(n_pending):
                x = pending[i]
                pending[kept] = x
                kept += 1
                if std_row[min(max(x, hw), w - 1 - hw)] >= min_texture:
                    textured += 1
            n_pending = kept
            if textured == 0:
                continue
            if sums_row[k] != yc:
                # the indices any row served by this centre searches (js .. je within)
                j_keep = kept_from[k, yc]
                j_end = kept_end[k, yc]
                _window_sums_t(hs[k, j_keep:j_end], cs[k, j_keep:j_end], hw)
                sums_row[k] = yc
            use_row = 4 * textured > w - 2 * hw
            left_ready = False  # the left-reference argmax is found on first need
            if use_row:
                _row_scores(curves, hs_k, n, hw, rs_row, ri_row, os_row, oi_row, d_min, False)
                # interior columns [xa, xb): the window fits at every disparity; the others
                # get their shifted windows' curves, and all their peaks come from row passes
                xa = max(hw, hw - d_min)
                xb = max(xa, min(w - hw, w - hw - d_min - n_disp + 1))
                _row_peaks(row_best, row_top, row_second, curves, xa, xb)
                _border_curves(shifted, j_first, j_last, curves, hw, d_min, 0, xa)
                _border_curves(shifted, j_first, j_last, curves, hw, d_min, xb, w)
                _row_peaks(row_best, row_top, row_second, shifted, 0, xa)
                _row_peaks(row_best, row_top, row_second, shifted, xb, w)
            kept = 0
            for i in range(n_pending):
                x = pending[i]
                pending[kept] = x
                kept += 1  # stays pending unless accepted below
                x_ref = min(max(x, hw), w - 1 - hw)  # nearest centre with the window inside
                if std_row[x_ref] < min_texture:
                    continue
                interior = x == x_ref and hw - x - d_min <= 0 and w - hw - x - d_min >= n_disp
                if use_row:
                    if interior:
                        j0 = 0
                        j1 = n_disp
                        source = curves
                    else:
                        j0 = j_first[x]
                        j1 = j_last[x]
                        if j1 - j0 < 3:
                            continue
                        source = shifted
                    best = np.int64(row_best[x])
                    best_value = row_top[x]
                    second = row_second[x]
                elif interior:
                    j0 = 0
                    j1 = n_disp
                    for j in range(n_disp):
                        curve[j] = _ncc(hs_k, n, rs_row, ri_row, os_row, oi_row, x, j, d_min)
                    best, best_value, second = _peak(curve, j0, j1)
                else:
                    # Near the image's sides the window is shifted (by at most its half-width,
                    # so it still contains the pixel) to lie inside both images.
                    j0 = n_disp
                    j1 = 0
                    for j in range(n_disp):
                        xc = _shifted_centre(x, j, hw, d_min, w)
                        if xc < hw or xc > w - 1 - hw or abs(xc - x) > hw:
                            curve[j] = -2.0
                            continue
                        curve[j] = _ncc(hs_k, n, rs_row, ri_row, os_row, oi_row, xc, j, d_min)
                        j0 = min(j0, j)
                        j1 = max(j1, j + 1)
                    if j1 - j0 < 3:
                        continue
                    best, best_value, second = _peak(curve, j0, j1)
                if best == j0 or best == j1 - 1 or best_value < min_ncc:
                    continue
                if best_value - second < margins[k]:
                    continue
                peak_seen[x] = True
                xc = x if interior else _shifted_centre(x, best, hw, d_min, w)
                xl = xc + d_min + best
                if use_row:
                    if not left_ready:
                        _left_best(left_index, left_value, curves, hw, d_min)
                        left_ready = True
                    lr_best = np.int64(left_index[xl])
                else:
                    # same tie rule as _left_best: of equal values the largest index wins
                    lr_best = -1
                    lr_value = np.float32(-np.inf)
                    for jj in range(n_disp - 1, -1, -1):
                        xr = xl - d_min - jj
                        if xr < hw or xr + hw >= w:
                            continue
                        value = _ncc(hs_k, n, rs_row, ri_row, os_row, oi_row, xr, jj, d_min)
                        if value > lr_value:
                            lr_value = value
                            lr_best = jj
                if abs(lr_best - best) > lr_tolerance:
                    continue
                # The window-edge asymmetry of the reference curve's neighbours appears with
                # the opposite sign in the left-reference curve, so averaging both parabola
                # vertices cancels it (an exact integer shift gives an exact integer).
                if use_row:
                    c_minus = source[best - 1, x]
                    c_plus = source[best + 1, x]
                else:
                    c_minus = curve[best - 1]
                    c_plus = curve[best + 1]
                offset = subpixel_offset(c_minus, best_value, c_plus, blend)
                if xc - 1 >= hw and xc + 1 + hw < w:
                    if use_row:  # the same values, already computed
                        before = curves[best - 1, xc + 1]
                        after = curves[best + 1, xc - 1]
                    else:
                        before = _ncc(
                            hs_k, n, rs_row, ri_row, os_row, oi_row, xc + 1, best - 1, d_min
                        )
                        after = _ncc(
                            hs_k, n, rs_row, ri_row, os_row, oi_row, xc - 1, best + 1, d_min
                        )
                    offset = 0.5 * (offset + subpixel_offset(before, best_value, after, blend))
                disparity[y, x] = np.float32(d_min + best + offset)
                window[y, x] = k
                kept -= 1  # accepted: drop from pending
            n_pending = kept
        for i in range(n_pending):
            if peak_seen[pending[i]]:
                disparity[y, pending[i]] = LR_REJECTED
    return disparity, window


@njit(cache=True)
def ncc_cost_volume(
    ref, other, d_min, n_disp, hw, ref_sums, ref_inv, other_sums, other_inv, out=None
):  # pragma: no cover - numba
    """Matching cost ``(1 - ZNCC) / 2`` in [0, 1] of one window, shape (H, W, D) float32.

    Where the window does not fit (image border, disparity beyond the other image) the cost
    is 0.5, the cost of an uncorrelated match, so semi-global aggregation fills it from the
    neighbours; the caller invalidates such pixels afterwards. The sums and each row's
    costs are disparity-major, as for :func:`adaptive_match`; only the copy into the
    (H, W, D) volume that aggregation reads is transposed.

    ``out``, if given, is an (H, W, D) float32 array to fill instead of a new one (every
    cell is written): a volume reused from frame to frame spares the kernel the page
    faults of fresh memory, which cost more than filling it.
    """
    h, w = ref.shape
    # 0.5 only where the rows below do not write: the border rows and columns
    if out is None:
        cost = np.empty((h, w, n_disp), np.float32)
    else:
        cost = out
    cost[: min(hw, h)] = 0.5
    cost[max(h - hw, hw) :] = 0.5
    cost[:, : min(hw, w)] = 0.5
    cost[:, max(w - hw, hw) :] = 0.5
    cs = np.zeros((n_disp, w), np.int32)
    hs = np.zeros((n_disp, w), np.int32)
    costs = np.empty((n_disp, w), np.float32)
    n = (2 * hw + 1) * (2 * hw + 1)
    for y in range(hw, h - hw):
        _advance_column_sums_t(cs, ref, other, y, hw, d_min)
        _window_sums_t(hs, cs, hw)
        _row_scores(
            costs, hs, n, hw, ref_sums[y], ref_inv[y], other_sums[y], other_inv[y], d_min, True
        )
        out = cost[y]
        for x in range(hw, w - hw):
            column = out[x]
            for j in range(n_disp):
                column[j] = costs[j, x]
    return cost


@njit(cache=True)
def flag_occluded(coded, tolerance, code):  # pragma: no cover - numba
    """In place: set the pixels :func:`occluded` flags to ``code`` (the rest unchanged).

    :func:`occluded`'s two passes row by row (a row's flags depend on that row only), with
    each pixel's landing column kept from the first pass and the code written in the
    second: no (H, W) flag array and no third pass.
    """
    h, w = coded.shape
    nearest = np.empty(w, np.float32)
    column = np.empty(w, np.int64)
    for y in range(h):
        nearest[:] = -np.inf
        for x in range(w):
            d = coded[y, x]
            c = -1
            if np.isfinite(d):
                c = int(np.floor(x + d + 0.5))
                if 0 <= c < w:
                    if d > nearest[c]:
                        nearest[c] = d
                else:
                    c = -1
            column[x] = c
        for x in range(w):
            c = column[x]
            if c >= 0 and nearest[c] > coded[y, x] + tolerance:
                coded[y, x] = code


@njit(cache=True)
def decode_status(coded):  # pragma: no cover - numba
    """Disparity (NaN where not valid) and int8 status from the one-array coding of
    :mod:`stages._stereo`: NaN no peak (1), -inf left-right rejected (2), +inf speckle
    (3), finite valid (0)."""
    h, w = coded.shape
    disparity = np.empty((h, w), np.float32)
    status = np.empty((h, w), np.int8)
    for y in range(h):
        for x in range(w):
            v = coded[y, x]
            if np.isfinite(v):
                status[y, x] = 0
                disparity[y, x] = v
            else:
                status[y, x] = 1 if np.isnan(v) else (2 if v < 0 else 3)
                disparity[y, x] = np.nan
    return disparity, status


@njit(cache=True)
def occluded(disparity, tolerance):  # pragma: no cover - numba
    """Reference pixels hidden in the other view by a nearer surface (uniqueness test).

    Each valid pixel lands at column ``round(x + d)`` of the other image; where several land
    on one column, the nearest (largest disparity) is what the other camera sees, and pixels
    more than ``tolerance`` px behind it cannot have been seen: they are flagged.
    """
    h, w = disparity.shape
    flags = np.zeros((h, w), np.bool_)
    nearest = np.empty(w, np.float32)
    for y in range(h):
        nearest[:] = -np.inf
        for x in range(w):
            d = disparity[y, x]
            if np.isfinite(d):
                c = int(np.floor(x + d + 0.5))
                if 0 <= c < w and d > nearest[c]:
                    nearest[c] = d
        for x in range(w):
            d = disparity[y, x]
            if np.isfinite(d):
                c = int(np.floor(x + d + 0.5))
                if 0 <= c < w and nearest[c] > d + tolerance:
                    flags[y, x] = True
    return flags
