"""Numba kernels of the sector analysis: every sector's modes, then every sector's thresholds.

Private helpers of :mod:`stages._continuity`. ``find_modes`` calls ``scipy.signal.find_peaks``
once per sector, 256 times a frame, and the call costs more than its work (about 5 ms a
frame). :func:`find_all_modes` runs the same two steps -- local maxima with plateaus at
their middle (rounded down), then each peak's prominence over the whole histogram, padded
with a zero bin on each side -- for every histogram in one compiled loop and returns the
same positions (``tests/stages/test_modes.py`` compares it with ``find_modes``).
:func:`sector_thresholds` runs the threshold rule of :mod:`stages._continuity` (valleys,
merged ground facets, width-based bands) for every sector at once, another 3 ms of Python a
frame, with the same arithmetic as the per-sector Python it replaced, kept as the reference
``_sector_band`` in ``tests/stages/test_modes.py`` and compared there.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["find_all_modes", "sector_thresholds"]

# at most one peak per two bins of the padded histogram (258 bins)
_MAX_MODES = 129


@njit(cache=True)
def _modes(hists, prominence, positions, counts):  # pragma: no cover - numba
    n_levels = hists.shape[1]
    x = np.zeros(n_levels + 2)
    for row in range(hists.shape[0]):
        top = hists[row].max()
        counts[row] = 0
        if top <= 0.0:
            continue
        x[1:-1] = hists[row]
        bar = max(prominence * top, 1.0)
        # local maxima (scipy.signal._peak_finding_utils._local_maxima_1d)
        i, last = 1, x.size - 1
        while i < last:
            if x[i - 1] < x[i]:
                ahead = i + 1
                while ahead < last and x[ahead] == x[i]:
                    ahead += 1
                if x[ahead] < x[i]:
                    peak = (i + ahead - 1) // 2
                    # prominence over the whole signal (_peak_prominences, no window)
                    left_min = x[peak]
                    k = peak
                    while k >= 0 and x[k] <= x[peak]:
                        if x[k] < left_min:
                            left_min = x[k]
                        k -= 1
                    right_min = x[peak]
                    k = peak
                    while k <= last and x[k] <= x[peak]:
                        if x[k] < right_min:
                            right_min = x[k]
                        k += 1
                    if x[peak] - max(left_min, right_min) >= bar:
                        positions[row, counts[row]] = peak - 1
                        counts[row] += 1
                    i = ahead
            i += 1


def find_all_modes(smoothed: np.ndarray, *, prominence: float) -> tuple[np.ndarray, np.ndarray]:
    """Mode positions of many smoothed histograms, as :func:`stages._sectors.find_modes`.

    Parameters
    ----------
    smoothed : (..., 256) ndarray of float64
        Smoothed histograms (:func:`stages._sectors.smooth_histograms`).
    prominence : float
        In ``[0, 1]``; the prominence rule of ``find_modes``.

    Returns
    -------
    positions : (..., 129) ndarray of int64
        Gray levels of each histogram's modes, increasing, in its first ``counts`` entries.
    counts : (...) ndarray of int64
        Modes per histogram.
    """
    smoothed = np.ascontiguousarray(smoothed, dtype=np.float64)
    if smoothed.ndim < 1 or smoothed.shape[-1] < 1:
        raise ValueError(f"histograms need a last axis of gray levels, got {smoothed.shape}")
    if not 0.0 <= prominence <= 1.0:
        raise ValueError(f"prominence must be in [0, 1], got {prominence}")
    flat = smoothed.reshape(-1, smoothed.shape[-1])
    positions = np.zeros((flat.shape[0], _MAX_MODES), np.int64)
    counts = np.zeros(flat.shape[0], np.int64)
    _modes(flat, float(prominence), positions, counts)
    lead = smoothed.shape[:-1]
    return positions.reshape(*lead, _MAX_MODES), counts.reshape(lead)


@njit(cache=True)
def _valley(hist, background, other):  # pragma: no cover - numba
    """Lowest bin between two modes; on a flat valley, its end nearest the background."""
    lo, hi = (other, background) if other < background else (background, other)
    floor = hist[lo : hi + 1].min() + 1e-12
    if other < background:
        for k in range(hi, lo - 1, -1):
            if hist[k] <= floor:
                return float(k)
    for k in range(lo, hi + 1):
        if hist[k] <= floor:
            return float(k)
    return float(hi)  # not reached: the minimum lies in the range


@njit(cache=True)
def _half_width(hist, peak, step):  # pragma: no cover - numba
    """Bins from ``peak`` to the first one below half its height, walking by ``step``."""
    half = hist[peak] / 2.0
    if step > 0:
        for k in range(peak, hist.size):
            if hist[k] < half:
                return float(k - peak)
        return float(hist.size - peak)
    for k in range(peak, -1, -1):
        if hist[k] < half:
            return float(peak - k)
    return float(peak + 1)


@njit(cache=True)
def _side(
    hist, background, modes, step, band_sigmas, min_band, merge, fwhm_to_sigma
):  # pragma: no cover - numba
    """Threshold and band on one side (step -1: darker, +1: lighter).

    Walks outwards from the background mode: a neighbouring mode behind a shallow valley
    (valley higher than ``merge`` times the lower of the two peaks) is ground texture and is
    absorbed; the first mode behind a deep valley sets the threshold at that valley; with no
    such mode the threshold lies ``max(min_band, band_sigmas * sigma)`` beyond the outermost
    ground mode.
    """
    edge = background
    count = modes.size
    for n in range(count):
        # outwards from the background: increasing modes above it, decreasing below
        mode = modes[n] if step > 0 else modes[count - 1 - n]
        if (step > 0 and mode <= background) or (step < 0 and mode >= background):
            continue
        valley = _valley(hist, edge, mode)
        floor = hist[int(valley)]
        if floor > merge * min(hist[edge], hist[mode]):
            edge = mode  # shallow valley: the same ground
            continue
        if abs(valley - edge) >= min_band:
            band = max(min_band, band_sigmas * _half_width(hist, edge, step) * fwhm_to_sigma)
            return valley, band
        break
    band = max(min_band, band_sigmas * _half_width(hist, edge, step) * fwhm_to_sigma)
    return edge + step * band, band


@njit(cache=True)
def _thresholds(
    smoothed, level, phantom, positions, counts, band_sigmas, min_band, merge, fwhm_to_sigma, out
):  # pragma: no cover - numba
    rows, cols = level.shape
    for i in range(rows):
        for j in range(cols):
            if phantom[i, j]:
                continue
            modes = positions[i, j, : counts[i, j]]
            background = int(level[i, j])
            hist = smoothed[i, j]
            low, band_low = _side(
                hist, background, modes, -1, band_sigmas, min_band, merge, fwhm_to_sigma
            )
            high, band_high = _side(
                hist, background, modes, 1, band_sigmas, min_band, merge, fwhm_to_sigma
            )
            out[0, i, j], out[1, i, j], out[2, i, j], out[3, i, j] = low, high, band_low, band_high


def sector_thresholds(
    smoothed: np.ndarray,
    level: np.ndarray,
    phantom: np.ndarray,
    positions: np.ndarray,
    counts: np.ndarray,
    *,
    band_sigmas: float,
    min_band: float,
    merge: float,
    fwhm_to_sigma: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Low and high thresholds and width-based bands of every sector with a real mode.

    Parameters
    ----------
    smoothed : (S, S, 256) ndarray of float64
        Smoothed sector histograms.
    level : (S, S) ndarray of float64
        Background gray level of each sector (a mode's position where not phantom).
    phantom : (S, S) ndarray of bool
        Sectors left out (NaN in every output).
    positions, counts : (S, S, K) and (S, S) ndarray of int64
        :func:`find_all_modes`.
    band_sigmas, min_band, merge, fwhm_to_sigma : float
        As :func:`stages._continuity.analyse_sectors` (``merge`` is its ``merge_ratio``).

    Returns
    -------
    low, high, band_low, band_high : (S, S) ndarray of float64
    """
    out = np.full((4, *level.shape), np.nan)
    _thresholds(
        np.ascontiguousarray(smoothed, dtype=np.float64),
        np.asarray(level, dtype=np.float64),
        np.asarray(phantom, dtype=bool),
        positions,
        counts,
        float(band_sigmas),
        float(min_band),
        float(merge),
        float(fwhm_to_sigma),
        out,
    )
    return out[0], out[1], out[2], out[3]
