"""Background level and thresholds of each sector: the study's continuity rule.

The background mode of each sector (modes from :func:`stages._sectors.find_modes`) is chosen
by *continuity*, never by size alone:

1. **Seeds.** A sector whose histogram has one mode, or one dominant mode (every other mode
   lower than ``seed_dominance`` times the highest), is an unambiguous seed. A seed that
   disagrees by more than ``continuity_range`` gray levels with the median of the nearest
   other seeds (a sector wholly covered by a large rock is unimodal too) is demoted. With no
   seed at all, sectors with a mode near the frame histogram's highest mode seed the map.
2. **Propagation.** Undecided sectors are decided in order of how many decided neighbours
   they have (8-neighbourhood, diagonals weighted ``1/sqrt(2)``). The background is predicted
   as the weighted mean of the decided neighbours' levels; the sector's mode nearest that
   prediction within ``continuity_range`` becomes the background. This is what picks the
   right mode when a rock covers most of a sector (the study's curtain case).
3. **C1 gradients** (an extension). When no mode lies in that range, the level the
   neighbours' gradient carries on to is tried as well: each decided neighbour whose own
   neighbour beyond it (same direction) is decided too predicts its level plus the step
   between the two once more, if that step is at most 1.5 continuity ranges; at least two
   such predictions agreeing within 2 continuity ranges (weighted standard deviation) give
   the carried level. Why: a lamp's falloff changes the ground level by 30-40 gray levels
   per sector on the lab's top rows (rows 0-2 of lab_0000 peak at 52-70, 83-118 and
   134-162), the plain mean lags one sector behind, no mode lies in range and the whole
   top band became a phantom-peak object that swallowed the rocks in it. On the lab
   catalog frames object F1 0.897 -> 0.908 (seed 2: 0.872 -> 0.904), mojave and lava
   unchanged; with steps up to 2 ranges lab gained a little more (0.909 / 0.918) but a
   dunes frame got one invented rock at a corner where dark and light sand meet.
4. **C2 ramps** (an extension). When C1 finds nothing either, the sector's highest mode is
   its ground if its histogram runs on into a decided edge neighbour's without a gap: in the
   sum of the two sectors' histograms, every bin between that mode and the neighbour's
   background is higher than ``_RAMP_VALLEY`` (0.5) times the lower of the two. Not next to
   a phantom sector, and not when the sector's own histogram reaches a tenth of its peak
   within 3 levels of the neighbours' mean level (``_RAMP_HIDDEN_GROUND``): there the ground
   is in the sector, beside a rock, and a phantom peak at that level is right. And a sector
   on the frame border that would get a phantom peak waits while other sectors of its round
   are decided by a mode: its neighbours lie on one side only, and the border row must be
   decided along itself before it falls back on the row inside. Why: the lamps' falloff is
   steepest at the top border of the lab frames (lab_0001 cols 155-186: gray 51 at row 0, 91
   at row 30, ~150 two sectors down). A sector on that ramp holds one broad flat mode (gray
   48-92) that abuts the next sector's (88-128), 40-50 levels from the neighbours' mean, and
   the step between sector rows grows from 13 to 41 to 52 towards the border, so C1's
   straight carry misses it. The unimodal top sectors were seeds, but demoted (the median of
   the nearest seeds lies in the brighter rows below); the top row is decided last, from the
   row below, and became phantom peaks at ~110 whose band put the whole ramp below the low
   threshold: 10 of the lab catalog's 11 false objects (0-44 rows tall at the top border,
   500-2300 px). Top sectors where a rock hides part of the ramp (its highest mode is the
   rock) are found by the plain rule once their row neighbours are decided: hence the wait.
   A rock wholly covering a sector is parted from the ground by a deep valley. Why the
   highest mode, the 0.5 and no phantom neighbour: with any mode and the ripple test's 0.35
   a lava rock sector (valley 0.37, lava seed 2) and a mojave rock sector (a minor mode of
   four) were taken for ground; a bright lava rock spanning sectors (next to a phantom) was
   too. Letting every phantom wait, not only the border's, chained lava rock sectors into
   the ground (lava catalog F1 0.812 -> 0.808). Object F1 of ``bench_segment.py --rundir
   DIR`` on the lab catalog run and seeds 2, 3: 0.943 -> 0.969, 0.899 -> 0.941, 0.919 ->
   0.961 (faithful mode, ``--set method=sector-histogram``: 0.878 -> 0.967, 0.825 -> 0.949,
   0.880 -> 0.967); mojave, lava and dunes (catalog runs, mojave seeds 2, 3, lava seed 2,
   dunes seeds 2-5, 7, 11) unchanged to the last object. With 0.45 lab seed 3 gains 0.003;
   with 0.6 it loses 0.002. The exception for a sector whose ground shows (measured on the
   depth v6 catalog runs and fresh seed runs, segment v25 against v24): lab's catalog 0.969
   -> 0.967 (one more false object), lab seeds 2 and 3 unchanged, lava's catalog F1
   unchanged and its near-rock width error (``bench_describe.py --rundir runs/eval/lava
   --labels segment``) 10.3 -> 9.7 %, faithful mode on lab's catalog 0.967 -> 0.964, lava
   seeds 3 and 5 0.817 -> 0.819 and 0.821 -> 0.822, seeds 2 and 4, mojave (catalog, seeds
   2-5) and dunes (catalog, seeds 2-5, 7, 11) unchanged; a twentieth cost lab (0.964, seed 3
   0.958), a fifth let lava's rock sectors through. On the frame border the next highest
   mode is tried too when the highest fails: there a dark rock at the top border can cover
   a little more of a sector than the ramp does (lab_0002 sector (0, 1): modes at 19 and
   67 of heights 35 and 34; lab_0003 (0, 8): 18 and 82), the sector became a phantom peak
   at the bright level below and the ramp's top rows a false object of 480-1,300 px. With
   it lab's catalog F1 0.974 -> 0.978 (5 -> 3 false objects; faithful mode 0.971 -> 0.976);
   lab seeds 2, 3, mojave (catalog, seeds 2-5), lava (catalog, seeds 2-5) and dunes
   (catalog, seeds 2-5, 7, 11) unchanged to the last object. Everywhere, not only on the
   border, lava seed 2 lost a rock (0.812 -> 0.811).
5. **Phantom peaks.** When no mode lies in either range and no ramp joins the sector to a
   neighbour, the background is a *phantom peak* at the predicted (mean) level: the
   sector is all object, or its ground is hidden in a shoulder.
6. **C3, a second look at phantoms** (an extension). Once every sector is decided, each
   phantom sector is predicted again from its neighbours decided by a mode only; when one of
   its modes lies within ``continuity_range`` of that prediction, it is the background and
   the sector is no phantom any more, until no phantom changes. Why: a phantom's level is an
   assumption, but the first pass let it predict its neighbours like a found mode, so one
   phantom could chain into a block. On lab_0006's top-left corner a dark rock filled
   sector (1, 2) (its ground a small mode at 75); its phantom at 122 (from the bright rows
   below) pulled the prediction of the top sectors, whose lamp-lit ground lies at 44-49,
   to 95-117, and six phantoms made the whole corner one false object of 5,700 px that
   swallowed three rocks; from their mode-decided neighbours alone (the top row's 51, the
   rows below) every one of the six finds its ground. Object F1 of ``bench_segment.py
   --rundir DIR`` on the lab catalog run and seeds 2, 3: 0.967 -> 0.974, 0.941 -> 0.947,
   0.961 -> 0.964 (faithful mode on the catalog 0.964 -> 0.971); mojave (catalog, seeds
   2-5), lava (seeds 2-5; the catalog gains one false object, F1 0.816 either way) and
   dunes (catalog, seeds 2-5, 7, 11) unchanged.
7. **C3b, a tilted prediction** (an extension). A phantom whose mode-decided neighbours'
   mean finds no mode in range tries the level at the sector of a plane fitted to them
   (``level = a + b row + c col`` over its decided 8-neighbours, at least three, not on
   one line), when the plane is steep (at least ``continuity_range`` gray levels per
   sector): where a lamp's falloff runs 30-60 levels per sector row, neighbours in the row
   below pull the mean 30-40 levels off a corner sector's own mode, and C1's straight
   carries from opposite sides disagree. On lab_0005's top-right corner sectors (0, 14),
   (0, 15) and (1, 15) became phantoms at 84, 98 and 121 over ramp modes at 53, 48-50 and
   80, and the dark corner a false object of 1,527 px (bbox x 442-499, y 0-36) measured
   1.485 m wide: alone 1.1 % of the surveyed ground, lab's rock area fraction 3.9 % against
   the truth's 2.8 %. With C3b (``bench_segment.py --rundir DIR``): lab's catalog 0.978 ->
   0.981 (3 -> 2 false objects), lab seeds 2 and 3 the same objects (seed 2's mean IoU
   0.938 -> 0.940: lab_0004's sector (0, 4), a phantom at 170 over a ramp mode at 76),
   mojave (catalog, seeds 2-5), lava (catalog, seeds 2-5) and dunes (catalog, seeds 2-5, 7,
   11) unchanged to the last object. Without the steepness bar a bottom-border sector of
   lava seed 5 (neighbours 54-79, a plane 6 levels lower than their mean) took a dark
   rock's mode for its ground and lost the rock (0.849 -> 0.847).

Thresholds lie on both sides of the background mode, because objects may be darker or
lighter than the ground. One extension to the study: a neighbouring mode separated from the
background by a *shallow* valley (higher than ``merge_ratio`` times the lower peak) is taken
as ground texture -- the lit and shaded facets of dune ripples -- and absorbed, the search
going on outwards from it (``merge_ratio = 1`` restores the study's rule). Thresholds lie at
the valley (lowest smoothed bin, taking the end of a flat valley nearest the background)
between the background mode and the neighbouring mode on that side; where no mode lies on
that side, at ``max(min_band, band_sigmas * sigma)`` from the background, ``sigma`` being the
background peak's half width at half maximum on that side divided by ``sqrt(2 ln 2)``.
Phantom sectors borrow the median band of their decided neighbours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ._modes import find_all_modes, sector_thresholds
from ._sectors import FWHM_TO_SIGMA, N_LEVELS, find_modes, smooth_histograms

__all__ = ["SectorAnalysis", "analyse_sectors"]


@dataclass(frozen=True)
class SectorAnalysis:
    """Per-sector results of the continuity pass; every grid has shape ``(S, S)``.

    Attributes
    ----------
    background : (S, S) ndarray of float32
        Background gray level (a mode or a phantom peak).
    low, high : (S, S) ndarray of float32
        Thresholds: a pixel darker than ``low`` or lighter than ``high`` is object.
    modes : (S, S) ndarray of int8
        Number of modes found in the smoothed histogram (capped at 127).
    phantom : (S, S) ndarray of bool
        True where the background is a phantom peak (no mode near the predicted level).
    seed : (S, S) ndarray of bool
        True where the sector seeded the continuity pass.
    """

    background: np.ndarray
    low: np.ndarray
    high: np.ndarray
    modes: np.ndarray
    phantom: np.ndarray
    seed: np.ndarray


# Rule C1: a neighbour carries its level on by a step of at most this many continuity
# ranges (a lamp's falloff: 30-40 gray levels per sector on the lab's top rows), and the
# carried levels must agree within this many.
_CARRY_STEP = 1.5
_CARRY_SPREAD = 2.0
_NEIGHBOURS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
# Rule C2: the lowest bin between two sectors' grounds in their summed histograms must be
# higher than this fraction of the lower ground (stricter than the ripple facets' 0.35:
# a lava rock sector whose tail reached the ground above had a valley of 0.37)
_RAMP_VALLEY = 0.5
# ... and the sector's own histogram must stay below this fraction of its peak within 3
# levels of the predicted ground: where the ground shows there, a rock shares the sector and
# its mode is not the ground (2 sectors of 2 lava catalog frames took a dark near rock's
# gray level for the ground: lava's near-rock width error 9.7 -> 10.3 %)
_RAMP_HIDDEN_GROUND = 0.1
# modes C2 tries on the frame border, highest first
_RAMP_BORDER_MODES = 2
_EDGE_NEIGHBOURS = [(-1, 0), (1, 0), (0, -1), (0, 1)]


def _seed_levels(
    positions: np.ndarray,
    counts: np.ndarray,
    smoothed: np.ndarray,
    *,
    seed_dominance: float,
    continuity_range: float,
) -> np.ndarray:
    """Background levels of the unambiguous sectors (NaN elsewhere), inconsistent ones removed.

    ``positions`` and ``counts`` as :func:`stages._modes.find_all_modes` gives them, the
    heights read from ``smoothed``; a sector with one mode is a seed, one with more when
    its second highest mode is below ``seed_dominance`` times its highest (a tie of the two
    highest is no seed, whichever the sort puts first).
    """
    n = counts.shape[0]
    levels = np.full((n, n), np.nan)
    _seed_pass(positions, counts, smoothed, float(seed_dominance), levels)
    return _demote_inconsistent(levels, float(continuity_range))


@njit(cache=True)
def _seed_pass(positions, counts, smoothed, seed_dominance, levels):  # pragma: no cover
    """The seeds of :func:`_seed_levels` in one compiled loop over the sectors (the
    per-sector argsort it replaced: ``test_continuity.py`` compares)."""
    n = counts.shape[0]
    for i in range(n):
        for j in range(n):
            size = counts[i, j]
            if size == 0:
                continue
            if size == 1:
                levels[i, j] = positions[i, j, 0]
                continue
            # the highest mode and the second highest height
            top = 0
            for k in range(1, size):
                if smoothed[i, j, positions[i, j, k]] > smoothed[i, j, positions[i, j, top]]:
                    top = k
            highest = smoothed[i, j, positions[i, j, top]]
            second = -np.inf
            for k in range(size):
                if k != top:
                    second = max(second, smoothed[i, j, positions[i, j, k]])
            if second < seed_dominance * highest:
                levels[i, j] = positions[i, j, top]


class _SectorModes:
    """``modes[i][j]``: the positions (int64) and smoothed heights of sector ``(i, j)``'s
    modes, read from :func:`stages._modes.find_all_modes`' arrays when asked (the rules
    read the few undecided sectors' only; no list of 256 pairs made first)."""

    def __init__(self, positions: np.ndarray, counts: np.ndarray, smoothed: np.ndarray) -> None:
        self._rows = [_ModeRow(positions[i], counts[i], smoothed[i]) for i in range(len(counts))]

    def __len__(self) -> int:
        return len(self._rows)

    def __getitem__(self, i: int) -> _ModeRow:
        return self._rows[i]


