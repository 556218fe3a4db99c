"""The relational scene graph of a frame as an edge table (pure functions).

Every edge reads "subject RELATION object". Definitions:

``left_of`` / ``right_of``
    From ground-frame positions (``x_m``, ``y_m`` of the descriptors): subject left_of object
    when ``x_subject < x_object - margin_m``; right_of when ``x_subject > x_object + margin_m``.
``in_front_of`` / ``behind``
    subject in_front_of object (nearer the camera along the ground's forward axis) when
    ``y_subject < y_object - margin_m``; behind when ``y_subject > y_object + margin_m``.
    Pairs closer than ``margin_m`` along an axis get no edge on that axis (near-ties are not
    facts). Both directions of each fact are emitted: if A left_of B then also B right_of A,
    so a query never has to look at both columns. Objects without a position (no depth) get
    no ordering edge.

    The four ordering relations are local: they link only objects whose ground positions lie
    within ``radius_m`` of each other (``distance_m <= radius_m``). The complete graph has
    up to 2 K (K - 1) such rows for K objects (about 4,100 per frame of the lava archive);
    the order of two distant rocks follows from their ``x_m``, ``y_m`` columns without an
    edge, while the graph is for the neighbourhood a scientist or a rover plans around.
    A radius beyond the scene (``inf`` here, e.g. ``1e6`` in a catalog, whose parameters must
    be finite) gives the complete graph.
``adjacent``
    The two regions touch or lie within ``gap_px`` pixels of each other in the image
    (chessboard distance between the pixel sets <= ``gap_px + 1``, a dilation test).
    Symmetric: emitted in both directions.
``occludes``
    Subject and object are in contact (at least 3 of the subject's pixels lie within
    ``contact_gap_px + 1`` 4-connected steps of the object: touching, or split by a line of
    at most ``contact_gap_px`` background pixels, as segmentation does at a depth edge; ground
    visible between them means no occlusion) and, along their shared boundary, the subject is
    nearer: the median disparity of the subject's pixels within ``band_px`` of the object
    exceeds that of the object's pixels within ``band_px`` of the subject by more than
    ``occlusion_jump_px``. Emitted once, from the nearer object. Rocks touching in the image
    at different depths are always an occlusion, and their depth difference at the contact
    is often a fraction of a pixel of disparity, so the default jump is small (0.1 px); the
    band medians keep it robust to matching noise.

Attributes of every edge:

``distance_m``
    Ground distance between the two positions, ``hypot(dx, dy)``, metres; NaN without
    positions.
``overlap``
    Horizontal image overlap of the two enclosing rectangles: length of the intersection of
    the column intervals ``[bbox_x_min, bbox_x_max]`` divided by the narrower interval, in
    [0, 1]. With ``behind`` it says how much of the subject is in line with the object
    (1: fully behind it as seen from the camera).
``shared_boundary``
    Share of the subject's boundary pixels lying within ``gap_px + 1`` pixels of the object
    (0 for non-adjacent pairs).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy import ndimage

from ._footprint import _dilate_diamond
from ._ground import _median

__all__ = [
    "RELATION_COLUMNS",
    "RELATIONS",
    "ordering_matrices",
    "horizontal_overlap",
    "region_neighbours",
    "boundary_disparity_difference",
    "contact_pixels",
    "relate_objects",
]

RELATIONS: tuple[str, ...] = (
    "left_of",
    "right_of",
    "in_front_of",
    "behind",
    "adjacent",
    "occludes",
)

RELATION_COLUMNS: dict[str, str] = {
    "subject_id": "int32",
    "relation": "str",
    "object_id": "int32",
    "distance_m": "float64",
    "overlap": "float64",
    "shared_boundary": "float64",
}
"""Relation column names and NumPy dtypes (``'str'``: unicode strings)."""

_MIN_CONTACT_PX = 3


def ordering_matrices(
    x_m: np.ndarray, y_m: np.ndarray, *, margin_m: float, radius_m: float = math.inf
) -> dict[str, np.ndarray]:
    """Boolean (K, K) matrices ``M[i, j]``: object i RELATION object j, for the four
    ordering relations.

    Parameters
    ----------
    x_m, y_m : (K,) ndarray of float
        Ground positions; an object with either coordinate NaN gets no edge.
    margin_m : float
        Near-tie margin, metres, >= 0.
    radius_m : float
        Only pairs whose ground distance ``hypot(dx, dy)`` is at most this get an edge,
        metres, > 0 (``inf``: every pair).
    """
    if margin_m < 0:
        raise ValueError(f"margin_m must be >= 0, got {margin_m!r}")
    if not radius_m > 0:
        raise ValueError(
            f"radius_m must be > 0 (metres; inf for the complete graph), got {radius_m!r}"
        )
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    known = np.isfinite(x) & np.isfinite(y)
    dx = x[:, None] - x[None, :]
    dy = y[:, None] - y[None, :]
    local = known[:, None] & known[None, :]
    local[local] = np.hypot(dx[local], dy[local]) <= radius_m
    dx = np.where(local, dx, 0.0)
    dy = np.where(local, dy, 0.0)
    return {
        "left_of": dx < -margin_m,
        "right_of": dx > margin_m,
        "in_front_of": dy < -margin_m,
        "behind": dy > margin_m,
    }


def horizontal_overlap(
    a_min: np.ndarray, a_max: np.ndarray, b_min: np.ndarray, b_max: np.ndarray
) -> np.ndarray:
    """Intersection of column intervals over the narrower interval (inclusive pixel ends).

    Parameters
    ----------
    a_min, a_max, b_min, b_max : ndarray of int
        Broadcastable interval ends, ``min <= max``.

    Returns
    -------
    ndarray of float64
        In [0, 1].
    """
    a0, a1 = np.asarray(a_min, np.float64), np.asarray(a_max, np.float64)
    b0, b1 = np.asarray(b_min, np.float64), np.asarray(b_max, np.float64)
    inter = np.clip(np.minimum(a1, b1) - np.maximum(a0, b0) + 1.0, 0.0, None)
    narrower = np.minimum(a1 - a0, b1 - b0) + 1.0
    return inter / narrower


_CROSS_KERNEL = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def _boundary(mask: np.ndarray) -> np.ndarray:
    # 4-connected erosion with background outside the array (scipy's border_value=0)
    eroded = cv2.erode(
        mask.view(np.uint8), _CROSS_KERNEL, borderType=cv2.BORDER_CONSTANT, borderValue=0
    ).view(bool)
    return mask & ~eroded


def _dilate_square(mask: np.ndarray, radius: int) -> np.ndarray:
    """Chessboard dilation by ``radius`` pixels: ``radius`` 3x3 dilations in one pass."""
    size = 2 * radius + 1
    kernel = np.ones((size, size), dtype=np.uint8)
    return cv2.dilate(np.ascontiguousarray(mask).view(np.uint8), kernel).view(bool)


def region_neighbours(labels: np.ndarray, object_id: int, *, gap_px: int) -> dict[int, float]:
    """Objects adjacent to ``object_id`` and the share of its boundary they line.

    Parameters
    ----------
    labels : (M, N) ndarray of int
        Label image (a crop is fine as long as it extends ``gap_px + 1`` beyond the object).
    object_id : int
    gap_px : int
        Largest gap (pixels of background) between two regions still called adjacent, >= 0.

    Returns
    -------
    dict of int to float
        Neighbour id -> share of the object's boundary pixels within ``gap_px + 1`` pixels
        (chessboard) of the neighbour.
    """
    if gap_px < 0:
        raise ValueError(f"gap_px must be >= 0, got {gap_px!r}")
    mask = labels == object_id
    if not mask.any():
        return {}
    reach = _dilate_square(mask, gap_px + 1)
    others = np.unique(labels[reach & ~mask])
    others = others[(others > 0) & (others != object_id)]
    boundary = _boundary(mask)
    n_boundary = max(int(boundary.sum()), 1)
    result: dict[int, float] = {}
    for other in others:
        near_other = _dilate_square(labels == other, gap_px + 1)
        result[int(other)] = float(np.sum(boundary & near_other)) / n_boundary
    return result


def boundary_disparity_difference(
    disparity: np.ndarray, mask_a: np.ndarray, mask_b: np.ndarray, *, band_px: int
) -> float:
    """Median disparity of A near B minus median disparity of B near A (pixels).

    Positive: A is nearer than B along their shared boundary. NaN when either band has no
    valid disparity.

    Parameters
    ----------
    disparity : (M, N) ndarray of float
        NaN where invalid.
    mask_a, mask_b : (M, N) ndarray of bool
        The two regions (disjoint).
    band_px : int
        Width of the band on each side of the shared boundary, >= 1.
    """
    if band_px < 1:
        raise ValueError(f"band_px must be >= 1, got {band_px!r}")
    d = np.asarray(disparity, dtype=np.float64)
    near_b = _dilate_square(np.asarray(mask_b, bool), band_px)
    near_a = _dilate_square(np.asarray(mask_a, bool), band_px)
    side_a = d[mask_a & near_b]
    side_b = d[mask_b & near_a]
    side_a, side_b = side_a[np.isfinite(side_a)], side_b[np.isfinite(side_b)]
    if side_a.size == 0 or side_b.size == 0:
        return float("nan")
    return float(_median(side_a) - _median(side_b))


def contact_pixels(mask_a: np.ndarray, mask_b: np.ndarray, *, gap_px: int) -> int:
    """Number of A's pixels within ``gap_px + 1`` 4-connected steps of B.

    With ``gap_px = 0`` these are A's pixels with a 4-neighbour in B (the contact line).

    Parameters
    ----------
    mask_a, mask_b : (M, N) ndarray of bool
        Two disjoint regions.
    gap_px : int
        Background pixels allowed between the regions, >= 0.
    """
    if gap_px < 0:
        raise ValueError(f"gap_px must be >= 0, got {gap_px!r}")
    near_b = _dilate_diamond(np.asarray(mask_b, bool), gap_px + 1)
    return int(np.count_nonzero(np.asarray(mask_a, bool) & near_b))


def _empty_columns() -> dict[str, np.ndarray]:
    return {
        name: np.array([], dtype=str if kind == "str" else kind)
        for name, kind in RELATION_COLUMNS.items()
    }


def relate_objects(
    labels: np.ndarray,
    disparity: np.ndarray,
    *,
    object_ids: np.ndarray,
    x_m: np.ndarray,
    y_m: np.ndarray,
    bbox_x_min: np.ndarray,
    bbox_x_max: np.ndarray,
    margin_m: float = 0.05,
    radius_m: float = 1.0,
    gap_px: int = 2,
    band_px: int = 3,
    contact_gap_px: int = 0,
    occlusion_jump_px: float = 0.1,
    object_slices: list | None = None,
) -> dict[str, np.ndarray]:
    """Edge table of one frame.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 = background.
    disparity : (M, N) ndarray of float
        Pixels, NaN (or <= 0) where invalid.
    object_ids, x_m, y_m, bbox_x_min, bbox_x_max : (K,) ndarray
        Descriptor columns of the frame's objects.
    margin_m : float
        Near-tie margin of the ordering relations, metres.
    radius_m : float
        Largest ground distance between two objects with ordering edges, metres, > 0
        (``inf``: the complete graph); ``adjacent`` and ``occludes`` do not depend on it.
    gap_px : int
        Adjacency gap, pixels.
    band_px : int
        Band width for the occlusion test, pixels.
    contact_gap_px : int
        Background pixels allowed between two regions in contact, <= ``gap_px``.
    occlusion_jump_px : float
        Disparity difference (pixels) above which the nearer region occludes the other.
    object_slices : list of (slice, slice) or None, optional
        ``scipy.ndimage.find_objects`` of ``labels`` with values <= 0 as background, when
        the caller has it (describe does: one whole-frame pass fewer); computed if None.

    Returns
    -------
    dict of str to (E,) ndarray
        :data:`RELATION_COLUMNS`, sorted by subject, relation (in :data:`RELATIONS` order)
        and object.
    """
    lab = np.asarray(labels)
    disp = np.asarray(disparity)  # crops are converted and cleaned where read
    if lab.ndim != 2 or disp.shape != lab.shape:
        raise ValueError(
            f"labels and disparity must be 2-D arrays of one shape, got {lab.shape} and "
            f"{disp.shape}"
        )
    if not 0 <= contact_gap_px <= gap_px:
        raise ValueError(
            f"contact_gap_px must be in [0, gap_px={gap_px}], got {contact_gap_px!r}; "
            "regions in contact must also be adjacent"
        )
    ids = np.asarray(object_ids, dtype=np.int64)
    k = ids.size
    x = np.asarray(x_m, dtype=np.float64)
    y = np.asarray(y_m, dtype=np.float64)
    bx0 = np.asarray(bbox_x_min, dtype=np.int64)
    bx1 = np.asarray(bbox_x_max, dtype=np.int64)
    for name, col in (("x_m", x), ("y_m", y), ("bbox_x_min", bx0), ("bbox_x_max", bx1)):
        if col.shape != (k,):
            raise ValueError(f"{name} must have one value per object ({k}), got {col.shape}")
    if k < 2:
        return _empty_columns()
    distance = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    overlap = horizontal_overlap(bx0[:, None], bx1[:, None], bx0[None, :], bx1[None, :])
    shared = np.zeros((k, k), dtype=np.float64)
    matrices = ordering_matrices(x, y, margin_m=margin_m, radius_m=radius_m)
    adjacent = np.zeros((k, k), dtype=bool)
    occludes = np.zeros((k, k), dtype=bool)
    position = {int(obj): i for i, obj in enumerate(ids)}
    slices = object_slices
    if slices is None:
        slices = ndimage.find_objects(np.where(lab > 0, lab, 0))
    pad = gap_px + 1 + band_px
    h, w = lab.shape
    for i, obj in enumerate(ids):
        if obj < 1 or obj > len(slices) or slices[obj - 1] is None:
            continue
        sl = slices[obj - 1]
        crop = (
            slice(max(sl[0].start - pad, 0), min(sl[0].stop + pad, h)),
            slice(max(sl[1].start - pad, 0), min(sl[1].stop + pad, w)),
        )
        lab_c = lab[crop]
        for other, share in region_neighbours(lab_c, int(obj), gap_px=gap_px).items():
            j = position.get(other)
            if j is None:
                continue
            adjacent[i, j] = True
            shared[i, j] = share
            if j < i:
                continue  # each unordered pair is tested for occlusion once
            mask_a, mask_b = lab_c == obj, lab_c == other
            if contact_pixels(mask_a, mask_b, gap_px=contact_gap_px) < _MIN_CONTACT_PX:
                continue
            disp_c = disp[crop].astype(np.float64)
            disp_c[~(disp_c > 0)] = np.nan
            diff = boundary_disparity_difference(disp_c, mask_a, mask_b, band_px=band_px)
            if diff > occlusion_jump_px:
                occludes[i, j] = True
            elif -diff > occlusion_jump_px:
                occludes[j, i] = True
    # adjacency seen from either side counts (crops may clip the far side of big regions)
    adjacent |= adjacent.T
    matrices["adjacent"] = adjacent
    matrices["occludes"] = occludes
    parts: list[tuple[np.ndarray, int, np.ndarray]] = []
    for rel_index, name in enumerate(RELATIONS):
        si, oi = np.nonzero(matrices[name] & ~np.eye(k, dtype=bool))
        parts.append((si, rel_index, oi))
    subj = np.concatenate([p[0] for p in parts])
    rel = np.concatenate([np.full(p[0].size, p[1]) for p in parts])
    objc = np.concatenate([p[2] for p in parts])
    order = np.lexsort((objc, rel, subj))
    subj, rel, objc = subj[order], rel[order], objc[order]
    names = np.array(RELATIONS, dtype=str)
    return {
        "subject_id": ids[subj].astype(np.int32),
        "relation": names[rel] if rel.size else np.array([], dtype=str),
        "object_id": ids[objc].astype(np.int32),
        "distance_m": distance[subj, objc].astype(np.float64),
        "overlap": overlap[subj, objc].astype(np.float64),
        "shared_boundary": shared[subj, objc],
    }
