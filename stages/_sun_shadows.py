"""Rules R6b, R6c and R7g: a rock's parts told from the ground beside it by the sun's direction.

It acts with R6 (:func:`stages._rock_parts.trim_attached_shadows`), where the heights are not
precise enough to have removed shadows (R2), on the objects R6 left whole:

* **R6b sun-side shadows** -- a dark rock with its cast shadow attached is one dark object
  whose gray levels split (Otsu) into the rock (the darker class) and the shadow (a lighter
  class, on the ground beside it). R6 removes that lighter class only when the core lies
  2.5 times further below the ground's gray level than it: a dark rock's lit face is a
  lighter class too, and R6 cannot tell the two apart by gray levels. On lava the shadow of
  a dark rock often fails that test (rock 0.14-0.3, shadow 0.3-0.4 of the ground's gray:
  ``benchmarks/bench_false_outlines.py runs/eval/lava``), and the object, rock plus shadow,
  is a false rock and a miss at IoU < 0.5. Where a lit face and a cast shadow lie tells
  them apart: the lit face on the sun's side of the rock, the shadow on the other. The
  frame's sun direction in the image comes from its clear pairs: every object with at least
  a fifth of its pixels past the high threshold and a fifth past the low one (a lit rock
  with its shaded face or shadow) points, from its light pixels' centroid to its dark ones',
  away from the sun; the pairs' unit vectors, each weighted by the smaller of its two
  pixel counts, are summed (:func:`anti_sun_direction`). With fewer than ``min_pairs`` (3)
  pairs, or when they agree less than ``min_agreement`` (0.5: the length of the weighted
  sum over the sum of weights) -- lamps from several sides, a frame with one rock (dunes) --
  the rule stays off. Else each dark object (median gray below its ground ring's, as R6)
  whose lighter class is at least ``min_gap`` (0.15) of the ground's gray level above its
  core and at most ``max_shadow`` (0.5) of it -- a cast shadow has only the sky's light, at
  most half the ground's for a sun higher than about 20 degrees (ambient 0.3 of a sun at
  elevation 20-65 degrees: 0.25-0.47) -- loses the 8-connected pieces of that class whose
  centroid lies at least 0.75 core radii from the core's, within 45 degrees of the
  anti-sun direction (:func:`trim_sun_shadows`). A lighter piece on the sun's side (a lit
  face) or beside the core stays, and so does the whole object when what is left would
  fall apart into pieces of ``min_area_px`` or more (the lighter class ran through the
  rock: a lit facet, not a shadow).
  With ``bench_segment.py --rundir`` (``--set sun_shadow_angle_deg=0`` for the old rules)
  object F1 on the catalog frames: lava 0.830 -> 0.833 (2 more true rocks, 2 fewer false
  ones), lab 0.978, mojave 0.915 and dunes (precision 1.0) unchanged; seeds lava 2-5 0.822
  -> 0.828, 0.829 -> 0.836, 0.821 -> 0.820, 0.833 -> 0.836; mojave 2-4 unchanged, 5 0.887
  -> 0.886 (a 36 px rock lost); lab 2, 3 and dunes 2, 3, 4, 5, 7, 11 unchanged. Rocks within
  2 m (``bench_describe.py --rundir DIR --labels segment``, ``--set
  segment.sun_shadow_angle_deg=0`` for the old rules), size class and median width error:
  lava's catalog 0.957 -> 0.966, 9.7 -> 9.4 %; seeds 2-5 0.931 -> 0.933, 0.935, 0.920,
  0.911 -> 0.912 and 9.2 -> 8.9, 12.6 -> 12.5, 11.5 -> 11.8, 13.1 %; mojave's catalog
  0.955, 7.4 -> 7.9 %, seeds 0.938, 0.898, 0.957 -> 0.978, 0.895 and 8.2 %, 8.0 -> 8.9,
  8.3, 9.7 % (a tighter outline, mojave seed 3 mojave_0008 rock 1 IoU 0.93 -> 0.97, is
  measured narrower: width -5 -> -14 %); lab unchanged. The cost, with ``bench_segment.py
  --stage-speed --archetypes lava --frames 3``: about 3 ms of CPU per frame (53.6 -> 56.5).

  Not on dunes: its frames hold one rock or none, no clear pair, so no sun direction; its
  false rocks on seeds 5, 7 and 11 (``benchmarks/bench_false_outlines.py``) stay. Tried
  there and dropped: R6's lighter class removed whatever its side when it lies on one side
  of the core (lab seed 2 0.959 -> 0.915, mojave's catalog 0.915 -> 0.787: a dark rock's lit
  face is such a class), with the class's texture below 0.3 of its ground ring's (lab seeds
  -0.011 and -0.014); the sun direction from the ground's shading against its heights (R^2
  0.01 on dunes' SGM heights); a light object's dark part cut one lit-face width from the
  lit face (dunes catalog lost its one true rock, lava 0.830 -> 0.806).

R6c acts after R7e (:mod:`stages._shadow_sides`; :func:`stages.segment.segment_image`), in
rows where the heights are precise, whenever R6b's angle is set:

* **R6c flat shadow sides** -- a dark rock whose faint lit face no rule found is one dark
  object of its shaded face and the cast shadow beside it (R7e splits the two only beside a
  lit face it found): ``benchmarks/bench_false_outlines.py runs/eval/lava`` shows 26 of the
  52 false objects on missed rocks that would reach IoU 0.5 without their off-rock pixels.
  The heights tell the shadow: it lies on the ground, the face stands up (lava's near rocks
  9-16 mm at their median, their shadows -4 to +1 mm, noise 4-5 mm). So in each dark object
  of at least 40 px, in rows whose ground noise sigma is at most R7e's ``max_noise_m``, the
  pixels at ground level (below R7e's flat level ``min(max(flat_tol_m, 2 sigma),
  max(min_height_m, 3 sigma) / 2)``) lying at least 0.75 radii from the centroid of the
  object's pixels above it, within ``max_angle_deg`` (30) degrees of the frame's anti-sun
  direction (:func:`anti_sun_direction`), are dropped when their mean contrast lies at least
  ``min_gap_bands`` (0.5) threshold bands below the rest's (a cast shadow is darker than the
  rock's shaded face: without that test lava_0008 rock 13, whose anti-sun flank the stereo
  flattens, lost a fifth of its pixels and its obstacle class) and what is left is one piece
  (pieces of a tenth of it apart are dropped too) of ``min_area_px`` or more, at least 0.6 of
  it above ground level (:func:`trim_flat_shadow_sides`). With ``bench_segment.py --rundir``
  object F1 (segment v39 -> v40): lava's catalog 0.848 -> 0.851 (2 more true rocks, 2 fewer
  false: lava_0006 rock 10 IoU 0.39 -> 0.61, lava_0011 rock 11 0.49 -> 0.57), seeds 2-5
  0.852, 0.846 -> 0.848, 0.834 -> 0.837, 0.854; mojave's catalog 0.920, seeds 0.918, 0.908,
  0.902 -> 0.904, 0.899 -> 0.905; lab (catalog 0.981, seeds 0.959, 0.964) and dunes
  (catalog, seeds 2, 3, 4, 5, 7, 11: precision 1, 1, 1, 1, 0.75, 0.86, 0.83) unchanged.
  Rocks within 2 m (``bench_describe.py --rundir DIR --labels segment``), size class and
  median width error: lava's catalog 0.958 -> 0.959, 9.4 %; mojave 0.956, 7.6 % and lab
  0.931, 5.7 % unchanged. Tried and dropped: the pixels raised above R7e's raise threshold
  (3 sigma, 12-15 mm) as the rock (most near rocks are lower: nothing trimmed); 45 degrees
  with 0.7 of the rest above ground level (lava seeds 2 and 5 -0.002); whole 8-connected
  flat pieces instead of pixels (the rock's flattened flanks go with the shadow: lava 0.848
  -> 0.846); no darkness test (lava's near
  class 0.958 -> 0.950). Most dark rocks found as shaded face plus shadow lie 3-6 m away, out
  of its reach: rows noisier than 7.5 mm, and their 1-2 cm do not stand up there (lava_0000
  objects 52 and 55: the rock pixels' median of the height product -11 and -12 mm).

R7g acts after R7b-R7d (:mod:`stages._rock_parts`, :mod:`stages._outlines`), on the objects
as those rules left them:

* **R7g pieces off the sun's side** -- the threshold mask takes pixels past either threshold,
  so a light rock on lava's blotchy ground is often one object with the dark blotches of
  ground texture that touch it (a dark rock with light ones), and the object holds the rock
  plus as much ground again (``benchmarks/bench_misses.py``'s fat misses). A rock's pixels
  on the other side of the ground's gray level are its other face: a light rock's shaded
  face lies away from the sun, a dark rock's lit face toward it. So where the frame's sun
  direction is known (:func:`anti_sun_direction`), in each object of at least 40 pixels,
  each 8-connected piece of pixels at least one band out on the other side of the ground
  level (past the other threshold) whose centroid lies at least 0.75 radii (of the rest of
  the object) from the rest's centroid, more than ``max_side_deg`` (105) degrees from the
  side the other face would lie on, is dropped (:func:`trim_off_side_pieces`); a piece
  near the rest's centre is on the rock whatever its side. Over lava's catalog frames 26 of
  the 31 such pieces of 3 px or more lay off the truth rock (seed 2: 18 of 21; measured
  without the 40 px and 0.75 radii limits). With ``bench_segment.py --rundir`` (``--set
  off_side_deg=0`` for the old rules; lava seeds with ``two_face_sigmas=3``) object F1:
  lava's catalog 0.838 -> 0.837 (lava_0005 rock 8, which R8b found as a faint blob, is not
  found: the trimmed pixels change R8b's candidates), seeds 2-5 0.833 unchanged, 0.840 ->
  0.843, 0.828 -> 0.829, 0.841 unchanged; mojave seed 5 0.886 -> 0.887, mojave's catalog
  and seeds 2-4, lab (catalog, seeds 2, 3) and dunes (catalog, seeds 2, 3, 4, 5, 7, 11; no
  sun direction) unchanged. Rocks within 2 m (``bench_describe.py --rundir DIR --labels
  segment``, ``--set segment.off_side_deg=0`` for the old rules), median width error and
  size class: lava's catalog 9.1 %, 0.966 unchanged; seed 3 12.8 %, 0.936 -> 0.945; seed 5
  12.1 -> 11.0 %, 0.922 -> 0.932; seeds 2 and 4 unchanged; mojave's catalog 7.9 -> 7.4 %,
  mojave seeds 2, 3, 5 and lab unchanged. Without the 0.75 radii lava's seed 2 lost two
  30-px rocks at IoU 0.50-0.52 (0.833 -> 0.830); without it, 135 degrees gained nothing
  (catalog 0.837, seeds 0.832, 0.840, 0.829, 0.841). Pieces 1.5 bands out (instead of 1)
  keep lava's catalog at 0.838 and the seeds' gains, but none of the widths' and classes'
  (seed 3 0.936, seed 5 12.1 %, mojave 7.9 %), and mojave seed 5 at 0.886; 0.6 bands gives
  the F1 of 1 band.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._heights import check_height_inputs
from ._regions import _extend_box
from ._select import median_u8

__all__ = [
    "anti_sun_direction",
    "trim_flat_shadow_sides",
    "trim_off_side_pieces",
    "trim_sun_shadows",
]

# A clear pair: an object with this share of its pixels past each threshold ...
_PAIR_SHARE = 0.2
# ... at least this many pairs in a frame ...
_MIN_PAIRS = 3
# ... agreeing at least this much (weighted resultant length, 0..1).
_MIN_AGREEMENT = 0.5
# The lighter class is at least this fraction of the ground's gray above the core ...
_MIN_GAP = 0.15
# ... and at most this fraction of the ground's gray: a cast shadow has only the sky's light.
_MAX_SHADOW = 0.5
# Each class holds at least this share of the object (as R6).
_MIN_SHARE = 0.1
# A shadow piece lies this many core radii from the core's centroid ...
_MIN_OFFSET = 0.75
# ... within this angle of the anti-sun direction.
_MAX_ANGLE_DEG = 45.0
# Objects smaller than this are not judged (as R6).
_MIN_PX = 40
# The ground's gray level: the median of a ring this wide around the object (as R6).
_RING_PX = 3
# R7g: an object's pieces on the other side of the ground level farther than this (degrees)
# from where its other face would lie are dropped
_MAX_SIDE_DEG = 105.0
# R6c: flat pixels within this angle of the anti-sun direction ...
_FLAT_ANGLE_DEG = 30.0
# ... this many threshold bands darker than the rest of the object are dropped ...
_FLAT_GAP_BANDS = 0.5
# ... when at least this share of what is left stands above ground level
_FLAT_STANDING = 0.6


def anti_sun_direction(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    min_pairs: int = _MIN_PAIRS,
    min_agreement: float = _MIN_AGREEMENT,
) -> np.ndarray | None:
    """The frame's direction away from the sun, from its lit objects' dark sides (R6b).

    Parameters
    ----------
    labels : (M, N) ndarray of int
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands
        (:func:`stages._depth_rules.gray_contrast`): above 1 past the high threshold, below
        -1 past the low one.
    min_pairs : int
        ``>= 1``; fewer clear pairs give no direction.
    min_agreement : float
        In ``[0, 1]``; the pairs' weighted resultant length must reach this.

    Returns
    -------
    (2,) ndarray of float or None
        Unit vector (rows, columns) pointing away from the sun in the image, or None when
        the frame does not say.
    """
    if labels.shape != contrast.shape:
        raise ValueError(
            f"labels {labels.shape} and contrast {contrast.shape} must have one shape"
        )
    if min_pairs < 1 or not 0 <= min_agreement <= 1:
        raise ValueError(
            f"need min_pairs >= 1 and 0 <= min_agreement <= 1, got {min_pairs} and "
            f"{min_agreement}"
        )
    count = int(labels.max())
    if count == 0:
        return None
    sums, _ = _object_sums(labels, contrast, count)
    return _direction(sums, min_pairs=min_pairs, min_agreement=min_agreement)


def _object_sums(
    labels: np.ndarray, contrast: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per object 0..count (``labels``' ids, count its largest), in one compiled pass: row
    0 its pixels, then per side (past the high threshold, past the low one) pixels and the
    sums of their rows and columns (rows 1-6: whole numbers, the same floats as
    np.bincount's in any order), row 7 the sum of its contrast in raster order (the
    float64 sum ``np.bincount(owners, weights=...)`` adds); and the boxes of
    :func:`stages._regions._object_boxes` (``test_sun_shadows.py`` compares all)."""
    sums = np.zeros((8, count + 1))
    boxes = np.empty((count + 1, 4), np.int64)
    boxes[:, 0::2] = np.iinfo(np.int64).max
    boxes[:, 1::2] = -1
    _object_pass(np.ascontiguousarray(labels), np.ascontiguousarray(contrast), sums, boxes)
    return sums, boxes


