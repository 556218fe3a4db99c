"""Rules R5-R5d: objects that are ground texture -- streaks and pieces of ripple fields.

They act on labelled objects (:func:`stages._regions.label_objects`), as R4 (split at
depth edges, :mod:`stages._regions`) and R6-R7c (attached shadows, halves and faces of
rocks, :mod:`stages._rock_parts`) do:

* **R5 streaks** -- an object more than ``max_elongation`` times longer than wide (its
  equivalent ellipse) is a wind striation or ripple trough, not a rock: dropped
  (:func:`drop_streaks`). Rocks seen from a rover are compact blobs.
* **R5b clear flat rocks** -- except when its median gray level lies at least 2.5 threshold
  bands from the ground level and it is at most 4 times longer than wide: a far rock seen
  edge-on is 3-3.6 times wider than tall, but stands out clearly, while ripple troughs
  barely cross the threshold (median 1.2-2.1 bands on the dunes frames) and striations are
  longer. On the catalog frames R5 dropped 11 true rocks of mojave and 13 of lava; with
  R5b mojave keeps 7 more (2 more false positives), lava 7 more (1 more), dunes none.
* **R5d rocks clear of their ground** -- R5b's bands are the sector's thresholds, which a
  rough patch of the sector widens: flat rocks on mojave's blotchy soil lay 1.4-2 bands out
  but 7-13 robust spreads (1.4826 MAD) of the smooth ground right around them. So an
  elongated object no longer than R5b's limit is also kept when its mean gray lies at least
  8 spreads of the ground 1-4 px around it from that ground's median: a striation or a
  trough is part of the ground's texture, within a few of its spreads. Of the objects R5
  dropped on the catalog frames and seeds 2-3 (4 archives, 17 runs; a diagnostic on R5's
  input, not in the repository) this kept 10 true rocks and 2 other objects; 6 spreads kept
  12 and 9, elongations up to 5 or 6 kept 18 and 8, 19 and 9. With ``bench_segment.py
  --rundir``: lab seed 2 4 more true rocks (0.947 -> 0.959), mojave seed 2 and lava seeds 3
  and 4 one more each, no false positive anywhere; the catalog frames and the dunes runs
  are unchanged (6 spreads: one invented rock on dunes seed 7).
* **R5c ripple fields** -- dune ripples near the camera have real relief (about 2 height
  sigmas, so they pass the depth vote) and their shading crosses the thresholds in pieces
  that are not elongated, or lie in the matcher's blind band along the frame's border; seen
  alone, such a piece looks like a small rock. What gives it away is its neighbourhood: the
  ground texture around it (the intensity objects before any depth rule) holds streaks
  (elongation above ``max_elongation``) that share one direction -- ripples do, rocks and
  soil texture do not. An object lies in a *field of ripples* when at least 3 such streaks
  lie within 100 px of its centroid (their boxes; one it is part of counts), together at
  least as large as the object itself (three 50 px specks of texture are no evidence about
  a 1200 px mojave rock), and their area-weighted mean of doubled axis angles has length
  >= 0.8 (1: all parallel) -- or, where the ripples are too faint to leave streaks, when
  the gray-level gradients in a 100 px window around it share one direction (structure
  tensor coherence >= 0.8, at half resolution; ripples 0.95, the highest at a true rock of
  lab, mojave or lava whose ratio below is under 1.5 was 0.62). There a rock must stand out
  of the ripple texture: its median
  gray level must lie at least 1.5 times further from the median of its ring of ground (3 to
  8 px out) than that ring's 5th percentile (darker objects) or 95th (lighter ones) does
  (:func:`drop_ripple_pieces`). A piece of a trough is as dark as the trough continuing
  beside it (ratio 0.1-1.1 on the dunes frames), a rock on sand is darker or lighter than
  any ripple around it (2.0-35). With ``bench_segment.py --rundir`` (12 frames each,
  ``--set ripple_texture_ratio=0`` for the old rules) the invented rocks went 2 -> 0 on the
  dunes catalog frames, 31 -> 0 on seed 2, 6 -> 1 on seed 7 (a true rock matched at IoU
  0.45), 5 -> 2 on seed 3 (two ripple pieces cut by the bottom corners, whose ring lies
  on one side only), 5 -> 1 on seed 11 (the gradient evidence: 3 with the streaks alone),
  keeping every true rock; lab and mojave (catalog and seed 2) are unchanged, lava lost 1
  and 2 false positives. Any ratio from 1.25 to 2, any gradient coherence from 0.7 to 0.9,
  gives the same counts (0.7: lab one false positive fewer).
* **R5c at range** -- the ring misses two kinds of ripple piece: a trough cut by a bottom
  corner of the frame, whose ring lies on the crest beside it alone (ratio 6-10), and, near
  the horizon (7-9 m), the aliased ripple troughs, black dashes and blobs on smooth bright
  sand whose ring holds no texture (ratio 9-15). Both are as dark as the streaks beside them
  at the same range (ripple shading changes with the range: broad troughs near the camera,
  dashes far away). So where at least 2 streaks longer than any rock (more than 4 times
  longer than wide, R5b's limit) lie within 100 px and 20 rows of an object, its median gray
  must also lie 1.5 times further from its ring's median than the median gray of those
  streaks' pixels on its side of that median. On the objects of the dunes frames (catalog
  and seeds 2, 3, 4, 5, 7, 11) that the ring kept and this judged: the 9 ripple pieces
  0.78-1.14, the 4 rocks 1.8, 2.0, 23 and one with no streak pixel on its side. With
  ``bench_segment.py --rundir`` on runs of the catalogs with ``seed =`` changed, the
  invented rocks of dunes seed 5 went 8 -> 1 (six aliased blobs in the top 20 rows of one
  frame and a corner trough; the one left is a true rock of 20 px, under the scorer's 30,
  matched at IoU 0.45) and of seed 3 2 -> 0 (its two corner troughs), every true rock kept;
  dunes seeds 2, 4, 7 and 11, the catalog frames of every archive and lab, mojave and lava
  seeds 2 and 3 are unchanged but for one false positive fewer on mojave seed 3 (a piece on
  the bottom border). Counting every streak (more than 3 times longer than wide) and one
  sufficing, mojave seed 2 lost 5 true rocks, lava seed 2 4 and lava's catalog frames 1: far
  rocks beside 1-2 far rocks seen edge-on (3.1-3.6 times longer than wide, as dark as they
  are); asking 3 such streaks instead of 2 kept seed 3's corner trough with 2 beside it. 1
  long streak instead of 2, or 30 rows instead of 20, gives the same counts; 10 rows leaves
  4 of seed 5's blobs.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._regions import (
    CLEAR_CONTRAST,
    _box_window,
    _lookup,
    _object_boxes,
    _renumber,
    _ring_kernel,
)

# R5c: streaks of the ground texture within this many pixels of an object ...
_RIPPLE_RADIUS_PX = 100.0
# ... at least this many and this parallel (length of the mean of the doubled angles) make a
# field of ripples ...
_RIPPLE_MIN_STREAKS = 3
_RIPPLE_COHERENCE = 0.8
# ... where an object must stand this many times beyond the texture of its ring of ground
# (3 to _TEXTURE_RING_PX pixels out).
_RIPPLE_TEXTURE_RATIO = 1.5
# ... or where the gray-level gradients around it share one direction this much (structure
# tensor coherence): ripples too faint to cross the thresholds leave few streaks.
_RIPPLE_GRADIENT_COHERENCE = 0.8
_TEXTURE_RING_PX = 8
# R5b: a clear object at most this many times longer than wide may be a far rock edge-on.
_CLEAR_ELONGATION = 4.0
# R5d: an elongated object (up to _CLEAR_ELONGATION) this many robust spreads of the ground
# within _SPREAD_RING_PX of it away from that ground's median is a rock
_CLEAR_SPREADS = 8.0
_SPREAD_RING_PX = 4
# R5c at range: where at least this many streaks longer than any rock (_CLEAR_ELONGATION)
# lie within _RIPPLE_RADIUS_PX and this many rows of an object (the image row is the range
# on the ground), it must also stand _RIPPLE_TEXTURE_RATIO times beyond their gray level.
_RANGE_STREAKS = 2
_STREAK_ROWS_PX = 20.0

__all__ = [
    "elongation",
    "drop_streaks",
    "drop_ripple_pieces",
]


def _moments(labels: np.ndarray) -> tuple[np.ndarray, ...]:
    """Area, centroid (y, x), elongation and axis angle of each label 0..max.

    The angle (radians in ``(-pi/2, pi/2]``, 0 along the rows, positive towards increasing
    row) is the major axis of the equivalent ellipse; it is 0 for label 0 and absent labels.
    """
    labels = np.ascontiguousarray(labels)
    count = int(labels.max()) + 1
    area, sum_y, sum_x = _sums(labels, count)
    area = np.maximum(area, 1).astype(np.float64)
    mx = sum_x / area
    my = sum_y / area
    sum_xx, sum_yy, sum_xy = _central_sums(labels, mx, my)
    # + 1/12: a pixel is a unit square, so a single row still has a width
    sxx = sum_xx / area + 1.0 / 12.0
    syy = sum_yy / area + 1.0 / 12.0
    sxy = sum_xy / area
    half_trace = (sxx + syy) / 2.0
    root = np.sqrt(((sxx - syy) / 2.0) ** 2 + sxy**2)
    major, minor = half_trace + root, np.maximum(half_trace - root, 1e-12)
    ratio = np.sqrt(major / minor)
    ratio[0] = 0.0
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    angle[0] = 0.0
    return area, my, mx, ratio, angle


def _sums(labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels, row sum and column sum of each label 0..count-1 (label 0: none counted).

    The sums run over the pixels in raster order, as ``np.bincount(ids, weights)`` of
    ``np.nonzero``'s pixels adds them (the same floats; ``test_texture_rules.py`` compares).
    """
    area = np.zeros(count, np.int64)
    sums = np.zeros((2, count))
    _sum_pass(labels, area, sums)
    return area, sums[0], sums[1]


