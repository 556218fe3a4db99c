"""Tiled stereo matching: a large frame matched tile by tile, equal to whole-frame matching.

:func:`match_tiled` matches a large frame tile by tile with ``dask.array.map_overlap``;
the overlap (:func:`tile_overlap`) covers everything a pixel's result depends on, so for the
``adaptive`` method the result is bit-identical to whole-frame matching (window sums are
exact integers, :mod:`stages._ncc`; so is the prefilter's arithmetic). Each tile gets its
own rows' search bands. ``sgm`` and ``opencv-sgbm`` aggregate along paths across the whole
frame, so their tiled results differ slightly near tile seams.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._stereo import Matching, _coerce_band, _decode, _match_coded, check_settings
from ._stereo_filters import _coerce_pair, _coerce_range

__all__ = ["match_tiled", "tile_overlap"]


def tile_overlap(
    *,
    min_disparity: int,
    max_disparity: int,
    largest_window: int,
    speckle_size: int,
    prefilter: int = 0,
) -> tuple[int, int]:
    """Tile overlap ``(rows, columns)`` that makes tiled matching equal whole-frame matching.

    A pixel's disparity depends on reference columns within ``|d|max + (d_max - d_min)``
    (left-right check), other-image columns within ``|d|max`` and half a window around it;
    speckle removal then looks ``speckle_size`` px further, the prefilter ``prefilter // 2``.
    """
    span = max(abs(min_disparity), abs(max_disparity))
    half = largest_window // 2 + prefilter // 2
    columns = span + (max_disparity - min_disparity) + half + 2 + speckle_size
    rows = half + 2 + speckle_size
    return rows, columns


def match_tiled(
    reference: np.ndarray,
    other: np.ndarray,
    *,
    tile_px: int,
    min_disparity: int,
    max_disparity: int,
    row_min_disparity: Any = None,
    row_max_disparity: Any = None,
    **settings: Any,
) -> Matching:
    """:func:`stages._stereo.match_disparity` tile by tile with ``dask.array.map_overlap``.

    Parameters
    ----------
    reference, other : (M, N) ndarray of uint8
        As for :func:`stages._stereo.match_disparity`.
    tile_px : int
        Tile side in px (>= 16); the frame is cut into ``tile_px`` square chunks, each
        matched with the overlap of :func:`tile_overlap` (dask enlarges chunks smaller
        than the overlap).
    row_min_disparity, row_max_disparity : (M,) array_like of int, optional
        As for :func:`stages._stereo.match_disparity`; each tile gets its rows' bands.
    **settings
        Any keyword of :func:`stages._stereo.match_disparity`.

    Returns
    -------
    Matching
        Equal to whole-frame matching for ``adaptive``.
    """
    import dask.array as da

    from pipeline.compute import compute

    if isinstance(tile_px, bool) or not isinstance(tile_px, int) or tile_px < 16:
        raise ValueError(f"tile_px must be an int >= 16, got {tile_px!r}")
    ref, oth = _coerce_pair(reference, other)
    lo, hi = _coerce_range(min_disparity, max_disparity)
    s = check_settings(**settings)
    largest = max(max(max(shape) for shape in s["windows"]), s["sgm_window"], 5)
    rows, cols = tile_overlap(
        min_disparity=lo, max_disparity=hi, largest_window=largest,
        speckle_size=s["speckle_size"], prefilter=s["prefilter"],
    )  # fmt: skip

    band = _coerce_band(row_min_disparity, row_max_disparity, ref.shape[0], lo, hi)
    # The bands travel as two more images (each row its floor, its ceiling), so the overlap
    # hands every tile exactly its own rows' bands.
    rows_band = np.array([[lo], [hi]], np.int64) + np.zeros(ref.shape[0], np.int64)
    rows_band = rows_band if band is None else band
    floor_d, ceiling_d = (
        da.from_array(np.broadcast_to(b[:, None], ref.shape), chunks=tile_px) for b in rows_band
    )

    def tile(
        ref_tile: np.ndarray, oth_tile: np.ndarray, floor_tile: np.ndarray, ceiling_tile: np.ndarray
    ) -> np.ndarray:
        tile_band = None if band is None else np.stack([floor_tile[:, 0], ceiling_tile[:, 0]])
        return _match_coded(ref_tile, oth_tile, lo, hi, s, tile_band)

    ref_d = da.from_array(ref, chunks=tile_px)
    oth_d = da.from_array(oth, chunks=tile_px)
    coded = da.map_overlap(
        tile, ref_d, oth_d, floor_d, ceiling_d, depth={0: rows, 1: cols}, boundary="none",
        trim=True, dtype=np.float32, meta=np.empty((0, 0), np.float32),
    )  # fmt: skip
    (result,) = compute(coded)
    return _decode(np.asarray(result, dtype=np.float32))
