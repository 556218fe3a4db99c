"""Numba kernels of ZNCC matching (stages._ncc): subpixel offsets, and the row-wise (D, W)
kernels against brute force."""

from __future__ import annotations

import numpy as np
import pytest
from stereo_scenes import shifted_pair

from stages import _ncc, _stereo


@pytest.mark.parametrize(
    ("samples", "parabola", "vee"),
    [
        ((0.5, 0.9, 0.5), 0.0, 0.0),  # symmetric: the peak is on the sample
        ((0.4, 0.8, 0.8), 0.5, 0.5),  # equal top samples: halfway between them
        ((0.6, 0.9, 0.8), 0.25, 0.5 * 0.2 / 0.3),  # towards the larger neighbour
        ((0.7, 0.7, 0.7), 0.0, 0.0),  # flat: no offset
    ],
)
def test_subpixel_offset_of_three_samples(samples, parabola, vee):
    assert _ncc.subpixel_offset(*samples, False) == pytest.approx(parabola)
    assert _ncc.subpixel_offset(*samples, True) == pytest.approx(0.5 * (parabola + vee))
    # mirrored samples, mirrored offsets
    assert _ncc.subpixel_offset(*samples[::-1], True) == pytest.approx(-0.5 * (parabola + vee))


def test_subpixel_offsets_are_exact_for_their_own_peak_shapes():
    # samples at -1, 0, 1 of a parabola and of a V with their top at 0.3: each estimator
    # is exact for its own shape and the blend lies between the two
    top = 0.3
    parabola = [1.0 - 0.2 * (x - top) ** 2 for x in (-1, 0, 1)]
    vee = [1.0 - 0.2 * abs(x - top) for x in (-1, 0, 1)]
    assert _ncc.subpixel_offset(*parabola, False) == pytest.approx(top)
    assert 0.5 * (top + _ncc._equiangular_offset(*parabola)) == pytest.approx(
        _ncc.subpixel_offset(*parabola, True)
    )
    assert _ncc._equiangular_offset(*vee) == pytest.approx(top)
    assert _ncc._equiangular_offset(*parabola) > top  # the V overshoots a round peak
    assert _ncc._parabola_offset(*vee) < top  # the parabola undershoots a sharp one


# -------------------------------------------------------------------- row kernels, (D, W)
# The row-wise kernels of stages._ncc must give exactly what the per-pixel path gives (a
# tile may take either path for the same pixel), so they are checked against brute force.


def _tied_curves(shape, seed):
    """ZNCC-like curves (D, W) on a coarse grid, so that many columns hold tied maxima."""
    rng = np.random.default_rng(seed)
    return (np.round(rng.uniform(-1.0, 1.0, shape) * 4) / 4).astype(np.float32)


def test_row_peaks_equal_the_per_pixel_peak():
    curves = _tied_curves((9, 40), seed=0)
    best = np.full(40, -7, np.int32)  # as adaptive_match keeps it
    top = np.zeros(40, np.float32)
    second = np.zeros(40, np.float32)
    _ncc._row_peaks(best, top, second, curves, 3, 37)
    for x in range(3, 37):
        expected = _ncc._peak(np.ascontiguousarray(curves[:, x]), 0, curves.shape[0])
        assert (best[x], top[x], second[x]) == expected
    assert np.all(best[:3] == -7) and np.all(best[37:] == -7)  # outside x0..x1 untouched


@pytest.mark.parametrize("d_min", [-3, 0, 2])
def test_left_best_is_the_left_reference_argmax(d_min):
    n_disp, w, hw = 7, 30, 2
    curves = _tied_curves((n_disp, w), seed=1)
    index = np.zeros(w, np.int32)  # as adaptive_match keeps it
    value = np.zeros(w, np.float32)
    _ncc._left_best(index, value, curves, hw, d_min)
    for xl in range(w):
        # C_left(xl, j) = C_ref(xl - d_min - j, j) where both windows fit; ties: largest j
        found = [
            (curves[j, xl - d_min - j], j)
            for j in range(n_disp)
            if hw <= xl < w - hw and hw <= xl - d_min - j < w - hw
        ]
        expected = max(found) if found else (-np.inf, -1)
        assert (value[xl], index[xl]) == expected


