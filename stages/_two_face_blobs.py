"""Rule R8c: small rocks seen as a lit face beside a shaded one, joined into one blob.

R8 (:mod:`stages._blobs`) and R8b (:mod:`stages._height_blobs`) search one side of the
ground's gray level at a time. A small lava rock lit from one side is often both: a light
facet and a dark one side by side, each a few ground spreads out at R8's scale, but each
alone a piece of the rock (IoU below 0.5, or under the 30 px floor), and their mean over
the rock near the ground's level (``bench_misses.py``: lava's catalog frames hold 91 rocks
no object touches, median contrast 1.8 spreads, against 5.4 for the rocks found). Of
those 91, 16 have pixels at least 3 spreads darker and others at least 3 spreads lighter
than the ground at R8's scale (lava_0000 rocks 29 and 40: -3.8 / +7.0 and -5.9 / +3.7;
R8's search at 3 or 4 spreads finds 15-24 px of one face, IoU 0.18-0.45; R8c's blobs
match them at IoU 0.54 and 0.80).

So R8c looks, after R7f and before R8, among the pixels no object claims
(:func:`add_two_faced_blobs`):

1. R8's darker and lighter regions at ``min_sigmas`` spreads (R8's steps 1-3 of
   :mod:`stages._blobs`: cores outside objects and their 3 px ring, grown over the free
   pixels with at least half the core's contrast);
2. a dark region and a light region that come within ``join_px`` (2) of each other are
   one blob, with the free pixels outside the ring between them (both dilated by
   ``join_px``);
3. a blob is added as an object when it holds both faces (each at least ``min_share``,
   0.15, of its pixels), keeps off every object and its ring, holds at least
   ``min_area_px`` pixels and is solid (R8's test, at least ``min_solidity`` 0.88: a
   dark and a light blotch of the ground's texture that touch rarely make one convex
   blob).

Why before R8: after it, R8's blob of one face (4 spreads out) and its ring keep the
joined blob out, and the face stays a piece. ``bench_segment.py --rundir DIR --set
two_face_sigmas=3`` against the same without ``--set``, object F1 (segment v32; tp / fp):
lava catalog 0.830 -> 0.834 (561 / 83 -> 566 / 85), seeds 2-5 0.822 -> 0.826 (559 / 93 ->
563 / 93), 0.829 -> 0.833 (554 / 84 -> 559 / 85), 0.821 -> 0.828 (515 / 81 -> 521 / 78),
0.833 -> 0.837 (528 / 65 -> 531 / 64). Run after R8b instead: 0.833, 0.822, 0.832, 0.824,
0.835. Near rocks (within 2 m; ``bench_describe.py --rundir DIR --labels segment --set
segment.two_face_sigmas=3``), count / class right / median width error: catalog
116 / 0.957 / 9.7 % -> 116 / 0.957 / 9.4 %, seeds 2-5 102 / 0.931 / 9.2 % -> 105 / 0.924
/ 9.5 % (two more near rocks classed right, one more wrong), 107 / 0.935 / 12.6 % -> 110
/ 0.936 / 13.0 %, 100 / 0.920 / 11.5 % -> 103 / 0.922 / 11.3 %, 101 / 0.911 / 13.1 % ->
102 / 0.912 / 13.0 %.

Variants (lava catalog, seeds 2-5; a sweep script not in the repository, the same
segmentation and scores as ``bench_segment.py --rundir``): 2.5 spreads 0.836 0.828 0.835
0.823 0.832, 2.75 0.837 0.830 0.833 0.827 0.834, 3.5 0.835 0.826 0.831 0.824 0.837, 4
0.833 0.826 0.829 0.822 0.834; ``join_px`` 1 0.831 0.823 0.830 0.821 0.833, 3 0.831
0.823 0.832 0.827 0.834; ``min_share`` 0.25 0.833 0.823 0.834 0.826 0.837 (0.1 as 0.15);
``min_solidity`` 0.8 0.835 0.827 0.832 0.829 0.839, 0.9 0.833 0.827 0.832 0.826 0.837,
none 0.834 0.822 0.829 0.828 0.833 (8-12 more false objects on four runs). R8b's
crispness test (texture ratio 1.2, 1.5 or 2) on the blobs as well: on every run the same
or 0.001-0.003 lower, so no crispness test. Heights: R2d's bump peak on the candidates
had median 2.0 on true rocks and 3.6 on the others (a diagnostic on the five runs, not in
the repository), so no height test.

Switched on elsewhere: mojave catalog 0.915 -> 0.905 (tp +1, fp +9); lab and dunes
catalogs unchanged. Cost: two more of R8's growths and four whole-frame counts, about a
tenth of the segmentation's CPU time on lava's catalog frames. R8c is off by default
(``two_face_sigmas = 0`` of :func:`stages.segment.segment_image`) and on in the lava
catalog (``two_face_sigmas = 3``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._blobs import (
    _GROW_PX,
    _MARGIN_PX,
    _TILE_PX,
    BlobScales,
    _free_contrast,
    _grow,
    _is_solid,
    blob_scales,
)
from ._regions import _lookup, _object_boxes

__all__ = ["add_two_faced_blobs", "two_faced_candidates"]

_JOIN_PX = 2
_MIN_SHARE = 0.15
_MIN_SOLIDITY = 0.88
# room around a blob's box for its tests, px
_PAD_PX = 5


def two_faced_candidates(
    labels: np.ndarray,
    image: np.ndarray,
    *,
    min_sigmas: float,
    min_area_px: int = 30,
    join_px: int = _JOIN_PX,
    min_share: float = _MIN_SHARE,
    _scales: BlobScales | None = None,
) -> tuple[np.ndarray, int]:
    """Steps 1-2 and R8c's face and ring tests: the two-faced blobs among free pixels.

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects.
    image : (M, N) ndarray of uint8
        Reference gray image.
    min_sigmas : float
        ``> 0``: R8's core contrast for either face, in ground spreads at R8's scale.
    min_area_px : int
        ``>= 1``; smaller blobs are not candidates.
    join_px : int
        ``>= 1``; a dark and a light region this close are one blob.
    min_share : float
        In ``[0, 0.5]``; each face's least share of the blob's pixels.
    _scales : BlobScales, optional
        R8's image maps of ``image`` (:func:`stages._blobs.blob_scales`).

    Returns
    -------
    blobs : (M, N) ndarray of int32
        0 elsewhere, 1..n the candidate blobs (not yet tested for solidity).
    n : int
    """
    blob_ids, kept = _candidates(
        labels,
        image,
        min_sigmas=min_sigmas,
        min_area_px=min_area_px,
        join_px=join_px,
        min_share=min_share,
        _scales=_scales,
    )
    numbers = np.zeros(int(blob_ids.max()) + 1, np.int32)
    numbers[kept] = np.arange(1, kept.size + 1, dtype=np.int32)
    return _lookup(numbers, blob_ids), int(kept.size)


def _candidates(
    labels: np.ndarray,
    image: np.ndarray,
    *,
    min_sigmas: float,
    min_area_px: int,
    join_px: int,
    min_share: float,
    _scales: BlobScales | None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`two_faced_candidates` (its inputs checked) as the connected components of
    the joined regions, (M, N) int32, and the ids of the candidates among them, ascending
    (numbered 1.. in that order they are the candidates' blobs)."""
    if labels.shape != image.shape or image.ndim != 2:
        raise ValueError(
            f"labels and image must be 2-D of one shape, got {labels.shape} and {image.shape}"
        )
    if image.dtype != np.uint8:
        raise TypeError(f"image must be uint8, got {image.dtype}")
    if not min_sigmas > 0:
        raise ValueError(f"min_sigmas must be > 0, got {min_sigmas}")
    if join_px < 1 or min_area_px < 1:
        raise ValueError(
            f"join_px and min_area_px must be >= 1, got {join_px} and {min_area_px}"
        )
    if not 0 <= min_share <= 0.5:
        raise ValueError(f"min_share must be in [0, 0.5], got {min_share}")
    if _scales is None or _scales.image is not image:
        _scales = blob_scales(image)
    z, ring, free = _free_contrast(labels, _scales, margin_px=_MARGIN_PX, tile_px=_TILE_PX)
    outside = ~ring
    dark = _grow((z <= -min_sigmas) & outside, _scales.fine, free, _GROW_PX, sign=-1.0)
    light = _grow((z >= min_sigmas) & outside, _scales.fine, free, _GROW_PX, sign=1.0)
    kernel = np.ones((2 * join_px + 1, 2 * join_px + 1), np.uint8)
    between = (
        cv2.dilate(dark.view(np.uint8), kernel).view(bool)
        & cv2.dilate(light.view(np.uint8), kernel).view(bool)
        & free
        & outside
    )
    joined = dark | light | between
    n_blobs, blob_ids = cv2.connectedComponents(joined.view(np.uint8), connectivity=8)
    if n_blobs == 1:
        return blob_ids, np.zeros(0, np.int64)
    # per blob: pixels, dark pixels, light pixels, ring pixels (one compiled pass for four
    # bincounts of masked copies; ``test_two_face_blobs.py`` compares them)
    counts = np.zeros((4, n_blobs), np.int64)
    _face_counts(
        np.ascontiguousarray(blob_ids),
        np.ascontiguousarray(dark),
        np.ascontiguousarray(light),
        np.ascontiguousarray(ring),
        counts,
    )
    pixels, darks, lights, ringed = counts
    keep = (
        (pixels >= min_area_px)
        & (darks >= min_share * pixels)
        & (lights >= min_share * pixels)
        & (ringed == 0)
    )
    keep[0] = False
    return blob_ids, np.flatnonzero(keep)