class _ModeRow:
    """One row of :class:`_SectorModes`."""

    def __init__(self, positions: np.ndarray, counts: np.ndarray, smoothed: np.ndarray) -> None:
        self._positions, self._counts, self._smoothed = positions, counts, smoothed

    def __getitem__(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        positions = self._positions[j, : self._counts[j]]
        return positions, self._smoothed[j][positions]


@njit(cache=True)
def _demote_inconsistent(levels, continuity_range):  # pragma: no cover - numba
    """Seeds (finite ``levels``, (S, S) float64) farther than ``continuity_range`` from the
    median of the other seeds in the nearest window (radius 2, 4, then all) holding at least
    three others, set to NaN in a copy; compiled (its numpy twin, the reference in
    ``tests/stages/test_continuity.py``, cost ~2 ms a frame)."""
    n = levels.shape[0]
    keep = levels.copy()
    window = np.empty(levels.size)
    for i in range(n):
        for j in range(n):
            value = levels[i, j]
            if not np.isfinite(value):
                continue
            count = 0
            for radius in (2, 4, n):
                count = 0
                for y in range(max(i - radius, 0), min(i + radius + 1, n)):
                    for x in range(max(j - radius, 0), min(j + radius + 1, n)):
                        if np.isfinite(levels[y, x]):
                            window[count] = levels[y, x]
                            count += 1
                if count >= 4:  # itself plus three others
                    break
            if count < 2:
                continue
            ordered = np.sort(window[:count])
            # leave one occurrence of the seed itself out (as np.delete of its first)
            at = np.searchsorted(ordered, value)
            size = count
            if at < count and ordered[at] == value:
                ordered[at:-1] = ordered[at + 1 :].copy()
                size = count - 1
            half = size // 2
            if size % 2:
                reference = ordered[half]
            else:
                reference = (ordered[half - 1] + ordered[half]) / 2
            if abs(value - reference) > continuity_range:
                keep[i, j] = np.nan
    return keep


def _global_level(smoothed: np.ndarray, *, prominence: float) -> float:
    """Highest mode of the whole-frame histogram: the fallback when no sector is a seed."""
    total = smoothed.reshape(-1, N_LEVELS).sum(axis=0)
    positions, heights = find_modes(total, prominence=prominence)
    return float(positions[np.argmax(heights)]) if positions.size else float(np.argmax(total))


def analyse_sectors(
    hist: np.ndarray,
    *,
    smoothing: int = 1,
    prominence: float = 0.1,
    seed_dominance: float = 0.3,
    continuity_range: float = 24.0,
    band_sigmas: float = 3.0,
    min_band: float = 6.0,
    merge_ratio: float = 0.5,
) -> SectorAnalysis:
    """Background level and thresholds per sector by the study's continuity rule.

    Parameters
    ----------
    hist : (S, S, 256) ndarray of int
        Sector histograms from :func:`sector_histograms`.
    smoothing : int
        Passes of the nine-point filter, ``>= 0``.
    prominence : float
        Mode prominence rule, see :func:`find_modes`; in ``[0, 1]``.
    seed_dominance : float
        In ``[0, 1]``: a sector seeds the continuity pass when every other mode is lower than
        this fraction of its highest mode.
    continuity_range : float
        Gray levels, ``> 0``: how far from the level predicted by decided neighbours a mode
        may lie and still be the background.
    band_sigmas : float
        ``> 0``: threshold distance in background-peak sigmas where no mode lies on that side.
    min_band : float
        ``>= 0`` gray levels: smallest distance between a width-based threshold and the
        background.
    merge_ratio : float
        In ``[0, 1]``: a neighbouring mode whose valley to the background is higher than this
        fraction of the lower peak is ground texture (ripple facets), not an object; 1 never
        merges (the study's rule).

    Returns
    -------
    SectorAnalysis
    """
    hist = np.asarray(hist)
    if hist.ndim != 3 or hist.shape[0] != hist.shape[1] or hist.shape[2] != N_LEVELS:
        raise ValueError(f"hist must have shape (S, S, {N_LEVELS}), got {hist.shape}")
    for name, value, lo, hi in (
        ("prominence", prominence, 0.0, 1.0),
        ("seed_dominance", seed_dominance, 0.0, 1.0),
        ("merge_ratio", merge_ratio, 0.0, 1.0),
    ):
        if not lo <= value <= hi:
            raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
    if continuity_range <= 0 or band_sigmas <= 0 or min_band < 0:
        raise ValueError(
            "continuity_range and band_sigmas must be > 0 and min_band >= 0, got "
            f"{continuity_range}, {band_sigmas}, {min_band}"
        )
    n = hist.shape[0]
    smoothed = smooth_histograms(hist, passes=smoothing)
    # find_modes of every sector, in one compiled loop instead of 256 scipy calls
    all_positions, counts = find_all_modes(smoothed, prominence=prominence)
    modes = _SectorModes(all_positions, counts, smoothed)
    level = _seed_levels(
        all_positions,
        counts,
        smoothed,
        seed_dominance=seed_dominance,
        continuity_range=continuity_range,
    )
    seed = np.isfinite(level)
    if not seed.any():
        _seed_from_global(level, modes, smoothed, prominence, continuity_range)
    phantom = np.zeros((n, n), dtype=bool)
    _propagate(level, phantom, modes, smoothed, continuity_range)
    _revisit_phantoms(level, phantom, modes, continuity_range)

    # _sector_band of every sector that is not a phantom, in one compiled loop
    low, high, band_low, band_high = sector_thresholds(
        smoothed,
        level,
        phantom,
        all_positions,
        counts,
        band_sigmas=band_sigmas,
        min_band=min_band,
        merge=merge_ratio,
        fwhm_to_sigma=FWHM_TO_SIGMA,
    )
    _phantom_bands(level, phantom, band_low, band_high, low, high, min_band)
    n_modes = np.minimum(counts, 127)
    return SectorAnalysis(
        background=level.astype(np.float32),
        low=low.astype(np.float32),
        high=high.astype(np.float32),
        modes=n_modes.astype(np.int8),
        phantom=phantom,
        seed=seed,
    )


def _seed_from_global(level, modes, smoothed, prominence, continuity_range) -> None:
    """No unambiguous sector: seed those with a mode near the frame's dominant level."""
    target = _global_level(smoothed, prominence=prominence)
    n = len(modes)
    for i in range(n):
        for j in range(n):
            positions = modes[i][j][0]
            if positions.size:
                nearest = positions[np.argmin(np.abs(positions - target))]
                if abs(nearest - target) <= continuity_range:
                    level[i, j] = nearest
    if not np.isfinite(level).any():
        level[n // 2, n // 2] = target


def _predict_all(level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of decided neighbours' levels and the total weight, per sector.

    Edge neighbours weigh 1, diagonal ones 1/sqrt(2); NaN prediction where none is decided.
    One compiled pass adding the neighbours in ``_NEIGHBOURS`` order, an undecided one as
    0.0 (the sums of the whole-grid shifted copies it replaced; ``test_continuity.py``
    compares them).
    """
    n = level.shape[0]
    predicted = np.empty((n, n))
    weight = np.empty((n, n))
    _predict_pass(
        np.ascontiguousarray(level, dtype=np.float64), _NEIGHBOUR_STEPS, predicted, weight
    )
    return predicted, weight


# _NEIGHBOURS as (dy, dx, weight) rows for the compiled pass
_NEIGHBOUR_STEPS = np.array(
    [(dy, dx, 1.0 if dy == 0 or dx == 0 else 1.0 / math.sqrt(2.0)) for dy, dx in _NEIGHBOURS]
)


@njit(cache=True)
def _predict_pass(level, steps, predicted, weight):  # pragma: no cover - numba
    n = level.shape[0]
    for i in range(n):
        for j in range(n):
            total = 0.0
            sum_w = 0.0
            for s in range(steps.shape[0]):
                y, x, w = i + int(steps[s, 0]), j + int(steps[s, 1]), steps[s, 2]
                if 0 <= y < n and 0 <= x < n and np.isfinite(level[y, x]):
                    total += w * level[y, x]
                    sum_w += w
                else:
                    # as the whole-grid sums: an undecided neighbour adds exactly 0.0
                    total += 0.0
                    sum_w += 0.0
            weight[i, j] = sum_w
            predicted[i, j] = total / sum_w if sum_w > 0 else math.nan


def _carried_level(level: np.ndarray, i: int, j: int, *, max_step: float, max_spread: float):
    """Level the decided neighbours' gradient carries on to at sector ``(i, j)`` (rule C1).

    A decided neighbour carries its level on when the sector beyond it in the same
    direction is decided too and the step between the two is at most ``max_step`` (its
    level plus that step once more). Returns the weighted mean of these (edge neighbours
    weigh 1, diagonal ones 1/sqrt(2)), or None when fewer than two neighbours carry or
    their carried levels disagree (weighted standard deviation above ``max_spread``): a
    gradient, not a patchwork.
    """
    n = level.shape[0]
    onward, weights = [], []
    for dy, dx in _NEIGHBOURS:
        near_y, near_x, far_y, far_x = i + dy, j + dx, i + 2 * dy, j + 2 * dx
        if not (0 <= far_y < n and 0 <= far_x < n):
            continue
        near, far = level[near_y, near_x], level[far_y, far_x]
        if np.isfinite(near) and np.isfinite(far) and abs(near - far) <= max_step:
            onward.append(2.0 * near - far)
            weights.append(1.0 if dy == 0 or dx == 0 else 1.0 / math.sqrt(2.0))
    if len(onward) < 2:
        return None
    values, w = np.asarray(onward), np.asarray(weights)
    mean = float(np.sum(w * values) / np.sum(w))
    spread = math.sqrt(max(float(np.sum(w * (values - mean) ** 2) / np.sum(w)), 0.0))
    return mean if spread <= max_spread else None


def _nearest_mode(positions, heights, predicted: float, reach: float) -> float | None:
    """The mode nearest ``predicted`` within ``reach`` (the higher breaks ties, then the
    first), or None; a compiled loop over the few modes (the pick of a lexsort by distance
    and height, without its whole-array calls; ``test_continuity.py`` compares)."""
    pick = _nearest_pass(positions, heights, float(predicted), float(reach))
    return None if pick < 0 else float(positions[pick])


@njit(cache=True)
def _nearest_pass(positions, heights, predicted, reach):  # pragma: no cover - numba
    pick = -1
    best_distance = 0.0
    for k in range(positions.size):
        distance = abs(positions[k] - predicted)
        if not distance <= reach:
            continue
        if pick < 0 or distance < best_distance or (
            distance == best_distance and heights[k] > heights[pick]
        ):
            pick, best_distance = k, distance
    return pick


def _ground_shows(smoothed: np.ndarray, predicted: float) -> bool:
    """Whether a sector's histogram holds the predicted ground level (C2's exception): at
    least ``_RAMP_HIDDEN_GROUND`` of its peak within 3 levels of it."""
    if not math.isfinite(predicted):
        return False
    k = int(round(min(max(predicted, 0.0), N_LEVELS - 1.0)))
    return bool(smoothed[max(0, k - 3) : k + 4].max() >= _RAMP_HIDDEN_GROUND * smoothed.max())


def _ramp_mode(smoothed, level, phantom, modes, i: int, j: int) -> float | None:
    """The highest mode of sector ``(i, j)`` when it runs on into a neighbour's ground (C2).

    The sector's and a decided edge neighbour's smoothed histograms are summed; when every
    bin between the sector's highest mode and the neighbour's background is higher than
    ``_RAMP_VALLEY`` times the lower of the two, the gray levels go on without a gap from
    one ground into the other: one floor under a steep illumination ramp. None when no
    neighbour qualifies or an edge neighbour is a phantom (an object spanning sectors).
    """
    positions, heights = modes[i][j]
    n = level.shape[0]
    edges = [(i + dy, j + dx) for dy, dx in _EDGE_NEIGHBOURS]
    edges = [(y, x) for y, x in edges if 0 <= y < n and 0 <= x < n]
    if positions.size == 0 or any(phantom[y, x] for y, x in edges):
        return None
    on_border = i in (0, n - 1) or j in (0, n - 1)
    # the highest mode; on the frame border the next highest too (see C2 of the module doc)
    tried = np.argsort(-heights, kind="stable")[: _RAMP_BORDER_MODES if on_border else 1]
    for top in positions[tried].astype(int):
        for y, x in edges:
            if not np.isfinite(level[y, x]):
                continue
            other = int(level[y, x])
            combined = smoothed[i, j] + smoothed[y, x]
            lo, hi = sorted((top, other))
            if combined[lo : hi + 1].min() > _RAMP_VALLEY * min(combined[top], combined[other]):
                return float(top)
    return None


def _propagate(level, phantom, modes, smoothed, continuity_range) -> None:
    """Decide undecided sectors, best-supported first (in place).

    The background is the mode nearest the neighbours' mean level; failing that, the mode
    nearest the level their gradient carries on to (rule C1 of the module doc); failing
    that, the highest mode when its histogram runs on into a neighbour's ground (rule C2);
    failing all, a phantom peak at the mean level, which a border sector only gets in a
    round where no sector was decided by a mode (C2).
    """
    border = np.ones(level.shape, dtype=bool)
    border[1:-1, 1:-1] = False
    while True:
        undecided = ~np.isfinite(level)
        if not undecided.any():
            return
        predicted_all, weight_all = _predict_all(level)
        best = float(weight_all[undecided].max())
        if best == 0.0:  # cannot happen on a connected grid with one seed; guard anyway
            level[~np.isfinite(level)] = np.nanmedian(level)
            return
        decided_now = []
        for i, j in np.argwhere(undecided & (weight_all >= best)):
            predicted = float(predicted_all[i, j])
            positions, heights = modes[i][j]
            found = _nearest_mode(positions, heights, predicted, continuity_range)
            if found is None:
                carried = _carried_level(
                    level,
                    i,
                    j,
                    max_step=_CARRY_STEP * continuity_range,
                    max_spread=_CARRY_SPREAD * continuity_range,
                )
                if carried is not None:
                    found = _nearest_mode(positions, heights, carried, continuity_range)
            if found is None and not _ground_shows(smoothed[i, j], predicted):
                found = _ramp_mode(smoothed, level, phantom, modes, i, j)
            if found is not None:
                decided_now.append((i, j, found, False))
            else:
                decided_now.append((i, j, float(np.clip(predicted, 0, N_LEVELS - 1)), True))
        if not all(entry[3] for entry in decided_now):
            # a border sector's phantom waits for the sectors decided by a mode this round:
            # its neighbours lie on one side, so the border row must first be decided
            # along itself (C2 of the module doc)
            decided_now = [entry for entry in decided_now if not (entry[3] and border[entry[:2]])]
        for i, j, value, is_phantom in decided_now:
            level[i, j] = value
            phantom[i, j] = is_phantom


def _revisit_phantoms(level, phantom, modes, continuity_range) -> None:
    """Give phantom sectors a mode near their mode-decided neighbours' level (C3, in place).

    Repeats until no phantom changes, so a corner of phantoms is undone from its edge in.
    """
    while phantom.any():
        predicted, weight = _predict_all(np.where(phantom, np.nan, level))
        changed = False
        for i, j in np.argwhere(phantom & (weight > 0)):
            positions, heights = modes[i][j]
            found = _nearest_mode(positions, heights, float(predicted[i, j]), continuity_range)
            if found is None:
                # C3b: under a steep falloff the mean of neighbours in other rows misses
                tilted = _plane_level(
                    np.where(phantom, np.nan, level), i, j, min_step=continuity_range
                )
                if tilted is not None:
                    found = _nearest_mode(positions, heights, tilted, continuity_range)
            if found is not None:
                level[i, j] = found
                phantom[i, j] = False
                changed = True
        if not changed:
            return


def _plane_level(level: np.ndarray, i: int, j: int, *, min_step: float) -> float | None:
    """Level at sector ``(i, j)`` of a plane fitted to its decided 8-neighbours (rule C3b).

    None when fewer than three are decided, they lie on one line (no plane) or the plane
    changes by less than ``min_step`` gray levels per sector (no steep falloff: the mean
    of the neighbours is the better guess there).
    """
    n = level.shape[0]
    design, values = [], []
    for dy, dx in _NEIGHBOURS:
        y, x = i + dy, j + dx
        if 0 <= y < n and 0 <= x < n and np.isfinite(level[y, x]):
            design.append((1.0, float(dy), float(dx)))
            values.append(float(level[y, x]))
    if len(values) < 3:
        return None
    a = np.asarray(design)
    if np.linalg.matrix_rank(a) < 3:
        return None
    coef = np.linalg.lstsq(a, np.asarray(values), rcond=None)[0]
    if math.hypot(coef[1], coef[2]) < min_step:
        return None
    return float(coef[0])


def _phantom_bands(level, phantom, band_low, band_high, low, high, min_band) -> None:
    """Phantom sectors take the median width-based band of their non-phantom neighbours."""
    if not phantom.any():
        return
    global_low = np.nanmedian(band_low) if np.isfinite(band_low).any() else 3 * min_band
    global_high = np.nanmedian(band_high) if np.isfinite(band_high).any() else 3 * min_band
    for i, j in np.argwhere(phantom):
        window = (slice(max(i - 1, 0), i + 2), slice(max(j - 1, 0), j + 2))
        lows = band_low[window][np.isfinite(band_low[window])]
        highs = band_high[window][np.isfinite(band_high[window])]
        low[i, j] = level[i, j] - (np.median(lows) if lows.size else global_low)
        high[i, j] = level[i, j] + (np.median(highs) if highs.size else global_high)
