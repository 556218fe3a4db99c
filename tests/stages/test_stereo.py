"""Stereo matching (stages._stereo) on textures with known disparity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from stereo_scenes import occlusion_scene, shifted_pair, texture, u8

from stages import _ncc, _stereo
from stages._stereo import STATUS_NO_PEAK, STATUS_VALID, match_disparity

# Small test images lose a border of half the largest window; these windows keep most of
# them while exercising the same adaptive rule as the default windows.
SMALL = {"windows": "5,9,15"}


def test_integer_shift_is_recovered_exactly():
    right, left = shifted_pair((64, 120), 7, seed=0)
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
    right, left = shifted_pair((40, 80), d, seed=seed)
    m = match_disparity(right, left, min_disparity=0, max_disparity=15)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.5 * m.disparity.size
    assert np.median(np.abs(values - d)) < 1e-3


@pytest.mark.parametrize("shift", [5.25, 5.5, 5.8])
def test_subpixel_shift_is_recovered(shift):
    world = texture((64, 160), seed=1, blur=1.2)
    left = u8(world[:, 10:130])
    right = u8(ndimage.shift(world, (0, -shift), order=3)[:, 10:130])  # right(x) = w(x + s)
    m = match_disparity(right, left, min_disparity=0, max_disparity=16, **SMALL)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.8 * m.disparity.size
    assert abs(np.mean(values) - shift) < 0.08
    assert np.median(np.abs(values - shift)) < 0.1


def _ramp_pair(seed, shape=(80, 140), d0=6.0, slope=0.0125):
    """(right, left, truth): disparity rising 0.0125 px per row, every fraction of a pixel."""
    h, w = shape
    world = texture((h, w + 30), seed)
    ys, xs = np.indices(shape, dtype=float)
    truth = d0 + slope * ys
    right = ndimage.map_coordinates(world, [ys, xs + truth], order=3)  # right(x) = w(x + d)
    return u8(right), u8(world[:, :w]), truth


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


def test_unknown_subpixel_estimator_is_rejected():
    right, left = shifted_pair((32, 48), 3, seed=0)
    with pytest.raises(ValueError, match="subpixel must be one of"):
        match_disparity(right, left, min_disparity=0, max_disparity=8, subpixel="cubic")


def test_occluded_pixels_are_invalid_after_the_lr_check():
    right, left, truth, occluded = occlusion_scene()
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
    right, left, _, occluded = occlusion_scene()
    m = match_disparity(
        right, left, min_disparity=0, max_disparity=20, lr_tolerance=100.0, speckle_size=0,
        **SMALL,
    )  # fmt: skip
    assert np.mean(m.status[occluded] != STATUS_VALID) < 0.4


def test_top_and_bottom_rows_are_matched_with_shifted_windows():
    # regression: rows nearer the top or bottom than half a window's height were left
    # invalid (5 % of a 500 px frame with a 51-row window; lab bad-2 21.7 -> 18.2 %)
    right, left = shifted_pair((64, 120), 7, seed=1)
    m = match_disparity(right, left, min_disparity=0, max_disparity=20, **SMALL)
    edge_rows = np.r_[0:7, 57:64]  # beyond half of the 15 px window (and of the 5 px one)
    assert np.mean(m.status[edge_rows, 10:-30] == STATUS_VALID) > 0.95
    assert np.nanmax(np.abs(m.disparity[edge_rows] - 7)) < 0.5


def test_row_gradient_carries_shifted_windows_to_their_rows():
    # regression (depth v5): a window shifted down at the top rows measured the ground
    # around its centre row, so a floor rising 0.05 px per row read up to +0.5 px too far
    # in the first rows (the lab's 63-row window: +0.9 px at row 0)
    slope = 0.05
    right, left, truth = _ramp_pair(seed=2, d0=4.0, slope=slope)
    edge = np.r_[0:4, 76:80]  # 6-10 rows from the 21-row window's centre rows 10 and 69

    def edge_error(row_gradient):
        m = match_disparity(
            right, left, min_disparity=0, max_disparity=16, windows=(21,), speckle_size=0,
            row_gradient=row_gradient,
        )  # fmt: skip
        err = (m.disparity - truth)[edge, 20:-30]
        return np.nanmedian(err[:4]), np.nanmedian(err[4:]), m

    top, bottom, plain = edge_error(0.0)
    assert top > 0.25 and bottom < -0.25
    top, bottom, carried = edge_error(slope)
    assert abs(top) < 0.08 and abs(bottom) < 0.08
    # only the shifted rows move
    np.testing.assert_array_equal(carried.disparity[10:70], plain.disparity[10:70])
    with pytest.raises(ValueError, match="row_gradient"):
        match_disparity(right, left, min_disparity=0, max_disparity=16, row_gradient=np.nan)


def test_textureless_image_is_invalid_not_guessed():
    flat = np.full((40, 60), 120, np.uint8)
    m = match_disparity(flat, flat, min_disparity=0, max_disparity=10)
    assert np.all(np.isnan(m.disparity))
    assert np.all(m.status == STATUS_NO_PEAK)


def test_sgm_recovers_a_shift():
    right, left = shifted_pair((48, 96), 6, seed=2)
    m = match_disparity(right, left, min_disparity=0, max_disparity=15, method="sgm", sgm_window=5)
    values = m.disparity[np.isfinite(m.disparity)]
    assert values.size > 0.7 * m.disparity.size
    assert np.median(np.abs(values - 6)) < 0.25


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
    right, left = shifted_pair((24, 40), 3, seed=0)
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


# ------------------------------------------------------------------ search band per row


def _kernel(right, left, lo, hi, row_start, row_end=None, windows="5,9"):
    """_ncc.adaptive_match on a pair: (disparity, window), with per-window row bands."""
    if row_end is None:
        row_end = np.full_like(row_start, hi - lo + 1)
    s = _stereo.check_settings(windows=windows)
    hys = np.array([r // 2 for r, _ in s["windows"]], np.int64)
    hxs = np.array([c // 2 for _, c in s["windows"]], np.int64)
    r32, o32 = _stereo._centred(right), _stereo._centred(left)
    return _ncc.adaptive_match(
        r32, o32, lo, hi - lo + 1, row_start, row_end, hys, hxs,
        1.0, 0.1, _stereo._margins(s), 1.0, True,
    )  # fmt: skip


@pytest.mark.parametrize("bands", [((0, 20), (3, 20), (6, 20)), ((0, 14), (2, 17), (5, 20))])
def test_row_bands_equal_narrowing_the_range_row_by_row(bands):
    # a band [f, c] searches exactly as a range [f, c] would; rows with different bands
    # share running column sums, which must stay exact across the bands' steps
    right, left, _, _ = occlusion_scene(shape=(48, 90))
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
    right, left, _, _ = occlusion_scene(shape=(48, 90))
    args = {"min_disparity": 0, "max_disparity": 20, "windows": "7"}
    plain = match_disparity(right, left, **args)
    banded = match_disparity(
        right, left, row_min_disparity=np.full(48, 10), row_max_disparity=np.full(48, 14), **args
    )
    np.testing.assert_array_equal(banded.disparity, plain.disparity)


def test_floor_above_the_truth_stops_the_larger_windows():
    # pixels left to the second window find nothing when the floor is above their disparity
    right, left = shifted_pair((40, 100), 5, seed=4)
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


def test_bad_row_bands_raise_clear_errors():
    right, left = shifted_pair((20, 40), 3, seed=0)
    args = {"min_disparity": 0, "max_disparity": 8}
    with pytest.raises(ValueError, match="row_min_disparity must hold one disparity per"):
        match_disparity(right, left, row_min_disparity=np.zeros(19, int), **args)
    with pytest.raises(TypeError, match="row_max_disparity must be integers"):
        match_disparity(right, left, row_max_disparity=np.full(20, 5.0), **args)


def test_ceiling_below_the_truth_stops_the_larger_windows():
    right, left = shifted_pair((40, 100), 9, seed=4)
    args = {"min_disparity": 0, "max_disparity": 16, "windows": "3,9"}
    open_band = match_disparity(right, left, **args)
    low_ceiling = match_disparity(right, left, row_max_disparity=np.full(40, 6), **args)
    right_open = np.abs(open_band.disparity - 9) < 0.5
    right_low = np.abs(low_ceiling.disparity - 9) < 0.5
    assert np.mean(right_open) > 0.85  # all but the columns that leave the image
    assert np.mean(right_low) < np.mean(right_open) - 0.05
    assert np.all(right_open[right_low])  # the first window's matches stay


def test_sgm_frames_in_a_row_match_as_each_alone():
    # _sgm_coded keeps its volumes per thread for the next frame of the same shape and
    # replaces them when the shape changes; no frame's result may depend on the one before
    pairs = [shifted_pair((30, 50), 4, seed=1), shifted_pair((30, 50), 6, seed=2)]
    other_shape = shifted_pair((26, 44), 5, seed=3)
    settings = {"method": "sgm", "min_disparity": 0, "max_disparity": 9}
    alone = []
    for right, left in [*pairs, other_shape]:
        _stereo._VOLUMES.arrays = None
        alone.append(match_disparity(right, left, **settings).disparity)
    in_a_row = [match_disparity(r, lft, **settings).disparity for r, lft in [*pairs, other_shape]]
    for got, want in zip(in_a_row, alone, strict=True):
        assert got.tobytes() == want.tobytes()


def test_sgm_volumes_above_the_cap_are_not_kept(monkeypatch):
    # regression: the volumes were kept per thread at any size, so a worker matching 1024 px
    # tiles with 256 disparities held 2.2 GB per thread between frames
    _stereo._VOLUMES.arrays = None
    small = _stereo._sgm_volumes((4, 5, 6))
    assert _stereo._sgm_volumes((4, 5, 6))[0] is small[0]  # kept for the next frame
    monkeypatch.setattr(_stereo, "_KEEP_MAX_BYTES", 4 * 5 * 6 * 4 - 1)
    large = _stereo._sgm_volumes((4, 5, 6 + 1))
    assert large[0].shape == (4, 5, 7)
    assert _stereo._VOLUMES.arrays is None  # the kept pair was freed, the new one not kept
    right, left = shifted_pair((30, 50), 4, seed=1)
    settings = {"method": "sgm", "min_disparity": 0, "max_disparity": 9}
    uncapped = match_disparity(right, left, **settings).disparity
    monkeypatch.setattr(_stereo, "_KEEP_MAX_BYTES", 0)
    capped = match_disparity(right, left, **settings).disparity
    assert capped.tobytes() == uncapped.tobytes()