def add_two_faced_blobs(
    labels: np.ndarray,
    image: np.ndarray,
    *,
    min_sigmas: float,
    min_area_px: int = 30,
    join_px: int = _JOIN_PX,
    min_share: float = _MIN_SHARE,
    min_solidity: float = _MIN_SOLIDITY,
    _scales: BlobScales | None = None,
) -> tuple[np.ndarray, int]:
    """Rule R8c: add blobs made of a lit and a shaded face side by side (module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects (after R8b); left unchanged where it is not 0.
    image : (M, N) ndarray of uint8
        Reference gray image.
    min_sigmas, min_area_px, join_px, min_share, _scales
        As :func:`two_faced_candidates`.
    min_solidity : float
        In ``[0, 1]``; R8's solidity test of a blob.

    Returns
    -------
    labels : (M, N) ndarray of int32
        The objects, then the added blobs numbered on from ``labels.max() + 1`` (the
        input itself when none is added and it is int32).
    added : int
    """
    if not 0 <= min_solidity <= 1:
        raise ValueError(f"min_solidity must be in [0, 1], got {min_solidity}")
    labels = labels.astype(np.int32, copy=False)
    blob_ids, kept = _candidates(
        labels,
        image,
        min_sigmas=min_sigmas,
        min_area_px=min_area_px,
        join_px=join_px,
        min_share=min_share,
        _scales=_scales,
    )
    # the candidates by their component ids (numbered 1.. in this order they are
    # two_faced_candidates' blobs: the same boxes and regions, no lookup of the frame);
    # labels copied once a blob is added (none added: labels as they came, as other
    # rules that change nothing return them)
    out = labels
    rows, cols = labels.shape
    boxes = _object_boxes(blob_ids, int(kept[-1])) if kept.size else None
    next_id = int(labels.max()) + 1
    added = 0
    for blob in kept:
        y0, y1, x0, x1 = boxes[blob].tolist()
        r0, r1 = max(y0 - _PAD_PX, 0), min(y1 + 1 + _PAD_PX, rows)
        c0, c1 = max(x0 - _PAD_PX, 0), min(x1 + 1 + _PAD_PX, cols)
        region = blob_ids[r0:r1, c0:c1] == blob
        if not _is_solid(region, min_solidity=min_solidity):
            continue
        if out is labels:
            out = labels.copy()
        out[r0:r1, c0:c1][region] = next_id
        next_id += 1
        added += 1
    return out, added


@njit(cache=True)
def _face_counts(blob_ids, dark, light, ring, counts):  # pragma: no cover - numba
    rows, cols = blob_ids.shape
    # blob 0 (most pixels) counted in registers: ``counts[0, 0] += 1`` on most pixels makes
    # each wait for the last store (see stages._regions._drop_specks)
    ground = ground_dark = ground_light = ground_ring = 0
    for y in range(rows):
        for x in range(cols):
            k = blob_ids[y, x]
            # the masks added as 0 or 1: no branch to mispredict
            if k == 0:
                ground += 1
                ground_dark += dark[y, x]
                ground_light += light[y, x]
                ground_ring += ring[y, x]
                continue
            counts[0, k] += 1
            counts[1, k] += dark[y, x]
            counts[2, k] += light[y, x]
            counts[3, k] += ring[y, x]
    counts[0, 0] += ground
    counts[1, 0] += ground_dark
    counts[2, 0] += ground_light
    counts[3, 0] += ground_ring
