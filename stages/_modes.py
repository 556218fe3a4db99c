"""Numba kernel: the modes of every sector histogram at once (:func:`stages._sectors.find_modes`).

Private helper of :mod:`stages._continuity`. ``find_modes`` calls ``scipy.signal.find_peaks``
once per sector, 256 times a frame, and the call costs more than its work (about 5 ms a
frame). :func:`find_all_modes` runs the same two steps -- local maxima with plateaus at
their middle (rounded down), then each peak's prominence over the whole histogram, padded
with a zero bin on each side -- for every histogram in one compiled loop and returns the
same positions (``tests/stages/test_modes.py`` compares it with ``find_modes``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["find_all_modes"]

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
