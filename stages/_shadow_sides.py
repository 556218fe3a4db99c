"""Rule R7e: near a lit rock, a dark neighbour split by height -- shaded face on, cast shadow off.

It acts on labelled objects after R7d (:mod:`stages._outlines`) and before R8
(:mod:`stages._blobs`), in rows where the heights are precise:

* **R7e shadow sides** -- a rock lit from one side shows a lit face lighter than the ground,
  a shaded face and, beyond it on the ground, its cast shadow. On lava and mojave the shaded
  face is often as dark as the cast shadow: the two make one dark object, parted from the
  lit face's object by a pixel or two of ground gray (the terminator) that R7b's join does
  not bridge. The rock is then found as its lit face only (an obstacle measured as a sample,
  often a miss at IoU < 0.5) and its shaded face and shadow as a false rock. Gray levels
  cannot tell face from shadow there; heights can where the stereo is precise: the face
  stands as high as the rock, the shadow lies on the ground. Near the camera (the rows whose
  band's ground height noise, measured as in R0b of :mod:`stages._depth_rules`, is at most
  ``max_noise_m``: 7.5 mm; on lava's and mojave's frames 4-6 mm within 2 m, 7-10 mm at 2.5-3
  m) each object lighter than the ground (median contrast above 0) takes, from every object
  darker than the ground within ``gap_px`` (3) of it, the pixels raised above
  ``max(min_height_m, 3 sigma)`` (sigma: the row's noise) that are connected through raised
  pixels of that dark object to it, and the ground-gray pixels a closing of that radius
  fills between them. Only a dark object holding a shadow is split: at least a quarter of its
  pixels in precise rows lie at ground level (below ``min(max(flat_tol_m, 2 sigma), half the
  raise threshold)``, R2's flat level) -- a dark rock beside a light one stands up whole and
  keeps its pixels. What is left of the dark object is dropped when most of it lies in
  precise rows and its median height is at ground level: the cast shadow
  (:func:`split_shadow_sides`).
  Second case: the shaded face is as gray as the ground and lies between the lit face and
  the cast shadow, which is no object (the vote found it flat) or a dark object of its own
  that the matcher, lost in the uniform dark, stood up as high as the rock. A light object
  with dark pixels (past the low threshold) of the ground or of a dark object near it --
  at least 10 within 8 px -- takes the pixels a closing of radius 4 fills between it and
  them that are neither dark nor below the raise threshold, less 1-px fringes (an opening
  with a 3x3 square) and whatever does not reach it: dark ground blotches beside small
  rocks otherwise gave them a comb of fringe pixels along the stereo fattening.
  With ``bench_segment.py --rundir`` (``--set shadow_noise_m=0`` for the old rules) object
  F1 on the catalog frames: lava 0.816 -> 0.820 (6 fewer false rocks: shadows left as
  objects), mojave 0.910 -> 0.912 (2 fewer), lab 0.967 and dunes (precision 1.0)
  unchanged; seeds (runs of the catalogs with ``seed =`` changed) lava 2-5 0.809 -> 0.812,
  0.819 -> 0.822, 0.819 unchanged (1 true and 1 false rock fewer), 0.822 -> 0.823; mojave
  2-5 0.913 -> 0.918, 0.892 unchanged, 0.883 -> 0.893, 0.885 -> 0.887; lab 2, 3 and dunes
  2, 3, 4, 5, 7, 11 unchanged. Size class of the rocks within 2 m (``bench_describe.py
  --rundir DIR --labels segment``, ``--set segment.shadow_noise_m=0`` for the old rules):
  lava's catalog frames 0.918 -> 0.945 (three obstacles measured as samples, their shaded
  faces joined: lava_0003 rocks 5 and 9, width error -4 -> +8 % and -25 -> +7 %, and by the
  second case lava_0004 rock 11), mojave 0.884 -> 0.907 (one, by the second case:
  mojave_0007 rock 5), lab unchanged; median width
  error lava 9.7 -> 9.4 %, mojave 8.3 % and lab 7.6 % unchanged. Seeds: lava 2-5 class
  0.926 -> 0.927, 0.931 -> 0.932, 0.899 -> 0.908, 0.887, width 9.0 -> 9.1, 12.3 -> 11.9,
  12.0 -> 12.2, 12.5 %; mojave 2-5 class 0.935 -> 0.938, 0.917, 0.955 -> 0.957, 0.892 ->
  0.895, width 9.1 %, 7.9, 10.3 -> 9.5, 9.5 -> 9.3 %; lab seed 2 unchanged. Without the
  second case's opening (and with shadows of the ground only) lava's catalog width error
  rose to 10.5 % (small rocks beside dark blotches widened by 10-25 %); asking for dark
  pixels a quarter of the object's instead of the opening gave 9.7 %; with a closing of
  radius 3 and 6 px of reach mojave lost its gain. Dropping, the other way round, the dark
  pieces at ground level on a light object's outline (a cast shadow R7b or R7c joined to
  it) raised mojave's class to 0.929 but lost whole rocks whose shaded lower side the
  stereo flattens (mojave_0002 rock 3; lava seed 5: F1 0.823 -> 0.820). The cost, with
  ``bench_segment.py --stage-speed --archetypes lava --frames 4``: 77-79 -> 85-89 ms of CPU
  per frame, half of it the heights smoothed, set against R0's ground and their noise
  measured again (:func:`stages.segment.segment_image` does not keep the depth rules').

  Before R7b: R7b joined a lit face to a dark neighbour, shaded face plus cast shadow, whole
  (mojave_0011 rock 4: IoU 0.81 -> 0.68, a sample classed an obstacle), and the pair was
  one object by the time R7e ran. So the first case also runs before R7b
  (:func:`stages.segment.segment_image`), with ``facing_only``: a dark neighbour is split
  there only when its raised part connected to the lit object holds at least ``sqrt(its
  area)`` pixels and at most the lit object's -- a shaded face the stereo flattened (mojave
  seed 2, mojave_0008 rock 7) and a dark rock body beside a small highlight (lava seed 3,
  lava_0008 rock 9) are left to R7b -- and the cast shadows it drops bar R7c, which took
  them back as the rock's other face (lava_0003 rock 9: width +19 %). Both cases run again
  after R7d as before (R7d trims the ground-gray face the second case fills: mojave seed 2,
  mojave_0010 rock 3). Size class within 2 m (``bench_describe.py --rundir DIR --labels
  segment``): mojave's catalog 0.932 -> 0.955, width error of mojave seed 4 8.8 -> 8.3 %;
  F1 (``bench_segment.py --rundir DIR``), class and width unchanged on lab, lava and dunes
  catalogs, mojave seeds 2-5, lava 2-5, lab 2, dunes 5, 7, 11. Moving all of R7e before
  R7b instead: mojave 0.955 but seed 2 F1 0.920 -> 0.912 (three rocks lost).

Why not re-decide every near outline by height: with 4-6 mm of height noise and rock flanks
that the stereo windows flatten (the median height of lava's and mojave's near rocks, 2-8 cm
high, is 5-25 mm), dropping an object's pixels at ground level more than 2-5 px from its
raised ones took off as many rock pixels as shadow pixels (mojave's near objects: pixel
precision 0.86 -> 0.89-0.93, recall 0.92 -> 0.74-0.90, mean IoU down), and growing objects
into raised background pixels added more ground (the stereo fattening around a rock) than
rock (recall 0.92 -> 0.94, precision 0.86 -> 0.80).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._heights import _percentile_by_label, check_height_inputs
from ._regions import _box_window, _object_boxes, _renumber

# R7e: rows whose ground height noise is at most this (metres) are precise enough ...
_MAX_NOISE_M = 0.0075
# ... there a pixel is raised above max(min_height_m, this many row sigmas) ...
_RAISE_SIGMAS = 3.0
# ... and at ground level below min(max(flat_tol_m, this many row sigmas), raise / 2).
_FLAT_SIGMAS = 2.0
# A dark object is split only when at least this share of its precise pixels lie flat.
_MIN_FLAT_SHARE = 0.25
# Objects this close (pixels) are neighbours; the gap between them is closed over.
_GAP_PX = 3
# A cast shadow no object holds: dark pixels this close (pixels) to a light object ...
_SHADOW_REACH_PX = 8
# ... at least this many ...
_SHADOW_MIN_PX = 10
# ... and the gap a closing of this radius fills between them ...
_SHADOW_CLOSE_PX = 4
# ... less its fringes this thin (an opening with a (2r+1)-square).
_FACE_OPEN_PX = 1

__all__ = ["split_shadow_sides"]


def split_shadow_sides(
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    row_noise: np.ndarray,
    *,
    max_noise_m: float = _MAX_NOISE_M,
    min_height_m: float = 0.008,
    flat_tol_m: float = 0.003,
    gap_px: int = _GAP_PX,
    cases: tuple[int, ...] = (1, 2),
    facing_only: bool = False,
) -> tuple[np.ndarray, int]:
    """Rule R7e: a light object takes the raised part of a dark neighbour (see module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float
        Gray-level distance from the ground level in threshold bands; the sign of an
        object's median says lighter (> 0) or darker than the ground.
    relative : (M, N) ndarray of float
        Metres above the local ground (smoothed heights minus R0's local ground), NaN
        where invalid.
    row_noise : (M,) ndarray of float
        Ground height noise of each row (metres, R0b's band MAD sigma).
    max_noise_m : float
        ``>= 0``; only rows whose noise is at most this are read; 0 disables.
    min_height_m, flat_tol_m : float
        Floors of the raise threshold (``> 0``) and of the flat level (``>= 0``).
    gap_px : int
        ``>= 1``; a dark object this close to a light one is its neighbour.
    cases : tuple of int
        Which cases run: 1 (a dark neighbour split) and/or 2 (a ground-gray face filled).
    facing_only : bool
        Split a dark neighbour only when its raised part connected to the lit object holds
        at least ``sqrt(its area)`` pixels (R7b's facing measure) and at most the lit
        object's: the call before R7b, which leaves to R7b's join a shaded face the stereo
        flattened (hardly raised) and a dark rock body beside a small highlight.

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m (a dropped shadow's id is gone).
    moved : int
        Pixels joined to light objects (raised parts and the gaps closed).
    """
    check_height_inputs(labels, contrast, relative, row_noise)
    if not max_noise_m >= 0 or not min_height_m > 0 or not flat_tol_m >= 0 or gap_px < 1:
        raise ValueError(
            "need max_noise_m >= 0 (0 disables), min_height_m > 0, flat_tol_m >= 0 and "
            f"gap_px >= 1, got {max_noise_m}, {min_height_m}, {flat_tol_m} and {gap_px}"
        )
    if not cases or not set(cases) <= {1, 2}:
        raise ValueError(f"cases must name 1, 2 or both, got {cases!r}")
    count = int(labels.max())
    if count == 0 or max_noise_m == 0:
        return labels, 0
    read = np.flatnonzero(row_noise <= max_noise_m)
    if read.size == 0:
        return labels, 0
    # the rows read: far rows are not, and every full-frame map is worked out on them only
    band = slice(int(read[0]), int(read[-1]) + 1)
    noise = row_noise[band].astype(np.float32)[:, None]
    raise_m = np.maximum(np.float32(min_height_m), _RAISE_SIGMAS * noise)
    flat_row = np.full(labels.shape[0], -np.inf, np.float32)
    flat_row[band] = np.minimum(
        np.maximum(np.float32(flat_tol_m), _FLAT_SIGMAS * noise), raise_m / 2
    ).ravel()
    precise = np.zeros(labels.shape, bool)
    raised = np.zeros(labels.shape, bool)
    flat = np.zeros(labels.shape, bool)
    precise[band] = np.isfinite(relative[band]) & (noise <= max_noise_m)
    with np.errstate(invalid="ignore"):
        raised[band] = precise[band] & (relative[band] > raise_m)
        flat[band] = precise[band] & (relative[band] < flat_row[band, None])
    if not precise.any():
        return labels, 0
    owners = labels.ravel()
    inside = owners > 0
    # only the medians' signs are read: float32 contrast takes the compiled float32 path
    # (the exact order statistic; the float64 path's sort of combined label-value keys
    # gives the same one, 0.4 ms a call slower); other dtypes the float64 path as before
    median = _percentile_by_label(contrast.ravel()[inside], owners[inside], count + 1, 50.0)
    # a light object in the precise rows (a far one is skipped: its rows are not read)
    n_pixels, n_precise, n_flat = _label_counts(labels, precise, flat, count + 1)
    # (an absent id, its median +inf, is no object: a rule before may have emptied it)
    light = (np.nan_to_num(median) > 0) & (n_precise >= 0.5 * n_pixels) & (n_pixels > 0)
    # a dark object that may hold a cast shadow: a quarter of what heights judge is flat
    shadowed = (np.nan_to_num(median) < 0) & (n_flat >= _MIN_FLAT_SHARE * np.maximum(n_precise, 1))
    shadowed &= n_flat > 0
    light[0] = shadowed[0] = False
    if not light.any():
        return labels, 0
    # a shadow's pixels: dark ones of the ground or of a dark object (not of a light one)
    shady = np.nan_to_num(median) < 0
    shady[0] = True
    out = labels.copy()
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * gap_px + 1, 2 * gap_px + 1))
    step = np.ones((3, 3), np.uint8)
    # find_objects' slices from one compiled pass, made for the objects read (the light
    # ones and their neighbours: slices for all cost 0.4 ms a frame); every id read is
    # present in ``labels``
    boxes = _object_boxes(labels, count)
    rows, cols = labels.shape
    moved = 0
    split: set[int] = set()
    for k in np.flatnonzero(light):
        sy, sx = _box_window(boxes[k])
        y0, x0 = max(0, sy.start - gap_px), max(0, sx.start - gap_px)
        y1, x1 = min(rows, sy.stop + gap_px), min(cols, sx.stop + gap_px)
        window = out[y0:y1, x0:x1]
        # the objects within gap_px: none when the window holds k's pixels only (all of
        # them: a light object loses none and gains only in its turn)
        neighbours: np.ndarray | tuple = ()
        if 1 in cases and np.count_nonzero(window) > n_pixels[k]:
            reach = cv2.dilate((window == k).view(np.uint8), disk).view(bool)
            neighbours = np.unique(window[reach])
        for d in neighbours:
            if 1 not in cases or not shadowed[d]:
                continue
            # a box holding both objects
            dy, dx = _box_window(boxes[d])
            by0, bx0 = min(y0, dy.start), min(x0, dx.start)
            by1, bx1 = max(y1, dy.stop), max(x1, dx.stop)
            box = out[by0:by1, bx0:bx1]
            lit = box == k
            face = raised[by0:by1, bx0:bx1] & (box == d)
            near = face & cv2.dilate(lit.view(np.uint8), disk).view(bool)
            if not near.any():
                continue
            # the raised pixels of the dark object connected (through raised ones) to the lit
            while True:
                grown = face & cv2.dilate(near.view(np.uint8), step).view(bool)
                if np.count_nonzero(grown) == np.count_nonzero(near):
                    break
                near = grown
            if facing_only and not np.sqrt(n_pixels[d]) <= np.count_nonzero(near) <= n_pixels[k]:
                # hardly raised: maybe a shaded face the stereo flattened; more raised than
                # the lit object: a rock's body beside a highlight, not a face (R7b joins)
                continue
            joined = lit | near
            closed = _closing(joined, disk)
            take = near | (closed & (box == 0))
            box[take] = k
            moved += int(np.count_nonzero(take))
            split.add(int(d))
        if 2 in cases:
            moved += _fill_to_shadow(
                out, k, _box_window(boxes[k]), labels, contrast, shady, raised
            )
    for d in split:
        dy, dx = _box_window(boxes[d])
        rest = out[dy, dx] == d
        judged = rest & precise[dy, dx]
        heights = relative[dy, dx][judged]
        levels = np.broadcast_to(flat_row[dy, None], rest.shape)[judged]
        if heights.size > 0.5 * np.count_nonzero(rest) and np.median(heights) < np.median(levels):
            out[dy, dx][rest] = 0  # what is left lies on the ground: the cast shadow
    if not moved:
        return labels, 0
    return _renumber(out, 1), moved


def _label_counts(
    labels: np.ndarray, precise: np.ndarray, flat: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per label 0..count-1: pixels, ``precise`` pixels and ``flat`` pixels; one compiled
    pass instead of three ``np.bincount`` of masked copies (``test_shadow_sides.py``
    compares them)."""
    counts = np.zeros((3, count), np.int64)
    _count_pass(
        np.ascontiguousarray(labels),
        np.ascontiguousarray(precise),
        np.ascontiguousarray(flat),
        counts,
    )
    return counts[0], counts[1], counts[2]


@njit(cache=True)
def _count_pass(labels, precise, flat, counts):  # pragma: no cover - numba
    rows, cols = labels.shape
    # label 0's counts in registers: ``counts[0, 0] += 1`` on most pixels makes each wait
    # for the last store
    ground = ground_precise = ground_flat = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                ground += 1
                if precise[y, x]:
                    ground_precise += 1
                if flat[y, x]:
                    ground_flat += 1
            else:
                counts[0, k] += 1
                if precise[y, x]:
                    counts[1, k] += 1
                if flat[y, x]:
                    counts[2, k] += 1
    counts[0, 0] += ground
    counts[1, 0] += ground_precise
    counts[2, 0] += ground_flat


def _fill_to_shadow(
    out: np.ndarray,
    k: int,
    span: tuple[slice, slice],
    labels: np.ndarray,
    contrast: np.ndarray,
    shady: np.ndarray,
    standing: np.ndarray,
) -> int:
    """R7e's second case, in place: light object ``k`` takes the standing pixels, neither
    dark nor its own, between it and the dark pixels near it of the ground or of an object
    ``shady`` (by id in ``labels``) says is dark: a cast shadow."""
    pad = _SHADOW_REACH_PX + _SHADOW_CLOSE_PX
    rows, cols = out.shape
    y0, x0 = max(0, span[0].start - pad), max(0, span[1].start - pad)
    y1, x1 = min(rows, span[0].stop + pad), min(cols, span[1].stop + pad)
    box = out[y0:y1, x0:x1]
    lit = box == k
    free = box == 0
    reach = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * _SHADOW_REACH_PX + 1,) * 2)
    shade = contrast[y0:y1, x0:x1] < -1  # past the low threshold: a shadow's gray
    shadow = shade & shady[labels[y0:y1, x0:x1]] & ~lit
    shadow &= cv2.dilate(lit.view(np.uint8), reach).view(bool)
    if np.count_nonzero(shadow) < _SHADOW_MIN_PX:
        return 0
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * _SHADOW_CLOSE_PX + 1,) * 2)
    closed = _closing(lit | shadow, disk)
    gap = closed & free & ~shade & standing[y0:y1, x0:x1]
    if _FACE_OPEN_PX:
        square = np.ones((2 * _FACE_OPEN_PX + 1,) * 2, np.uint8)
        gap = cv2.morphologyEx(gap.view(np.uint8), cv2.MORPH_OPEN, square).view(bool)
    if not gap.any():
        return 0
    # only pixels that reach the object through the gap
    _, pieces = cv2.connectedComponents((gap | lit).view(np.uint8), connectivity=8)
    # (a lookup of the pieces holding a lit pixel: np.isin sorts them)
    reached = np.zeros(int(pieces.max()) + 1, bool)
    reached[pieces[lit]] = True
    gap &= reached[pieces]
    box[gap] = k
    return int(np.count_nonzero(gap))


def _closing(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Binary closing that treats pixels beyond the window as background: OpenCV's default
    border lets an erosion keep whatever touches the window's edge, which would grow an
    object along the edge of the box it is judged in."""
    return cv2.morphologyEx(
        mask.view(np.uint8),
        cv2.MORPH_CLOSE,
        kernel,
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    ).view(bool)