def test_window_sums_are_box_sums_of_the_products():
    rng = np.random.default_rng(2)
    ref = rng.integers(-128, 128, (12, 25)).astype(np.int32)
    oth = rng.integers(-128, 128, (12, 25)).astype(np.int32)
    d_min, n_disp, hy, hw = -2, 6, 2, 3
    cs = np.zeros((n_disp, 25), np.int32)
    hs = np.zeros((n_disp, 25), np.int32)
    for y in range(hy, 12 - hy):
        _ncc._advance_column_sums_t(cs, ref, oth, y, hy, d_min)
        _ncc._window_sums_t(hs, cs, hw)
        for j in range(n_disp):
            d = d_min + j
            product = np.zeros((12, 25), np.int64)  # R(y, x) L(y, x + d), 0 off the image
            lo, hi = max(0, -d), min(25, 25 - d)
            product[:, lo:hi] = ref[:, lo:hi] * oth[:, lo + d : hi + d]
            window = product[y - hy : y + hy + 1].sum(axis=0)
            expected = np.convolve(window, np.ones(2 * hw + 1, np.int64), mode="valid")
            np.testing.assert_array_equal(hs[j, hw : 25 - hw], expected)


@pytest.mark.parametrize("d_min", [-5, 0, 4])
def test_cost_volume_is_half_one_minus_the_zncc(d_min):
    # sgm's cost (1 - ZNCC) / 2 from the (D, W) row sums, against ZNCC computed window by
    # window; 0.5 (uncorrelated) wherever the window leaves either image
    right, left = shifted_pair((21, 40), 3, seed=4)
    ref, oth = _stereo._centred(right), _stereo._centred(left)
    n_disp, hw = 9, 2
    hws = np.array([hw], np.int64)
    rs, ri, _ = _ncc.window_stats(ref, hws, hws)
    os_, oi, _ = _ncc.window_stats(oth, hws, hws)
    cost = _ncc.ncc_cost_volume(ref, oth, d_min, n_disp, hw, rs[0], ri[0], os_[0], oi[0])
    assert cost.shape == (21, 40, n_disp) and cost.dtype == np.float32
    h, w = ref.shape
    for y, x, j in np.ndindex(cost.shape):
        xo = x + d_min + j
        if not (hw <= y < h - hw and hw <= x < w - hw and hw <= xo < w - hw):
            assert cost[y, x, j] == 0.5
            continue
        a = ref[y - hw : y + hw + 1, x - hw : x + hw + 1].astype(np.float64).ravel()
        b = oth[y - hw : y + hw + 1, xo - hw : xo + hw + 1].astype(np.float64).ravel()
        zncc = np.corrcoef(a, b)[0, 1]
        assert cost[y, x, j] == pytest.approx(0.5 * (1.0 - zncc), abs=1e-6)


def test_cost_volume_into_a_used_volume_equals_a_fresh_one():
    # every cell is written, so a volume reused from the previous frame gives the same costs
    right, left = shifted_pair((21, 40), 3, seed=4)
    ref, oth = _stereo._centred(right), _stereo._centred(left)
    hws = np.array([2], np.int64)
    rs, ri, _ = _ncc.window_stats(ref, hws, hws)
    os_, oi, _ = _ncc.window_stats(oth, hws, hws)
    args = (ref, oth, -1, 9, 2, rs[0], ri[0], os_[0], oi[0])
    out = np.full((21, 40, 9), np.nan, np.float32)
    _ncc.ncc_cost_volume(*args, out)
    assert out.tobytes() == _ncc.ncc_cost_volume(*args).tobytes()


@pytest.mark.parametrize("d_min", [-4, 0, 3])
def test_border_curves_read_the_shifted_windows(d_min):
    # a window that does not fit is moved to the nearest centre where it does, at most hw
    # px from the pixel; the row pass must read exactly that centre's value
    n_disp, w, hw = 8, 30, 3
    curves = _tied_curves((n_disp, w), seed=3)
    shifted = np.zeros((n_disp, w), np.float32)
    first = np.zeros(w, np.int64)
    last = np.zeros(w, np.int64)
    _ncc._border_curves(shifted, first, last, curves, hw, d_min, 0, w)
    for x in range(w):
        valid = []
        for j in range(n_disp):
            x_ref = min(max(x, hw), w - 1 - hw)
            xc = max(min(x_ref, w - 1 - hw - d_min - j), hw - d_min - j)
            if hw <= xc <= w - 1 - hw and abs(xc - x) <= hw:
                valid.append(j)
                assert shifted[j, x] == curves[j, xc]
            else:
                assert shifted[j, x] == -np.inf
        assert valid == list(range(first[x], last[x]))  # one contiguous range


