"""Rules R4b and R6-R7d: objects made whole rocks -- necks cut, attached shadows off,
halves and faces on, faint rims off.

They act on labelled objects (:func:`stages._regions.label_objects`), after R4 (split at
depth edges, :mod:`stages._regions`); R4b comes first, R6-R7c after R5-R5c (streaks, ripple
fields, :mod:`stages._texture_rules`), R7d last:

* **R4b necks** -- rocks that touch at one range are one component of the threshold mask,
  and R4 cannot part them: far away the step in disparity between a rock and the one behind
  it is a fraction of a pixel (0.2-0.5 px at 4 m on lava), far below any usable jump. On
  lava's frames the commonest kind of object too fat for the rock it holds (about half of
  them, 85 of 170 over the catalog run and seeds 2-5) holds a neighbouring rock too, mostly
  small far rocks stacked in the view. Where two such rocks meet through a narrow neck their
  union is a dumbbell: an object splits where it narrows to at most ``neck_ratio`` (0.5) of
  the depth (distance to its edge) of the lobes on both sides, lobes at least 2 px deep,
  each of at least ``min_area_px`` pixels, no longer than 2.5 times their width (a rock, not
  the piece of a streak R5 would then drop), and each at least 0.05 more solid than the
  object (two compact blobs, not one ragged one; solidity as in R7); every other pixel of
  the object goes to the lobe it reaches first (:func:`split_at_necks`). With
  ``bench_segment.py --rundir`` (``--set neck_ratio=0`` for the old rules), object F1 on
  lava's catalog frames 0.795 -> 0.795 (1 more true rock, 1 more false one); seeds 2-5 (runs
  of the catalog with ``seed =`` changed): 0.778 -> 0.781, 0.804 -> 0.805, 0.809 -> 0.811,
  0.794 -> 0.804 (15 more true rocks and 2 fewer false ones over the four); mojave 0.905 ->
  0.908, seed 2 0.915 -> 0.916, seed 3 0.893 -> 0.892 (1 more true rock, 2 more false
  ones); lab (catalog, seed 2) and dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged. It
  is a small lever: most merged rocks overlap in the view without a neck. Without the
  elongation limit lab lost 4 rocks of one frame (0.943 -> 0.932: a split-off piece dropped
  as a streak, the rest regrown by R7) and lava's catalog frames fell to 0.792 (1 true rock
  fewer, 4 false ones more); a solidity gain of 0 or 0.1 instead of 0.05 gives lava within
  0.003 of these figures; a ratio of 0.4 gains nothing on seed 2, 0.7 as much as 0.5. The
  median width error of lava's rocks within 2 m (``bench_describe.py --rundir DIR --labels
  segment``, ``--set segment.neck_ratio=0`` for the old rules) went 10.5 -> 10.4 % on the
  catalog frames, 8.1, 12.6 % unchanged on seeds 2 and 3, 12.2 -> 12.1 % on seed 4 and
  11.3 -> 11.7 % on seed 5 (one more near rock matched); mojave's and lab's unchanged. After
  the merge of R8 (on in lava's catalog) and describe v6: object F1 on lava's catalog frames
  0.812 -> 0.812 (1 more true rock, 1 more false one), widths 10.5 -> 9.8 % on the catalog
  frames, seeds 2-5 7.9 and 12.0 % unchanged, 11.4 -> 11.5 %, 13.0 -> 12.8 %; mojave and
  lab unchanged.
* **R6 attached shadows** -- a cast shadow touching a dark rock is dark too, so intensity
  keeps it as rock; where depth cannot tell (a shadow lies on the ground, but noisy heights
  are smoothed across it), gray levels can: an object darker than its background ring whose
  gray levels split (Otsu) into a dark core and a lighter class at least ``min_gap`` levels
  apart, each holding >= ``min_share`` of the object, the core ``core_ratio`` times further
  below the ground than the lighter class, loses the lighter class
  (:func:`trim_attached_shadows`). Light objects are left alone: their shadows are darker
  than the ground and never merged with them.
* **R7 weak halves** -- where a threshold lies close to a rock's own gray level, part of the
  rock lies just inside it and the object covers half the rock (IoU below 0.5: a miss, and
  often a false positive too). On lava the low threshold sits 2.5 sigmas from the ground
  (the catalog's ``band_sigmas``): a dark rock at gray 30-46 on ground at 73 with the
  threshold at 36 was found as a crescent; of lava's catalog misses 58 were such halves
  (20 % to 50 % of the rock found, the rest between the thresholds). So, after every other
  rule, each object grows -- hysteresis, up to ``weak_growth_px`` (12) 8-connected steps --
  into pixels past neither threshold but at least ``weak_bands`` (0.7) threshold bands
  from the ground on its own side (the sign of its mean contrast), and keeps that growth
  only when its solidity (pixels over the pixel area of their convex hull) drops by no
  more than 0.02 (pixels make a straight cut look more solid than an arc: a digital disk
  of radius 10 scores 0.943, its half 0.958): the rest of a rock completes a compact blob,
  growth along a shading gradient or into a blotch of ground texture makes it ragged
  (:func:`grow_weak_halves`). Pixels past a threshold that a rule removed (R2's flat
  pixels, R6's shadow) stay removed. With ``bench_segment.py --rundir`` (``--set
  weak_bands=0`` for the old rules), object F1 on the catalog frames: lab 0.938 -> 0.943,
  mojave 0.889 -> 0.894, lava 0.732 -> 0.757 (17 more true rocks, 16 fewer false ones),
  dunes unchanged; seed 2 (the catalogs with ``seed = 2``): lab 0.893 -> 0.899, mojave
  0.900 -> 0.903, lava 0.738 -> 0.744; seed 3: lab 0.914 unchanged, mojave 0.867 ->
  0.875, lava 0.751 -> 0.760; dunes seeds 2, 3, 7 and 11 unchanged (precision 1, 0.67,
  0.86, 0.83). The matched rocks' mean IoU drops by up to 0.016 (lab 0.949 -> 0.933: a
  blurred rim grows too). Without the solidity test lab fell 0.938 -> 0.895 (seed 2:
  0.870; objects grew 2-4 times along the lamp's falloff) and dunes seed 11 traded a true
  rock for a false one; growing into removed pixels too cost lab 0.938 -> 0.914; without
  the 0.02 slack the figures are within 0.003. 0.6 bands cost lab (0.933) and mojave seed
  2 (0.895), 0.8 gains less (lava 0.752, seed 2 0.738); 4 steps cost lab seed 3 (0.908),
  20 equal 12.
  Mojave's half-found rocks are mostly lit rocks whose shaded half has the ground's gray:
  no threshold band reaches them.
* **R7b opposite halves** -- a rock lit from one side can be found as two objects: its lit
  face lighter than the ground, its shaded face darker, a few pixels of ground-gray
  (the terminator) between them. Each is half the rock: two false positives, or one and a
  miss. A lighter and a darker object whose pixels come within ``join_gap_px`` (5) of
  each other, facing over at least ``sqrt(area)`` of the smaller one's pixels, are joined
  -- with the background between them (a closing of that radius) -- when the union is at
  most 0.05 less solid than the more solid half (:func:`join_opposite_halves`): two
  halves make one compact blob, a rock and a neighbour beside it do not. A lit rock and
  its cast shadow pass that test too; on the catalog frames the joins still removed far
  more false positives than true rocks. With ``--set join_gap_px=0`` for the old rules
  (R7 on in both), object F1 on the catalog frames: mojave 0.894 -> 0.897, lava 0.757 ->
  0.771 (4 more true rocks, 17 fewer false ones; 13 pairs joined), lab and dunes unchanged
  (no pair); seed 2: lab 0.899 unchanged, mojave 0.903 -> 0.910, lava 0.744 -> 0.750;
  seed 3: lab 0.914 unchanged, mojave 0.875 -> 0.878, lava 0.760 -> 0.769; dunes seeds 2,
  3, 7 and 11 unchanged. Without R7 it gains less (lava 0.732 -> 0.747). A gap of 4 gave
  lava 0.769 (seed 2 0.751), 6 lava seed 2 0.744; a slack of 0 joined 1-4 pairs.
* **R7c other face** -- a rock lit from above shows a face lighter than the ground and a
  shaded side darker; often only one is found as an object (the other too small, or voted
  flat, on its own) and the object covers under half the rock: of lava's catalog rocks found
  that thinly, about a third have their missing part 0.3 or more bands on the other side of
  the ground level. Last, after R7b, each object grows -- up to ``weak_growth_px``
  8-connected steps -- into background pixels at least ``face_bands`` (0.5) threshold bands
  from the ground on the *other* side (a dark object into lighter pixels), past a threshold
  or not (a lit face a rule removed alone is judged again as part of its rock), and keeps
  that growth when it adds at least a fifth of its pixels (a face, not a rim) and its
  solidity drops by no more than 0.02, as in R7 (:func:`grow_other_faces`). With
  ``bench_segment.py --rundir`` (``--set face_bands=0`` for the old rules) object F1 on the
  catalog frames: lava 0.791 -> 0.795 (3 more true rocks, 3 fewer false ones), lab, mojave
  and dunes unchanged; seed 2: lava 0.773 -> 0.778, mojave 0.912 -> 0.915, lab unchanged;
  seed 3: lava 0.795 -> 0.804, lab 0.914 -> 0.919, mojave unchanged; seeds 4 and 5: lava
  0.797 -> 0.807 and 0.801 -> 0.794 (the one loss), mojave 0.872 -> 0.880 and 0.860 ->
  0.869; dunes seeds 2, 3, 4, 5, 7 and 11 unchanged. The cost is in the widths of a few near
  rocks whose face takes in a light blotch of ground beside it: ``arroyo evaluate``'s width
  error of rocks within 2 m went 10.6 -> 11.4 % on lava's catalog frames (4 of 99 rocks
  changed, all wider), 8.4 -> 8.3 % on seed 2, 12.6 % unchanged on seed 3; mojave and lab
  unchanged. Without the fifth, lava gained 0.797 but mojave's matched rocks lost mean IoU
  (0.824 -> 0.819: rims of light pixels around dark rocks); 0.6 bands gains less (lava seed
  2 0.773); growing only into pixels past neither threshold gains less (mojave seed 2 0.909,
  lab seed 3 0.914); an opening of the growth (3 or 5 px) against tails gains less.
* **R7d faint rims** -- a rock's edge is blurred over a pixel or two, and where its gray
  level is halfway between the rock's and the ground's lies its outline; R7 (growing into
  pixels 0.7 bands out), R7b's closed gap and, around a rock of high contrast, the threshold
  itself take rim pixels far nearer the ground's gray than that, which widen a small rock by
  a pixel on each side. After R7c every
  outline pixel (a 4-neighbour in the background) on the object's own side of the ground
  level but less than ``rim_fraction`` (0.3) of the object's median contrast from it is
  dropped, once; pixels on the other side (a face R7b or R7c joined) stay
  (:func:`trim_faint_rims`). With ``bench_segment.py --rundir`` (``--set rim_fraction=0``
  for the old rules; R4b on in both) object F1 on lava's catalog frames 0.812 -> 0.815 (2
  more true rocks, 2 fewer false ones); seeds 2-5 0.781 -> 0.784, 0.805 -> 0.808, 0.811
  and 0.804 unchanged (with ``--set blob_sigmas=4``, R8 on as in the catalog: 0.802 ->
  0.805, 0.815 -> 0.818, 0.818 -> 0.819, 0.821 unchanged); mojave 0.908 -> 0.911, seed 2
  0.916 -> 0.913 (a rock at IoU 0.50 fell below), seed 3 0.892 -> 0.895; lab (catalog, seed
  2) and dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged. Median width error of the rocks
  within 2 m (``bench_describe.py --rundir DIR --labels segment``, describe v6): lava's
  catalog 9.8 % unchanged, seeds 2-5 7.9, 12.0, 11.5 % unchanged and 12.8 -> 12.5 %; mojave
  unchanged; lab 7.5 -> 7.1 %, lab seed 2 7.8 -> 7.9 %. Measured before describe v6 (which
  now leaves more of a rim out of the width itself) the widths gained more: lava's catalog
  10.4 -> 10.3 %, seed 2 8.1 -> 7.9 %, seed 5 11.7 -> 11.1 %. A fraction of 0.2 gains less
  (lava's catalog 0.814, seeds 2 and 3 0.781, 0.806), 0.4 about as much on lava (0.814,
  0.784, 0.813, 0.810, 0.804) but nothing on mojave's seed 3 (0.892); 0.5 costs lava's
  catalog frames and seed 2 (0.809, 0.777); peeling twice instead of once changed nothing
  (measured before the merge of R8 and describe v6).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import find_objects

from ._heights import _percentile_by_label
from ._regions import _coerce_mask, _object_boxes, _renumber, _ring_kernel
from ._texture_rules import elongation

# R7: objects grow into pixels at least this many threshold bands out on their side ...
_WEAK_CONTRAST = 0.7
# ... at most this many pixels (8-connected steps) out.
_WEAK_STEPS = 12
# ... and keep it when their solidity drops by no more than this: on pixels a straight cut
# looks more solid than an arc (a digital disk of radius 10 scores 0.943, its half 0.958)
_WEAK_SOLIDITY_SLACK = 0.02
# R7c: objects grow into pixels this many bands out on the other side of the ground level ...
_FACE_CONTRAST = 0.5
# ... and keep it when it adds at least this fraction of their pixels (a face, not a rim).
_FACE_MIN_GAIN = 0.2
# R4b: an object splits where it narrows to at most this fraction of its lobes' depth ...
_NECK_RATIO = 0.5
# ... into lobes at least this deep (pixels from their edge: 4 px across) ...
_NECK_LOBE_DEPTH_PX = 2.0
# ... of at least this many pixels, each no longer than this times its width (a rock, not
# the piece of a streak R5 would drop) ...
_NECK_LOBE_PX = 15
_NECK_LOBE_ELONGATION = 2.5
# ... and each at least this much more solid than the object (two blobs, not one ragged).
_NECK_SOLIDITY_GAIN = 0.05
# R7d: an object's outline pixels closer to the ground's gray than this fraction of its
# median contrast (on its own side) are dropped.
_RIM_FRACTION = 0.3
# R7b: objects of opposite sides this close (pixels) are candidate halves of one rock ...
_JOIN_GAP_PX = 5
# ... facing each other over at least sqrt(area of the smaller) pixels, joined when the
# union (gap closed) is at most this much less solid than the more solid half.
_JOIN_SOLIDITY_SLACK = 0.05

__all__ = [
    "split_at_necks",
    "trim_attached_shadows",
    "grow_weak_halves",
    "join_opposite_halves",
    "grow_other_faces",
    "trim_faint_rims",
]


def split_at_necks(
    labels: np.ndarray,
    *,
    neck_ratio: float = _NECK_RATIO,
    min_lobe_px: int = _NECK_LOBE_PX,
    solidity_gain: float = _NECK_SOLIDITY_GAIN,
) -> tuple[np.ndarray, int]:
    """Rule R4b: split an object at a neck between two compact lobes (see the module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    neck_ratio : float
        In ``[0, 1)``; an object is cut where it narrows to at most this fraction of the
        depth (distance to the object's edge) of the lobes on both sides; 0 disables.
    min_lobe_px : int
        ``>= 1``; each part of a split holds at least this many pixels.
    solidity_gain : float
        ``>= 0``; each part must be at least this much more solid (pixels over the pixel area
        of their convex hull) than the object.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m (split parts get their own ids).
    splits : int
        Objects split.
    """
    if not 0 <= neck_ratio < 1 or min_lobe_px < 1 or not solidity_gain >= 0:
        raise ValueError(
            "need 0 <= neck_ratio < 1, min_lobe_px >= 1 and solidity_gain >= 0, got "
            f"{neck_ratio}, {min_lobe_px} and {solidity_gain}"
        )
    count = int(labels.max())
    if count == 0 or neck_ratio == 0:
        return labels, 0
    out = labels.copy()
    spans = find_objects(labels)
    next_id = count + 1
    splits = 0
    for k, span in enumerate(spans, start=1):
        if span is None:
            continue
        sy, sx = span
        # one pixel of background around the object: its edge is at distance 1
        y0, x0 = max(0, sy.start - 1), max(0, sx.start - 1)
        inside = labels[y0 : sy.stop + 1, x0 : sx.stop + 1] == k
        if np.count_nonzero(inside) < 2 * min_lobe_px:
            continue
        whole = _solidity(inside)
        if whole >= 1 - solidity_gain:
            continue  # as solid as a convex blob: no part can be more solid
        parts = _neck_parts(inside, neck_ratio)
        if len(parts) < 2 or min(np.count_nonzero(part) for part in parts) < min_lobe_px:
            continue
        numbered = np.zeros(inside.shape, np.int32)
        for n, part in enumerate(parts, start=1):
            numbered[part] = n
        if elongation(numbered)[1:].max() > _NECK_LOBE_ELONGATION:
            continue
        if min(_solidity(part) for part in parts) < whole + solidity_gain:
            continue
        window = out[y0 : sy.stop + 1, x0 : sx.stop + 1]
        for part in parts[1:]:
            window[part] = next_id
            next_id += 1
        splits += 1
    if not splits:
        return labels, 0
    return _renumber(out, 1), splits


def _neck_parts(inside: np.ndarray, neck_ratio: float) -> list[np.ndarray]:
    """An object's parts at its narrowest neck (R4b), or ``[inside]`` when it has none.

    The distance to the edge is thresholded at rising levels ``r``; the first level at which
    two or more of the pieces above it reach ``r / neck_ratio`` (and ``_NECK_LOBE_DEPTH_PX``)
    gives the lobes, and every other pixel of the object goes to the lobe it reaches first
    (8-connected steps inside the object).
    """
    depth = cv2.distanceTransform(inside.view(np.uint8), cv2.DIST_L2, 5)
    top = float(depth.max())
    for level in np.unique(depth[inside]):
        if level >= neck_ratio * top:
            break
        count, pieces = cv2.connectedComponents((depth > level).view(np.uint8), connectivity=8)
        if count <= 2:
            continue
        peaks = np.zeros(count, np.float32)
        np.maximum.at(peaks, pieces.ravel(), depth.ravel())
        lobes = np.flatnonzero(
            (neck_ratio * peaks >= level) & (peaks >= _NECK_LOBE_DEPTH_PX)
        )
        lobes = lobes[lobes > 0]
        if lobes.size < 2:
            continue
        lookup = np.zeros(count, np.uint16)
        lookup[lobes] = np.arange(1, lobes.size + 1, dtype=np.uint16)
        front = lookup[pieces]
        free = inside & (front == 0)
        kernel = np.ones((3, 3), np.uint8)
        while free.any():
            reach = cv2.dilate(front, kernel)
            new = free & (reach > 0)
            if not new.any():
                break  # unreachable bits (none in a connected object)
            np.copyto(front, reach, where=new)
            free &= ~new
        return [front == n for n in range(1, lobes.size + 1)]
    return [inside]


def trim_attached_shadows(
    labels: np.ndarray,
    image: np.ndarray,
    *,
    min_gap: float = 25.0,
    min_share: float = 0.1,
    core_ratio: float = 2.5,
    ring_px: int = 3,
) -> np.ndarray:
    """Rule R6: remove the attached cast shadow of a dark object (see the module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    image : (M, N) ndarray of uint8
        Reference gray image.
    min_gap : float
        ``>= 0`` gray levels; the two gray classes of an object must differ by this much.
    min_share : float
        In ``[0, 0.5]``; each class holds at least this share of the object.
    core_ratio : float
        ``>= 1``; the core must be this many times further below the ground than the shadow.
    ring_px : int
        ``>= 1``; width of the background ring that gives the ground's gray level.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids; shadow pixels set to 0 (objects are not renumbered).
    """
    if labels.shape != image.shape:
        raise ValueError(f"labels {labels.shape} and image {image.shape} must have one shape")
    if not 0 <= min_share <= 0.5 or min_gap < 0 or core_ratio < 1 or ring_px < 1:
        raise ValueError(
            "need min_gap >= 0, 0 <= min_share <= 0.5, core_ratio >= 1, ring_px >= 1; got "
            f"{min_gap}, {min_share}, {core_ratio}, {ring_px}"
        )
    out = labels.copy()
    count = int(labels.max())
    if count == 0:
        return out
    kernel = np.ones((2 * ring_px + 1, 2 * ring_px + 1), np.uint8)
    rows, cols = labels.shape
    boxes = _object_boxes(labels, count)
    for k in range(1, count + 1):
        y0, y1, x0, x1 = boxes[k]
        if y1 < y0:
            continue
        y0, x0 = max(0, y0 - ring_px), max(0, x0 - ring_px)
        y1, x1 = min(rows, y1 + ring_px + 1), min(cols, x1 + ring_px + 1)
        window = labels[y0:y1, x0:x1]
        inside = window == k
        gray = image[y0:y1, x0:x1][inside]
        if gray.size < 40:
            continue
        ring = cv2.dilate(inside.view(np.uint8), kernel).view(bool) & (window == 0)
        if not ring.any():
            continue
        ground = float(np.median(image[y0:y1, x0:x1][ring]))
        if np.median(gray) >= ground:
            continue  # a light object's shadow is darker than the ground: never merged
        split, _ = cv2.threshold(gray.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        core = gray <= split
        share = core.mean()
        if not min_share <= share <= 1 - min_share:
            continue
        core_mean, shade_mean = float(gray[core].mean()), float(gray[~core].mean())
        if shade_mean - core_mean < min_gap or not shade_mean < ground:
            continue
        if ground - core_mean < core_ratio * (ground - shade_mean):
            continue
        shade = np.zeros_like(inside)
        shade[inside] = ~core
        out[y0:y1, x0:x1][shade] = 0
    return out


def grow_weak_halves(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    between: np.ndarray,
    min_contrast: float = _WEAK_CONTRAST,
    max_steps: int = _WEAK_STEPS,
    solidity_slack: float = _WEAK_SOLIDITY_SLACK,
    opposite: bool = False,
    min_gain: float = 0.0,
) -> tuple[np.ndarray, int]:
    """Rule R7: grow objects into the weak pixels of their own side, if they grow compact.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands
        (:func:`stages._depth_rules.gray_contrast`); its sign says darker or lighter.
    between : (M, N) ndarray of bool
        Pixels past neither threshold: the only ones an object may take (pixels past one
        that a rule removed -- a trimmed shadow, a flat blotch -- stay removed).
    min_contrast : float
        ``> 0`` bands; a pixel is weak for a dark object when its contrast is below
        ``-min_contrast``, for a light object (mean contrast above 0) above it.
    max_steps : int
        ``>= 0``; growth goes at most this many 8-connected steps out; 0 disables.
    solidity_slack : float
        ``>= 0``; an object keeps its growth only when its solidity (pixels over the pixel
        area of their convex hull) drops by no more than this.
    opposite : bool
        Rule R7c: grow into the pixels of the other side instead (a dark object into pixels
        lighter than ``min_contrast``, a light one into darker): the other face of a rock.
    min_gain : float
        ``>= 0``; an object keeps its growth only when it adds at least this fraction of its
        pixels (R7c: a face, not a rim of light pixels around a dark rock).

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids (no object is added or removed).
    grown : int
        Pixels added.
    """
    between = _coerce_mask(between, "between")
    if not labels.shape == contrast.shape == between.shape:
        raise ValueError(
            f"labels {labels.shape}, contrast {contrast.shape} and between {between.shape} "
            "must have one shape"
        )
    if not min_contrast > 0 or max_steps < 0 or not solidity_slack >= 0 or not min_gain >= 0:
        raise ValueError(
            "need min_contrast > 0, max_steps >= 0, solidity_slack >= 0 and min_gain >= 0, got "
            f"{min_contrast}, {max_steps}, {solidity_slack} and {min_gain}"
        )
    count = int(labels.max())
    if count == 0 or max_steps == 0:
        return labels, 0
    owners = labels.ravel()
    inside = owners > 0
    # the side of an object: the sign of its mean contrast
    dark_object = np.bincount(owners[inside], contrast.ravel()[inside], minlength=count + 1) < 0
    out = labels.copy()
    background = labels == 0
    kernel = np.ones((3, 3), np.uint8)
    ids_dtype = np.uint16 if count < 2**16 else np.float32
    # every object is on one side: the light ones are the rest (one lookup, not two)
    dark_ids = np.where(dark_object, np.arange(count + 1), 0).astype(ids_dtype)[labels]
    fronts = {True: dark_ids, False: labels.astype(ids_dtype) - dark_ids}
    for dark, front in fronts.items():
        weak = (contrast < -min_contrast) if dark != opposite else (contrast > min_contrast)
        weak &= between & background
        for _ in range(max_steps):
            # where two objects of one side reach a pixel at once, the higher id takes it
            reach = cv2.dilate(front, kernel)
            new = weak & (reach > 0)
            if not new.any():
                break
            weak &= ~new
            np.copyto(front, reach, where=new)
        np.copyto(out, front, where=background & (front > 0), casting="unsafe")
    grown = out != labels
    changed = np.unique(out[grown])
    spans = find_objects(out)
    for k in changed:
        window = spans[k - 1]
        before = labels[window] == k
        after = out[window] == k
        gain = np.count_nonzero(after) - np.count_nonzero(before)
        if (
            gain < min_gain * np.count_nonzero(before)
            or _solidity(after) < _solidity(before) - solidity_slack
        ):
            after &= grown[window]
            out[window][after] = 0
    return out, int(np.count_nonzero(out)) - int(np.count_nonzero(labels))


def grow_other_faces(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    min_contrast: float = _FACE_CONTRAST,
    max_steps: int = _WEAK_STEPS,
) -> tuple[np.ndarray, int]:
    """Rule R7c: grow objects into the other face of their rock, across the ground's gray.

    :func:`grow_weak_halves` with ``opposite=True`` into every background pixel (past a
    threshold or not) at least ``min_contrast`` bands out on the object's other side, kept
    when it adds at least ``_FACE_MIN_GAIN`` of the object's pixels and its solidity drops
    by no more than ``_WEAK_SOLIDITY_SLACK``.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands.
    min_contrast : float
        ``> 0`` bands.
    max_steps : int
        ``>= 0`` 8-connected steps; 0 disables.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids.
    grown : int
        Pixels added.
    """
    return grow_weak_halves(
        labels,
        contrast,
        between=labels == 0,
        min_contrast=min_contrast,
        max_steps=max_steps,
        opposite=True,
        min_gain=_FACE_MIN_GAIN,
    )


def join_opposite_halves(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    gap_px: int = _JOIN_GAP_PX,
    solidity_slack: float = _JOIN_SOLIDITY_SLACK,
) -> tuple[np.ndarray, int]:
    """Rule R7b: join a lighter and a darker object that together make one compact rock.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands; the sign of an
        object's mean says whether it is lighter or darker than the ground.
    gap_px : int
        ``>= 0``; objects of opposite sides whose pixels come this close are candidates when
        at least ``sqrt(area)`` of the smaller one's pixels lie that close to the other; 0
        disables.
    solidity_slack : float
        ``>= 0``; a pair is joined (with the background between them, a morphological
        closing of radius ``gap_px``) when the union's solidity is at most this much below
        the more solid of the two.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m.
    joined : int
        Pairs joined.
    """
    if labels.shape != contrast.shape:
        raise ValueError(f"labels {labels.shape} and contrast {contrast.shape} must have one shape")
    if gap_px < 0 or not solidity_slack >= 0:
        raise ValueError(
            f"need gap_px >= 0 and solidity_slack >= 0, got {gap_px} and {solidity_slack}"
        )
    count = int(labels.max())
    if count < 2 or gap_px == 0:
        return labels, 0
    owners = labels.ravel()
    inside = owners > 0
    area = np.bincount(owners, minlength=count + 1)
    lighter = np.bincount(owners[inside], contrast.ravel()[inside], minlength=count + 1) >= 0
    spans = find_objects(labels)
    kernel = _ring_kernel(gap_px)
    rows, cols = labels.shape
    parent = np.arange(count + 1)

    def root(k: int) -> int:
        while parent[k] != k:
            k = parent[k]
        return int(k)

    out = labels.copy()
    joined = 0
    for k in range(1, count + 1):
        sy, sx = spans[k - 1]
        y0, x0 = max(0, sy.start - gap_px), max(0, sx.start - gap_px)
        y1, x1 = min(rows, sy.stop + gap_px), min(cols, sx.stop + gap_px)
        window = labels[y0:y1, x0:x1]
        near = cv2.dilate((window == k).view(np.uint8), kernel).view(bool)
        others, facing = np.unique(window[near], return_counts=True)
        for j, n_facing in zip(others, facing, strict=True):
            # each pair once (j > k), opposite sides, facing over a boundary of their size
            if j <= k or lighter[j] == lighter[k]:
                continue
            if n_facing < np.sqrt(min(area[k], area[j])):
                continue
            oy, ox = spans[j - 1]
            v0, v1 = max(0, min(sy.start, oy.start) - gap_px), max(sy.stop, oy.stop) + gap_px
            u0, u1 = max(0, min(sx.start, ox.start) - gap_px), max(sx.stop, ox.stop) + gap_px
            pair = labels[v0:v1, u0:u1]
            one, two = pair == k, pair == j
            union = cv2.morphologyEx((one | two).view(np.uint8), cv2.MORPH_CLOSE, kernel)
            union = union.view(bool) & ((pair == 0) | one | two)
            if _solidity(union) < max(_solidity(one), _solidity(two)) - solidity_slack:
                continue
            first, second = root(k), root(int(j))
            if first == second:
                continue
            parent[second] = first
            out[v0:v1, u0:u1][union & (pair == 0) & (out[v0:v1, u0:u1] == 0)] = first
            joined += 1
    if not joined:
        return labels, 0
    roots = np.array([root(k) for k in range(count + 1)])
    return _renumber(roots[out], 1), joined


def _solidity(mask: np.ndarray) -> float:
    """Pixels of a mask over the pixel area of their convex hull (1: convex)."""
    ys, xs = np.nonzero(mask)
    hull = cv2.convexHull(np.stack([xs, ys], axis=1).astype(np.int32))
    # the hull runs through pixel centres: half its perimeter (+1 for the corners) is the
    # area of the boundary pixels outside it, so a convex blob scores about 1
    area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0
    return ys.size / area


def trim_faint_rims(
    labels: np.ndarray, contrast: np.ndarray, *, fraction: float = _RIM_FRACTION
) -> tuple[np.ndarray, int]:
    """Rule R7d: drop an object's outline pixels that are almost ground gray (module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands; the sign of an
        object's median says whether it is lighter or darker than the ground.
    fraction : float
        In ``[0, 1)``; an outline pixel (a 4-neighbour is background) on the object's own side
        of the ground level, but less than this fraction of the object's median contrast
        from it, is dropped; pixels on the other side (a face joined by R7b or R7c) stay;
        0 disables.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m (an object of only such pixels is gone).
    trimmed : int
        Pixels dropped.
    """
    if labels.shape != contrast.shape:
        raise ValueError(f"labels {labels.shape} and contrast {contrast.shape} must have one shape")
    if not 0 <= fraction < 1:
        raise ValueError(f"fraction must be in [0, 1) (0 disables), got {fraction}")
    count = int(labels.max())
    if count == 0 or fraction == 0:
        return labels, 0
    owners = labels.ravel()
    inside = owners > 0
    median = _percentile_by_label(
        contrast.ravel()[inside].astype(np.float64), owners[inside], count + 1, 50.0
    )
    median[~np.isfinite(median)] = 0.0
    median[0] = 0.0
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    # outside the frame counts as nothing: an object cut by the border keeps its cut edge
    outline = (cv2.dilate((labels == 0).view(np.uint8), cross) > 0) & (labels > 0)
    own_side = contrast * np.sign(median)[labels].astype(np.float32)
    faint = outline & (own_side >= 0) & (own_side < fraction * np.abs(median)[labels])
    trimmed = int(np.count_nonzero(faint))
    if not trimmed:
        return labels, 0
    return _renumber(np.where(faint, 0, labels), 1), trimmed
