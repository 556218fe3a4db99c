"""Sector histograms, their modes and Chow-Kaneko interpolation (``stages/segment.py``).

The frame is split into ``S x S`` sectors (edges ``np.round(np.linspace(0, H, S + 1))``).
Each sector gets a 256-bin gray-level histogram, smoothed with a nine-point moving average.
Its modes are the local maxima whose prominence (height above the higher of the two
surrounding valleys) is at least ``prominence`` times the sector's highest bin and at least
one pixel count. The background level and thresholds of each sector are chosen in
:mod:`stages._continuity`.

The per-sector thresholds belong to the sector centres and are interpolated bilinearly to
every pixel (Chow and Kaneko, 1972), extrapolated linearly to the frame border, so no block
edge appears at sector boundaries (:func:`interpolate_sector_grid`).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit
from scipy.ndimage import uniform_filter1d
from scipy.signal import find_peaks

__all__ = [
    "N_LEVELS",
    "FWHM_TO_SIGMA",
    "sector_edges",
    "sector_histograms",
    "smooth_histograms",
    "find_modes",
    "interpolate_sector_grid",
]

N_LEVELS = 256
_SMOOTHING_WIDTH = 9  # the study's nine-point filter
FWHM_TO_SIGMA = 1.0 / math.sqrt(2.0 * math.log(2.0))  # half width at half max -> sigma


def _coerce_image(image: np.ndarray) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise TypeError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim != 2:
        raise ValueError(f"image must be 2-D (rows, columns), got shape {image.shape}")
    if image.dtype != np.uint8:
        raise TypeError(
            f"image must be uint8 gray levels, got dtype {image.dtype}; "
            "convert with np.clip(image, 0, 255).astype(np.uint8)"
        )
    return image


def _check_sectors(sectors: int, shape: tuple[int, ...]) -> int:
    if not isinstance(sectors, int | np.integer) or isinstance(sectors, bool):
        raise TypeError(f"sectors must be an int, got {type(sectors).__name__} {sectors!r}")
    if sectors < 1:
        raise ValueError(f"sectors must be >= 1, got {sectors}")
    if min(shape) < sectors:
        raise ValueError(
            f"cannot split an image of shape {tuple(shape)} into {sectors}x{sectors} sectors; "
            f"use sectors <= {min(shape)}"
        )
    return int(sectors)


def sector_edges(length: int, sectors: int) -> np.ndarray:
    """Sector boundaries along one axis.

    Parameters
    ----------
    length : int
        Image size along the axis (rows or columns).
    sectors : int
        Number of sectors along the axis, ``1 <= sectors <= length``.

    Returns
    -------
    edges : (sectors + 1,) ndarray of int64
        ``np.round(np.linspace(0, length, sectors + 1))``; sector ``i`` is
        ``[edges[i], edges[i + 1])``. With 500 rows and 16 or 8 sectors, row 250 is an edge,
        so 250-row tiles hold whole sectors.
    """
    _check_sectors(sectors, (length,))
    return np.round(np.linspace(0, length, sectors + 1)).astype(np.int64)


def sector_histograms(image: np.ndarray, *, sectors: int) -> np.ndarray:
    """256-bin gray-level histogram of each of ``sectors x sectors`` sectors.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Gray image, ``M, N >= sectors``.
    sectors : int
        Sectors per axis; edges from :func:`sector_edges`.

    Returns
    -------
    hist : (sectors, sectors, 256) ndarray of int64
        ``hist[i, j, g]`` = number of pixels of gray ``g`` in sector row ``i``, column ``j``.
    """
    image = _coerce_image(image)
    sectors = _check_sectors(sectors, image.shape)
    return _histograms_between(
        image, sector_edges(image.shape[0], sectors), sector_edges(image.shape[1], sectors)
    )


def _histograms_between(image: np.ndarray, row_edges: np.ndarray, col_edges: np.ndarray):
    """Histograms of the sectors delimited by local edges (first edge 0, last the size)."""
    n_rows, n_cols = len(row_edges) - 1, len(col_edges) - 1
    row_sector = np.repeat(np.arange(n_rows, dtype=np.int64), np.diff(row_edges))
    col_sector = np.repeat(np.arange(n_cols, dtype=np.int64), np.diff(col_edges))
    counts = np.zeros((n_rows, n_cols, N_LEVELS), np.int64)
    _count_levels(np.ascontiguousarray(image, dtype=np.uint8), row_sector, col_sector, counts)
    return counts


@njit(cache=True)
def _count_levels(image, row_sector, col_sector, counts):  # pragma: no cover - numba
    """Add each pixel to its sector's histogram: the counts of ``np.bincount`` over
    ``sector * 256 + gray`` without its int64 index image (a third of the time)."""
    rows, cols = image.shape
    for y in range(rows):
        i = row_sector[y]
        for x in range(cols):
            counts[i, col_sector[x], image[y, x]] += 1


def smooth_histograms(hist: np.ndarray, *, passes: int = 1) -> np.ndarray:
    """Nine-point moving average along the gray axis, applied ``passes`` times.

    Parameters
    ----------
    hist : (..., 256) ndarray of int or float
        Histograms; the last axis is the gray level.
    passes : int
        Number of passes, ``>= 0`` (0 returns a float copy).

    Returns
    -------
    smoothed : (..., 256) ndarray of float64
        Same total count per histogram up to the reflected ends.
    """
    hist = np.asarray(hist)
    if hist.shape[-1:] != (N_LEVELS,):
        raise ValueError(f"histograms need {N_LEVELS} bins on the last axis, got {hist.shape}")
    if passes < 0:
        raise ValueError(f"passes must be >= 0, got {passes}")
    smoothed = hist.astype(np.float64)
    for _ in range(passes):
        smoothed = uniform_filter1d(smoothed, _SMOOTHING_WIDTH, axis=-1, mode="reflect")
    return smoothed


def find_modes(smoothed: np.ndarray, *, prominence: float) -> tuple[np.ndarray, np.ndarray]:
    """Modes of one smoothed histogram with the prominence rule.

    Parameters
    ----------
    smoothed : (256,) ndarray of float
        One smoothed histogram.
    prominence : float
        In ``[0, 1]``: a mode must rise above its higher surrounding valley by this fraction
        of the histogram's highest bin (and by at least one count).

    Returns
    -------
    positions : (K,) ndarray of int64
        Gray levels of the modes, increasing; a peak at 0 or 255 counts.
    heights : (K,) ndarray of float64
        Smoothed counts at the modes.
    """
    smoothed = np.asarray(smoothed, dtype=np.float64)
    if smoothed.shape != (N_LEVELS,):
        raise ValueError(f"one histogram of {N_LEVELS} bins expected, got shape {smoothed.shape}")
    if not 0.0 <= prominence <= 1.0:
        raise ValueError(f"prominence must be in [0, 1], got {prominence}")
    top = float(smoothed.max())
    if top <= 0.0:
        return np.zeros(0, np.int64), np.zeros(0)
    padded = np.concatenate(([0.0], smoothed, [0.0]))  # let peaks at 0 and 255 count
    peaks, _ = find_peaks(padded, prominence=max(prominence * top, 1.0))
    positions = peaks.astype(np.int64) - 1
    return positions, smoothed[positions]


def _interpolation_weights(length: int, edges: np.ndarray) -> np.ndarray:
    """``(length, S)`` matrix of linear weights from sector centres to pixel centres."""
    centres = (edges[:-1] + edges[1:]) / 2.0 - 0.5  # in pixel-index coordinates
    pixels = np.arange(length, dtype=np.float64)
    n = centres.size
    weights = np.zeros((length, n))
    if n == 1:
        weights[:, 0] = 1.0
        return weights
    upper = np.clip(np.searchsorted(centres, pixels, side="right"), 1, n - 1)
    lower = upper - 1
    # linear beyond the outermost centres too: half a sector of a steep illumination ramp
    # (the far floor darkening towards the horizon) must not be cut off at a constant
    t = (pixels - centres[lower]) / (centres[upper] - centres[lower])
    weights[np.arange(length), lower] = 1.0 - t
    weights[np.arange(length), upper] += t
    return weights


@functools.lru_cache(maxsize=8)
def _pixel_weights(length: int, sectors: int) -> np.ndarray:
    """:func:`_interpolation_weights` of ``length`` pixels cut into ``sectors``, made once
    per size (a frame interpolates three grids of one shape; read only)."""
    weights = _interpolation_weights(length, sector_edges(length, sectors))
    weights.flags.writeable = False
    return weights


_SINGLE_THREAD_GEMM = 4 * 65536


def interpolate_sector_grid(grid: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear interpolation of per-sector values between sector centres (Chow and Kaneko).

    Parameters
    ----------
    grid : (S, S) ndarray of float
        One value per sector, finite.
    shape : tuple of int
        ``(M, N)`` image shape the sectors were cut from (edges from :func:`sector_edges`).

    Returns
    -------
    field : (M, N) ndarray of float32
        Equal to ``grid[i, j]`` at sector ``(i, j)``'s centre, linear in between and
        extrapolated linearly beyond the outermost centres (half a sector at most).
    """
    grid = np.asarray(grid, dtype=np.float64)
    if grid.ndim != 2 or grid.shape[0] != grid.shape[1]:
        raise ValueError(f"grid must be square (S, S), got shape {grid.shape}")
    if not np.isfinite(grid).all():
        raise ValueError("grid must be finite everywhere; decide every sector first")
    rows, cols = (int(v) for v in shape)
    n = grid.shape[0]
    wy = _pixel_weights(rows, n)
    wx = _pixel_weights(cols, n)
    left = wy @ grid
    field = np.empty((rows, cols), dtype=np.float32)
    # row blocks below OpenBLAS's threading threshold (m*n*k <= 4 * 65536): a threaded
    # product of this size spends ten times its arithmetic waking and syncing threads
    step = max(1, _SINGLE_THREAD_GEMM // max(1, n * cols))
    for start in range(0, rows, step):
        field[start : start + step] = left[start : start + step] @ wx.T
    return field