def _numpy_window_stats(image, hy, hx):
    """Reference of one window's statistics: box sums over the whole window, numpy only."""
    v = image.astype(np.int64)
    h, w = v.shape
    sums = np.zeros((h, w), np.float32)
    inv = np.zeros((h, w), np.float32)
    std = np.zeros((h, w), np.float32)
    if h < 2 * hy + 1 or w < 2 * hx + 1:
        return sums, inv, std
    boxes = np.lib.stride_tricks.sliding_window_view(v, (2 * hy + 1, 2 * hx + 1))
    n = (2 * hy + 1) * (2 * hx + 1)
    s = boxes.sum(axis=(2, 3))
    spread = n * (boxes * boxes).sum(axis=(2, 3)) - s * s
    root = np.sqrt(spread.astype(np.float64))
    inner = (slice(hy, h - hy), slice(hx, w - hx))
    sums[inner] = s
    with np.errstate(divide="ignore"):
        inv[inner] = np.where(spread > 0, 1.0 / root, 0.0)
    std[inner] = root / n
    return sums, inv, std


@pytest.mark.parametrize(("hy", "hx"), [(1, 1), (2, 4), (0, 3), (4, 13)])
def test_window_stats_and_row_stats_equal_numpy_box_sums(hy, hx):
    # the whole-frame kernel (sgm) and the row-by-row one (adaptive) give the same float32
    # bits as box sums over each window; flat patches give zero inverse roots and stds
    rng = np.random.default_rng(5)
    image = rng.integers(-128, 128, (11, 23)).astype(np.int32)
    image[:6, :9] = 7  # flat
    sums, inv, std = _numpy_window_stats(image, hy, hx)
    got = _ncc.window_stats(image, np.array([hy]), np.array([hx]))
    for mine, expected in zip(got, (sums, inv, std), strict=True):
        assert mine[0].tobytes() == expected.tobytes()
    no_std = _ncc.window_stats(image, np.array([hy]), np.array([hx]), False)
    assert no_std[1][0].tobytes() == inv.tobytes() and no_std[2].size == 0
    h, w = image.shape
    col, col2 = np.zeros(w, np.int64), np.zeros(w, np.int64)
    row = [np.full(w, -1.0, np.float32) for _ in range(3)]
    scratch = np.zeros(w + 1, np.int64), np.zeros(w + 1, np.int64)
    n = (2 * hy + 1) * (2 * hx + 1)
    for yc in range(hy, h - hy):
        _ncc._advance_stat_columns(col, col2, image, yc, hy)
        _ncc._row_stats(*row, col, col2, hx, n, *scratch)
        for mine, expected in zip(row, (sums, inv, std), strict=True):
            assert mine.tobytes() == expected[yc].tobytes()


def _coded_row_mix(seed):
    rng = np.random.default_rng(seed)
    coded = rng.uniform(0, 6, (9, 30)).astype(np.float32)
    pick = rng.random(coded.shape)
    coded[pick < 0.3] = np.nan
    coded[(pick >= 0.3) & (pick < 0.4)] = -np.inf
    coded[(pick >= 0.4) & (pick < 0.5)] = np.inf
    return coded


def test_decode_status_equals_the_numpy_masks():
    coded = _coded_row_mix(8)
    disparity, status = _ncc.decode_status(coded)
    expected = np.zeros(coded.shape, np.int8)  # numpy reference, the passes it replaced
    expected[np.isnan(coded)] = 1
    expected[np.isneginf(coded)] = 2
    expected[np.isposinf(coded)] = 3
    np.testing.assert_array_equal(status, expected)
    reference = np.where(expected == 0, coded, np.nan).astype(np.float32)
    assert disparity.dtype == np.float32 and disparity.tobytes() == reference.tobytes()


def test_flag_occluded_codes_what_occluded_flags_ignoring_codes():
    # the coded map's NaN and +-inf are skipped like NaN in the plain disparity
    coded = _coded_row_mix(9)
    plain = np.where(np.isfinite(coded), coded, np.nan).astype(np.float32)
    hidden = _ncc.occluded(plain, np.float32(1.0))
    assert hidden.any()
    expected = np.where(hidden, _ncc.LR_REJECTED, coded).astype(np.float32)
    _ncc.flag_occluded(coded, np.float32(1.0), _ncc.LR_REJECTED)
    assert coded.tobytes() == expected.tobytes()