@njit(cache=True)
def _sum_pass(labels, area, sums):  # pragma: no cover - numba
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k != 0:
                area[k] += 1
                sums[0, k] += y
                sums[1, k] += x


def _central_sums(
    labels: np.ndarray, mx: np.ndarray, my: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums of dx*dx, dy*dy and dx*dy about each label's centroid, in raster order."""
    sums = np.zeros((3, mx.size))
    _central_pass(labels, mx, my, sums)
    return sums[0], sums[1], sums[2]


@njit(cache=True)
def _central_pass(labels, mx, my, sums):  # pragma: no cover - numba
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k != 0:
                dx = x - mx[k]
                dy = y - my[k]
                sums[0, k] += dx * dx
                sums[1, k] += dy * dy
                sums[2, k] += dx * dy


def elongation(labels: np.ndarray) -> np.ndarray:
    """Ratio of the major to the minor axis of each object's equivalent ellipse.

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects.

    Returns
    -------
    ratio : (n + 1,) ndarray of float64
        ``ratio[k]`` for object ``k`` (>= 1; ``inf`` for a one-pixel-wide line); ``ratio[0]``
        is 0.
    """
    return _moments(labels)[3]


def drop_streaks(
    labels: np.ndarray,
    *,
    max_elongation: float,
    contrast: np.ndarray | None = None,
    clear_contrast: float = CLEAR_CONTRAST,
    clear_elongation: float = _CLEAR_ELONGATION,
    image: np.ndarray | None = None,
    clear_spreads: float = _CLEAR_SPREADS,
) -> tuple[np.ndarray, int]:
    """Remove objects longer than ``max_elongation`` times their width; renumber densely.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
    max_elongation : float
        ``> 1``; major/minor axis ratio above which an object is a streak (wind striation,
        ripple trough), not a rock.
    contrast : (M, N) ndarray of float, optional
        Gray-level distance from the ground level in threshold bands
        (:func:`stages._depth_rules.gray_contrast`); when given, an elongated object no longer
        than ``clear_elongation`` whose median ``|contrast|`` is at least ``clear_contrast``
        is kept (rule R5b): a flat rock seen edge-on, not a faint trough.
    clear_contrast : float
        ``>= 1`` threshold bands.
    clear_elongation : float
        ``> 1``; at or below ``max_elongation`` no object is kept this way.
    image : (M, N) ndarray of uint8, optional
        Reference gray image; when given, an elongated object no longer than
        ``clear_elongation`` whose mean gray lies at least ``clear_spreads`` robust spreads
        of its ring of ground from that ring's median is kept too (rule R5d).
    clear_spreads : float
        ``> 0``; R5d's distance, in robust spreads (1.4826 MAD, at least one gray level) of
        the ground 1 to ``_SPREAD_RING_PX`` pixels around the object.

    Returns
    -------
    labels : (M, N) ndarray of int32
    dropped : int
        Number of objects removed.
    """
    if not max_elongation > 1:
        raise ValueError(f"max_elongation must be > 1, got {max_elongation}")
    if not clear_contrast >= 1 or not clear_elongation > 1:
        raise ValueError(
            "need clear_contrast >= 1 and clear_elongation > 1, got "
            f"{clear_contrast} and {clear_elongation}"
        )
    if not clear_spreads > 0:
        raise ValueError(f"clear_spreads must be > 0, got {clear_spreads}")
    for name, values in (("contrast", contrast), ("image", image)):
        if values is not None and values.shape != labels.shape:
            raise ValueError(
                f"{name} {values.shape} and labels {labels.shape} must have one shape"
            )
    ratio = elongation(labels)
    streak = ratio > max_elongation
    if contrast is not None or image is not None:
        candidates = np.flatnonzero(streak & (ratio <= clear_elongation))
        boxes = _object_boxes(labels, int(labels.max())) if candidates.size else None
        for k in candidates:
            y0, y1, x0, x1 = boxes[k]
            inside = labels[y0 : y1 + 1, x0 : x1 + 1] == k
            if contrast is not None:
                window = contrast[y0 : y1 + 1, x0 : x1 + 1]
                if np.median(np.abs(window[inside])) >= clear_contrast:
                    streak[k] = False  # R5b
                    continue
            if image is not None and _ring_spreads(image, labels, boxes[k], k) >= clear_spreads:
                streak[k] = False  # R5d
    if not streak.any():
        return labels, 0
    # the streaks to 0 (one lookup), then renumbered
    table = np.where(streak, 0, np.arange(streak.size)).astype(labels.dtype)
    return _renumber(_lookup(table, labels), 1), int(streak.sum())


def _ring_spreads(image: np.ndarray, labels: np.ndarray, box: np.ndarray, k: int) -> float:
    """R5d: how many robust spreads of its ring of ground object ``k``'s mean gray lies from
    that ring's median (0 when the ring has fewer than 10 pixels: no evidence)."""
    rows, cols = labels.shape
    y0, y1 = max(0, int(box[0]) - _SPREAD_RING_PX), min(rows, int(box[1]) + 1 + _SPREAD_RING_PX)
    x0, x1 = max(0, int(box[2]) - _SPREAD_RING_PX), min(cols, int(box[3]) + 1 + _SPREAD_RING_PX)
    window = labels[y0:y1, x0:x1]
    inside = window == k
    grown = cv2.dilate(inside.view(np.uint8), _ring_kernel(_SPREAD_RING_PX)).view(bool)
    ring = image[y0:y1, x0:x1][grown & (window == 0)].astype(np.float64)
    if ring.size < 10:
        return 0.0
    level = float(np.median(ring))
    spread = max(1.4826 * float(np.median(np.abs(ring - level))), 1.0)
    return abs(float(image[y0:y1, x0:x1][inside].mean()) - level) / spread


def drop_ripple_pieces(
    labels: np.ndarray,
    *,
    texture: np.ndarray,
    image: np.ndarray,
    max_elongation: float = 3.0,
    radius_px: float = _RIPPLE_RADIUS_PX,
    min_streaks: int = _RIPPLE_MIN_STREAKS,
    min_coherence: float = _RIPPLE_COHERENCE,
    min_texture_ratio: float = _RIPPLE_TEXTURE_RATIO,
    min_gradient_coherence: float = _RIPPLE_GRADIENT_COHERENCE,
) -> tuple[np.ndarray, int]:
    """Rule R5c: in a field of ripples, drop objects that do not stand out of its texture.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects (the candidates).
    texture : (M, N) ndarray of int32
        The frame's intensity objects before any depth rule, 0 background: their streaks
        (elongation above ``max_elongation``) are the evidence of ripples.
    image : (M, N) ndarray of uint8
        Reference gray image.
    max_elongation : float
        ``> 1``; a texture object longer than this times its width is a streak.
    radius_px : float
        ``> 0``; streaks whose bounding box lies within this distance of an object's
        centroid count (one the object is part of too).
    min_streaks : int
        ``>= 1``; an object lies in a field of ripples when at least this many streaks
        count ...
    min_coherence : float
        In ``(0, 1]``; ... and the length of the area-weighted mean of their doubled axis
        angles reaches this (1: all parallel, 0: no common direction).
    min_texture_ratio : float
        ``> 0``; an object in a field of ripples is kept when its median gray level lies at
        least this many times further from the median of its ring of ground (3 to 8 pixels
        out) than the ring's own 5th (darker objects) or 95th (lighter objects) percentile,
        and, where at least 2 streaks longer than any rock lie within ``radius_px`` and 20
        rows of it, than the median gray of their pixels on its side (R5c at range).
    min_gradient_coherence : float
        In ``(0, 1]``; an object also lies in a field of ripples where the structure-tensor
        coherence of the gray-level gradients in a window of side ``radius_px`` around its
        centroid reaches this; 1 disables this evidence.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m without the dropped objects.
    dropped : int
    """
    if labels.shape != texture.shape or labels.shape != image.shape:
        raise ValueError(
            f"labels {labels.shape}, texture {texture.shape} and image {image.shape} must "
            "have one shape"
        )
    if not (
        max_elongation > 1
        and radius_px > 0
        and min_streaks >= 1
        and 0 < min_coherence <= 1
        and min_texture_ratio > 0
        and 0 < min_gradient_coherence <= 1
    ):
        raise ValueError(
            "need max_elongation > 1, radius_px > 0, min_streaks >= 1, 0 < min_coherence <= 1, "
            "min_texture_ratio > 0 and 0 < min_gradient_coherence <= 1; got "
            f"{max_elongation}, {radius_px}, {min_streaks}, {min_coherence}, "
            f"{min_texture_ratio} and {min_gradient_coherence}"
        )
    count = int(labels.max())
    if count == 0:
        return labels, 0
    pixels, sum_y, sum_x = _sums(np.ascontiguousarray(labels), count + 1)
    area = np.maximum(pixels, 1).astype(np.float64)[1:]
    cy = sum_y[1:] / area
    cx = sum_x[1:] / area
    streaks = _streaks(texture, max_elongation=max_elongation)
    in_field = _streak_field(
        streaks,
        area,
        cy,
        cx,
        radius_px=radius_px,
        min_streaks=min_streaks,
        min_coherence=min_coherence,
    )
    if min_gradient_coherence < 1:
        in_field |= _gradient_coherence(image, cy, cx, radius_px=radius_px) >= (
            min_gradient_coherence
        )
    in_field = np.flatnonzero(in_field) + 1
    if in_field.size == 0:
        return labels, 0
    boxes = _object_boxes(labels, count)
    rows, cols = labels.shape
    # R5c at range counts only streaks longer than any rock: a subset of the field's
    streak_ids, t_boxes, _, _, t_ratio = streaks
    longer = t_ratio > _CLEAR_ELONGATION
    streak_ids, t_boxes = streak_ids[longer], t_boxes[longer]
    gap_y, gap_x = _box_gaps(t_boxes, cy[in_field - 1], cx[in_field - 1])
    # the streaks at each object's range: ripple shading changes with it (broad troughs near
    # the camera, aliased dashes near the horizon)
    at_range = (np.hypot(gap_y, gap_x) <= radius_px) & (gap_y <= _STREAK_ROWS_PX)
    is_streak = np.zeros(int(texture.max()) + 1, dtype=bool)
    ripple = np.zeros(count + 1, dtype=bool)
    for row, k in enumerate(in_field):
        sy, sx = _box_window(boxes[k])
        y0, x0 = max(0, sy.start - _TEXTURE_RING_PX), max(0, sx.start - _TEXTURE_RING_PX)
        y1, x1 = min(rows, sy.stop + _TEXTURE_RING_PX), min(cols, sx.stop + _TEXTURE_RING_PX)
        window = labels[y0:y1, x0:x1]
        ratio, gray_level, level = _texture_ratio(image[y0:y1, x0:x1], window, window == k)
        if ratio >= min_texture_ratio and np.count_nonzero(at_range[row]) >= _RANGE_STREAKS:
            # R5c streaks: a trough cut by the frame's corner (its ring lies on the crest
            # alone) or an aliased far trough (its ring is smooth sand) stands out of its
            # ring but not of the streaks beside it, which are as dark as it is
            is_streak[:] = False
            is_streak[streak_ids[at_range[row]]] = True
            pixels = _lookup(is_streak, texture) & (labels != k)
            ratio = min(ratio, _streak_ratio(image, pixels, gray_level, level))
        ripple[k] = ratio < min_texture_ratio
    if not ripple.any():
        return labels, 0
    # labels are dense and numbered in raster order: dropping some keeps the order
    remap = np.zeros(count + 1, dtype=np.int32)
    remap[1:][~ripple[1:]] = np.arange(1, count + 1 - int(ripple.sum()), dtype=np.int32)
    return _lookup(remap, labels), int(ripple.sum())


def _streaks(
    texture: np.ndarray, *, max_elongation: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """R5c's evidence: ids, inclusive (y0, y1, x0, x1) boxes, areas, axis angles and
    elongations of streaks.

    A streak is a texture object more than ``max_elongation`` times longer than wide.
    """
    if not texture.any():
        empty = np.zeros(0)
        return empty.astype(np.int64), np.zeros((0, 4)), empty, empty, empty
    t_area, _, _, t_ratio, t_angle = _moments(texture)
    streaks = np.flatnonzero(t_ratio > max_elongation)
    boxes = _object_boxes(texture, t_area.size - 1)[streaks].astype(np.float64)
    return streaks, boxes, t_area[streaks], t_angle[streaks], t_ratio[streaks]


def _box_gaps(
    boxes: np.ndarray, cy: np.ndarray, cx: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Row and column distances (objects x boxes, 0 inside) from each centroid to each box."""
    gap_y = np.maximum(boxes[None, :, 0] - cy[:, None], cy[:, None] - boxes[None, :, 1])
    gap_x = np.maximum(boxes[None, :, 2] - cx[:, None], cx[:, None] - boxes[None, :, 3])
    return np.maximum(gap_y, 0.0), np.maximum(gap_x, 0.0)


def _streak_field(
    streaks: tuple[np.ndarray, ...],
    area: np.ndarray,
    cy: np.ndarray,
    cx: np.ndarray,
    *,
    radius_px: float,
    min_streaks: int,
    min_coherence: float,
) -> np.ndarray:
    """R5c: which objects (area and centroid of each) have a field of parallel streaks
    (:func:`_streaks`) around."""
    in_field = np.zeros(area.size, dtype=bool)
    streaks, t_boxes, t_weights, t_angles, _ = streaks
    if streaks.size < min_streaks:
        return in_field
    # doubled angles: an axis at 89 degrees and one at -89 degrees are parallel
    t_vectors = t_weights * np.exp(2j * t_angles)
    # distance from each object's centroid to each streak's box (0 inside it)
    near = np.hypot(*_box_gaps(t_boxes, cy, cx)) <= radius_px
    n_near = np.count_nonzero(near, axis=1)
    streak_area = near @ t_weights
    with np.errstate(invalid="ignore", divide="ignore"):
        coherence = np.abs(near @ t_vectors) / streak_area
    # specks of texture smaller together than the object say nothing of it: a rock is not a
    # piece of them (a mojave rock of 1179 px had three 50 px streaks around it)
    return (n_near >= min_streaks) & (coherence >= min_coherence) & (streak_area >= area)


def _gradient_coherence(
    image: np.ndarray, cy: np.ndarray, cx: np.ndarray, *, radius_px: float
) -> np.ndarray:
    """R5c: coherence of the gray-level gradients in a window around each centroid.

    The structure tensor (products of Sobel gradients) summed over a square window of side
    ``radius_px``; coherence ``sqrt((Jxx - Jyy)^2 + 4 Jxy^2) / (Jxx + Jyy)`` is 1 where
    every gradient has one direction (ripples), near 0 for isotropic texture. Computed at
    half resolution (the average of 2x2 pixels also tempers the sensor noise).
    """
    small = cv2.resize(
        image.astype(np.float32),
        (max(1, image.shape[1] // 2), max(1, image.shape[0] // 2)),
        interpolation=cv2.INTER_AREA,
    )
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1)
    size = max(3, int(radius_px) // 2 | 1)
    jxx = cv2.boxFilter(gx * gx, -1, (size, size))
    jyy = cv2.boxFilter(gy * gy, -1, (size, size))
    jxy = cv2.boxFilter(gx * gy, -1, (size, size))
    rows = np.clip((cy / 2).astype(np.int64), 0, small.shape[0] - 1)
    cols = np.clip((cx / 2).astype(np.int64), 0, small.shape[1] - 1)
    xx, yy, xy = jxx[rows, cols], jyy[rows, cols], jxy[rows, cols]
    return np.sqrt((xx - yy) ** 2 + 4.0 * xy**2) / np.maximum(xx + yy, 1e-6)


def _texture_ratio(
    image: np.ndarray, labels: np.ndarray, inside: np.ndarray
) -> tuple[float, float, float]:
    """R5c: how far an object's median gray lies beyond its ring's texture (see above).

    The ring is the ground 3 to ``_TEXTURE_RING_PX`` pixels out (not the object's own
    blurred edge). Returns the ratio, the object's median gray and the ring's median gray;
    ``(inf, nan, nan)`` when the ring has fewer than 20 pixels (nothing to compare with).
    Medians and percentiles are nearest-rank (one sort each: 3x faster than numpy's).
    """
    mask = inside.view(np.uint8)
    inner = cv2.dilate(mask, _ring_kernel(3)).view(bool)
    outer = cv2.dilate(mask, _ring_kernel(_TEXTURE_RING_PX)).view(bool)
    ring = np.sort(image[outer & ~inner & (labels == 0)])
    if ring.size < 20:
        return float("inf"), float("nan"), float("nan")
    gray = np.sort(image[inside])
    gray_level = float(gray[(gray.size - 1) // 2])
    level = float(ring[(ring.size - 1) // 2])
    tail_rank = 0.05 if gray_level < level else 0.95
    tail = float(ring[int(tail_rank * (ring.size - 1))])
    return abs(gray_level - level) / max(abs(tail - level), 1.0), gray_level, level


def _streak_ratio(
    image: np.ndarray, streak_pixels: np.ndarray, gray_level: float, level: float
) -> float:
    """R5c: how far an object's median gray lies beyond the streaks of its field.

    ``streak_pixels`` are the field's streaks at the object's range (not the object); their
    median gray on the object's side of the ring's ``level`` is the texture's; ``inf`` when
    no streak pixel lies on that side.
    """
    values = image[streak_pixels]
    values = values[values < level] if gray_level < level else values[values > level]
    if values.size == 0:
        return float("inf")
    values = np.sort(values)
    streak_level = float(values[(values.size - 1) // 2])
    return abs(gray_level - level) / max(abs(streak_level - level), 1.0)
