"""Rule R8: compact blobs -- rocks no threshold reached, found at their own scale.

On lava the ground is a fine-grained blotchy texture: its pixel spread is wide, so the
sector thresholds (:mod:`stages._continuity`, ``band_sigmas`` bands from the ground) sit
far out (gray 14-40 on ground at 76) and miss small rocks only 20-45 levels darker or
lighter than the ground; the noisy-height vote (:mod:`stages._height_vote`) then removes
what is left as flat (rocks 1.5-3 cm high read 0.2-0.9 cm under 0.8 cm of height noise).
Of the catalog's 185 missed rocks 128 were touched by no object at all.

At a rock's scale the texture averages out more than a compact rock does, so R8 looks
for compact blobs at that scale, after every other rule but R8b
(:mod:`stages._height_blobs`), among the pixels no object (nor R8c's two-faced blob,
:mod:`stages._two_face_blobs`) claims (:func:`add_compact_blobs`):

1. the image is smoothed (Gaussian, ``sigma_px`` 1.5) and the ground level taken as a
   median over ``ground_px`` (41) pixels (at half resolution); their difference, divided
   by the ground's robust spread of that difference (1.4826 x its median magnitude over
   tiles of ``tile_px`` (50), objects and a ``margin_px`` (3) ring around them left out,
   interpolated), is the contrast at scale;
2. cores are the connected pixels at least ``min_sigmas`` spreads darker (or lighter)
   than the ground, outside objects and their ring;
3. each core grows into the free pixels within ``grow_px`` (10) of it whose own contrast
   (Gaussian 0.8) is at least half the core's mean contrast (of the strongest core in
   reach), connected to a core; holes are filled, blotches hanging off by a pixel or two
   are cut (a 3x3 opening) and overlapping regions of one side are one region;
4. a region is added as an object when it keeps off every object and its ring, holds at
   least ``min_area_px`` pixels, is solid (pixels over the area of their convex hull plus
   half its outline, at least ``min_solidity`` 0.88), thick (at least ``min_interior``
   0.35 of its pixels survive a 3x3 erosion; the frame's edge erodes nothing), stands
   alone (the mean contrast on its side 3-5 px around it is at most ``max_ring`` 0.1 of its
   own: a blotch in a cluster of blotches does not), and, when lighter than the ground,
   peaks at least ``light_factor`` (1.375) times ``min_sigmas`` (lava's near ground has
   light squiggles, more compact than its dark ones).

The ring around every object keeps the cast shadow of a found lit rock (dark, flat,
touching it) and the other half of a found rock out: R8 only adds rocks nothing touched.
Heights play no part: on lava's candidates the mean height over the blob minus its
surroundings had median 0.3 cm on rocks and 0.1 cm on ground blotches, quartiles
overlapping (-0.1..0.8 cm against -0.1..0.4 cm).

R8 is off by default (``blob_sigmas = 0`` of :func:`stages.segment.segment_image`) and on
in the lava catalog (``blob_sigmas = 4``). With ``benchmarks/bench_segment.py --rundir DIR
--set blob_sigmas=4`` against the same without ``--set`` (each run's depth products,
segmented again), object F1 on lava: catalog 0.795 -> 0.812 (tp 522 -> 546, fp 84 ->
92), seeds 2-5 0.778 -> 0.799, 0.804 -> 0.814, 0.809 -> 0.817, 0.794 -> 0.811
(the matched rocks' mean IoU drops by at most 0.005: the blobs' outlines are rougher).
Of the true rocks R8 adds over the five runs, 43 of 112 lie in the frame's right-hand 40
px, where the depth stage has no disparity and R3b keeps only clear objects.

Switched on elsewhere: lab 0.943 -> 0.947 and seed 2 0.899 -> 0.926 (more rocks found,
precision down 0.02), but mojave 0.905 -> 0.883 (seeds 2, 3: 0.915 -> 0.898, 0.893 ->
0.873) and dunes gains 1-9 false rocks on 6 of its 7 runs (catalog precision 1.0 ->
0.25) -- hence a catalog setting.

Variants (mean F1 gain over the five lava runs / smallest gain): as above +0.015 /
+0.008; 3.5 spreads +0.013 / -0.003 (twice the false rocks), 4.5 +0.012 / +0.007;
without the solidity test +0.013 / +0.002, 0.92 +0.012 / +0.007; without the light
factor +0.013 / +0.007, lighter blobs never +0.012 / +0.006; ``sigma_px`` 1 or 2,
``ground_px`` 61, ``grow_px`` 6 or 14, ``margin_px`` 1 or 5 within 0.002 of the chosen
settings (``ground_px`` 31: +0.013 / +0.002); without the isolation test within 0.001 on
lava, but switched on there dunes runs gain 1-5 and mojave runs 9-15 more false rocks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit

from ._regions import _box_window, _extend_box, _row_ends
from ._sectors import sector_edges
from ._select import _kth

__all__ = ["BlobScales", "add_compact_blobs", "blob_scales"]

# Gaussian scale of the blob search, px: a 30-150 px rock keeps its contrast, 2-5 px
# blotches lose most of theirs
_SIGMA_PX = 1.5
# median window of the ground level, px (odd): wider than the rocks R8 looks for
_GROUND_PX = 41
# tiles of the spread estimate, px: the texture coarsens towards the camera
_TILE_PX = 50
# ring around objects kept out of the cores and the spread, px
_MARGIN_PX = 3
# farthest growth from a core, px
_GROW_PX = 10
# share of the core's contrast a pixel needs to join its region
_GROW_SHARE = 0.5
_MIN_SOLIDITY = 0.88
_MIN_INTERIOR = 0.35
_MAX_RING = 0.1
# the isolation ring: pixels this many px from a region, inclusive
_RING_PX = (3, 5)
_LIGHT_FACTOR = 1.375
# a tile with fewer free pixels sampled (every other row and column) takes the frame's
# median spread
_MIN_TILE_PX = 12
# floor of the spread, gray levels (a flat synthetic ground has none)
_MIN_SPREAD = 0.5


def add_compact_blobs(
    labels: np.ndarray,
    image: np.ndarray,
    *,
    min_sigmas: float,
    min_area_px: int = 30,
    sigma_px: float = _SIGMA_PX,
    ground_px: int = _GROUND_PX,
    tile_px: int = _TILE_PX,
    margin_px: int = _MARGIN_PX,
    grow_px: int = _GROW_PX,
    min_solidity: float = _MIN_SOLIDITY,
    min_interior: float = _MIN_INTERIOR,
    max_ring: float = _MAX_RING,
    light_factor: float = _LIGHT_FACTOR,
    _scales: BlobScales | None = None,
) -> tuple[np.ndarray, int]:
    """Rule R8: add compact blobs darker or lighter than the ground at their own scale.

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects; left unchanged where it is not 0.
    image : (M, N) ndarray of uint8
        Reference gray image.
    min_sigmas : float
        ``> 0``: contrast at scale of a core, in spreads of the ground at that scale.
    min_area_px : int
        ``>= 1``; smaller regions are not added.
    sigma_px : float
        ``> 0``; Gaussian scale of the search, px.
    ground_px : int
        Odd, ``>= 3``; median window of the ground level, px.
    tile_px : int
        ``>= 8``; tiles of the spread estimate, px.
    margin_px, grow_px : int
        ``>= 0``; ring kept around objects, and farthest growth from a core, px.
    min_solidity, min_interior, max_ring : float
        In ``[0, 1]``; shape and isolation tests of a region (module docstring).
    light_factor : float
        ``>= 1``; lighter blobs need ``light_factor * min_sigmas``.
    _scales : BlobScales, optional
        :func:`blob_scales` of this very ``image`` (R8 and R8b share them); computed here
        when absent or made of another image or settings.

    Returns
    -------
    labels : (M, N) ndarray of int32
        The objects, then the added blobs numbered on from ``labels.max() + 1`` (the
        input itself when none is added and it is int32).
    added : int
    """
    if labels.shape != image.shape or image.ndim != 2:
        raise ValueError(
            f"labels and image must be 2-D of one shape, got {labels.shape} and {image.shape}"
        )
    if image.dtype != np.uint8:
        raise TypeError(f"image must be uint8, got {image.dtype}")
    if not min_sigmas > 0 or not sigma_px > 0 or not light_factor >= 1:
        raise ValueError(
            "need min_sigmas > 0, sigma_px > 0 and light_factor >= 1, got "
            f"{min_sigmas}, {sigma_px} and {light_factor}"
        )
    if ground_px < 3 or ground_px % 2 == 0 or tile_px < 8 or min(margin_px, grow_px) < 0:
        raise ValueError(
            "need an odd ground_px >= 3, tile_px >= 8, margin_px and grow_px >= 0, got "
            f"{ground_px}, {tile_px}, {margin_px} and {grow_px}"
        )
    if min_area_px < 1:
        raise ValueError(f"min_area_px must be >= 1, got {min_area_px}")
    if not all(0 <= value <= 1 for value in (min_solidity, min_interior, max_ring)):
        raise ValueError(
            "min_solidity, min_interior and max_ring must be in [0, 1], got "
            f"{min_solidity}, {min_interior} and {max_ring}"
        )
    labels = labels.astype(np.int32, copy=False)
    if _scales is None or _scales.key != (sigma_px, ground_px) or _scales.image is not image:
        _scales = blob_scales(image, sigma_px=sigma_px, ground_px=ground_px)
    fine = _scales.fine
    z, ring, free = _free_contrast(labels, _scales, margin_px=margin_px, tile_px=tile_px)
    added = 0
    next_id = int(labels.max()) + 1
    # labels copied once a blob is added (none added: labels as they came, as other rules
    # that change nothing return them)
    out = labels
    outside = ~ring
    for sign in (-1.0, 1.0):
        # contrast on this side of the ground positive
        # (-z >= min_sigmas is z <= -min_sigmas: negation is exact, and the helpers take
        # the sign rather than whole-frame negated copies)
        cores = ((z <= -min_sigmas) if sign < 0 else (z >= min_sigmas)) & outside
        grown = _grow(cores, fine, free, grow_px, sign=sign)
        # overlapping regions of one side are one blob
        n_blobs, blob_ids = cv2.connectedComponents(grown.view(np.uint8), connectivity=8)
        if n_blobs == 1:
            continue
        # the interior test for all blobs at once: one blob's 3x3 neighbourhood holds no
        # other blob's pixels (they would be one blob), and the frame's edge erodes nothing
        interior = cv2.erode(grown.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        peaks, areas, touching, inner, boxes = _blob_statistics(
            blob_ids, n_blobs, z, ring, interior, sign=sign
        )
        need = min_sigmas * (light_factor if sign > 0 else 1.0)
        candidate = (
            (peaks >= need)
            & ~touching
            & (areas >= min_area_px)
            & (inner >= min_interior * areas)
        )
        for blob in np.flatnonzero(candidate):
            if blob == 0 or boxes[blob, 1] < boxes[blob, 0]:
                continue
            box = _box_window(boxes[blob])
            # the box with room for the isolation ring
            far = _RING_PX[1]
            r0, r1 = max(box[0].start - far, 0), box[0].stop + far
            c0, c1 = max(box[1].start - far, 0), box[1].stop + far
            region = blob_ids[r0:r1, c0:c1] == blob
            if not _is_solid(region, min_solidity=min_solidity) or not _stands_alone(
                region, fine[r0:r1, c0:c1], free[r0:r1, c0:c1], max_ring=max_ring, sign=sign
            ):
                continue
            if out is labels:
                out = labels.copy()
            out[r0:r1, c0:c1][region] = next_id
            next_id += 1
            added += 1
    return out, added


@dataclass(frozen=True)
class BlobScales:
    """The image-only maps of R8's search (step 1), computed once per frame.

    Attributes
    ----------
    image : (M, N) ndarray of uint8
        The image they were made of (compared by identity).
    key : tuple of (float, int)
        ``(sigma_px, ground_px)``.
    at_scale, fine : (M, N) ndarray of float32
        The image smoothed at ``sigma_px`` and at 0.8 px, minus the ground level.
    tiles : dict
        The last spread estimate's pixels and tile spreads (:func:`_tile_spread`): R8b's
        search measures again only the tiles whose free pixels R8 changed.
    """

    image: np.ndarray
    key: tuple[float, int]
    at_scale: np.ndarray
    fine: np.ndarray
    tiles: dict = field(default_factory=dict)


def blob_scales(
    image: np.ndarray, *, sigma_px: float = _SIGMA_PX, ground_px: int = _GROUND_PX
) -> BlobScales:
    """R8's contrast maps of ``image`` (uint8, 2-D), for :func:`add_compact_blobs` calls on
    one frame (R8, then R8b's candidates) to share; settings as there."""
    pixels = image.astype(np.float32)
    ground = _ground_level(image, ground_px)
    at_scale = cv2.GaussianBlur(pixels, (0, 0), sigma_px) - ground
    # the rock's own gray, only lightly smoothed: its outline, not the blob's
    fine = cv2.GaussianBlur(pixels, (0, 0), 0.8) - ground
    return BlobScales(image=image, key=(sigma_px, ground_px), at_scale=at_scale, fine=fine)


def _blob_statistics(
    blob_ids: np.ndarray,
    n_blobs: int,
    z: np.ndarray,
    ring: np.ndarray,
    interior: np.ndarray,
    *,
    sign: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per blob 0..n_blobs-1: peak of ``sign * z`` (-inf for 0), pixels, whether a ``ring``
    pixel is its, its ``interior`` pixels and its inclusive (y0, y1, x0, x1) box as
    :func:`stages._regions._object_boxes` gives it (blob 0: absent, y1 < y0); one compiled
    pass instead of an ``ufunc.at``, three ``bincount`` of masked copies and the boxes'
    pass (``test_blobs.py`` compares them)."""
    peaks = np.full(n_blobs, -np.inf)
    counts = np.zeros((3, n_blobs), np.int64)
    boxes = np.empty((n_blobs, 4), np.int64)
    boxes[:, 0::2] = np.iinfo(np.int64).max
    boxes[:, 1::2] = -1
    _blob_pass(
        blob_ids, np.ascontiguousarray(z), float(sign), ring, interior, peaks, counts, boxes
    )
    return peaks, counts[0], counts[1] > 0, counts[2], boxes


@njit(cache=True)
def _blob_pass(blob_ids, z, sign, ring, interior, peaks, counts, boxes):  # pragma: no cover
    rows, cols = blob_ids.shape
    # blob 0's ring count in a register: ``counts[1, 0] += 1`` on most ring pixels makes
    # each wait for the last store
    ground_ring = 0
    for y in range(rows):
        for x in range(cols):
            k = blob_ids[y, x]
            if k == 0:
                if ring[y, x]:
                    ground_ring += 1
                continue
            if ring[y, x]:
                counts[1, k] += 1
            # sign +-1: an exact negation, as of a negated copy
            value = sign * z[y, x]
            if value > peaks[k]:
                peaks[k] = value
            counts[0, k] += 1
            if interior[y, x]:
                counts[2, k] += 1
            _extend_box(boxes, k, y, x)
    counts[1, 0] += ground_ring


def _ground_level(image: np.ndarray, ground_px: int) -> np.ndarray:
    """Median over ``ground_px`` pixels, taken at half resolution (a quarter of the cost)."""
    rows, cols = image.shape
    if min(rows, cols) < 2 * ground_px:
        return cv2.medianBlur(image, ground_px).astype(np.float32)
    half = cv2.resize(image, ((cols + 1) // 2, (rows + 1) // 2), interpolation=cv2.INTER_AREA)
    level = cv2.medianBlur(half, ground_px // 2 | 1)
    return cv2.resize(level, (cols, rows), interpolation=cv2.INTER_LINEAR).astype(np.float32)


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """A bool mask dilated by a square of ``radius``; the mask's bytes are the uint8 image
    and the 0/1 result the bool mask (no converted copies)."""
    mask = np.ascontiguousarray(mask, dtype=bool)
    if radius == 0:
        return mask.copy()
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(mask.view(np.uint8), kernel).view(bool)


def _free_contrast(
    labels: np.ndarray, scales: BlobScales, *, margin_px: int, tile_px: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-2's maps (module doc), shared by R8 and R8c: the contrast at scale in
    ground spreads, the objects' ``margin_px`` ring (objects included) and the free pixels.

    Returns
    -------
    z : (M, N) ndarray of float
    ring, free : (M, N) ndarray of bool
    """
    taken = labels > 0
    ring = _dilate(taken, margin_px)
    spread = _tile_spread(scales.at_scale, ~ring, tile_px, _memo=scales.tiles)
    np.maximum(spread, _MIN_SPREAD, out=spread)
    if scales.at_scale.dtype != spread.dtype:
        return scales.at_scale / spread, ring, ~taken
    # in place in the resized spread map (a fresh array of the maps' float32): no two
    # more whole-frame arrays
    return np.divide(scales.at_scale, spread, out=spread), ring, ~taken


def _tile_spread(
    values: np.ndarray, use: np.ndarray, tile_px: int, *, _memo: dict | None = None
) -> np.ndarray:
    """1.4826 x MAD of ``values`` over ``use`` per tile, bilinear between tile centres.

    ``_memo`` (kept with one ``values`` map, empty at first) holds the last call's ``use``
    and tile spreads: a tile none of whose ``use`` pixels changed keeps its spread.
    """
    rows, cols = values.shape
    row_edges = sector_edges(rows, max(1, round(rows / tile_px)))
    col_edges = sector_edges(cols, max(1, round(cols / tile_px)))
    grid = np.full((row_edges.size - 1, col_edges.size - 1), np.nan, np.float32)
    known = None
    if _memo is not None and _memo.get("tile_px") == tile_px:
        # per tile: did any of its pixels change -- the tiles of the (few hundred) changed
        # pixels; summing the whole frame's differences per tile cost 0.5 ms, and so does
        # a 2-D np.nonzero (the flat one a tenth)
        changed_rows, changed_cols = np.divmod(np.flatnonzero(use != _memo["use"]), cols)
        changed = np.zeros(grid.shape, bool)
        changed[
            np.searchsorted(row_edges, changed_rows, side="right") - 1,
            np.searchsorted(col_edges, changed_cols, side="right") - 1,
        ] = True
        known = _memo["grid"]
    if known is None:
        todo = np.ones(grid.shape, bool)
    else:
        # the unchanged tiles copied at once; the loop visits the (few) changed ones
        todo = changed
        grid[~changed] = known[~changed]
    # the tiles' spreads in one compiled pass (per tile: a sample, its absolute values and
    # np.partition cost 10-15 us, 1.2 ms for a frame's 100 tiles)
    _tile_mads(
        np.ascontiguousarray(values),
        np.ascontiguousarray(use),
        row_edges,
        col_edges,
        todo,
        values.dtype.type(1.4826),
        grid,
    )
    if _memo is not None:
        _memo.update(tile_px=tile_px, use=use.copy(), grid=grid.copy())
    if np.isnan(grid).all():
        grid[:] = _MIN_SPREAD
    empty = np.isnan(grid)
    if empty.any():
        # (nanmedian costs 0.1 ms even when no tile is empty)
        grid[empty] = np.nanmedian(grid)
    return cv2.resize(grid, (cols, rows), interpolation=cv2.INTER_LINEAR)


@njit(cache=True)
def _tile_mads(values, use, row_edges, col_edges, todo, scale, grid):  # pragma: no cover
    """``grid[i, j] = scale * median`` of the absolute ``values`` over ``use`` on every other
    row and column of each tile ``todo`` says (the values are already measured from the
    ground: MAD about 0); a tile with fewer than ``_MIN_TILE_PX`` such pixels is left.
    The median is the upper middle order statistic, as ``np.partition`` selects it, and
    ``scale`` has the values' dtype: numpy's product of a Python float and a float32."""
    largest = 0
    for i in range(row_edges.size - 1):
        for j in range(col_edges.size - 1):
            rows = (row_edges[i + 1] - row_edges[i] + 1) // 2
            cols = (col_edges[j + 1] - col_edges[j] + 1) // 2
            largest = max(largest, rows * cols)
    sample = np.empty(largest, values.dtype)
    for i in range(row_edges.size - 1):
        for j in range(col_edges.size - 1):
            if not todo[i, j]:
                continue
            # every other row and column: the spread of tens of thousands of pixels is
            # stable on a quarter of them
            n = 0
            for y in range(row_edges[i], row_edges[i + 1], 2):
                for x in range(col_edges[j], col_edges[j + 1], 2):
                    if use[y, x]:
                        sample[n] = abs(values[y, x])
                        n += 1
            if n >= _MIN_TILE_PX:
                grid[i, j] = scale * _kth(sample[:n], n // 2)


def _grow(
    cores: np.ndarray, contrast: np.ndarray, free: np.ndarray, grow_px: int, *, sign: float = 1.0
) -> np.ndarray:
    """The union of the cores' regions (module docstring, step 3), all cores at once;
    contrast on the blobs' side is ``sign * contrast`` (+-1)."""
    at, owner, counts, sums = _core_sums(cores, contrast)
    if counts.size == 1:
        return np.zeros(cores.shape, bool)
    # a sum of negated values is the negated sum (rounding is symmetric)
    level = (sign * sums) / np.maximum(counts, 1)
    level[0] = 0.0
    # each pixel within grow_px of a core needs half the contrast of the strongest one
    # whole gray levels: a uint8 dilation is several times faster than a float one
    # (level 0, outside the cores, is 0)
    levels = np.zeros(cores.shape, np.uint8)
    levels.ravel()[at] = np.clip(np.round(level), 0, 255).astype(np.uint8)[owner]
    reach = cv2.dilate(levels, np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8))
    filled = _seeded_regions(cores, reach, contrast, free, sign=sign, at=at)
    # blotches of ground texture touching a rock hang off it by a pixel or two
    opened = cv2.morphologyEx(filled.view(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return opened.view(bool)  # 0/1 bytes


def _core_sums(
    cores: np.ndarray, contrast: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cores' 8-connected components: their pixels' flat indices in raster order, each
    pixel's core (1..), and per core 0..n its pixels and its sum of ``contrast`` (core 0:
    none, 0). One compiled pass over the (few) core pixels instead of the whole frame's
    connected components, their sums and a lookup; the sums are added in raster order,
    the same floats as :func:`stages._regions._label_sums` (``test_blobs.py`` compares;
    the cores may be numbered otherwise)."""
    cores = np.ascontiguousarray(cores)
    # the core pixels found by numpy's vectorised search, not a compiled scan
    at = np.flatnonzero(cores).astype(np.int64, copy=False)
    return _core_pass(cores, np.ascontiguousarray(contrast), at)


@njit(cache=True)
def _core_pass(cores, contrast, at):  # pragma: no cover - numba
    rows, cols = cores.shape
    n = at.size
    seen = np.zeros((rows, cols), np.bool_)
    # read only where seen
    ids = np.empty((rows, cols), np.int32)
    stack = np.empty(n, np.int64)
    count = 0
    for t in range(n):
        y, x = divmod(at[t], cols)
        if seen[y, x]:
            continue
        count += 1
        seen[y, x] = True
        ids[y, x] = count
        stack[0] = at[t]
        top = 1
        while top > 0:
            top -= 1
            py, px = divmod(stack[top], cols)
            for ny in range(max(py - 1, 0), min(py + 2, rows)):
                for nx in range(max(px - 1, 0), min(px + 2, cols)):
                    if cores[ny, nx] and not seen[ny, nx]:
                        seen[ny, nx] = True
                        ids[ny, nx] = count
                        stack[top] = ny * cols + nx
                        top += 1
    owner = np.empty(n, np.int64)
    counts = np.zeros(count + 1, np.int64)
    sums = np.zeros(count + 1)
    for t in range(n):
        y, x = divmod(at[t], cols)
        k = ids[y, x]
        owner[t] = k
        counts[k] += 1
        sums[k] += contrast[y, x]
    return at, owner, counts, sums


def _seeded_regions(
    cores: np.ndarray,
    reach: np.ndarray,
    contrast: np.ndarray,
    free: np.ndarray,
    *,
    sign: float = 1.0,
    at: np.ndarray | None = None,
) -> np.ndarray:
    """The 8-connected parts of the pixels ``reach`` can take (``reach > 0``, ``free`` and
    ``sign * contrast >= 0.5 * reach``, in float32) that hold a pixel of ``cores``, each
    with its pockets filled: the pixels of a box grown by one pixel around the part that
    4-steps from its edge through other pixels cannot reach, as flooding the whole frame's
    background from its border would leave them (``test_blobs.py`` compares both).

    One compiled pass: each part is walked from its cores (the reach test read at the
    pixels the walk meets), then flooded in its box, instead of the whole-frame reach
    map, its connected components and the seeded parts' lookup (``test_blobs.py``
    compares that composition). ``at``: the flat indices of the core pixels in raster
    order when known (:func:`_core_sums` gives them; no scan of the frame for them).
    """
    filled = np.zeros(reach.shape, bool)
    if at is None:
        at = np.flatnonzero(cores)
    _seeded_pass(
        np.ascontiguousarray(at, dtype=np.int64),
        np.ascontiguousarray(reach),
        np.ascontiguousarray(contrast, dtype=np.float32),
        np.float32(sign),
        np.ascontiguousarray(free),
        filled,
    )
    return filled


@njit(cache=True)
def _seeded_pass(at, reach, contrast, sign, free, filled):  # pragma: no cover - numba
    share = np.float32(_GROW_SHARE)
    rows, cols = reach.shape
    # ``filled`` is the only whole-frame map (no map of part ids: zeroing a 1 MB one cost
    # as much as the walks). A pixel filled before is never walked again: two parts are
    # never 8-adjacent, and a part 8-adjacent to another's pocket lies wholly in it (its
    # diagonal steps pass pixels next to it, so not the other part's), already filled.
    # The part's pixels, walked breadth-first, stay in ``queue[:tail]`` for its pockets
    queue = np.empty(rows * cols + 2 * (rows + cols) + 8, np.int64)
    # the core pixels in raster order: parts numbered as a scan of the frame meets them
    for t in range(at.size):
        sy, sx = divmod(at[t], cols)
        if filled[sy, sx]:
            continue
        r = reach[sy, sx]
        # the reach test (see _seeded_regions), at this pixel
        if not (r > 0 and free[sy, sx] and sign * contrast[sy, sx] >= share * np.float32(r)):
            continue
        filled[sy, sx] = True
        y0, y1, x0, x1 = sy, sy, sx, sx
        queue[0] = sy * cols + sx
        head, tail = 0, 1
        while head < tail:
            y, x = divmod(queue[head], cols)
            head += 1
            y0, y1 = min(y0, y), max(y1, y)
            x0, x1 = min(x0, x), max(x1, x)
            for ny in range(max(y - 1, 0), min(y + 2, rows)):
                for nx in range(max(x - 1, 0), min(x + 2, cols)):
                    if filled[ny, nx]:
                        continue
                    r = reach[ny, nx]
                    if (
                        r > 0
                        and free[ny, nx]
                        and sign * contrast[ny, nx] >= share * np.float32(r)
                    ):
                        filled[ny, nx] = True
                        queue[tail] = ny * cols + nx
                        tail += 1
        # the part's pockets: its box grown by a pixel, flooded
        # from that edge through 4-steps over pixels not the part's
        top_row, left = y0 - 1, x0 - 1
        height, width = y1 - y0 + 3, x1 - x0 + 3
        mine = np.zeros((height, width), np.bool_)
        for u in range(tail):
            y, x = divmod(queue[u], cols)
            mine[y - top_row, x - left] = True
        outside = np.zeros((height, width), np.bool_)
        n_stack = 0
        for i in range(height):
            for j in range(width):
                if i == 0 or j == 0 or i == height - 1 or j == width - 1:
                    outside[i, j] = True
                    queue[n_stack] = i * width + j
                    n_stack += 1
        while n_stack > 0:
            n_stack -= 1
            i, j = divmod(queue[n_stack], width)
            for ni, nj in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
                if 0 <= ni < height and 0 <= nj < width and not outside[ni, nj]:
                    if not mine[ni, nj]:
                        outside[ni, nj] = True
                        queue[n_stack] = ni * width + nj
                        n_stack += 1
        for i in range(1, height - 1):
            for j in range(1, width - 1):
                if not outside[i, j]:
                    filled[top_row + i, left + j] = True


def _is_solid(region: np.ndarray, *, min_solidity: float) -> bool:
    """The solidity test of one region (module docstring, step 4)."""
    # the hull of each row's end pixels: the same vertex list as of the region's outline
    # (see stages._regions._solidity; ``test_blobs.py`` compares), a third of the cost
    ends, pixels = _row_ends(np.ascontiguousarray(region))
    hull = cv2.convexHull(ends)
    # the pixel area of the hull: its polygon area plus half its outline
    hull_px = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1
    return pixels >= min_solidity * hull_px


def _stands_alone(
    region: np.ndarray, contrast: np.ndarray, free: np.ndarray, *, max_ring: float, sign: float
) -> bool:
    """The isolation test of one region (module docstring, step 4), on ``sign * contrast``
    (+-1: the mean of negated values is the negated mean)."""
    near, far = _RING_PX
    ring = _dilate(region, far) & ~_dilate(region, near - 1) & free
    own = sign * float(contrast[region].mean())
    if not ring.any():
        return True
    return sign * float(contrast[ring].mean()) <= max_ring * max(own, 1.0)
