"""Rules R4b and R7d: an object's outline corrected -- cut at a neck, faint rims off.

They act on labelled objects (:func:`stages._regions.label_objects`): R4b right after R4
(split at depth edges, :mod:`stages._regions`), R7d after R7c (the rules that make objects
whole rocks, :mod:`stages._rock_parts`) and before R8 (:mod:`stages._blobs`):

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

from ._heights import _percentile_by_label
from ._regions import _box_window, _object_boxes, _renumber, _solidity
from ._texture_rules import elongation

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

__all__ = ["split_at_necks", "trim_faint_rims"]


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
    boxes = _object_boxes(labels, count)
    next_id = count + 1
    splits = 0
    for k in range(1, count + 1):
        if boxes[k, 1] < boxes[k, 0]:
            continue
        sy, sx = _box_window(boxes[k])
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
        contrast.ravel()[inside].astype(np.float32, copy=False), owners[inside], count + 1, 50.0
    )
    median[~np.isfinite(median)] = 0.0
    median[0] = 0.0
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    # outside the frame counts as nothing: an object cut by the border keeps its cut edge
    outline = cv2.dilate((labels == 0).view(np.uint8), cross).view(bool) & (labels > 0)
    # read at the outline pixels only (the same products and comparisons as whole-frame
    # maps of the objects' signs and medians would give there)
    owner = labels[outline]
    own_side = contrast[outline] * np.sign(median)[owner].astype(np.float32)
    faint = np.zeros(labels.shape, bool)
    faint[outline] = (own_side >= 0) & (own_side < fraction * np.abs(median)[owner])
    trimmed = int(np.count_nonzero(faint))
    if not trimmed:
        return labels, 0
    return _renumber(np.where(faint, 0, labels), 1), trimmed