def _direction(sums: np.ndarray, *, min_pairs: int, min_agreement: float) -> np.ndarray | None:
    """:func:`anti_sun_direction` from :func:`_object_sums`' rows 0-6."""
    size = sums[0]
    centroids = []
    for n, y, x in (sums[1:4], sums[4:7]):
        centroids.append((n, y / np.maximum(n, 1), x / np.maximum(n, 1)))
    (n_lit, y_lit, x_lit), (n_dark, y_dark, x_dark) = centroids
    pair = (n_lit >= _PAIR_SHARE * size) & (n_dark >= _PAIR_SHARE * size) & (size > 0)
    pair[0] = False
    offsets = np.stack([y_dark - y_lit, x_dark - x_lit], axis=1)[pair]
    lengths = np.hypot(offsets[:, 0], offsets[:, 1])
    keep = lengths >= 1.0  # a pair whose halves share a centroid says no side
    if np.count_nonzero(keep) < min_pairs:
        return None
    weights = np.minimum(n_lit, n_dark)[pair][keep]
    total = (offsets[keep] / lengths[keep, None] * weights[:, None]).sum(axis=0)
    length = float(np.hypot(*total))
    if length < min_agreement * float(weights.sum()):
        return None
    return total / length


def trim_sun_shadows(
    labels: np.ndarray,
    image: np.ndarray,
    contrast: np.ndarray,
    *,
    skip: np.ndarray | None = None,
    min_gap: float = _MIN_GAP,
    max_shadow: float = _MAX_SHADOW,
    max_angle_deg: float = _MAX_ANGLE_DEG,
    min_area_px: int = 30,
) -> tuple[np.ndarray, int]:
    """Rule R6b: drop a dark object's lighter pieces on the frame's shadow side (module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    image : (M, N) ndarray of uint8
        Reference gray image.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands.
    skip : (n + 1,) ndarray of bool, optional
        Objects not to judge (those R6 trimmed already).
    min_gap, max_shadow : float
        In ``[0, 1]``, fractions of the ground's gray level: the lighter class lies at least
        ``min_gap`` above the core and at most ``max_shadow`` times the ground's gray.
    max_angle_deg : float
        In ``[0, 90]``; a shadow piece lies within this angle of the anti-sun direction;
        0 disables.
    min_area_px : int
        ``>= 1``; an object that a trim would split into pieces this large is left whole.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids; shadow pixels set to 0 (objects are not renumbered).
    trimmed : int
        Objects that lost a shadow.
    """
    if not labels.shape == image.shape == contrast.shape:
        raise ValueError(
            f"labels {labels.shape}, image {image.shape} and contrast {contrast.shape} must "
            "have one shape"
        )
    if not 0 <= min_gap <= 1 or not 0 <= max_shadow <= 1 or not 0 <= max_angle_deg <= 90:
        raise ValueError(
            "need min_gap and max_shadow in [0, 1] and max_angle_deg in [0, 90], got "
            f"{min_gap}, {max_shadow} and {max_angle_deg}"
        )
    if min_area_px < 1:
        raise ValueError(f"min_area_px must be >= 1, got {min_area_px}")
    out = labels.copy()
    count = int(labels.max())
    if count == 0 or max_angle_deg == 0:
        return out, 0
    if skip is not None and skip.shape != (count + 1,):
        raise ValueError(f"skip must hold one flag per id 0..{count}, got shape {skip.shape}")
    # the sun's side, the objects' sizes, darkness and boxes from one pass
    sums, boxes = _object_sums(labels, contrast, count)
    away = _direction(sums, min_pairs=_MIN_PAIRS, min_agreement=_MIN_AGREEMENT)
    if away is None:
        return out, 0
    cos_max = float(np.cos(np.radians(max_angle_deg)))
    # only dark objects large enough are judged (mean contrast below 0)
    judged = (sums[0] >= _MIN_PX) & (sums[7] < 0)
    if skip is not None:
        judged &= ~skip
    kernel = np.ones((2 * _RING_PX + 1, 2 * _RING_PX + 1), np.uint8)
    rows, cols = labels.shape
    trimmed = 0
    for k in range(1, count + 1):
        y0, y1, x0, x1 = boxes[k]
        if y1 < y0 or not judged[k]:
            continue
        y0, x0 = max(0, y0 - _RING_PX), max(0, x0 - _RING_PX)
        y1, x1 = min(rows, y1 + _RING_PX + 1), min(cols, x1 + _RING_PX + 1)
        window = labels[y0:y1, x0:x1]
        inside = window == k
        gray = image[y0:y1, x0:x1][inside]
        if gray.size < _MIN_PX:
            continue
        ring = cv2.dilate(inside.view(np.uint8), kernel).view(bool) & (window == 0)
        if not ring.any():
            continue
        ground = median_u8(image[y0:y1, x0:x1][ring])
        if median_u8(gray) >= ground:
            continue  # a light object: its shadow is darker than it, never its lighter class
        split, _ = cv2.threshold(gray.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        core = gray <= split
        if not _MIN_SHARE <= core.mean() <= 1 - _MIN_SHARE:
            continue
        core_gray, light_gray = float(gray[core].mean()), float(gray[~core].mean())
        if light_gray - core_gray < min_gap * ground or light_gray > max_shadow * ground:
            continue
        shadow = _shadow_pieces(inside, core, away, cos_max)
        if not shadow.any():
            continue
        _, pieces = cv2.connectedComponents((inside & ~shadow).view(np.uint8), connectivity=8)
        sizes = np.sort(np.bincount(pieces.ravel())[1:])
        if (sizes[:-1] >= min_area_px).any():
            continue  # the lighter class ran through the rock: a facet, not a shadow
        out[y0:y1, x0:x1][shadow] = 0
        trimmed += 1
    return out, trimmed


def trim_off_side_pieces(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    max_side_deg: float = _MAX_SIDE_DEG,
    min_bands: float = 1.0,
) -> tuple[np.ndarray, int]:
    """Rule R7g: drop the pieces of an object's other side that lie where no face can.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands; the sign of an
        object's mean says its side.
    max_side_deg : float
        In ``[0, 180]``; an 8-connected piece of an object's pixels at least ``min_bands``
        out on the other side of the ground level whose centroid, seen from the centroid of
        the object's other pixels, lies more than this many degrees from the side its other
        face would lie on (a light object's shaded face away from the sun, a dark object's
        lit face toward it) is dropped; 0 or 180 disables.
    min_bands : float
        ``> 0`` threshold bands.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids (objects are not renumbered; an object of such pieces only is kept).
    trimmed : int
        Pixels dropped.
    """
    if labels.shape != contrast.shape:
        raise ValueError(f"labels {labels.shape} and contrast {contrast.shape} must have one shape")
    if not 0 <= max_side_deg <= 180 or not min_bands > 0:
        raise ValueError(
            "need max_side_deg in [0, 180] (0 disables) and min_bands > 0, got "
            f"{max_side_deg} and {min_bands}"
        )
    count = int(labels.max())
    if count == 0 or not 0 < max_side_deg < 180:
        return labels, 0
    # the sun's side, the objects' sizes, sides and boxes from one pass
    sums, boxes = _object_sums(labels, contrast, count)
    away = _direction(sums, min_pairs=_MIN_PAIRS, min_agreement=_MIN_AGREEMENT)
    if away is None:
        return labels, 0
    side = np.where(sums[7] >= 0, 1.0, -1.0)
    # pixels past the other threshold band of their object's side
    side_of = side.astype(np.float32)
    side_of[0] = 0.0
    other = np.empty(labels.shape, bool)
    has_other = np.zeros(count + 1, bool)
    # the bar in contrast's float type, as numpy compares an array with a Python float
    threshold = np.asarray(-min_bands, dtype=np.result_type(contrast.dtype, np.float32))[()]
    _other_pass(
        np.ascontiguousarray(labels),
        np.ascontiguousarray(contrast),
        side_of,
        threshold,
        other,
        has_other,
    )
    # a small object's centroids say little about where its faces lie
    has_other &= sums[0] >= _MIN_PX
    has_other[0] = False
    cos_max = float(np.cos(np.radians(max_side_deg)))
    out = labels.copy()
    trimmed = 0
    for k in np.flatnonzero(has_other):
        y0, y1, x0, x1 = boxes[k]
        window = (slice(y0, y1 + 1), slice(x0, x1 + 1))
        inside_k = labels[window] == k
        pieces_mask = inside_k & other[window]
        core = inside_k & ~pieces_mask
        if not core.any():
            continue
        rows, cols = np.nonzero(core)
        n, pieces, _, centroids = cv2.connectedComponentsWithStats(
            pieces_mask.view(np.uint8), connectivity=8
        )
        # a light object's other face (shaded) lies away from the sun, a dark one's toward
        expected = away * side[k]
        offsets = centroids[1:, ::-1] - np.array([rows.mean(), cols.mean()])
        lengths = np.hypot(offsets[:, 0], offsets[:, 1])
        # a piece near the core's centre lies on the rock, whatever its side
        radius = np.sqrt(rows.size / np.pi)
        off = (lengths >= _MIN_OFFSET * radius) & (offsets @ expected < cos_max * lengths)
        if off.any():
            drop = np.isin(pieces, np.flatnonzero(off) + 1)
            out[window][drop] = 0
            trimmed += int(np.count_nonzero(drop))
    return out, trimmed


def _shadow_pieces(
    inside: np.ndarray, core: np.ndarray, away: np.ndarray, cos_max: float
) -> np.ndarray:
    """The 8-connected pieces of an object's lighter class (``~core`` over its pixels)
    whose centroid lies at least ``_MIN_OFFSET`` core radii from the core's centroid,
    within ``acos(cos_max)`` of ``away``."""
    ys, xs = np.nonzero(inside)
    radius = np.sqrt(np.count_nonzero(core) / np.pi)
    cy, cx = ys[core].mean(), xs[core].mean()
    light = np.zeros_like(inside)
    light[ys[~core], xs[~core]] = True
    n_pieces, pieces = cv2.connectedComponents(light.view(np.uint8), connectivity=8)
    shadow = np.zeros_like(inside)
    for j in range(1, n_pieces):
        py, px = np.nonzero(pieces == j)
        offset = np.array([py.mean() - cy, px.mean() - cx])
        length = float(np.hypot(*offset))
        if length >= _MIN_OFFSET * radius and offset @ away >= cos_max * length:
            shadow |= pieces == j
    return shadow


@njit(cache=True)
def _object_pass(labels, contrast, sums, boxes):  # pragma: no cover - numba
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k <= 0:
                continue
            sums[0, k] += 1.0
            value = contrast[y, x]
            sums[7, k] += np.float64(value)
            if value > 1:
                sums[1, k] += 1.0
                sums[2, k] += y
                sums[3, k] += x
            elif value < -1:
                sums[4, k] += 1.0
                sums[5, k] += y
                sums[6, k] += x
            _extend_box(boxes, k, y, x)


@njit(cache=True)
def _other_pass(labels, contrast, side_of, threshold, other, has_other):  # pragma: no cover
    """R7g's pixels past the other threshold band of their object's side: ``(labels > 0)
    & (contrast * side_of[labels] <= threshold)`` (the product in ``contrast``'s float
    type, as numpy's), and which objects hold one."""
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            hit = k > 0 and contrast[y, x] * side_of[k] <= threshold
            other[y, x] = hit
            if hit:
                has_other[k] = True


def trim_flat_shadow_sides(
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    row_sigma: np.ndarray,
    *,
    max_noise_m: float,
    flat_tol_m: float,
    min_height_m: float,
    max_angle_deg: float = _FLAT_ANGLE_DEG,
    min_gap_bands: float = _FLAT_GAP_BANDS,
    min_standing: float = _FLAT_STANDING,
    min_area_px: int = 30,
) -> tuple[np.ndarray, int]:
    """Rule R6c: drop a dark object's flat, darker pixels on the frame's shadow side (module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands.
    relative : (M, N) ndarray of float
        Heights above the local ground (R0), metres; NaN where invalid.
    row_sigma : (M,) ndarray of float
        Ground height noise of each row (R0b), metres.
    max_noise_m : float
        Rows noisier than this are not judged; ``<= 0`` disables.
    flat_tol_m, min_height_m : float
        ``>= 0`` and ``> 0``: a pixel lies at ground level below
        ``min(max(flat_tol_m, 2 sigma), max(min_height_m, 3 sigma) / 2)`` (R7e's flat level).
    max_angle_deg : float
        In ``[0, 90]``; a dropped pixel lies within this angle of the anti-sun direction,
        seen from the centroid of the object's pixels above ground level; 0 disables.
    min_gap_bands : float
        ``>= 0``; the dropped pixels' mean contrast lies this many bands below the rest's.
    min_standing : float
        In ``[0, 1]``; at least this share of what is left lies above ground level.
    min_area_px : int
        ``>= 1``; what is left is one 8-connected piece of at least this many pixels (pieces
        of at most a tenth of it apart, dropped too).

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids (objects are not renumbered).
    trimmed : int
        Pixels dropped.
    """
    check_height_inputs(labels, contrast, relative, row_sigma, noise_name="row_sigma")
    if not (
        0 <= max_angle_deg <= 90
        and min_gap_bands >= 0
        and 0 <= min_standing <= 1
        and min_area_px >= 1
        and flat_tol_m >= 0
        and min_height_m > 0
    ):
        raise ValueError(
            "need max_angle_deg in [0, 90], min_gap_bands >= 0, min_standing in [0, 1], "
            "min_area_px >= 1, flat_tol_m >= 0 and min_height_m > 0, got "
            f"{max_angle_deg}, {min_gap_bands}, {min_standing}, {min_area_px}, {flat_tol_m} "
            f"and {min_height_m}"
        )
    count = int(labels.max())
    if count == 0 or max_angle_deg == 0 or max_noise_m <= 0:
        return labels, 0
    # the sun's side, the objects' sizes, darkness and boxes from one pass
    sums, boxes = _object_sums(labels, contrast, count)
    away = _direction(sums, min_pairs=_MIN_PAIRS, min_agreement=_MIN_AGREEMENT)
    if away is None:
        return labels, 0
    cos_max = float(np.cos(np.radians(max_angle_deg)))
    sigma = np.where(np.isfinite(row_sigma), row_sigma, np.inf)[:, None]
    flat_m = np.minimum(np.maximum(flat_tol_m, 2 * sigma), np.maximum(min_height_m, 3 * sigma) / 2)
    precise_rows = sigma <= max_noise_m
    judged = (sums[0] >= _MIN_PX) & (sums[7] < 0)
    judged[0] = False
    out = labels.copy()
    trimmed = 0
    for k in np.flatnonzero(judged):
        y0, y1, x0, x1 = boxes[k]
        window = (slice(y0, y1 + 1), slice(x0, x1 + 1))
        inside_k = labels[window] == k
        # in the object's box only: its standing and flat pixels (NaN compares False: an
        # invalid height is neither)
        heights, level = relative[window], flat_m[y0 : y1 + 1]
        precise = inside_k & np.isfinite(heights) & precise_rows[y0 : y1 + 1]
        standing = precise & (heights >= level)
        flat = precise & (heights < level)
        if np.count_nonzero(standing) < min_area_px // 2 or not flat.any():
            continue
        sy, sx = np.nonzero(standing)
        radius = np.sqrt(sy.size / np.pi)
        fy, fx = np.nonzero(flat)
        dy, dx = fy - sy.mean(), fx - sx.mean()
        length = np.hypot(dy, dx)
        side = (dy * away[0] + dx * away[1] >= cos_max * length) & (
            length >= _MIN_OFFSET * radius
        )
        if not side.any():
            continue
        cut = np.zeros_like(inside_k)
        cut[fy[side], fx[side]] = True
        rest = inside_k & ~cut
        c = contrast[window]
        if not c[cut].mean() <= c[rest].mean() - min_gap_bands:
            continue  # a cast shadow is clearly darker than the rock's shaded face
        n, pieces = cv2.connectedComponents(rest.view(np.uint8), connectivity=8)
        if n < 2:
            continue
        sizes = np.bincount(pieces.ravel())[1:]
        main = int(np.argmax(sizes))
        if sizes[main] < min_area_px or sizes.sum() - sizes[main] > 0.1 * sizes.sum():
            continue  # what is left falls apart: the flat pixels ran through the rock
        keep = pieces == main + 1
        if np.count_nonzero(keep & standing) < min_standing * np.count_nonzero(keep):
            continue  # what is left does not stand up: no rock to trim to
        drop = inside_k & ~keep
        out[window][drop] = 0
        trimmed += int(np.count_nonzero(drop))
    return out, trimmed
