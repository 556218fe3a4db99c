"""Stereo matching (stages._stereo) on textures with known disparity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from stages import _ncc, _stereo
from stages._stereo import (
    STATUS_NO_PEAK,
    STATUS_VALID,
    match_disparity,
    match_tiled,
    remove_speckles,
    sgbm_disparity,
)

# Small test images lose a border of half the largest window; these windows keep most of
# them while exercising the same adaptive rule as the default windows.
SMALL = {"windows": "5,9,15"}


def _texture(shape: tuple[int, int], seed: int, blur: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(128.0, 45.0, shape), blur)


def _u8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _shifted_pair(shape, d, seed):
    """(right, left) with right(x) = left(x + d) for an integer d: right is the reference."""
    h, w = shape
    world = _u8(_texture((h, w + d), seed))
    left = world[:, :w]
    right = world[:, d : d + w]
    return right, left


def _occlusion_scene(seed=3, shape=(64, 120), d_back=4, d_front=12, square=(20, 44, 40, 70)):
    """Background at d_back and a foreground square at d_front, built from the left view.

    Returns right, left, true disparity and the mask of right pixels the left camera cannot
    see (background just right of the square).
    """
    h, w = shape
    back = _u8(_texture((h, w + 40), seed))
    front = _u8(_texture((h, w + 40), seed + 100))
    y0, y1, x0, x1 = square
    ys, xs = np.indices(shape)
    in_square = (ys >= y0) & (ys < y1) & (xs >= x0) & (xs < x1)
    right = np.where(in_square, front[:, :w], back[:, d_back : d_back + w])
    left = back[:, :w].copy()
    for y in range(y0, y1):
        cols = np.arange(x0, x1) + d_front
        keep = cols < w
        left[y, cols[keep]] = front[y, np.arange(x0, x1)[keep]]
    truth = np.where(in_square, d_front, d_back).astype(np.float32)
    occluded = (ys >= y0) & (ys < y1) & (xs >= x1) & (xs < x1 + d_front - d_back) & ~in_square
    return right, left, truth, occluded


def test_integer_shift_is_recovered_exactly():
    right, left = _shifted_pair((64, 120), 7, seed=0)
    m = match_disparity(right, left, min_disparity=0, max_disparity=20, **SMALL)
    assert m.valid_fraction > 0.8
    err = np.abs(m.disparity - 7)
    # interior pixels get the exact integer (the symmetric subpixel fit cancels its bias);
    # windows shifted to fit at the image's sides keep a small one-sided bias
    interior = err[:, 8:-30]
    assert np.mean(interior[np.isfinite(interior)] < 1e-3) > 0.98
    assert np.nanmax(err) < 0.5 and np.nanmean(err) < 0.02


@settings(max_examples=8, deadline=None)
@given(d=st.integers(min_value=1, max_value=14), seed=st.integers(0, 1000))
def test_any_integer_shift_in_range_is_recovered(d, seed):
    right, left = _shifted_pair((40, 80), d, seed=seed)
    m = match_disparity(right, left, min_disparity=0, max_disparity=15)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.5 * m.disparity.size
    assert np.median(np.abs(values - d)) < 1e-3


@pytest.mark.parametrize("shift", [5.25, 5.5, 5.8])
def test_subpixel_shift_is_recovered(shift):
    world = _texture((64, 160), seed=1, blur=1.2)
    left = _u8(world[:, 10:130])
    right = _u8(ndimage.shift(world, (0, -shift), order=3)[:, 10:130])  # right(x) = w(x + s)
    m = match_disparity(right, left, min_disparity=0, max_disparity=16, **SMALL)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.8 * m.disparity.size
    assert abs(np.mean(values) - shift) < 0.08
    assert np.median(np.abs(values - shift)) < 0.1


def _ramp_pair(seed, shape=(80, 140), d0=6.0, slope=0.0125):
    """(right, left, truth): disparity rising 0.0125 px per row, every fraction of a pixel."""
    h, w = shape
    world = _texture((h, w + 30), seed)
    ys, xs = np.indices(shape, dtype=float)
    truth = d0 + slope * ys
    right = ndimage.map_coordinates(world, [ys, xs + truth], order=3)  # right(x) = w(x + d)
    return _u8(right), _u8(world[:, :w]), truth


def _bias_by_fraction(disparity, truth):
    """Median signed error where the true fraction is in [0.2, 0.4) and in [0.6, 0.8)."""
    err = disparity - truth
    frac = truth - np.floor(truth)
    ok = np.isfinite(err)
    return [float(np.median(err[ok & (frac >= a) & (frac < a + 0.2)])) for a in (0.2, 0.6)]


def test_blend_subpixel_removes_the_parabolas_pixel_locking():
    right, left, truth = _ramp_pair(seed=0)
    runs = {
        mode: match_disparity(
            right, left, min_disparity=0, max_disparity=16, subpixel=mode, **SMALL
        ).disparity
        for mode in ("parabola", "blend")
    }
    # the parabola pulls estimates towards the nearest integer ...
    low, high = _bias_by_fraction(runs["parabola"], truth)
    assert low < -0.02 and high > 0.02
    # ... the mean of parabola and V does not, and is closer to the truth overall
    low, high = _bias_by_fraction(runs["blend"], truth)
    assert abs(low) < 0.01 and abs(high) < 0.01
    errors = {mode: np.nanmedian(np.abs(d - truth)) for mode, d in runs.items()}
    assert errors["blend"] < 0.75 * errors["parabola"]
    # only the subpixel estimate differs: the same pixels match, to the same whole pixel
    assert np.array_equal(np.isfinite(runs["blend"]), np.isfinite(runs["parabola"]))
    assert np.nanmax(np.abs(runs["blend"] - runs["parabola"])) <= 0.5


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


def test_unknown_subpixel_estimator_is_rejected():
    right, left = _shifted_pair((32, 48), 3, seed=0)
    with pytest.raises(ValueError, match="subpixel must be one of"):
        match_disparity(right, left, min_disparity=0, max_disparity=8, subpixel="cubic")


def test_occluded_pixels_are_invalid_after_the_lr_check():
    right, left, truth, occluded = _occlusion_scene()
    m = match_disparity(right, left, min_disparity=0, max_disparity=20, speckle_size=0, **SMALL)
    assert occluded.sum() == 8 * 24
    invalid = m.status != STATUS_VALID
    # Away from the band's edges (half the smallest window) the occluded pixels are
    # rejected; at the edges windows reach into visible surfaces, the known limit of
    # window matching (foreground "fattening").
    core = occluded.copy()
    core[:22], core[42:], core[:, 76:], core[:, :72] = False, False, False, False
    assert np.mean(invalid[core]) >= 0.95
    assert np.mean(invalid[occluded]) >= 0.65
    seen = np.isfinite(m.disparity) & ~occluded
    assert np.mean(np.abs(m.disparity[seen] - truth[seen]) <= 1) > 0.97
    assert m.lr_consistency < 1.0


def test_without_lr_check_occluded_pixels_get_matches():
    # the control experiment: a huge tolerance disables the left-right and uniqueness tests
    right, left, _, occluded = _occlusion_scene()
    m = match_disparity(
        right, left, min_disparity=0, max_disparity=20, lr_tolerance=100.0, speckle_size=0,
        **SMALL,
    )  # fmt: skip
    assert np.mean(m.status[occluded] != STATUS_VALID) < 0.4


@pytest.mark.parametrize("prefilter", [0, 15])
def test_tiled_equals_whole_frame(prefilter):
    right, left, _, _ = _occlusion_scene(shape=(80, 130))
    args = {"min_disparity": 0, "max_disparity": 20, "speckle_size": 20, "prefilter": prefilter}
    whole = match_disparity(right, left, **args)
    tiled = match_tiled(right, left, tile_px=32, **args)
    np.testing.assert_array_equal(tiled.disparity, whole.disparity)
    np.testing.assert_array_equal(tiled.status, whole.status)


def test_top_and_bottom_rows_are_matched_with_shifted_windows():
    # regression: rows nearer the top or bottom than half a window's height were left
    # invalid (5 % of a 500 px frame with a 51-row window; lab bad-2 21.7 -> 18.2 %)
    right, left = _shifted_pair((64, 120), 7, seed=1)
    m = match_disparity(right, left, min_disparity=0, max_disparity=20, **SMALL)
    edge_rows = np.r_[0:7, 57:64]  # beyond half of the 15 px window (and of the 5 px one)
    assert np.mean(m.status[edge_rows, 10:-30] == STATUS_VALID) > 0.95
    assert np.nanmax(np.abs(m.disparity[edge_rows] - 7)) < 0.5


def _shaded_pair(seed=5, shape=(80, 160), d=6):
    """(right, left): faint fine texture (std ~1.5) under a strong lamp-like shading."""
    h, w = shape
    rng = np.random.default_rng(seed)
    fine = ndimage.gaussian_filter(rng.normal(0.0, 3.0, (h, w + d)), 1.0)
    ys, xs = np.indices((h, w + d))
    shade = 60 + 120 * np.exp(-(((xs - 80) / 60.0) ** 2 + ((ys - 20) / 50.0) ** 2))
    world = _u8(shade + fine)
    return world[:, d : d + w], world[:, :w]


def test_prefilter_finds_faint_texture_under_shading():
    # the lab floor's failure: a window's ZNCC is dominated by the lamp's brightness gradient,
    # its curve is a broad hump and the peak is not distinct; the high-pass exposes the texture
    right, left = _shaded_pair()
    args = {"min_disparity": 0, "max_disparity": 20, "windows": "5,9,15x41"}
    raw = match_disparity(right, left, prefilter=0, **args)
    high = match_disparity(right, left, prefilter=15, **args)
    assert high.valid_fraction > 0.8 > 0.2 > raw.valid_fraction
    assert np.nanmax(np.abs(high.disparity - 6)) < 1.0


def test_prefilter_image_is_the_rounded_high_pass():
    image = _u8(_texture((40, 50), seed=2, blur=2.0))
    out = _stereo.prefilter_image(image, size=9)
    f = image.astype(np.float64)
    mean = ndimage.uniform_filter(f, 9, mode="reflect")  # scipy 'reflect' = cv2 BORDER_REFLECT
    expected = np.clip(np.floor(2 * (f - mean) + 0.5) + 128, 0, 255)
    assert out.dtype == np.uint8
    # the float box mean may land a hair off a .5 tie; the integer one does not
    assert np.mean(out == expected) > 0.99 and np.abs(out - expected).max() <= 1
    # a linear ramp has no high-pass content away from the border
    ramp = np.add.outer(np.arange(40) * 3, np.arange(50)).astype(np.uint8)
    assert np.all(_stereo.prefilter_image(ramp, size=9)[4:-4, 4:-4] == 128)


def test_prefilter_tiles_equal_the_whole_image():
    image = _u8(_texture((70, 90), seed=4))
    whole = _stereo.prefilter_image(image, size=15)
    part = _stereo.prefilter_image(image[10:60, 20:80], size=15)
    np.testing.assert_array_equal(part[7:-7, 7:-7], whole[17:53, 27:73])


def test_textureless_image_is_invalid_not_guessed():
    flat = np.full((40, 60), 120, np.uint8)
    m = match_disparity(flat, flat, min_disparity=0, max_disparity=10)
    assert np.all(np.isnan(m.disparity))
    assert np.all(m.status == STATUS_NO_PEAK)


def test_sgm_recovers_a_shift():
    right, left = _shifted_pair((48, 96), 6, seed=2)
    m = match_disparity(right, left, min_disparity=0, max_disparity=15, method="sgm", sgm_window=5)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.7 * m.disparity.size
    assert np.median(np.abs(values - 6)) < 0.25


def test_sgbm_gives_right_reference_disparity():
    right, left = _shifted_pair((64, 128), 9, seed=4)
    d = sgbm_disparity(left, right, min_disparity=0, max_disparity=30)
    values = d[np.isfinite(d)]
    assert values.size > 0.5 * d.size
    assert np.median(values) == pytest.approx(9, abs=0.1)
    # right-reference: the right image's last columns have no partner in the left image
    assert np.all(np.isnan(d[:, -8:]))


def test_opencv_method_matches_sgbm_function():
    right, left = _shifted_pair((48, 96), 5, seed=5)
    m = match_disparity(
        right, left, min_disparity=0, max_disparity=20, method="opencv-sgbm", speckle_size=0
    )
    np.testing.assert_array_equal(
        m.disparity, sgbm_disparity(left, right, min_disparity=0, max_disparity=20)
    )


def test_speckles_are_removed_and_large_regions_kept():
    d = np.full((30, 30), 10.0, np.float32)
    d[5:8, 5:8] = 20.0  # 9-pixel island
    d[15:30, 15:30] = 3.0  # 225-pixel region
    cleaned, removed = remove_speckles(d, max_size=20, max_diff=1.0)
    assert removed.sum() == 9 and np.all(removed[5:8, 5:8])
    assert np.all(np.isnan(cleaned[5:8, 5:8]))
    assert np.all(cleaned[15:30, 15:30] == 3.0)


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"method": "census"}, ValueError, "method must be one of"),
        ({"windows": "5,8"}, ValueError, "odd"),
        ({"windows": "9,5"}, ValueError, "increasing"),
        ({"windows": "5,x"}, ValueError, "comma-separated"),
        ({"windows": (5, 257)}, ValueError, "at most 255"),
        ({"max_disparity": 1}, ValueError, "at least 2"),
        ({"max_disparity": 10.5}, TypeError, "must be an int"),
        ({"min_ncc": 2.0}, ValueError, "min_ncc"),
        ({"speckle_size": -1}, ValueError, "speckle_size"),
        ({"sgm_paths": 3}, ValueError, "sgm_paths"),
        ({"prefilter": 4}, ValueError, "prefilter"),
        ({"min_texture": float("nan")}, ValueError, "min_texture"),
    ],
)
def test_bad_settings_raise_clear_errors(kwargs, error, words):
    right, left = _shifted_pair((24, 40), 3, seed=0)
    args = {"min_disparity": 0, "max_disparity": 8, **kwargs}
    with pytest.raises(error, match=words):
        match_disparity(right, left, **args)


def test_bad_images_raise_clear_errors():
    img = np.zeros((20, 30), np.uint8)
    with pytest.raises(ValueError, match="same shape"):
        match_disparity(img, img[:, :20], min_disparity=0, max_disparity=5)
    with pytest.raises(TypeError, match="uint8"):
        match_disparity(img.astype(float), img, min_disparity=0, max_disparity=5)
    with pytest.raises(ValueError, match="2-D"):
        match_disparity(img[None], img[None], min_disparity=0, max_disparity=5)
    with pytest.raises(ValueError, match=r"\[0, 255\]"):
        match_disparity(img.astype(np.int32) - 1, img, min_disparity=0, max_disparity=5)


def test_check_settings_rejects_unknown_keys():
    with pytest.raises(TypeError, match="unknown matching settings"):
        _stereo.check_settings(window=5)


# ---------------------------------------------------------------- adaptive kernels, (D, W)
# The row-wise kernels of stages._ncc must give exactly what the per-pixel path gives (a
# tile may take either path for the same pixel), so they are checked against brute force.


def _tied_curves(shape, seed):
    """ZNCC-like curves (D, W) on a coarse grid, so that many columns hold tied maxima."""
    rng = np.random.default_rng(seed)
    return (np.round(rng.uniform(-1.0, 1.0, shape) * 4) / 4).astype(np.float32)


def test_row_peaks_equal_the_per_pixel_peak():
    curves = _tied_curves((9, 40), seed=0)
    best = np.full(40, -7, np.int64)
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
    index = np.zeros(w, np.int64)
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
    right, left = _shifted_pair((21, 40), 3, seed=4)
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


def _kernel(right, left, lo, hi, row_start, row_end=None, windows="5,9"):
    """_ncc.adaptive_match on a pair: (disparity, window), with per-window row bands."""
    if row_end is None:
        row_end = np.full_like(row_start, hi - lo + 1)
    s = _stereo.check_settings(windows=windows)
    hys = np.array([r // 2 for r, _ in s["windows"]], np.int64)
    hxs = np.array([c // 2 for _, c in s["windows"]], np.int64)
    r32, o32 = _stereo._centred(right), _stereo._centred(left)
    rs, ri, rsd = _ncc.window_stats(r32, hys, hxs)
    os_, oi, _ = _ncc.window_stats(o32, hys, hxs)
    return _ncc.adaptive_match(
        r32, o32, lo, hi - lo + 1, row_start, row_end, hys, hxs, rs, ri, rsd, os_, oi,
        1.0, 0.1, _stereo._margins(s), 1.0, True,
    )  # fmt: skip


@pytest.mark.parametrize("bands", [((0, 20), (3, 20), (6, 20)), ((0, 14), (2, 17), (5, 20))])
def test_row_bands_equal_narrowing_the_range_row_by_row(bands):
    # a band [f, c] searches exactly as a range [f, c] would; rows with different bands
    # share running column sums, which must stay exact across the bands' steps
    right, left, _, _ = _occlusion_scene(shape=(48, 90))
    h = right.shape[0]
    part = np.where(np.arange(h) < 20, 0, np.where(np.arange(h) < 33, 1, 2))
    floors = np.array([b[0] for b in bands])[part]
    ceilings = np.array([b[1] for b in bands])[part]
    row_start = np.tile(floors, (2, 1)).astype(np.int64)
    row_end = np.tile(ceilings + 1, (2, 1)).astype(np.int64)
    varied, _ = _kernel(right, left, 0, 20, row_start, row_end)
    for i, (f, c) in enumerate(bands):
        whole, _ = _kernel(right, left, f, c, np.zeros((2, h), np.int64))
        np.testing.assert_array_equal(varied[part == i], whole[part == i])


def test_band_leaves_the_first_window_whole_range():
    # the first window's competitors outside the band flag ambiguous matches (see the
    # "Search band" docstring): with a single window the band changes nothing
    right, left, _, _ = _occlusion_scene(shape=(48, 90))
    args = {"min_disparity": 0, "max_disparity": 20, "windows": "7"}
    plain = match_disparity(right, left, **args)
    banded = match_disparity(
        right, left, row_min_disparity=np.full(48, 10), row_max_disparity=np.full(48, 14), **args
    )
    np.testing.assert_array_equal(banded.disparity, plain.disparity)


def test_floor_above_the_truth_stops_the_larger_windows():
    # pixels left to the second window find nothing when the floor is above their disparity
    right, left = _shifted_pair((40, 100), 5, seed=4)
    lo_floor = match_disparity(
        right, left, min_disparity=0, max_disparity=16, windows="3,9",
        row_min_disparity=np.zeros(40, np.int64),
    )  # fmt: skip
    hi_floor = match_disparity(
        right, left, min_disparity=0, max_disparity=16, windows="3,9",
        row_min_disparity=np.full(40, 8),
    )  # fmt: skip
    right_lo = np.abs(lo_floor.disparity - 5) < 0.5
    right_hi = np.abs(hi_floor.disparity - 5) < 0.5
    assert np.mean(right_lo) > 0.9
    # the second window's matches are gone; the first window's stay where they were
    assert np.mean(right_hi) < np.mean(right_lo) - 0.05
    assert np.all(right_lo[right_hi])


def test_tiled_equals_whole_frame_with_row_bands():
    right, left, _, _ = _occlusion_scene(shape=(80, 130))
    floor = (np.arange(80) // 10).astype(np.int64)
    band = {"row_min_disparity": floor, "row_max_disparity": floor + 13}
    args = {"min_disparity": 0, "max_disparity": 20, "speckle_size": 20, "windows": "5,9,15"}
    whole = match_disparity(right, left, **band, **args)
    tiled = match_tiled(right, left, tile_px=32, **band, **args)
    np.testing.assert_array_equal(tiled.disparity, whole.disparity)
    np.testing.assert_array_equal(tiled.status, whole.status)


def test_bad_row_bands_raise_clear_errors():
    right, left = _shifted_pair((20, 40), 3, seed=0)
    args = {"min_disparity": 0, "max_disparity": 8}
    with pytest.raises(ValueError, match="row_min_disparity must hold one disparity per"):
        match_disparity(right, left, row_min_disparity=np.zeros(19, int), **args)
    with pytest.raises(TypeError, match="row_max_disparity must be integers"):
        match_disparity(right, left, row_max_disparity=np.full(20, 5.0), **args)


def test_ceiling_below_the_truth_stops_the_larger_windows():
    right, left = _shifted_pair((40, 100), 9, seed=4)
    args = {"min_disparity": 0, "max_disparity": 16, "windows": "3,9"}
    open_band = match_disparity(right, left, **args)
    low_ceiling = match_disparity(right, left, row_max_disparity=np.full(40, 6), **args)
    right_open = np.abs(open_band.disparity - 9) < 0.5
    right_low = np.abs(low_ceiling.disparity - 9) < 0.5
    assert np.mean(right_open) > 0.85  # all but the columns that leave the image
    assert np.mean(right_low) < np.mean(right_open) - 0.05
    assert np.all(right_open[right_low])  # the first window's matches stay
