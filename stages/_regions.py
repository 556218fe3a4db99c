"""From thresholds to labelled objects, split at depth edges (rule R4).

Intensity: a pixel is object when its gray level is below the interpolated low threshold or
above the high one (:func:`threshold_mask`). :func:`label_objects` then fills holes (background
pockets enclosed by object pixels), optionally splits components at depth discontinuities,
drops specks smaller than ``min_area_px`` and numbers the objects ``1..n`` densely.

Depth rules R0-R3 (height above ground: local ground, raised, flat, no depth) are in
:mod:`stages._depth_rules` (the noisy-height vote R2-R2d in :mod:`stages._height_vote`);
the ones that act on objects are R4 here, R5-R5c (streaks, ripple fields) in
:mod:`stages._texture_rules` and R6-R7c (attached shadows, halves and faces of rocks) in
:mod:`stages._rock_parts`:

* **R4 split** -- a pixel where the (median-smoothed) disparity drops by more than
  ``split_disparity_px`` towards a 4-neighbour is a depth edge: the surface behind an
  occluding boundary. An object made of two or more cores (4-connected pieces of at least
  ``min_area_px`` after removing its depth edges) is split into those cores; every other pixel
  of the object goes to its nearest core. Touching rocks at different ranges thus become
  separate objects.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit
from scipy.ndimage import distance_transform_edt

#: Threshold bands from the ground level beyond which an object is clear in gray level
#: without further evidence (R3b, R5b): ground texture that crosses a threshold stays
#: close to it (on the catalog frames 90 % of the texture objects lie within 1.9 bands on
#: mojave and lava, 2.4 on dunes), true rocks lie at a median 2-2.6 bands.
CLEAR_CONTRAST = 2.5

__all__ = [
    "CLEAR_CONTRAST",
    "threshold_mask",
    "fill_holes",
    "depth_edges",
    "label_objects",
]


def _coerce_mask(mask: np.ndarray, name: str = "mask") -> np.ndarray:
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(mask).__name__}")
    if mask.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {mask.shape}")
    if mask.dtype != bool:
        raise TypeError(f"{name} must be a bool array, got dtype {mask.dtype}; use mask != 0")
    return mask


def threshold_mask(image: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Object pixels: darker than ``low`` or lighter than ``high``.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Reference gray image.
    low, high : (M, N) ndarray of float
        Interpolated thresholds (gray levels).

    Returns
    -------
    mask : (M, N) ndarray of bool
    """
    if image.shape != low.shape or image.shape != high.shape:
        raise ValueError(
            f"image {image.shape}, low {low.shape} and high {high.shape} must have one shape"
        )
    gray = image.astype(np.float32)
    return (gray < low) | (gray > high)


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Set background pockets not connected (4-connectivity) to the frame border to object.

    Parameters
    ----------
    mask : (M, N) ndarray of bool

    Returns
    -------
    filled : (M, N) ndarray of bool
    """
    mask = _coerce_mask(mask)
    padded = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    flood_mask = np.zeros((padded.shape[0] + 2, padded.shape[1] + 2), np.uint8)
    cv2.floodFill(padded, flood_mask, (0, 0), 2, flags=4)
    return padded[1:-1, 1:-1] != 2


def depth_edges(disparity: np.ndarray, *, jump_px: float) -> np.ndarray:
    """Pixels on the far side of a disparity drop larger than ``jump_px`` (4-neighbours).

    Parameters
    ----------
    disparity : (M, N) ndarray of float32
        Pixels, NaN where invalid (invalid pixels are never edges).
    jump_px : float
        Smallest disparity difference between 4-neighbours that counts as a discontinuity.

    Returns
    -------
    edges : (M, N) ndarray of bool
    """
    if jump_px <= 0:
        raise ValueError(f"jump_px must be > 0, got {jump_px}")
    d = np.asarray(disparity, dtype=np.float32)
    valid = np.isfinite(d)
    d = cv2.medianBlur(np.where(valid, d, np.float32(0.0)).astype(np.float32), 3)
    d = np.where(valid, d, np.float32(np.nan))
    edges = np.zeros(d.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        down_x = d[:, 1:] - d[:, :-1]  # > 0: right pixel nearer
        edges[:, :-1] |= down_x > jump_px
        edges[:, 1:] |= down_x < -jump_px
        down_y = d[1:, :] - d[:-1, :]
        edges[:-1, :] |= down_y > jump_px
        edges[1:, :] |= down_y < -jump_px
    return edges


def _dense_components(mask: np.ndarray, min_area_px: int, connectivity: int = 8) -> np.ndarray:
    """Connected components, specks removed, numbered 1..n."""
    # without OpenCV's statistics (bounding boxes, centroids): a quarter of the cost; the
    # areas are counted in the same compiled pass that renumbers
    count, labels = cv2.connectedComponents(
        mask.view(np.uint8), connectivity=connectivity, ltype=cv2.CV_32S
    )
    _drop_specks(labels, count, min_area_px)
    return labels


@njit(cache=True)
def _drop_specks(labels, count, min_area_px):  # pragma: no cover - numba
    """Renumber components ``1..count-1`` in place: under ``min_area_px`` pixels to 0, the
    others ``1..n`` in their order (``test_regions.py`` checks it against OpenCV's areas)."""
    rows, cols = labels.shape
    area = np.zeros(count, np.int64)
    # the ground (0) counted in a register: ``area[0] += 1`` on most pixels makes each
    # wait for the last store (several times slower)
    ground = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                ground += 1
            else:
                area[k] += 1
    area[0] = ground
    lookup = np.zeros(count, np.int32)
    kept = 0
    for k in range(1, count):
        if area[k] >= min_area_px:
            kept += 1
            lookup[k] = kept
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k != 0:  # the ground (most pixels) stays 0: no store
                labels[y, x] = lookup[k]


def _split_at_edges(labels: np.ndarray, edges: np.ndarray, min_area_px: int) -> np.ndarray:
    """Split objects holding several depth-separated cores; returns new (not dense) labels
    (of ``labels``' dtype, ids up to ``labels.max()`` plus the number of cores)."""
    # 4-connected cores: a one-pixel staircase of edge pixels must be a closed cut
    cores = _dense_components((labels > 0) & ~edges, min_area_px, connectivity=4)
    # parent object of each core (one compiled pass), and how many cores each object has
    parent = _core_parents(cores, labels)
    n_cores = parent.size - 1
    if n_cores < 2:
        return labels
    offset = int(labels.max())
    cores_per_object = np.bincount(parent[1:], minlength=offset + 1)
    split_objects = np.flatnonzero(cores_per_object >= 2)
    if split_objects.size == 0:
        return labels
    core_pixels = cores > 0
    # offset + a core's id stays below 2**31 (both count pixels)
    result = labels.copy()
    boxes = _object_boxes(labels, offset)
    h, w = labels.shape
    for k in split_objects:
        y0, y1, x0, x1 = boxes[k].tolist()
        # the object's own cores lie in its box: no pixel of it is farther from its nearest
        # core than from its nearest own one, at most ``reach`` (measured in the box), so a
        # crop that much larger holds every core that can be nearest (whole-frame transforms
        # cost 13 ms a frame on lava; the box's diagonal, the bound before, 7 ms on dunes).
        # The same indices as the whole frame's for the object's pixels: scipy's feature
        # transform (Maurer's) gives a pixel the nearest feature of its column (the upper
        # of two), then the leftmost of those nearest along its row -- all within reach,
        # and a site nearest somewhere is never removed, whatever lies beyond
        box = (slice(y0, y1 + 1), slice(x0, x1 + 1))
        own = core_pixels[box] & (parent[cores[box]] == k)
        reach = int(np.ceil(distance_transform_edt(~own)[labels[box] == k].max())) + 1
        ys = slice(max(0, y0 - reach), min(h, y1 + reach + 1))
        xs = slice(max(0, x0 - reach), min(w, x1 + reach + 1))
        # the nearest core's indices alone (the distances, worked out from them, unread)
        iy, ix = distance_transform_edt(
            ~core_pixels[ys, xs], return_distances=False, return_indices=True
        )
        nearest = cores[ys, xs][iy, ix]
        mine = (labels[ys, xs] == k) & (parent[nearest] == k)
        result[ys, xs][mine] = offset + nearest[mine]
    return result


def _core_parents(cores: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per core 0..n (``cores`` numbered 1..n densely, each inside one object of
    ``labels``): its object's id (core 0: 0), as ``parent[cores[cores > 0]] =
    labels[cores > 0]`` sets it, in one compiled pass (``test_regions.py`` compares)."""
    return _parents_pass(np.ascontiguousarray(cores), np.ascontiguousarray(labels))


@njit(cache=True)
def _parents_pass(cores, labels):  # pragma: no cover - numba
    rows, cols = cores.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            n = max(n, cores[y, x])
    parent = np.zeros(n + 1, np.int64)
    for y in range(rows):
        for x in range(cols):
            if cores[y, x] > 0:
                parent[cores[y, x]] = labels[y, x]
    return parent


def label_objects(
    mask: np.ndarray,
    *,
    min_area_px: int = 30,
    fill: bool = True,
    edges: np.ndarray | None = None,
) -> np.ndarray:
    """Label 8-connected objects of a mask.

    Parameters
    ----------
    mask : (M, N) ndarray of bool
        Object pixels.
    min_area_px : int
        ``>= 1``; objects (and split cores) smaller than this are dropped as specks.
    fill : bool
        Fill holes first (:func:`fill_holes`).
    edges : (M, N) ndarray of bool, optional
        Depth edges (:func:`depth_edges`); when given, objects are split at them (rule R4).

    Returns
    -------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects, dense.
    """
    mask = _coerce_mask(mask)
    if not isinstance(min_area_px, int | np.integer) or min_area_px < 1:
        raise ValueError(f"min_area_px must be an int >= 1, got {min_area_px!r}")
    if fill:
        mask = fill_holes(mask)
    labels = _dense_components(mask, min_area_px)
    if edges is not None:
        edges = _coerce_mask(edges, "edges")
        if edges.shape != mask.shape:
            raise ValueError(f"edges shape {edges.shape} differs from mask shape {mask.shape}")
        split = _split_at_edges(labels, edges, min_area_px)
        if split is not labels:
            labels = _renumber(split, min_area_px)
    return labels


def _lookup(table: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``table[labels]`` for a 1-D table and 2-D integer labels in its range, compiled:
    fancy indexing and ``np.take`` first convert the labels to ``intp`` (0.3-0.5 ms a
    frame per lookup; ``test_regions.py`` compares)."""
    if table.ndim != 1 or labels.ndim != 2 or labels.dtype.kind not in "iu":
        raise TypeError(
            f"need a 1-D table and 2-D integer labels, got {table.ndim}-D and "
            f"{labels.ndim}-D {labels.dtype}"
        )
    if labels.size and (labels.min() < 0 or labels.max() >= table.size):
        raise IndexError(f"labels must lie in [0, {table.size}), the table's range")
    out = np.empty(labels.shape, table.dtype)
    _lookup_pass(table, np.ascontiguousarray(labels), out)
    return out


@njit(cache=True)
def _lookup_pass(table, labels, out):  # pragma: no cover - numba
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            out[y, x] = table[labels[y, x]]


def _label_areas(labels: np.ndarray, count: int) -> np.ndarray:
    """Pixels of each label 0..count-1 (int64), as ``np.bincount(labels.ravel(),
    minlength=count)`` counts them for labels in that range, in one compiled pass without
    the bincount's conversion of the labels to ``intp`` (``test_regions.py`` compares)."""
    if labels.ndim != 2 or labels.dtype.kind not in "iu":
        raise TypeError(f"labels must be a 2-D integer array, got {labels.ndim}-D {labels.dtype}")
    if labels.size and (labels.min() < 0 or labels.max() >= count):
        raise IndexError(f"labels must lie in [0, {count})")
    areas = np.zeros(count, np.int64)
    _areas_pass(np.ascontiguousarray(labels), areas)
    return areas


@njit(cache=True)
def _areas_pass(labels, areas):  # pragma: no cover - numba
    rows, cols = labels.shape
    # label 0 counted in a register (see _drop_specks)
    ground = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                ground += 1
            else:
                areas[k] += 1
    areas[0] += ground


def _label_sums(
    labels: np.ndarray, values: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of each label 0..count-1 and the sum of ``values`` over each object's pixels
    (label 0's sum is 0), added in raster order as ``np.bincount(labels[labels > 0],
    values[labels > 0])`` adds them (the same floats; ``test_regions.py`` compares)."""
    if labels.shape != values.shape or labels.ndim != 2:
        raise ValueError(f"labels {labels.shape} and values {values.shape}: need 2-D, one shape")
    if labels.size and (labels.min() < 0 or labels.max() >= count):
        raise IndexError(f"labels must lie in [0, {count})")
    counts = np.zeros(count, np.int64)
    sums = np.zeros(count)
    _sums_pass(np.ascontiguousarray(labels), np.ascontiguousarray(values), counts, sums)
    return counts, sums


@njit(cache=True)
def _sums_pass(labels, values, counts, sums):  # pragma: no cover - numba
    rows, cols = labels.shape
    # label 0 counted in a register (see _drop_specks); the sums are unchanged
    ground = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                ground += 1
            else:
                counts[k] += 1
                sums[k] += values[y, x]
    counts[0] += ground


def _renumber(labels: np.ndarray, min_area_px: int) -> np.ndarray:
    """Dense 1..n in raster order of first pixel, dropping labels smaller than min_area_px.

    Returns int32. Labels ``>= 0`` are renumbered by two compiled passes (count and first
    appearance, then the lookup); otherwise by the numpy twin :func:`_renumber_numpy`
    (``test_regions.py`` compares them).
    """
    if labels.ndim == 2 and labels.dtype.kind in "iu" and labels.size:
        top = int(labels.max())
        if labels.min() >= 0 and top < 2**31:
            out = np.empty(labels.shape, np.int32)
            _renumber_pass(np.ascontiguousarray(labels), top, min_area_px, out)
            return out
    return _renumber_numpy(labels, min_area_px)


@njit(cache=True)
def _renumber_pass(labels, top, min_area_px, out):  # pragma: no cover - numba
    rows, cols = labels.shape
    area = np.zeros(top + 1, np.int64)
    order = np.empty(top + 1, np.int64)
    seen = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k > 0:
                if area[k] == 0:
                    order[seen] = k
                    seen += 1
                area[k] += 1
    remap = np.zeros(top + 1, np.int32)
    kept = 0
    for n in range(seen):
        k = order[n]
        if area[k] >= min_area_px:
            kept += 1
            remap[k] = kept
    for y in range(rows):
        for x in range(cols):
            out[y, x] = remap[labels[y, x]]


def _renumber_numpy(labels: np.ndarray, min_area_px: int) -> np.ndarray:
    """:func:`_renumber` by sorting the object pixels (any integer labels)."""
    flat = labels.ravel()
    # objects are a small share of a frame: sort their pixels only (positions stay in order)
    inside = np.flatnonzero(flat)
    values, first, counts = np.unique(flat[inside], return_index=True, return_counts=True)
    keep = counts >= min_area_px
    kept = values[keep][np.argsort(first[keep])]
    remap = np.zeros(int(values.max(initial=0)) + 1, dtype=np.int32)
    remap[kept] = np.arange(1, kept.size + 1, dtype=np.int32)
    return remap[labels]


# _ring_kernel and _object_boxes serve both stages._texture_rules and stages._rock_parts
def _ring_kernel(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _object_boxes(labels: np.ndarray, count: int) -> np.ndarray:
    """Inclusive (y0, y1, x0, x1) of each label 0..count (y1 < y0 when absent; label 0 is
    always absent); ``labels`` holds ids 0..count. One compiled pass: a third of
    ``scipy.ndimage.find_objects``, a fifth of ``np.nonzero`` and ``ufunc.at``; ids above
    ``count`` are left out."""
    if labels.ndim != 2 or labels.dtype.kind not in "iu":
        raise TypeError(f"labels must be a 2-D integer array, got {labels.ndim}-D {labels.dtype}")
    return _boxes(np.ascontiguousarray(labels), int(count))


def _box_window(box: np.ndarray) -> tuple[slice, slice]:
    """The slices of an inclusive (y0, y1, x0, x1) box, as ``find_objects`` gives them."""
    # (tolist: Python ints at a fifth of the cost of int() of each numpy item)
    y0, y1, x0, x1 = np.asarray(box).tolist()
    return slice(y0, y1 + 1), slice(x0, x1 + 1)


@njit(cache=True, inline="always")
def _extend_box(boxes, k, y, x):  # pragma: no cover - numba
    """Grow object ``k``'s inclusive (y0, y1, x0, x1) box to pixel (y, x), pixels visited in
    raster order: the one box update of the compiled passes that gather boxes as they go
    (stages._blobs, _fronts, _height_grow, _sun_shadows)."""
    if y < boxes[k, 0]:
        boxes[k, 0] = y
    boxes[k, 1] = y  # rows come in order
    if x < boxes[k, 2]:
        boxes[k, 2] = x
    if x > boxes[k, 3]:
        boxes[k, 3] = x


@njit(cache=True)
def _boxes(labels, count):  # pragma: no cover - numba
    boxes = np.empty((count + 1, 4), np.int64)
    for k in range(count + 1):
        boxes[k, 0] = boxes[k, 2] = np.iinfo(np.int64).max
        boxes[k, 1] = boxes[k, 3] = -1
    rows, cols = labels.shape
    # by runs of one id along each row: a run's first pixel sets the rows and the left
    # column, its last the right one (two to four times faster than each pixel's updates)
    for y in range(rows):
        last = 0
        for x in range(cols):
            k = labels[y, x]
            if k == last:
                continue
            if 0 < last <= count and x - 1 > boxes[last, 3]:
                boxes[last, 3] = x - 1
            if 0 < k <= count:
                if y < boxes[k, 0]:
                    boxes[k, 0] = y
                boxes[k, 1] = y  # rows come in order
                if x < boxes[k, 2]:
                    boxes[k, 2] = x
            last = k
        if 0 < last <= count and cols - 1 > boxes[last, 3]:
            boxes[last, 3] = cols - 1
    return boxes


def _solidity(mask: np.ndarray) -> float:
    """Pixels of a mask over the pixel area of their convex hull (1: convex)."""
    # the hull of each row's first and last pixel is the hull of all the pixels (every
    # pixel lies between its row's ends): OpenCV's hull of these few points is the same
    # vertex list as of all pixels (it drops points on an edge; ``test_regions.py``
    # compares), and sorting them costs a fraction
    ends, pixels = _row_ends(np.ascontiguousarray(mask))
    hull = cv2.convexHull(ends)
    # the hull runs through pixel centres: half its perimeter (+1 for the corners) is the
    # area of the boundary pixels outside it, so a convex blob scores about 1
    area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0
    return pixels / area


@njit(cache=True)
def _row_ends(mask):  # pragma: no cover - numba
    """The (x, y) of each row's first and last pixel of ``mask`` (a (K, 1, 2) int32 array,
    as cv2.findNonZero shapes points) and the mask's pixel count."""
    rows, cols = mask.shape
    ends = np.empty((2 * rows, 1, 2), np.int32)
    n = 0
    pixels = 0
    for y in range(rows):
        first = -1
        last = -1
        for x in range(cols):
            if mask[y, x]:
                if first < 0:
                    first = x
                last = x
                pixels += 1
        if first >= 0:
            ends[n, 0, 0], ends[n, 0, 1] = first, y
            ends[n + 1, 0, 0], ends[n + 1, 0, 1] = last, y
            n += 2
    return ends[:n], pixels
