"""Tests of stages/_continuity.py: background by continuity, phantom peaks, thresholds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages._continuity import (
    _demote_inconsistent,
    _plane_level,
    _seed_levels,
    analyse_sectors,
)

LEVELS = np.arange(256)


def gaussian_hist(*components: tuple[float, float, float]) -> np.ndarray:
    """Histogram (256,) of Gaussian components given as (mean, sigma, pixel count)."""
    hist = np.zeros(256)
    for mean, sigma, count in components:
        bump = np.exp(-0.5 * ((LEVELS - mean) / sigma) ** 2)
        hist += count * bump / bump.sum()
    return np.round(hist).astype(np.int64)


def grid_of(hist: np.ndarray, n: int) -> np.ndarray:
    return np.broadcast_to(hist, (n, n, 256)).copy()


def test_uniform_background_is_found_everywhere_without_phantoms():
    analysis = analyse_sectors(grid_of(gaussian_hist((140, 6, 900)), 8))
    assert not analysis.phantom.any()
    assert analysis.seed.all()
    np.testing.assert_allclose(analysis.background, 140, atol=1)
    assert np.all(analysis.low < 140) and np.all(analysis.high > 140)


def test_curtain_case_continuity_picks_the_smaller_background_mode():
    # a rock (gray 60) covers 70 % of sector (3, 3): its largest mode is not the ground
    hist = grid_of(gaussian_hist((150, 6, 900)), 8)
    hist[3, 3] = gaussian_hist((60, 6, 630), (150, 6, 270))
    analysis = analyse_sectors(hist)
    assert analysis.background[3, 3] == pytest.approx(150, abs=1)
    assert not analysis.phantom[3, 3]
    # dark object: the low threshold lies in the valley between the rock and the ground
    assert 60 < analysis.low[3, 3] < 150 - 6
    assert analysis.high[3, 3] > 150


def test_sector_wholly_covered_by_a_rock_gets_a_phantom_peak():
    hist = grid_of(gaussian_hist((150, 6, 900)), 8)
    hist[4, 2] = gaussian_hist((60, 6, 900))  # unimodal, but not the ground
    analysis = analyse_sectors(hist)
    assert analysis.phantom[4, 2]
    assert analysis.phantom.sum() == 1
    assert not analysis.seed[4, 2]
    assert analysis.background[4, 2] == pytest.approx(150, abs=1)
    assert analysis.low[4, 2] > 60  # the rock's gray is below the threshold: object


def test_phantom_follows_an_illumination_gradient():
    n = 8
    hist = np.stack(
        [np.stack([gaussian_hist((100 + 10 * j, 5, 900)) for j in range(n)]) for _ in range(n)]
    )
    hist[2, 4] = gaussian_hist((230, 5, 900))  # bright rock covering a sector
    analysis = analyse_sectors(hist)
    assert analysis.phantom[2, 4]
    assert analysis.background[2, 4] == pytest.approx(140, abs=2)
    assert analysis.high[2, 4] < 230


def test_continuity_follows_a_steep_lamp_falloff_to_the_frame_edge():
    # rule C1, regression: the lab's ground darkens by 30-40 gray levels per sector towards
    # the top rows; the plain mean of the neighbours lagged behind, no mode lay in range and
    # the whole top band became phantom-peak object
    n = 8
    levels = [60, 95, 130, 160, 180, 190, 195, 198]  # ground level of each sector row
    hist = np.stack([np.stack([gaussian_hist((lv, 5, 900))] * n) for lv in levels])
    hist[0, 2] = gaussian_hist((60, 5, 600), (15, 5, 300))  # a dark rock in the top row
    analysis = analyse_sectors(hist)
    expected = np.broadcast_to(np.array(levels[:2], float)[:, None], (2, n))
    np.testing.assert_allclose(analysis.background[:2], expected, atol=2)
    assert not analysis.phantom.any()
    assert analysis.low[0, 2] > 15  # the rock is found, not the ground
    assert analysis.low[0, 0] < 60 - 5


def ramp_hist(top: float, bottom: float, columns: int = 31) -> np.ndarray:
    """Histogram of a 31-row sector whose ground brightens linearly from ``top`` to ``bottom``."""
    return gaussian_hist(*[(level, 4, columns) for level in np.linspace(top, bottom, 31)])


def lamp_ramp_grid(n: int = 8) -> np.ndarray:
    """Sector histograms of a floor under a lamp whose falloff is steepest at the top border.

    Gray 50 at row 0 to ~150 two sectors down, the step between sector rows growing towards
    the border as on lab_0001 cols 155-186.
    """
    rows = [
        ramp_hist(50, 92),
        ramp_hist(90, 128),
        ramp_hist(128, 152) + gaussian_hist((150, 3, 300)),
        gaussian_hist((162, 5, 961)),
        gaussian_hist((170, 5, 961)),
    ] + [gaussian_hist((173, 5, 961))] * (n - 5)
    return np.stack([np.stack([row] * n) for row in rows])


def test_a_steep_lamp_ramp_at_the_top_border_is_ground_not_object():
    # rule C2, regression (lab_0001 cols 155-186): the top rows' broad flat modes lie 40
    # levels from their neighbours' mean and past C1's straight carry, so they became
    # phantom peaks and the ramp became object
    analysis = analyse_sectors(lamp_ramp_grid(), band_sigmas=3.5, merge_ratio=0.35)
    assert not analysis.phantom.any()
    assert np.all((analysis.background[0] > 50) & (analysis.background[0] < 92))
    assert np.all((analysis.background[1] > 90) & (analysis.background[1] < 128))
    # the whole ramp lies inside the band: no pixel of it is object
    assert np.all(analysis.low[0] < 50 - 4) and np.all(analysis.high[0] > 92 + 4)
    assert np.all(analysis.low[1] < 90 - 4) and np.all(analysis.high[1] > 128 + 4)


def test_a_border_sector_waits_for_its_row_before_a_phantom_peak():
    # regression (lab_0000, lab_0007, lab_0008 top rows): a rock hides half of a top
    # sector's ramp, so its highest mode is the rock and C2 cannot join it to the row
    # below; decided in the same round as its row neighbours it became a phantom peak at
    # the lower row's level; once they are decided, the plain rule finds its ground
    hist = lamp_ramp_grid()
    hist[0, 3] = ramp_hist(50, 92, columns=16) + gaussian_hist((15, 4, 465))
    analysis = analyse_sectors(hist, band_sigmas=3.5, merge_ratio=0.35)
    assert not analysis.phantom.any()
    assert 50 < analysis.background[0, 3] < 92
    assert 15 + 4 < analysis.low[0, 3] < 50 - 4  # the rock is object, the ramp is not


def test_a_rock_spilling_into_its_neighbour_is_not_a_ramp():
    # rule C2, regression (lava seed 2): a dark rock covers one sector and reaches into the
    # next; the summed histograms' valley (0.36 of the lower peak) passed the ripple test's
    # 0.35, not C2's 0.5: the sector keeps its phantom peak and the rock stays object
    hist = grid_of(gaussian_hist((72, 8, 961)), 8)
    hist[4, 4] = gaussian_hist((12, 3, 450), (32, 10, 500))
    hist[3, 4] = gaussian_hist((72, 8, 600), (40, 10, 360))
    analysis = analyse_sectors(hist, band_sigmas=3.5, merge_ratio=0.35)
    assert analysis.phantom[4, 4]
    assert analysis.background[4, 4] == pytest.approx(72, abs=3)
    assert analysis.low[4, 4] > 32


def test_continuity_does_not_carry_a_patchwork_on():
    # C1 needs a gradient: neighbours whose carried levels disagree keep the study's rule
    hist = grid_of(gaussian_hist((150, 6, 900)), 8)
    hist[3, 3] = gaussian_hist((60, 6, 900))  # a sector wholly covered by a dark rock
    hist[3, 5] = gaussian_hist((100, 6, 900))  # and a darker patch two sectors away
    analysis = analyse_sectors(hist)
    assert analysis.phantom[3, 3]
    assert analysis.background[3, 3] == pytest.approx(150, abs=15)


def test_light_object_threshold_at_the_upper_valley():
    hist = grid_of(gaussian_hist((90, 6, 900)), 6)
    hist[1, 1] = gaussian_hist((90, 6, 600), (200, 8, 300))
    analysis = analyse_sectors(hist)
    assert analysis.background[1, 1] == pytest.approx(90, abs=1)
    assert 90 + 6 < analysis.high[1, 1] < 200
    assert analysis.modes[1, 1] == 2


def test_trimodal_sector_thresholds_on_both_sides():
    hist = grid_of(gaussian_hist((128, 6, 900)), 6)
    hist[2, 3] = gaussian_hist((40, 5, 200), (128, 6, 400), (220, 5, 300))
    analysis = analyse_sectors(hist)
    assert analysis.modes[2, 3] == 3
    assert 40 < analysis.low[2, 3] < 128 < analysis.high[2, 3] < 220


def test_no_unambiguous_sector_falls_back_on_the_frame_level():
    hist = grid_of(gaussian_hist((70, 5, 450), (160, 5, 450)), 4)
    hist[0, 0] = gaussian_hist((70, 5, 300), (160, 5, 600))
    analysis = analyse_sectors(hist)
    assert np.isfinite(analysis.background).all()
    assert len(np.unique(analysis.background)) <= 2


def test_analyse_sectors_validates():
    with pytest.raises(ValueError, match=r"\(S, S, 256\)"):
        analyse_sectors(np.zeros((4, 5, 256)))
    with pytest.raises(ValueError, match="seed_dominance"):
        analyse_sectors(np.zeros((4, 4, 256)), seed_dominance=2.0)
    with pytest.raises(ValueError, match="continuity_range"):
        analyse_sectors(np.zeros((4, 4, 256)), continuity_range=0)


def test_ripple_facets_merge_into_the_ground_but_rocks_do_not():
    # lit and shaded ripple faces: two overlapping modes with a shallow valley
    ripples = gaussian_hist((120, 7, 450), (142, 7, 450))
    hist = grid_of(ripples, 6)
    hist[2, 2] = gaussian_hist((120, 7, 300), (142, 7, 300), (40, 5, 300))  # plus a dark rock
    merged = analyse_sectors(hist, merge_ratio=0.35)
    study = analyse_sectors(hist, merge_ratio=1.0)
    # merged: both facets lie inside the band in every sector
    assert np.all(merged.low < 115) and np.all(merged.high > 147)
    # the rock behind a deep valley is still outside the band
    assert 40 < merged.low[2, 2] < 115
    # the study's rule puts a threshold between the facets
    assert np.any((study.low > 120) & (study.low < 142) | (study.high > 120) & (study.high < 142))


def _median_without(values: np.ndarray, value: float) -> float:
    """Median of ``values`` with one occurrence of ``value`` left out (as ``np.median``):
    the numpy twin's, checked against ``np.delete`` below."""
    ordered = np.sort(values)
    at = int(np.searchsorted(ordered, value))
    if at < ordered.size and ordered[at] == value:
        ordered = np.concatenate((ordered[:at], ordered[at + 1 :]))
    half = ordered.size // 2
    if ordered.size % 2:
        return float(ordered[half])
    return float((ordered[half - 1] + ordered[half]) / 2)


