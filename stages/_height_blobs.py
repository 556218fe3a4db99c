"""Rule R8b: faint compact blobs kept when they stand as a height bump and have crisp edges.

R8 (:mod:`stages._blobs`) adds compact blobs at least 4 ground spreads out at their scale;
lava's catalog frames still hold 100 true rocks that no object touches (``bench_misses.py``:
median 54 px at 2.05 m, 1.9 ground spreads of gray contrast against 5.6 for found rocks).
R8's search at fewer spreads reaches some of them, but finds the ground's own blotches
several times as often. Two cues tell the rocks among them
(:func:`add_height_blobs`):

* **height bump** -- the stereo windows leave a small rock as a bump of their own scale; the
  map of rule R2d (:func:`stages._height_vote._height_bumps`, here on R0's median-smoothed
  relative heights: Gaussians at 2 px minus at 6 px, in that map's robust noise on the
  ground) must peak at least
  ``min_bump`` (2, R2d's own floor) on the blob. A blotch lying on the ground makes none;
* **crisp edges** -- a faceted rock has sharp outlines and lit facets, a blotch of the
  ground's texture fades into the ground. The gray level's fine detail (the image minus
  its Gaussian at 1 px, as a local RMS at 2 px) averaged over the blob must be at least
  ``min_texture`` (1.2) times its level around the blob (that RMS smoothed at 15 px).

Candidates are R8's blobs at ``min_sigmas`` spreads (every R8 test: keeping off objects and
their 3 px ring, solid, thick, standing alone, lighter blobs 1.375 times as far out), among
the pixels no object claims after R8 itself. Where the heights are unusable (lab) or not
used, R8b does nothing (:func:`stages.segment.segment_image`).

Separability, lava's catalog frames (a diagnostic on the v28 labels, not in the
repository). The 100 untouched rocks against 400 disks of ground of their size in their
rows (medians, 10th-90th percentiles): texture ratio 2.00 (1.01-4.06) against 0.85
(0.55-1.06), bump peak 2.6 (0.0-5.8) against 1.0 (0.0-4.3), the mean relative height minus
the ring's 0.45 cm (-0.49-1.54) against 0.00 (-0.90-0.99) -- the heights alone barely part
them, as R8's docstring found. R8's search at 3 spreads after R8 found 11 true rocks, 62
blobs of ground, 8 pieces of rocks too small to match and 11 rocks under the graded 30 px;
the texture test alone kept 9 / 6 / 6 / 11, the bump alone 10 / 13 / 4 / 9, both 8 / 0 / 3
/ 9. At 2 spreads: 23 / 823 / 23 / 35, both cues 16 / 3 / 13 / 26 -- the pieces cost what
the rocks gain.

R8b is off by default (``height_blob_sigmas = 0``) and on in the lava catalog
(``height_blob_sigmas = 3``). ``benchmarks/bench_segment.py --rundir DIR --set
height_blob_sigmas=3`` against the same without ``--set``, object F1 on lava: catalog
0.819 -> 0.825 (tp 549 -> 557, fp 84 -> 87), seeds 2-5 0.812 -> 0.819, 0.822 -> 0.824,
0.819 -> 0.818 (tp +1, fp +3), 0.823 -> 0.832; the matched rocks' mean IoU drops by up to
0.004 (the blobs' outlines are R8's). ``bench_misses.py``: untouched 100 -> 91, the ground's
false objects 19 unchanged, 3 more on missed rocks. Variants (F1 gain on the five lava
runs, mean / smallest): 3 spreads, bump 2, texture 1.2 +0.0046 / -0.001; texture 1.1 or
bump 1.5 +0.0048-0.0049 / -0.001, texture 1.3 +0.0040; 3.25 spreads +0.0038-0.0043 / 0.000;
3.5 spreads +0.0017-0.0027 (bump 1.5-2); 2.5 spreads +0.0002-0.0021 (5-20 more false
objects per run);
2 spreads: catalog +0.005, seeds -0.008 to +0.001; without the texture test -0.000 (7-17
more false objects per run), without the bump +0.001, without both -0.032 (60-91 more).
R8's isolation, solidity, light-factor or growth settings changed for the candidates: within
0.0003 of the mean, none better; a second pass at 2 or 2.5 spreads with stricter cues (bump
2.5-4, texture 1.2-1.8): +0.0022 to +0.0045.
Switched on elsewhere: mojave catalog 0.912 -> 0.911 (tp +6, fp +8); lab unchanged
(heights unusable); dunes catalog unchanged. Cost, 6 lava catalog frames, one process:
about 25 ms of CPU per frame (R8's search again 14, the bump map 5, the detail maps 3);
10-14 ms on the 12 catalog frames since R8b shares R8's image maps and unchanged tile
spreads (:class:`stages._blobs.BlobScales`) and R2d's bump-map weights
(:class:`stages._height_vote.BumpWeights`), the same labels.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._blobs import BlobScales, add_compact_blobs
from ._height_vote import BumpWeights, _height_bumps
from ._regions import _lookup

__all__ = ["add_height_blobs", "detail_ratio"]

_MIN_BUMP = 2.0
_MIN_TEXTURE = 1.2
# fine detail: the image minus its Gaussian at this scale, px
_DETAIL_PX = 1.0
# its local RMS, px
_RMS_PX = 2.0
# the level of detail around a blob, px
_AROUND_PX = 15.0
# ... taken at this fraction of the resolution
_AROUND_SHRINK = 4


def detail_ratio(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gray level's fine detail and its level around each pixel.

    Parameters
    ----------
    image : (M, N) ndarray of uint8

    Returns
    -------
    detail, around : (M, N) ndarray of float32
        Local RMS (Gaussian ``_RMS_PX``) of the image minus its Gaussian at ``_DETAIL_PX``,
        and that RMS smoothed at ``_AROUND_PX`` (at a quarter of the resolution on frames
        of at least 16 px a side); a region's mean ``detail`` over its mean
        ``around`` is its texture ratio.
    """
    pixels = image.astype(np.float32)
    # the squared fine detail in one pass (float32, as ``fine * fine`` of the difference)
    squared = cv2.GaussianBlur(pixels, (0, 0), _DETAIL_PX)
    _squared_difference(pixels, squared)
    detail = cv2.GaussianBlur(squared, (0, 0), _RMS_PX)
    np.sqrt(detail, out=detail)
    rows, cols = image.shape
    if min(rows, cols) < 4 * _AROUND_SHRINK:
        return detail, cv2.GaussianBlur(detail, (0, 0), _AROUND_PX)
    # a 15 px Gaussian is smooth: at a quarter of the resolution, a tenth of the cost
    small = cv2.resize(
        detail,
        (cols // _AROUND_SHRINK, rows // _AROUND_SHRINK),
        interpolation=cv2.INTER_AREA,
    )
    small = cv2.GaussianBlur(small, (0, 0), _AROUND_PX / _AROUND_SHRINK)
    around = cv2.resize(small, (cols, rows), interpolation=cv2.INTER_LINEAR)
    return detail, around


@njit(cache=True)
def _squared_difference(pixels, smoothed):  # pragma: no cover - numba
    """``smoothed = (pixels - smoothed) ** 2`` in float32, in place."""
    rows, cols = pixels.shape
    for y in range(rows):
        for x in range(cols):
            fine = pixels[y, x] - smoothed[y, x]
            smoothed[y, x] = fine * fine


def add_height_blobs(
    labels: np.ndarray,
    image: np.ndarray,
    relative: np.ndarray,
    *,
    min_sigmas: float,
    min_area_px: int = 30,
    min_bump: float = _MIN_BUMP,
    min_texture: float = _MIN_TEXTURE,
    _scales: BlobScales | None = None,
    _weights: BumpWeights | None = None,
) -> tuple[np.ndarray, int]:
    """Rule R8b: add faint compact blobs that stand as a height bump with crisp edges.

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects (after R8); left unchanged where it is not 0.
    image : (M, N) ndarray of uint8
        Reference gray image.
    relative : (M, N) ndarray of float32
        Heights above the local ground (R0 of :mod:`stages._depth_rules`), metres, NaN
        invalid; the bump map is 0 there, so a blob without valid heights is never added.
    min_sigmas : float
        ``> 0``: R8's core contrast for the candidates, in ground spreads at their scale.
    min_area_px : int
        ``>= 1``; smaller blobs are not added.
    min_bump : float
        Peak of R2d's bump map (its noise on the ground) a blob needs.
    min_texture : float
        ``>= 0``: the blob's fine gray detail over the detail around it.
    _scales : BlobScales, optional
        R8's image maps of ``image`` (:func:`stages._blobs.blob_scales`), shared with R8.
    _weights : BumpWeights, optional
        The frame's bump-map weights, shared with R2d.

    Returns
    -------
    labels : (M, N) ndarray of int32
        The objects, then the added blobs numbered on from ``labels.max() + 1``.
    added : int
    """
    if relative.shape != labels.shape:
        raise ValueError(
            f"relative must have the labels' shape {labels.shape}, got {relative.shape}"
        )
    if relative.dtype.kind != "f":
        raise TypeError(f"relative must be float (NaN invalid), got dtype {relative.dtype}")
    if not min_texture >= 0:
        raise ValueError(f"min_texture must be >= 0, got {min_texture}")
    labels = labels.astype(np.int32, copy=False)
    first = int(labels.max()) + 1
    found, n_found = add_compact_blobs(
        labels, image, min_sigmas=min_sigmas, min_area_px=min_area_px, _scales=_scales
    )
    if n_found == 0:
        return found, 0
    bumps = _height_bumps(
        relative.astype(np.float32, copy=False), labels > 0, _weights=_weights
    )
    detail, around = detail_ratio(image)
    count = n_found + 1
    peak, pixels, detail_sum, around_sum = _blob_cues(found, first, count, bumps, detail, around)
    ratio = detail_sum / np.maximum(around_sum, 1e-6)
    keep = (peak >= min_bump) & (ratio >= min_texture) & (pixels > 0)
    keep[0] = False
    # kept blobs numbered on densely, the others back to ground
    numbers = np.zeros(count, np.int32)
    numbers[keep] = np.arange(first, first + int(keep.sum()), dtype=np.int32)
    # the objects keep their ids, blob ``first + i`` becomes ``numbers[i + 1]``
    table = np.concatenate([np.arange(first, dtype=np.int32), numbers[1:]])
    return _lookup(table, found), int(keep.sum())


def _blob_cues(
    found: np.ndarray,
    first: int,
    count: int,
    bumps: np.ndarray,
    detail: np.ndarray,
    around: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per blob ``1..count-1`` (labels ``first..`` of ``found``; index 0 the rest): peak
    of ``bumps`` (-inf for 0), pixels, and the sums of ``detail`` and ``around`` in raster
    order (0 for 0). One compiled pass for ``np.maximum.at`` and two :func:`_label_sums`
    of the blob ids (``test_height_blobs.py`` compares them)."""
    peak = np.full(count, -np.inf)
    pixels = np.zeros(count, np.int64)
    sums = np.zeros((2, count))
    _cue_pass(
        np.ascontiguousarray(found),
        first,
        np.ascontiguousarray(bumps),
        np.ascontiguousarray(detail),
        np.ascontiguousarray(around),
        peak,
        pixels,
        sums,
    )
    return peak, pixels, sums[0], sums[1]


@njit(cache=True)
def _cue_pass(found, first, bumps, detail, around, peak, pixels, sums):  # pragma: no cover
    rows, cols = found.shape
    ground = 0
    for y in range(rows):
        for x in range(cols):
            label = found[y, x]
            if label < first:
                ground += 1
                continue
            k = label - first + 1
            pixels[k] += 1
            value = bumps[y, x]
            # np.maximum: a NaN, once met, stays
            if peak[k] == peak[k] and (value > peak[k] or value != value):
                peak[k] = value
            sums[0, k] += detail[y, x]
            sums[1, k] += around[y, x]
    pixels[0] = ground
