"""Rules R6-R7c and R7h: objects made whole rocks -- attached shadows off, halves, faces
and pieces on.

They act on labelled objects (:func:`stages._regions.label_objects`) after R5-R5c (streaks,
ripple fields, :mod:`stages._texture_rules`); the outline rules R4b (necks, right after R4)
and R7d (faint rims, after R7c) are in :mod:`stages._outlines`; R7h acts last, after R7f
(:mod:`stages._height_grow`):

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
  Until segment v36 the pair's window reached only ``join_gap_px`` past the pair, so the
  closing's dilation touched the window's edge and OpenCV's erosion (which keeps what
  touches the edge) left tails along it: the union's solidity fell (mojave_s5 mojave_0011
  rock 73: 0.89 -> 0.73) and true pairs stayed apart. The window now reaches twice the
  gap. With that fix alone the newly joined pairs were, on mojave, a rock's lit and shaded
  faces with the shaded one 1-15 degrees from the direction away from the sun (seen from
  the lit one), and, on lava, mostly a light and a dark rock side by side at 62-146
  degrees (lava_s2 lava_0006 rocks 153 and 144, IoU 0.82 and 0.74 apart, 0.45 joined).
  So where the frame says where its sun is (R6b's :func:`stages._sun_shadows.
  anti_sun_direction`), a pair whose darker object lies more than ``join_side_deg`` (60)
  from that direction is not joined. ``bench_segment.py --rundir DIR`` (lava seeds with
  ``--set two_face_sigmas=3``), segment v35 -> the fix alone -> fix and side test at 60
  degrees: mojave catalog 0.915 -> 0.914 -> 0.918, seeds 2-5 0.920 / 0.897 / 0.893 / 0.887
  -> 0.921 / 0.897 / 0.896 / 0.895 -> 0.921 / 0.897 / 0.896 / 0.897; lava catalog 0.837 ->
  0.837 -> 0.837, seeds 2-5 0.833 / 0.843 / 0.829 / 0.841 -> 0.830 / 0.839 / 0.829 / 0.838
  -> 0.836 / 0.844 / 0.829 / 0.841; lab, dunes (catalog, seeds 2, 3, 4, 5, 7, 11) and lab
  seeds 2-3 unchanged. 45 degrees: mojave seed 3 0.896, lava catalog 0.835; 90 degrees:
  mojave seed 5 0.895, lava seeds 2-3 0.831 / 0.841. Without the side test, the slack at
  0, 0.02, 0.03, 0.04 gave lava seeds 2-3 0.835 / 0.843, 0.836 / 0.841, 0.836 / 0.838,
  0.834 / 0.839 and mojave seeds 4-5 0.895 / 0.893, 0.895 / 0.893, 0.896 / 0.891, 0.896
  / 0.895.
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
  On lava the ground is blotchy, and a light rock can grow into dark blotches of ground
  texture as readily as into its shaded face (lava_0000 object 49: 52 -> 121 px, IoU
  0.74 -> 0.40, the growth on the sun's side of a rock lit from there). Where R6b's sun
  direction is known (:func:`stages._sun_shadows.anti_sun_direction`, from the objects
  as R7c finds them), a rock's other face lies on one side of it: a light object's shaded
  face away from the sun, a dark object's lit face toward it. So each 8-connected piece of
  an object's growth whose centroid, seen from the object's centroid, lies more than
  ``face_side_deg`` (105) degrees from that side is dropped before the fifth and solidity
  tests (:func:`grow_other_faces`); with no sun direction (fewer than 3 clear pairs, or
  pairs that disagree: dunes) nothing changes. With ``bench_segment.py --rundir`` (``--set
  face_side_deg=0`` for the old rules; lava seeds with ``two_face_sigmas=3`` as lava's
  catalog) object F1 on lava's catalog frames 0.837 -> 0.838 (1 more true rock, 1 fewer
  false one), seeds 2-5 0.832 -> 0.833, 0.840 and 0.828 unchanged, 0.839 -> 0.841; mojave
  seed 3 0.895 -> 0.897, mojave's catalog and seeds 2, 4, 5, lab (catalog, seeds 2, 3)
  and dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged. Rocks within 2 m
  (``bench_describe.py --rundir DIR --labels segment``, ``--set segment.face_side_deg=0``
  for the old rules), median width error and size class: lava's catalog 9.2 -> 9.1 %,
  0.966; seed 5 13.1 -> 12.1 %, 0.913 -> 0.922; seed 2 9.0 -> 9.1 % (one more near rock
  matched), 0.925 -> 0.926; seeds 3 and 4 unchanged; mojave and lab unchanged. 99 degrees
  gives the same figures; 120 lava seeds 4 and 5 0.829 and 0.839; 90 the catalog 0.837
  and seed 5 0.842. Pieces tested whole-object (the growth's centroid) instead gain less
  (catalog 0.838, seeds unchanged); the same side test on R7b's pairs changed nothing.
  On lava's low sun a lit face's shaded face is often found by R7c but lost to the
  solidity test: the growth takes the shaded face with a strip of the cast shadow beside
  it and the terminator's ground-gray pixels stay out, so the union is 0.07-0.15 less
  solid than the lit face alone (lava_0000 object 40, rock 20: IoU 0.40, 0.87 with the
  face, solidity 0.87 -> 0.78; lava_0011 object 58, rock 30: 0.43 and 0.65, 0.87 ->
  0.77). Ground texture the growth takes lies mostly within a band of the ground's gray; a
  face lies past the threshold. Of the growths the tests rejected on lava's catalog and
  seeds 2-3 and mojave's catalog and seed 2 (segment v38), the 13 that would have lifted
  an object over IoU 0.5 held a median 0.39 of their pixels past the other threshold (9
  of them 0.3 or more), the 85 that would have sunk one below it a median 0.05 (8 of them
  0.3 or more). So a growth with at least ``_FACE_PAST_SHARE`` (0.3) of its
  pixels past the other threshold may lose up to ``_FACE_PAST_SLACK`` (0.15) of solidity
  (``past_share``, ``past_slack`` of :func:`grow_weak_halves`). With ``bench_segment.py
  --rundir`` (after R7h; ``_FACE_PAST_SLACK = 0`` for the old rule) object F1: lava's
  catalog 0.848 unchanged (rocks 20 of lava_0000 and 30 of lava_0011 found, rock 2 of
  lava_0005 lost: its pieces no longer meet for R7h), seeds 2-5 0.845 -> 0.852, 0.846
  unchanged, 0.832 -> 0.834, 0.850 -> 0.854; mojave's catalog 0.921 -> 0.920 (one more
  false object), seeds 2-5 0.921 -> 0.918 (mojave_0009 rock 2, 40 px: the growth took its
  cast shadow), 0.905 -> 0.908, 0.899 -> 0.902, 0.899 unchanged; lab (catalog, seeds 2, 3)
  and dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged. Slacks of 0.1 (share 0.2 or
  0.3) gained less on lava (catalog 0.847, seed 2 0.847-0.849); a share of 0.4 the same
  as 0.3 but seed 2 0.851. Without the share test the looser slack loses more rocks than
  it finds (over the growths above: 2-5 per run), and a floor of 0.75-0.8 on the union's
  solidity instead gained nothing (segment v38: lava's catalog 0.839-0.840). Letting the
  growth cross one pixel of the terminator first (a front through pixels within half a
  band) gained 2 rocks on lava's catalog (segment v38), two pixels lost 16.
* **R7h grown pieces** -- a large near rock whose gray levels wander across the ground's
  (lit facets, shaded ones, blotches of its own texture) is often found as two or three
  objects of one side, each grown by R7, R7c and R7f until they touch along a seam; each
  covers under half the rock, so the rock is missed and every piece is a false rock. Of the
  59 false objects on missed lava rocks (``benchmarks/bench_misses.py runs/eval/lava``), 17
  were such pieces of 8 rocks, 6 of which the union of the pieces would match at IoU >= 0.5.
  R7b joins only a lighter and a darker object, and before the growth. So last, after R7f
  (:mod:`stages._height_grow`) and before R8-R8c, two objects of either side whose pixels
  come within ``piece_gap_px`` (2) of each other, facing over at least ``sqrt(area)`` of
  the smaller one's pixels, are joined -- with the background between them (a closing of
  that radius) -- when the union is at most 0.02 less solid than the more solid piece; a
  lighter and a darker pair still faces the sun's way, as in R7b (:func:`join_grown_pieces`,
  R7b's :func:`join_opposite_halves` with ``any_side``). Two rocks side by side meet over a
  short seam or make a far less solid union (the touching pairs of two matched rocks in
  segment v38's labels of lava's catalog and seeds 2-3 and mojave's catalog and seed 2:
  union 0.70-0.80, each rock alone 0.80-0.97). With ``bench_segment.py --rundir`` (``--set
  piece_gap_px=0`` for the old rules) object F1: lava's catalog 0.840 -> 0.848 (3 more true
  rocks, 8 fewer false ones: lava_0002 rock 62, lava_0004 rock 3, lava_0005 rock 2), seeds
  2-5 0.845, 0.846, 0.832, 0.850 unchanged; mojave's catalog and seeds 2-4 unchanged, seed 5
  0.900 -> 0.899 (mojave_0011 rock 53, 51 px at 5.5 m, joined to a neighbour); lab
  (catalog, seeds 2, 3) and dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged. R7b's slack
  of 0.05 joined two rocks on lava seed 2 (lava_0006 rocks 21 and 27: 0.845 -> 0.843) and
  mojave seed 5 lost a second far rock; same-side pairs only gained less (lava 0.845); a gap
  of 1 gained less (lava 0.844 with R7b's slack; 2 gave 0.848 and 3 0.847 with it). Rocks within 2 m
  (``bench_describe.py --rundir DIR --labels segment``, ``--set segment.piece_gap_px=0``
  for the old rules): lava's catalog 118 -> 120 near rocks matched, size class 0.958,
  median width error 9.4 -> 9.5 %; mojave and lab unchanged. The cost, with
  ``bench_segment.py --stage-speed --archetypes lava --frames 3``: about 3 ms of CPU per
  frame (52-55 -> 56-57 ms).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._fronts import grow_fronts, merge_fronts
from ._regions import (
    _box_window,
    _coerce_mask,
    _label_sums,
    _lookup,
    _object_boxes,
    _renumber,
    _ring_kernel,
    _solidity,
)
from ._select import median_u8
from ._sun_shadows import anti_sun_direction

# R7: objects grow into pixels at least this many threshold bands out on their side ...
_WEAK_CONTRAST = 0.7
# ... at most this many pixels (8-connected steps) out.
_WEAK_STEPS = 12
# ... and keep it when their solidity drops by no more than this: on pixels a straight cut
# looks more solid than an arc (a digital disk of radius 10 scores 0.943, its half 0.958)
_WEAK_SOLIDITY_SLACK = 0.02
# R7c: objects grow into pixels this many bands out on the other side of the ground level ...
_FACE_CONTRAST = 0.5
# ... and keep it when it adds at least this fraction of their pixels (a face, not a rim);
_FACE_MIN_GAIN = 0.2
# ... where the frame says where its sun is, pieces of the growth more than this far (degrees)
# from the side the other face lies on are ground texture, not the face
_FACE_SIDE_DEG = 105.0
# ... a growth with at least this share of its pixels past the other threshold (a shaded
# face darker than the ground's texture reaches, not a blotch half a band out) is kept when
# the solidity drops by no more than this (its terminator and cast shadow leave it ragged)
_FACE_PAST_SHARE = 0.3
_FACE_PAST_SLACK = 0.15
# R7b: objects of opposite sides this close (pixels) are candidate halves of one rock ...
_JOIN_GAP_PX = 5
# ... facing each other over at least sqrt(area of the smaller) pixels, joined when the
# union (gap closed) is at most this much less solid than the more solid half.
_JOIN_SOLIDITY_SLACK = 0.05
# R7h: after R7f, objects of either side this close (pixels) are candidate pieces of one
# rock ...
_PIECE_GAP_PX = 2
# ... joined when the union is at most this much less solid than the more solid piece (R7b's
# 0.05 joined two rocks side by side on lava seed 2, lava_0006 rocks 21 and 27)
_PIECE_SOLIDITY_SLACK = 0.02

__all__ = [
    "trim_attached_shadows",
    "grow_weak_halves",
    "join_opposite_halves",
    "grow_other_faces",
    "join_grown_pieces",
]


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
        y0, y1, x0, x1 = boxes[k].tolist()
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
        ground = median_u8(image[y0:y1, x0:x1][ring])
        if median_u8(gray) >= ground:
            continue  # a light object's shadow is darker than the ground: never merged
        split, _ = cv2.threshold(gray.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        core = gray <= split
        # the shares and means from counts and whole-number sums: the same floats as
        # numpy's means (exact float64 sums divided by the count), without their overhead
        n_core = np.count_nonzero(core)
        share = n_core / gray.size
        if not min_share <= share <= 1 - min_share:
            continue
        core_sum, total = int(gray[core].sum()), int(gray.sum())
        core_mean = core_sum / n_core
        shade_mean = (total - core_sum) / (gray.size - n_core)
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
    anti_sun: np.ndarray | None = None,
    max_side_deg: float = 180.0,
    past_share: float = 1.0,
    past_slack: float = 0.0,
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
    anti_sun : (2,) ndarray of float, optional
        With ``opposite`` (R7c): the frame's unit vector (rows, columns) pointing away from
        the sun (:func:`stages._sun_shadows.anti_sun_direction`); None when unknown.
    max_side_deg : float
        In ``[0, 180]``; with ``anti_sun``, each 8-connected piece of an object's growth
        whose centroid, seen from the object's, lies more than this many degrees from the
        other face's side (a light object's shaded face away from the sun, a dark one's lit
        face toward it) is dropped before the tests above; 180 keeps every piece.
    past_share, past_slack : float
        In ``[0, 1]`` and ``>= 0``: a growth with at least ``past_share`` of its pixels past
        a threshold (contrast at least 1 band out) may lower the solidity by up to
        ``past_slack`` instead of ``solidity_slack`` (R7c: 0.3 and 0.15); a ``past_slack``
        not above ``solidity_slack`` leaves the test as it is.

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
    if not 0 <= max_side_deg <= 180:
        raise ValueError(f"max_side_deg must be in [0, 180] degrees, got {max_side_deg}")
    if not 0 <= past_share <= 1 or not past_slack >= 0:
        raise ValueError(
            f"need 0 <= past_share <= 1 and past_slack >= 0, got {past_share} and {past_slack}"
        )
    if anti_sun is not None:
        anti_sun = np.asarray(anti_sun, dtype=np.float64)
        if anti_sun.shape != (2,):
            raise ValueError(f"anti_sun must be a (2,) vector, got shape {anti_sun.shape}")
    side_test = opposite and anti_sun is not None and max_side_deg < 180
    count = int(labels.max())
    if count == 0 or max_steps == 0:
        return labels, 0
    # the side of an object: the sign of its mean contrast
    dark_object = _label_sums(labels, contrast, count + 1)[1] < 0
    background = labels == 0
    ids_dtype = np.uint16 if count < 2**16 else np.float32
    # every object is on one side: the light ones are the rest (one lookup, not two)
    dark_ids = _lookup(np.where(dark_object, np.arange(count + 1), 0).astype(ids_dtype), labels)
    fronts = {True: dark_ids, False: labels.astype(ids_dtype) - dark_ids}
    for dark, front in fronts.items():
        weak = (contrast < -min_contrast) if dark != opposite else (contrast > min_contrast)
        weak &= between & background
        # where two objects of one side reach a pixel at once, the higher id takes it
        grow_fronts(front, weak, max_steps=max_steps)
    # the growth written back, the objects that grew and the boxes, in one pass (the
    # sides take disjoint pixels)
    out, changed, boxes = merge_fronts(labels, fronts[True], fronts[False])
    for k in changed:
        window = _box_window(boxes[k])
        before = labels[window] == k
        after = out[window] == k
        if side_test:
            assert anti_sun is not None  # for mypy: side_test says so
            # a lit face lies toward the sun from its shaded face, a shaded face away
            side = -anti_sun if dark_object[k] else anti_sun
            wrong = _off_side_pieces(before, after & ~before, side, max_side_deg)
            if wrong.any():
                after &= ~wrong
                out[window][wrong] = 0
        gain = np.count_nonzero(after) - np.count_nonzero(before)
        slack = solidity_slack
        if past_slack > slack and gain > 0:
            # R7c: a growth mostly past the other threshold is a face, not ground texture
            past = np.count_nonzero(np.abs(contrast[window][after & ~before]) >= 1)
            if past >= past_share * gain:
                slack = past_slack
        if gain < min_gain * np.count_nonzero(before) or _solidity(after) < _solidity(
            before
        ) - slack:
            # its growth (the pixels it took were background)
            after &= ~before
            out[window][after] = 0
    return out, int(np.count_nonzero(out)) - int(np.count_nonzero(labels))


def _off_side_pieces(
    core: np.ndarray, grown: np.ndarray, side: np.ndarray, max_deg: float
) -> np.ndarray:
    """The 8-connected pieces of ``grown`` whose centroid, seen from ``core``'s, lies more
    than ``max_deg`` degrees from the unit vector ``side`` (rows, columns); a (M, N) mask."""
    count, pieces, _, centroids = cv2.connectedComponentsWithStats(
        grown.view(np.uint8), connectivity=8
    )
    if count < 2:
        return np.zeros(grown.shape, dtype=bool)
    # the core's centroid from its moments: whole-number sums, the same floats as the
    # means of np.nonzero's rows and columns at a fifth of the cost
    moments = cv2.moments(core.view(np.uint8), binaryImage=True)
    centre = np.array([moments["m01"], moments["m10"]]) / moments["m00"]
    # cv2's centroids are (x, y)
    offsets = centroids[1:, ::-1] - centre
    lengths = np.hypot(offsets[:, 0], offsets[:, 1])
    cosines = (offsets @ side) / np.maximum(lengths, 1e-9)
    off = np.zeros(count, dtype=bool)
    off[1:] = (lengths > 0) & (cosines < np.cos(np.radians(max_deg)))
    # a lookup of the pieces (np.isin sorts them)
    return off[pieces]


def grow_other_faces(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    min_contrast: float = _FACE_CONTRAST,
    max_steps: int = _WEAK_STEPS,
    barrier: np.ndarray | None = None,
    max_side_deg: float = _FACE_SIDE_DEG,
) -> tuple[np.ndarray, int]:
    """Rule R7c: grow objects into the other face of their rock, across the ground's gray.

    :func:`grow_weak_halves` with ``opposite=True`` into every background pixel (past a
    threshold or not) at least ``min_contrast`` bands out on the object's other side, kept
    when it adds at least ``_FACE_MIN_GAIN`` of the object's pixels and its solidity drops
    by no more than ``_WEAK_SOLIDITY_SLACK``; where the frame's sun direction is known
    (:func:`stages._sun_shadows.anti_sun_direction` of ``labels``), pieces of the growth
    on the wrong side of the object are dropped first.

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
    barrier : (M, N) ndarray of bool, optional
        Background pixels not to grow into (R7e's cast shadows, dropped by height: dark
        like a shaded face, but known to lie on the ground).
    max_side_deg : float
        In ``[0, 180]`` degrees; a piece of an object's growth (8-connected) whose centroid
        lies more than this far from the side its other face lies on, seen from the
        object's centroid, is dropped; 0 or 180 disables (0: the test is off, not
        everything dropped).

    Returns
    -------
    labels : (M, N) ndarray of int32
        Same ids.
    grown : int
        Pixels added.
    """
    between = labels == 0
    if barrier is not None:
        if barrier.shape != labels.shape:
            raise ValueError(
                f"barrier {barrier.shape} must have the labels' shape {labels.shape}"
            )
        between &= ~barrier
    if not 0 <= max_side_deg <= 180:
        raise ValueError(
            f"max_side_deg must be in [0, 180] degrees (0 disables), got {max_side_deg}"
        )
    on = 0 < max_side_deg < 180 and max_steps > 0 and labels.max() > 0
    return grow_weak_halves(
        labels,
        contrast,
        between=between,
        min_contrast=min_contrast,
        max_steps=max_steps,
        opposite=True,
        min_gain=_FACE_MIN_GAIN,
        anti_sun=anti_sun_direction(labels, contrast) if on else None,
        max_side_deg=max_side_deg if on else 180.0,
        past_share=_FACE_PAST_SHARE,
        past_slack=_FACE_PAST_SLACK,
    )


def join_opposite_halves(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    gap_px: int = _JOIN_GAP_PX,
    solidity_slack: float = _JOIN_SOLIDITY_SLACK,
    max_side_deg: float = 180.0,
    any_side: bool = False,
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
    max_side_deg : float
        In ``(0, 180]`` degrees; when the frame says where its sun is
        (:func:`stages._sun_shadows.anti_sun_direction` of ``labels``), a pair whose darker
        object's centroid, seen from the lighter one's, lies more than this far from the
        direction away from the sun is two rocks, not the lit and the shaded face of one;
        180 disables the test.
    any_side : bool
        Rule R7h (:func:`join_grown_pieces`): pairs of one side are candidates too (the side
        test above applies to pairs of opposite sides only).

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
    if not 0 < max_side_deg <= 180:
        raise ValueError(
            f"max_side_deg must be in (0, 180] degrees (180 disables), got {max_side_deg}"
        )
    count = int(labels.max())
    if count < 2 or gap_px == 0:
        return labels, 0
    area, sums = _label_sums(labels, contrast, count + 1)
    lighter = sums >= 0
    anti_sun = anti_sun_direction(labels, contrast) if max_side_deg < 180 else None
    if anti_sun is not None:
        safe = np.maximum(area, 1)
        # the objects' row and column sums in one compiled pass: whole numbers, the same
        # floats as _label_sums of the index maps (``test_rock_parts.py`` compares)
        coordinate_sums = np.zeros((2, count + 1))
        _coordinate_sums(np.ascontiguousarray(labels), coordinate_sums)
        centroids = np.stack([coordinate_sums[0] / safe, coordinate_sums[1] / safe], axis=1)
        min_cos = np.cos(np.radians(max_side_deg))
    boxes = _object_boxes(labels, count)
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
        sy, sx = _box_window(boxes[k])
        y0, x0 = max(0, sy.start - gap_px), max(0, sx.start - gap_px)
        y1, x1 = min(rows, sy.stop + gap_px), min(cols, sx.stop + gap_px)
        window = labels[y0:y1, x0:x1]
        if np.count_nonzero(window) == area[k]:
            continue  # no other object comes this close (the window holds all of k)
        near = cv2.dilate((window == k).view(np.uint8), kernel).view(bool)
        # np.unique's values and counts, from a bincount (no sort)
        facing = np.bincount(window[near])
        others = np.flatnonzero(facing)
        for j, n_facing in zip(others, facing[others], strict=True):
            # each pair once (j > k), opposite sides, facing over a boundary of their size
            if j <= k or (lighter[j] == lighter[k] and not any_side):
                continue
            if n_facing < np.sqrt(min(area[k], area[j])):
                continue
            if anti_sun is not None and lighter[j] != lighter[k]:
                # a lit face's shaded face lies away from the sun (mojave_s5 0007 rock 13:
                # 1 degree off; two rocks side by side in lava_s2/s3: 62-146 degrees)
                light, dark = (k, j) if lighter[k] else (j, k)
                offset = centroids[dark] - centroids[light]
                norm = float(np.hypot(*offset))
                if norm > 0 and float(offset @ anti_sun) < min_cos * norm:
                    continue
            oy, ox = _box_window(boxes[j])
            # twice the closing's radius around the pair: OpenCV's erosion keeps what touches
            # the window's edge, and a margin of one radius let the dilated pair touch it
            # (tails along the edge that sank the union's solidity, mojave_s5 0011 rock 73)
            pad = 2 * gap_px
            v0, v1 = max(0, min(sy.start, oy.start) - pad), max(sy.stop, oy.stop) + pad
            u0, u1 = max(0, min(sx.start, ox.start) - pad), max(sx.stop, ox.stop) + pad
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
    return _renumber(_lookup(roots, out), 1), joined


def join_grown_pieces(
    labels: np.ndarray,
    contrast: np.ndarray,
    *,
    gap_px: int = _PIECE_GAP_PX,
    solidity_slack: float = _PIECE_SOLIDITY_SLACK,
    max_side_deg: float = 180.0,
) -> tuple[np.ndarray, int]:
    """Rule R7h: join the pieces of one rock that the growth rules brought together.

    :func:`join_opposite_halves` with pairs of either side: two objects whose pixels come
    within ``gap_px`` of each other, facing over at least ``sqrt(area)`` of the smaller one's
    pixels, are joined (with the background between them) when the union is at most
    ``solidity_slack`` less solid than the more solid of the two; a lighter and a darker
    object whose darker one lies more than ``max_side_deg`` from the direction away from
    the sun stay apart, as in R7b.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands.
    gap_px : int
        ``>= 0`` pixels; 0 disables.
    solidity_slack : float
        ``>= 0``.
    max_side_deg : float
        In ``(0, 180]`` degrees; 180 disables the side test.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m.
    joined : int
        Pairs joined.
    """
    return join_opposite_halves(
        labels,
        contrast,
        gap_px=gap_px,
        solidity_slack=solidity_slack,
        max_side_deg=max_side_deg,
        any_side=True,
    )


@njit(cache=True)
def _coordinate_sums(labels, sums):  # pragma: no cover - numba
    # per object (label 0 left at 0): the sums of its pixels' rows and columns
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k > 0:
                sums[0, k] += y
                sums[1, k] += x