def _demote_inconsistent_numpy(levels: np.ndarray, continuity_range: float) -> np.ndarray:
    """:func:`stages._continuity._demote_inconsistent` in numpy: the compiled pass's reference."""
    n = levels.shape[0]
    candidates = np.argwhere(np.isfinite(levels))
    keep = levels.copy()
    for i, j in candidates:
        # compare with the nearest other seeds, widening the window until there are three
        for radius in (2, 4, n):
            window = levels[
                max(i - radius, 0) : i + radius + 1, max(j - radius, 0) : j + radius + 1
            ]
            others = window[np.isfinite(window)]
            if others.size >= 4:  # itself plus three others
                break
        if others.size >= 2:
            reference = _median_without(others, levels[i, j])
            if abs(levels[i, j] - reference) > continuity_range:
                keep[i, j] = np.nan
    return keep


@given(st.lists(st.integers(0, 255), min_size=2, max_size=30), st.data())
def test_median_without_leaves_out_one_occurrence_like_np_delete(levels, data):
    values = np.array(levels, dtype=np.float64)
    value = values[data.draw(st.integers(0, values.size - 1))]
    expected = np.median(np.delete(values, np.flatnonzero(values == value)[:1]))
    assert _median_without(values, value) == expected


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 18),
    seed=st.integers(0, 2**16),
    step=st.sampled_from([1, 20]),
    missing=st.floats(0.0, 0.95),
    continuity_range=st.sampled_from([10.0, 24.0, 40.0]),
)
def test_compiled_seed_demotion_equals_its_numpy_twin(n, seed, step, missing, continuity_range):
    # step 20: many equal levels, so leaving out one occurrence of the seed matters
    rng = np.random.default_rng(seed)
    levels = (rng.integers(0, 256, (n, n)) // step * step).astype(np.float64)
    levels[rng.random((n, n)) < missing] = np.nan
    np.testing.assert_array_equal(
        _demote_inconsistent(levels, continuity_range),
        _demote_inconsistent_numpy(levels, continuity_range),
    )


def test_a_rock_sector_whose_ground_shows_at_the_predicted_level_is_not_a_ramp():
    # rule C2, regression (lava_0001, lava_0008 catalog frames): a dark near rock fills most
    # of a sector on a broad, blotchy ground; the summed histograms have no valley, so C2
    # took the rock's gray (36) for the ground. The ground shows in the sector at the level
    # its neighbours predict: the sector keeps its phantom peak there
    hist = grid_of(gaussian_hist((70, 14, 961)), 8)
    hist[4, 4] = gaussian_hist((36, 6, 700), (70, 14, 261))
    analysis = analyse_sectors(hist, band_sigmas=2.5, merge_ratio=0.35)
    assert analysis.phantom[4, 4]
    assert analysis.background[4, 4] == pytest.approx(70, abs=1)
    assert analysis.low[4, 4] > 30  # the rock's darker half is object, not ground


def test_phantoms_do_not_chain_into_a_block_of_false_ground_levels():
    # rule C3, regression (lab_0006 top-left corner): a dark rock fills most of a sector on
    # the lamp ramp; its phantom peak, at the level of the bright rows below, pulled its
    # neighbours' predictions away from their own ramp modes, six phantoms chained and the
    # corner became one false object. Predicted from mode-decided neighbours only, every
    # sector finds its ground
    hist = lamp_ramp_grid()
    hist[1, 2] = ramp_hist(90, 128, columns=8) + gaussian_hist((15, 4, 961 - 31 * 8))
    analysis = analyse_sectors(hist, band_sigmas=3.5, merge_ratio=0.35)
    assert not analysis.phantom.any()
    assert np.all((analysis.background[0] > 50) & (analysis.background[0] < 92))
    assert np.all((analysis.background[1] > 90) & (analysis.background[1] < 128))
    assert 15 + 4 < analysis.low[1, 2] < 90 - 4  # the rock is object, the ramp is not


def test_a_border_sector_whose_highest_mode_is_a_rock_finds_its_ramp_in_the_next():
    # rule C2 on the frame border, regression (lab_0002 sector (0, 1), lab_0003 (0, 8)): a
    # dark rock covers a little more of a top sector than the lamp ramp does, so its
    # highest mode is the rock and C2 tried nothing else; the sector became a phantom peak
    # at the bright level below, and the ramp part of it a false object at the top border
    hist = lamp_ramp_grid()
    for j in (2, 3, 4):
        hist[0, j] = ramp_hist(50, 92, columns=14) + gaussian_hist((15, 4, 31 * 17))
    analysis = analyse_sectors(hist, band_sigmas=3.5, merge_ratio=0.35)
    assert not analysis.phantom.any()
    assert np.all((analysis.background[0] > 50) & (analysis.background[0] < 92))
    assert np.all(analysis.low[0, 2:5] > 15 + 4)  # the rock is still object


def lab_0005_corner_grid() -> np.ndarray:
    """Sector histograms of lab_0005's top-right 5 x 6 sectors (rows 0-4, cols 10-15) and a
    row of plain floor: (mode, sigma, pixels) per component, a ramp sector's broad mode at
    its dark end (the lamp's falloff), dark rocks in (0, 1), (0, 2), (0, 3), (1, 0), (2, 2)."""
    components = [
        [[(52, 10, 990)], [(25, 5, 200), (51, 8, 380), (64, 8, 380)], [(25, 5, 150), (54, 10, 810)],
         [(9, 4, 250), (63, 10, 740)], [(53, 10, 960)], [(49, 9, 960)]],
        [[(17, 5, 300), (85, 12, 690)], [(93, 10, 960)], [(109, 10, 960)],
         [(90, 8, 500), (111, 8, 490)], [(85, 12, 960)], [(80, 12, 960)]],
        [[(127, 7, 1020)], [(134, 10, 990)], [(20, 5, 200), (139, 8, 790)], [(140, 9, 1020)],
         [(143, 9, 990)], [(141, 10, 990)]],
        [[(141, 4, 990)], [(144, 3, 960)], [(148, 3, 960)], [(151, 3, 990)], [(153, 3, 960)],
         [(153, 3, 960)]],
        [[(149, 3, 990)], [(149, 3, 960)], [(151, 3, 960)], [(152, 3, 990)], [(154, 3, 960)],
         [(155, 3, 960)]],
        [[(155, 3, 990)]] * 6,
    ]  # fmt: skip
    return np.array([[gaussian_hist(*sector) for sector in row] for row in components])


def test_a_corner_under_a_steep_falloff_gets_its_ground_not_phantom_peaks():
    # rule C3b, regression (lab_0005 object 3, a 1,527 px false object in the top-right
    # corner that alone raised lab's rock area fraction 2.8 -> 3.9 %): the corner sectors'
    # ramp modes (49-85) lay 30-40 levels from the mean of neighbours one sector row lower
    # (the lamp's falloff is 30-60 levels per sector row there), C1's carries disagreed, and
    # four phantoms at 112-142 put the dark corner below the low threshold. A plane through
    # the mode-decided neighbours follows the falloff to the corner's own modes
    analysis = analyse_sectors(
        lab_0005_corner_grid(), band_sigmas=3.5, merge_ratio=0.35, continuity_range=24.0
    )
    assert not analysis.phantom.any()
    assert np.all(analysis.background[0, 4:] < 60)
    assert np.all(analysis.background[1, 4:] < 90)
    assert np.all(analysis.low[:2, 4:] < 49)  # the corner's ground is not object


def test_plane_level_needs_a_steep_plane_of_three_neighbours():
    level = np.full((3, 3), np.nan)
    level[1, 0], level[2, 0] = 100.0, 140.0
    assert _plane_level(level, 1, 1, min_step=24.0) is None  # two: no plane
    level[2, 1] = 140.0
    assert _plane_level(level, 1, 1, min_step=24.0) == pytest.approx(100.0)  # 40 per row
    gentle = np.where(np.isfinite(level), 70.0 + np.arange(3)[:, None] * 5.0, np.nan)
    # a gentle slope (lava's ground): the neighbours' mean stands, a plane must not tip it
    assert _plane_level(gentle, 1, 1, min_step=24.0) is None


def _predict_all_twin(level):
    """_predict_all as it was before its compiled pass: shifted copies of a padded grid."""
    n = level.shape[0]
    padded = np.full((n + 2, n + 2), np.nan)
    padded[1:-1, 1:-1] = level
    decided = np.isfinite(padded)
    values = np.where(decided, padded, 0.0)
    total = np.zeros((n, n))
    weight = np.zeros((n, n))
    for dy, dx in [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]:
        w = 1.0 if dy == 0 or dx == 0 else 1.0 / np.sqrt(2.0)
        window = (slice(1 + dy, n + 1 + dy), slice(1 + dx, n + 1 + dx))
        total += np.where(decided[window], w * values[window], 0.0)
        weight += np.where(decided[window], w, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        predicted = np.where(weight > 0, total / weight, np.nan)
    return predicted, weight


def test_predict_all_equals_its_shifted_copies_twin():
    from stages._continuity import _predict_all

    rng = np.random.default_rng(20)
    for _ in range(50):
        n = int(rng.integers(2, 20))
        level = rng.uniform(0, 255, (n, n))
        level[rng.random((n, n)) < rng.uniform(0, 1)] = np.nan
        for got, want in zip(_predict_all(level), _predict_all_twin(level), strict=True):
            np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


def test_nearest_mode_equals_the_pick_of_its_lexsort_twin():
    # the twin: the mode nearest within reach by np.lexsort (height breaks ties, then order)
    from stages._continuity import _nearest_mode

    rng = np.random.default_rng(21)
    for _ in range(500):
        positions = np.sort(rng.choice(256, size=int(rng.integers(0, 8)), replace=False))
        heights = rng.integers(1, 4, positions.size).astype(np.float64)  # ties happen
        predicted = float(rng.choice([rng.uniform(0, 255), rng.integers(0, 256), np.nan]))
        reach = float(rng.integers(1, 40))
        distance = np.abs(positions - predicted)
        candidates = np.flatnonzero(distance <= reach)
        want = None
        if candidates.size:
            pick = candidates[np.lexsort((-heights[candidates], distance[candidates]))[0]]
            want = float(positions[pick])
        assert _nearest_mode(positions, heights, predicted, reach) == want


def test_seed_levels_equal_the_per_sector_argsort_they_replaced():
    # the twin: the loop over a list of (positions, heights) pairs, one argsort per sector
    from stages._modes import find_all_modes
    from stages._sectors import smooth_histograms

    rng = np.random.default_rng(31)
    for _ in range(10):
        n = int(rng.integers(2, 9))
        hist = rng.poisson(rng.uniform(0, 40, (n, n, 256))).astype(np.int64)
        hist[rng.random((n, n)) < 0.1] = 0  # sectors without modes
        smoothed = smooth_histograms(hist, passes=2)
        smoothed[0, 0, :] = np.round(smoothed[0, 0, :])  # ties between heights
        positions, counts = find_all_modes(smoothed, prominence=0.05)
        for dominance in (0.3, 0.7, 1.0):
            levels = np.full((n, n), np.nan)
            for i in range(n):
                for j in range(n):
                    at = positions[i, j, : counts[i, j]]
                    heights = smoothed[i, j][at]
                    if heights.size == 1:
                        levels[i, j] = at[0]
                    elif heights.size > 1:
                        order = np.argsort(heights)[::-1]
                        if heights[order[1]] < dominance * heights[order[0]]:
                            levels[i, j] = at[order[0]]
            np.testing.assert_array_equal(
                _seed_levels(
                    positions, counts, smoothed, seed_dominance=dominance, continuity_range=12.0
                ),
                _demote_inconsistent(levels, 12.0),
            )
