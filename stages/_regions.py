"""From thresholds to labelled objects, and the depth rules that act on objects.

Intensity: a pixel is object when its gray level is below the interpolated low threshold or
above the high one (:func:`threshold_mask`). :func:`label_objects` then fills holes (background
pockets enclosed by object pixels), optionally splits components at depth discontinuities,
drops specks smaller than ``min_area_px`` and numbers the objects ``1..n`` densely.

Depth rules R0-R3 (height above ground: local ground, raised, flat, no depth) are in
:mod:`stages._depth_rules`; the ones that act on objects are here:

* **R4 split** -- a pixel where the (median-smoothed) disparity drops by more than
  ``split_disparity_px`` towards a 4-neighbour is a depth edge: the surface behind an
  occluding boundary. An object made of two or more cores (4-connected pieces of at least
  ``min_area_px`` after removing its depth edges) is split into those cores; every other pixel
  of the object goes to its nearest core. Touching rocks at different ranges thus become
  separate objects.
* **R5 streaks** -- an object more than ``max_elongation`` times longer than wide (its
  equivalent ellipse) is a wind striation or ripple trough, not a rock: dropped
  (:func:`drop_streaks`). Rocks seen from a rover are compact blobs.
* **R5b clear flat rocks** -- except when its median gray level lies at least 2.5 threshold
  bands from the ground level and it is at most 4 times longer than wide: a far rock seen
  edge-on is 3-3.6 times wider than tall, but stands out clearly, while ripple troughs
  barely cross the threshold (median 1.2-2.1 bands on the dunes frames) and striations are
  longer. On the catalog frames R5 dropped 11 true rocks of mojave and 13 of lava; with
  R5b mojave keeps 7 more (2 more false positives), lava 7 more (1 more), dunes none.
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
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt, find_objects

#: Threshold bands from the ground level beyond which an object is clear in gray level
#: without further evidence (R3b, R5b): ground texture that crosses a threshold stays
#: close to it (on the catalog frames 90 % of the texture objects lie within 1.9 bands on
#: mojave and lava, 2.4 on dunes), true rocks lie at a median 2-2.6 bands.
CLEAR_CONTRAST = 2.5

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
# R7b: objects of opposite sides this close (pixels) are candidate halves of one rock ...
_JOIN_GAP_PX = 5
# ... facing each other over at least sqrt(area of the smaller) pixels, joined when the
# union (gap closed) is at most this much less solid than the more solid half.
_JOIN_SOLIDITY_SLACK = 0.05

__all__ = [
    "CLEAR_CONTRAST",
    "threshold_mask",
    "fill_holes",
    "depth_edges",
    "label_objects",
    "elongation",
    "drop_streaks",
    "drop_ripple_pieces",
    "trim_attached_shadows",
    "grow_weak_halves",
    "join_opposite_halves",
    "grow_other_faces",
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
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        mask.view(np.uint8), connectivity=connectivity, ltype=cv2.CV_32S
    )
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    keep[0] = False
    lookup = np.zeros(count, dtype=np.int32)
    lookup[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return lookup[labels]


def _split_at_edges(labels: np.ndarray, edges: np.ndarray, min_area_px: int) -> np.ndarray:
    """Split objects holding several depth-separated cores; returns new (not dense) labels."""
    # 4-connected cores: a one-pixel staircase of edge pixels must be a closed cut
    cores = _dense_components((labels > 0) & ~edges, min_area_px, connectivity=4)
    n_cores = int(cores.max())
    if n_cores < 2:
        return labels
    # parent object of each core, and how many cores each object has
    core_pixels = cores > 0
    parent = np.zeros(n_cores + 1, dtype=np.int64)
    parent[cores[core_pixels]] = labels[core_pixels]
    cores_per_object = np.bincount(parent[1:], minlength=int(labels.max()) + 1)
    split_objects = np.flatnonzero(cores_per_object >= 2)
    if split_objects.size == 0:
        return labels
    in_split = np.isin(labels, split_objects)
    _, (iy, ix) = distance_transform_edt(~core_pixels, return_indices=True)
    nearest = cores[iy, ix]
    same_parent = parent[nearest] == labels
    result = labels.astype(np.int64)
    offset = int(labels.max())
    result[in_split & same_parent] = offset + nearest[in_split & same_parent]
    return result


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


def _renumber(labels: np.ndarray, min_area_px: int) -> np.ndarray:
    """Dense 1..n in raster order of first pixel, dropping labels smaller than min_area_px."""
    values, first, counts = np.unique(labels.ravel(), return_index=True, return_counts=True)
    keep = (values > 0) & (counts >= min_area_px)
    kept = values[keep][np.argsort(first[keep])]
    remap = np.zeros(int(values.max()) + 1, dtype=np.int32)
    remap[kept] = np.arange(1, kept.size + 1, dtype=np.int32)
    return remap[labels]


def _moments(labels: np.ndarray) -> tuple[np.ndarray, ...]:
    """Area, centroid (y, x), elongation and axis angle of each label 0..max.

    The angle (radians in ``(-pi/2, pi/2]``, 0 along the rows, positive towards increasing
    row) is the major axis of the equivalent ellipse; it is 0 for label 0 and absent labels.
    """
    labels = np.asarray(labels)
    count = int(labels.max()) + 1
    ys, xs = np.nonzero(labels)
    ids = labels[ys, xs]
    area = np.maximum(np.bincount(ids, minlength=count), 1).astype(np.float64)
    mx = np.bincount(ids, xs, minlength=count) / area
    my = np.bincount(ids, ys, minlength=count) / area
    dx, dy = xs - mx[ids], ys - my[ids]
    # + 1/12: a pixel is a unit square, so a single row still has a width
    sxx = np.bincount(ids, dx * dx, minlength=count) / area + 1.0 / 12.0
    syy = np.bincount(ids, dy * dy, minlength=count) / area + 1.0 / 12.0
    sxy = np.bincount(ids, dx * dy, minlength=count) / area
    half_trace = (sxx + syy) / 2.0
    root = np.sqrt(((sxx - syy) / 2.0) ** 2 + sxy**2)
    major, minor = half_trace + root, np.maximum(half_trace - root, 1e-12)
    ratio = np.sqrt(major / minor)
    ratio[0] = 0.0
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    angle[0] = 0.0
    return area, my, mx, ratio, angle


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
    clear_elongation: float = 4.0,
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
    ratio = elongation(labels)
    streak = ratio > max_elongation
    if contrast is not None:
        if contrast.shape != labels.shape:
            raise ValueError(
                f"contrast {contrast.shape} and labels {labels.shape} must have one shape"
            )
        candidates = np.flatnonzero(streak & (ratio <= clear_elongation))
        boxes = _object_boxes(labels, int(labels.max())) if candidates.size else None
        for k in candidates:
            y0, y1, x0, x1 = boxes[k]
            window = np.s_[y0 : y1 + 1, x0 : x1 + 1]
            if np.median(np.abs(contrast[window][labels[window] == k])) >= clear_contrast:
                streak[k] = False
    if not streak.any():
        return labels, 0
    kept = np.where(streak[labels], 0, labels)
    return _renumber(kept, 1), int(streak.sum())


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
        out) than the ring's own 5th (darker objects) or 95th (lighter objects) percentile.
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
    ys, xs = np.nonzero(labels)
    ids = labels[ys, xs]
    area = np.maximum(np.bincount(ids, minlength=count + 1), 1).astype(np.float64)[1:]
    cy = (np.bincount(ids, ys, minlength=count + 1)[1:]) / area
    cx = (np.bincount(ids, xs, minlength=count + 1)[1:]) / area
    in_field = _streak_field(
        texture,
        area,
        cy,
        cx,
        max_elongation=max_elongation,
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
    boxes = find_objects(labels)
    rows, cols = labels.shape
    ripple = np.zeros(count + 1, dtype=bool)
    for k in in_field:
        sy, sx = boxes[k - 1]
        y0, x0 = max(0, sy.start - _TEXTURE_RING_PX), max(0, sx.start - _TEXTURE_RING_PX)
        y1, x1 = min(rows, sy.stop + _TEXTURE_RING_PX), min(cols, sx.stop + _TEXTURE_RING_PX)
        window = labels[y0:y1, x0:x1]
        ratio = _texture_ratio(image[y0:y1, x0:x1], window, window == k)
        ripple[k] = ratio < min_texture_ratio
    if not ripple.any():
        return labels, 0
    # labels are dense and numbered in raster order: dropping some keeps the order
    remap = np.zeros(count + 1, dtype=np.int32)
    remap[1:][~ripple[1:]] = np.arange(1, count + 1 - int(ripple.sum()), dtype=np.int32)
    return remap[labels], int(ripple.sum())


def _streak_field(
    texture: np.ndarray,
    area: np.ndarray,
    cy: np.ndarray,
    cx: np.ndarray,
    *,
    max_elongation: float,
    radius_px: float,
    min_streaks: int,
    min_coherence: float,
) -> np.ndarray:
    """R5c: which objects (area and centroid of each) have a field of parallel streaks around."""
    in_field = np.zeros(area.size, dtype=bool)
    if not texture.any():
        return in_field
    t_area, _, _, t_ratio, t_angle = _moments(texture)
    streaks = np.flatnonzero(t_ratio > max_elongation)
    if streaks.size < min_streaks:
        return in_field
    # inclusive (y0, y1, x0, x1) of each streak; find_objects is C, _object_boxes is not
    spans = find_objects(texture)
    t_boxes = np.array(
        [
            (sy.start, sy.stop - 1, sx.start, sx.stop - 1)
            for sy, sx in (spans[k - 1] for k in streaks)
        ],
        dtype=np.float64,
    )
    # doubled angles: an axis at 89 degrees and one at -89 degrees are parallel
    t_weights = t_area[streaks]
    t_vectors = t_weights * np.exp(2j * t_angle[streaks])
    # distance from each object's centroid to each streak's box (0 inside it)
    gap_y = np.maximum(t_boxes[None, :, 0] - cy[:, None], cy[:, None] - t_boxes[None, :, 1])
    gap_x = np.maximum(t_boxes[None, :, 2] - cx[:, None], cx[:, None] - t_boxes[None, :, 3])
    near = np.hypot(np.maximum(gap_y, 0.0), np.maximum(gap_x, 0.0)) <= radius_px
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


def _texture_ratio(image: np.ndarray, labels: np.ndarray, inside: np.ndarray) -> float:
    """R5c: how far an object's median gray lies beyond its ring's texture (see above).

    The ring is the ground 3 to ``_TEXTURE_RING_PX`` pixels out (not the object's own
    blurred edge); ``inf`` when it has fewer than 20 pixels (nothing to compare with).
    Medians and percentiles are nearest-rank (one sort each: 3x faster than numpy's).
    """
    mask = inside.view(np.uint8)
    inner = cv2.dilate(mask, _ring_kernel(3)).view(bool)
    outer = cv2.dilate(mask, _ring_kernel(_TEXTURE_RING_PX)).view(bool)
    ring = np.sort(image[outer & ~inner & (labels == 0)])
    if ring.size < 20:
        return float("inf")
    gray = np.sort(image[inside])
    gray_level = float(gray[(gray.size - 1) // 2])
    level = float(ring[(ring.size - 1) // 2])
    tail_rank = 0.05 if gray_level < level else 0.95
    tail = float(ring[int(tail_rank * (ring.size - 1))])
    return abs(gray_level - level) / max(abs(tail - level), 1.0)


def _ring_kernel(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


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


def _object_boxes(labels: np.ndarray, count: int) -> np.ndarray:
    """Inclusive (y0, y1, x0, x1) of each label 0..count (y1 < y0 when absent)."""
    ys, xs = np.nonzero(labels)
    ids = labels[ys, xs]
    boxes = np.empty((count + 1, 4), dtype=np.int64)
    boxes[:, 0] = boxes[:, 2] = np.iinfo(np.int64).max
    boxes[:, 1] = boxes[:, 3] = -1
    np.minimum.at(boxes[:, 0], ids, ys)
    np.maximum.at(boxes[:, 1], ids, ys)
    np.minimum.at(boxes[:, 2], ids, xs)
    np.maximum.at(boxes[:, 3], ids, xs)
    return boxes



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
