"""Footprint measurements of the describe stage: an object's width and length on the ground.

Pure functions, arrays in, numbers out, used by :func:`stages._descriptors.describe_objects`:
:func:`footprint_disparity` (the disparity the footprint is measured on),
:func:`footprint_dimensions` (width and length of the ground points),
:func:`ground_fringe_keep` (which pixels count: not the ground-level fringes),
:func:`too_dark_to_match` (pixels whose heights that decision must not read),
:func:`widest_row_width_m` (the width when there is no ground frame).

``width_m`` and ``length_m`` are the largest horizontal dimension of the object's visible
footprint and its dimension across that (:func:`footprint_dimensions`), measured on the
object's pixels without its ground-level fringes (:func:`ground_fringe_keep`: a sun shadow
segmented with the rock lies on the ground) on a disparity fitted to the pixels kept,
constant along each image row (:func:`footprint_disparity`). For an object that touches the
image border they are of the visible part only, a lower bound (``touches_border``); its
``size_class`` then also reads a lower bound of the whole rock's width from its visible
height (:mod:`stages._border`).

A fringe pixel is one whose height, alone *and* averaged over a 7x7 box of the object
(``fringe_smoothing_px``), stays under 4 mm: one by one a third of a flat shadow's noisy
stereo heights stand above 4 mm on mojave and lava. Median width error of the rocks within
2 m, pixel by pixel -> with the box (``benchmarks/bench_describe.py --rundir DIR --set
describe.fringe_smoothing_px=1`` or ``7``; DIR the catalog run of ``evaluate_archives.sh``
and runs of the catalogs with ``seed = 2..5``, depth v5, segment v19): lab 7.0 / 8.4 / 7.8
-> 6.4 / 7.3 / 6.1 % (catalog, seeds 2, 3); mojave 11.3 / 10.9 / 11.2 / 12.2 / 12.5 ->
8.7 / 10.5 / 10.5 / 13.7 / 11.5 %; lava 11.4 / 8.3 / 12.6 / 11.1 / 10.5 -> 10.5 / 8.1 /
12.6 / 12.7 / 11.3 % (catalog, seeds 2-5). Class right: the same or better on 10 of the 13
runs; worse on lab seed 3 (97.8 -> 95.7 %), lava's catalog (92.0 -> 91.0) and lava seed 4
(91.1 -> 88.9).
The catalog frames gain more than the seeds: on average over the runs lab 7.7 -> 6.6 %,
mojave 11.6 -> 11.0 %, lava 10.8 -> 11.0 %.

Pixels too dark for stereo to match (gray below 0.15 of the object's background ring,
:func:`too_dark_to_match`) count as of unknown height in that decision: a black rock's lower
half takes the floor's disparity through the matching windows, reads ground level and was
cut off as a fringe, with the rock's widest rows (lab's widths read ~5 % short, rocks of
0.10-0.12 m became samples). Near-rock (within 2 m) class right / median width error with
labels segmented again (``benchmarks/bench_describe.py --rundir DIR --labels segment``;
catalog runs and seeds 2, 3 for lab, 2..5 for mojave and lava; depth v6, segment v27,
describe v6 -> v7): lab 0.914 / 0.944 / 0.957 -> 0.914 / 0.963 / 0.978, 7.6 / 8.2 / 7.4 ->
5.7 / 5.8 / 5.5 %; mojave 0.907 / 0.938 / 0.917 / 0.957 / 0.895 -> 0.907 / 0.938 / 0.896 /
0.957 / 0.895, 8.3 / 9.1 / 7.9 / 9.5 / 9.3 -> 7.6 / 8.2 / 7.3 / 9.1 / 9.6 %; lava 0.945 /
0.927 / 0.932 / 0.908 / 0.887 -> 0.955 / 0.927 / 0.932 / 0.908 / 0.897, 9.4 / 9.1 / 11.9 /
12.2 / 12.5 -> 9.1 / 9.1 / 12.4 / 11.1 / 12.9 %. The one rock lost (mojave seed 3) is a
dark rock whose near-black shadow is now kept. A ratio of 0.10 classes the same rocks
(lab widths 6.4 / 6.9 / 6.4 %); 0.20 loses a rock on mojave seed 2 (0.917), lava's catalog
(0.936) and lava seed 2 (0.917), 0.25 also on mojave seed 4 (0.935): shadows start to count.

Far rocks read as ground (:func:`bound_footprint_slope`, describe v9): the row fit follows
whatever slope the matcher gives the object's rows, and on a far or a black rock that is
the ground's (lab_0000 object 2, a black rock 3.8 m away whose true disparity is 8.04-8.10
on every row, measured 7.41 at its top row and 8.11 at its foot: 0.535 m wide against the
truth's 0.368, 0.338 with the bound). All-rock median / p90 width error and the
size-frequency ``k`` against the truth's (``benchmarks/bench_describe.py --rundir DIR
--labels segment`` for the widths; ``k`` from the same rows with
:func:`stages._sizefreq.size_frequency_from_table`, ground = the frames'
``describe_ground_area_m2``, 5 m, as ``arroyo evaluate``; segment v38), before -> after:
lab 8.8 / 36.7 % -> 9.0 / 30.9 %, k 0.045 -> 0.042 (truth 0.040); mojave 11.5 / 49.0 ->
11.0 / 41.1 %, k 0.035 -> 0.034 (0.033); lava 12.5 / 48.2 -> 12.0 / 45.5 %, k 0.044 ->
0.040 (0.040). Seeds (lab 2, 3; mojave 2-5; lava 2-5 with ``two_face_sigmas = 3``): p90
31.1 / 30.4 -> 30.6 / 30.4 %, 68.4 / 57.7 / 46.2 / 56.1 -> 43.5 / 41.2 / 43.2 / 40.7 %,
49.7 / 49.3 / 47.2 / 50.4 -> 39.2 / 41.0 / 43.3 / 44.0 %; medians the same or lower (lab's
catalog 8.8 -> 9.0 %); k moves lower everywhere (by up to 0.007), towards the truth on lava
seeds 3-5, away from it on the mojave and lab seeds (whose k was low already: they miss
rocks) and on lava seed 2 (0.042 -> 0.036, truth 0.040). The rocks within 2 m keep their
median width error and class on all 13 runs (lava seed 2's class 0.892 -> 0.901); all
rocks' class on the catalog runs: lab 0.882 -> 0.873, mojave 0.885 -> 0.887, lava 0.870. Bounding
every object (no gates) cost them: mojave's near width error 7.6 -> 8.3 %, seed 4 7.7 ->
8.5 %; so did a bound from the footprint's extent alone (along > across: mojave 7.9 %),
and a constant disparity beyond 2.5 m (k 0.030 on mojave and lava: far widths 5-9 % short).
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from pipeline.camera import Camera

from ._ground import GroundFrame, _median, fit_disparity_surface, pixel_points
from ._small_stats import footprint_spreads

__all__ = [
    "widest_row_width_m",
    "footprint_disparity",
    "bound_footprint_slope",
    "ground_disparity_slope",
    "face_rows",
    "footprint_dimensions",
    "ground_fringe_keep",
    "too_dark_to_match",
]


def widest_row_width_m(
    rows: np.ndarray, cols: np.ndarray, depth: np.ndarray, *, focal_px: float, fallback_z: float
) -> float:
    """Largest width across the view, metres: max over image rows of span x Z / f.

    The span of a row is ``max col - min col + 1`` pixels (the visible extremities); Z is the
    median valid depth of that row's pixels, or ``fallback_z`` where the row has none.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The object's pixels (any order).
    depth : (K,) ndarray of float
        Range Z of those pixels, NaN where invalid.
    focal_px : float
    fallback_z : float
        Depth used for rows without a valid pixel (the object's median range).
    """
    r = np.asarray(rows, dtype=np.int64)
    c = np.asarray(cols, dtype=np.int64)
    z = np.asarray(depth, dtype=np.float64)
    if r.size == 0:
        return math.nan
    uniq, inverse = np.unique(r, return_inverse=True)
    span = np.full(uniq.size, 0, dtype=np.int64)
    cmin = np.full(uniq.size, np.iinfo(np.int64).max)
    cmax = np.full(uniq.size, np.iinfo(np.int64).min)
    np.minimum.at(cmin, inverse, c)
    np.maximum.at(cmax, inverse, c)
    span = cmax - cmin + 1
    row_z = np.full(uniq.size, fallback_z, dtype=np.float64)
    valid = np.isfinite(z)
    if valid.any():
        vi, vz = inverse[valid], z[valid]
        order = np.lexsort((vz, vi))
        vi, vz = vi[order], vz[order]
        starts = np.searchsorted(vi, np.arange(uniq.size), side="left")
        counts = np.searchsorted(vi, np.arange(uniq.size), side="right") - starts
        has = counts > 0
        lower = vz[starts[has] + (counts[has] - 1) // 2]
        upper = vz[starts[has] + counts[has] // 2]
        row_z[has] = (lower + upper) / 2.0
    widths = span * row_z / focal_px
    if not np.isfinite(widths).any():
        return math.nan
    return float(np.nanmax(widths))


def footprint_disparity(rows: np.ndarray, cols: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """The disparity an object's footprint is measured on: a robust straight line in rows,
    ``d = a + b row``, constant along each image row
    (:func:`stages._ground.fit_disparity_surface` with ``row_only=True``).

    Why constant along rows: at these ranges a rock's visible surface lies at about one depth
    across the view, while the measured disparity of a small rock tilts across it (the
    matching windows take the ground's disparity on one side, sub-pixel bias); a fitted tilt
    across columns turned far rocks into diagonal streaks on the ground. Why no curvature:
    on a small rock the curvature terms follow the matching windows' blur at its rim (the
    disparity falls towards the ground's there), which spreads the footprint along the line
    of sight, and on the large rocks a row-squared term measured no better.

    Median signed / absolute width error of the rocks seen whole, by range 0-2 / 2-3 / 3-4 /
    beyond 4 m; describe v5 (a plane in (col, row), a quadratic from 500 valid pixels) ->
    v6 (this line); ``benchmarks/bench_describe.py --rundir runs/eval/ARCHIVE --dump CSV``
    on the catalog runs of ``evaluate_archives.sh``:

    ======  ====================================  ====================================
    lab     -3/6, +5/13, +12/21, +89/89 %          -4/5, -0/10, -1/10, +11/17 %
    mojave  +4/8, +13/14, +17/19, +36/39 %         +4/7, +6/10, +3/11, +5/13 %
    lava    +3/11, +5/11, +17/23, +48/48 %         +1/10, -1/10, -2/13, +4/16 %
    ======  ====================================  ====================================

    All matched rocks' median width error (the size-frequency fit reads those within 5 m),
    catalog runs and runs of the catalogs with ``seed = 2, 3`` (lab) or ``2..5``: lab 13.3 /
    10.9 / 10.4 -> 9.7 / 8.8 / 9.5 %, mojave 21.3 / 19.6 / 16.6 / 19.1 / 18.4 -> 12.2 / 11.4
    / 10.8 / 12.6 / 13.2 %, lava 18.7 / 19.2 / 18.6 / 19.0 / 17.8 -> 11.8 / 12.7 / 12.9 /
    12.7 / 12.6 %. The rocks within 2 m, for which a tilt is measurable, change little: lab
    6.4 / 7.3 / 6.1 -> 7.5 / 7.8 / 5.6 %, mojave 8.7 / 10.5 / 10.5 / 13.7 / 11.5 -> 8.3 /
    10.3 / 7.7 / 11.3 / 9.7 %, lava 10.5 / 8.1 / 12.6 / 12.7 / 11.3 -> 9.5 / 7.9 / 12.0 /
    11.6 / 13.0 % (means 6.6 -> 7.0, 11.0 -> 9.5, 11.0 -> 10.8 %). A row-squared term from
    250, 500, 1000 or 2000 valid pixels measured the same or worse on these runs, and so did
    keeping v5's surface for rocks of 200, 500 or 1000 pixels and more on the catalog runs.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The object's pixels (those the footprint keeps).
    disparity : (K,) ndarray of float
        Their measured disparity, NaN (or <= 0) where invalid.

    Returns
    -------
    (K,) ndarray of float64
        The fitted disparity of every pixel; all NaN when none is valid.
    """
    return fit_disparity_surface(rows, cols, disparity, row_only=True)


# bound_footprint_slope reads an object as a face when its height stood up on the ground
# spans at least this share of its rows, or when its fitted footprint reads this many times
# longer along the line of sight than across it
_MIN_FACE_SHARE = 0.7
_MAX_ALONG_RATIO = 1.5


def ground_disparity_slope(ground: GroundFrame, camera: Camera) -> float:
    """Disparity change per image row of the ground plane, pixels per row (> 0: the ground
    comes nearer down the image).

    The plane ``up . X = up . origin`` meets the ray ``Z ((u - cx) / f, (v - cy) / f, 1)`` at
    ``Z = (up . origin) / (up . ray)``, so its disparity ``f b / Z`` is linear in ``v`` with
    slope ``f b up_y / (f (up . origin))`` (the same at every column).
    """
    level = float(ground.up @ ground.origin)
    if level == 0.0:
        return math.nan
    return float(camera.k_m_px * ground.up[1] / (camera.focal_px * level))


def face_rows(
    row: float,
    col: float,
    disparity: float,
    height_m: float,
    *,
    camera: Camera,
    ground: GroundFrame,
    shape: tuple[int, int],
) -> float:
    """Image rows a vertical face ``height_m`` high spans, standing on the ground under the
    point seen at pixel ``(row, col)`` with ``disparity``; 0 for a height <= 0 or NaN."""
    if not (height_m > 0 and disparity > 0):
        return 0.0
    point = pixel_points(
        np.array([row]), np.array([col]), np.array([disparity]), camera=camera, shape=shape
    )[0]
    foot = point - float(ground.up @ (point - ground.origin)) * ground.up
    top = foot + height_m * ground.up
    if not (foot[2] > 0 and top[2] > 0):
        return 0.0
    return float(abs(camera.focal_px * (foot[1] / foot[2] - top[1] / top[2])))


def _hinge_slope(face_share: float) -> float:
    """Least-squares slope of ``max(0, x - s)`` on ``x`` in [0, 1], ``s = face_share``: a
    profile flat over its first ``s`` and rising by 1 per unit after, fitted by one line."""
    s = min(max(face_share, 0.0), 1.0)
    return 12.0 * ((1.0 - s**3) / 3.0 - s * (1.0 - s**2) / 2.0 - (1.0 - s) ** 2 / 4.0)


def bound_footprint_slope(
    rows: np.ndarray,
    cols: np.ndarray,
    fitted: np.ndarray,
    *,
    ground_slope_px: float,
    face_px: float,
    focal_px: float,
    min_face_share: float = _MIN_FACE_SHARE,
    max_along_ratio: float = _MAX_ALONG_RATIO,
) -> np.ndarray:
    """The footprint disparity with its row slope bounded where a face reads as ground.

    A rock's visible surface is a face (``face_px`` rows: the object's height stood up on
    the ground, about one depth) under a top that recedes at most as fast as the ground
    (``ground_slope_px`` per row). Fitted with one line, such a profile has at most the
    slope :func:`_hinge_slope` gives for the face's share of the rows, times the ground's.
    The stereo windows often give a face the ground's slope instead (a black rock takes
    the floor's disparity around it, the windows at a small far rock's top rim the
    ground's behind it): its upper rows land far behind, and the footprint reads the rock
    up to several times its width along the line of sight. The fitted slope is bounded by
    that profile's (its level at the middle row kept) where the face spans at least
    ``min_face_share`` of the object's rows (a far rock, seen from the side) or where the
    fitted footprint reads more than ``max_along_ratio`` times longer along the line of
    sight than across the view (the slope then decides the width). Elsewhere (rocks near
    the camera, seen from above, their top over many rows) the fit measures the rock's
    depth and is kept: bounded there too, near rocks' widths read a little short.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The pixels.
    fitted : (K,) ndarray of float
        Their fitted disparity (:func:`footprint_disparity`), constant along rows.
    ground_slope_px : float
        The ground's disparity change per row, px (:func:`ground_disparity_slope`).
    face_px : float
        Rows of the object's face (:func:`face_rows`), >= 0.
    focal_px : float
    min_face_share : float
        In [0, 1]: share of the rows the face must span for the bound to apply (1: only an
        object all face, its slope then bounded to 0).
    max_along_ratio : float
        > 0: along / across the view extent of the fitted footprint above which the bound
        applies whatever the face's share.

    Returns
    -------
    (K,) ndarray of float64
        ``fitted`` itself or the bounded disparity.
    """
    if not 0.0 <= min_face_share <= 1.0 or not max_along_ratio > 0:
        raise ValueError(
            "min_face_share must be a share of the object's rows in [0, 1] and "
            f"max_along_ratio > 0, got {min_face_share!r} and {max_along_ratio!r}"
        )
    d = np.asarray(fitted, dtype=np.float64)
    r = np.asarray(rows, dtype=np.float64)
    c = np.asarray(cols, dtype=np.float64)
    if r.size < 2 or not (np.all(d > 0) and math.isfinite(ground_slope_px)):
        return d
    span = float(r.max() - r.min()) + 1.0
    share = face_px / span
    # the fitted footprint's extent along the line of sight over its extent across it
    along = (1.0 / d.min() - 1.0 / d.max()) * _median(d) * focal_px / (c.max() - c.min() + 1.0)
    if span <= 1.0 or not (share >= min_face_share or along > max_along_ratio):
        return d
    first, last = int(np.argmin(r)), int(np.argmax(r))
    slope = (d[last] - d[first]) / (r[last] - r[first])
    middle = (r.max() + r.min()) / 2.0
    level = float(_median(d - slope * (r - middle)))
    bound = abs(ground_slope_px) * _hinge_slope(share)
    return level + min(slope, bound) * (r - middle)


def footprint_dimensions(
    x_m: np.ndarray, y_m: np.ndarray, *, pixel_m: float, step_deg: float = 3.0
) -> tuple[float, float]:
    """Largest horizontal dimension of a point set and its dimension across that direction.

    The points (ground-frame x, y of the object's visible surface) are projected on
    directions every ``step_deg`` degrees; the width is the largest spread, the length the
    spread at right angles to it. Each spread gets one ``pixel_m`` added (a point stands for
    a pixel's footprint). Points farther than 4 scaled MADs from the median in x or y (for
    example ground behind the silhouette that took the object's label) are dropped first;
    that rule keeps every point of a uniformly filled extent.

    Parameters
    ----------
    x_m, y_m : (K,) ndarray of float
        Ground coordinates, metres; NaN entries are ignored.
    pixel_m : float
        Size of one pixel at the object's range (Z / f), metres.
    step_deg : float
        Angular step, degrees, in (0, 90].

    Returns
    -------
    width_m, length_m : float
        NaN when fewer than two finite points remain.
    """
    angles, cos, sin = _directions(float(step_deg))
    # compiled (stages._small_stats.footprint_spreads): the finite points, those within 4
    # scaled MADs of the median in x, then in y; the max - min of their projections on
    # every direction, numpy's arithmetic without the (K, D) array
    spread = footprint_spreads(x_m, y_m, cos, sin)
    if spread.size == 0:  # fewer than two points
        return math.nan, math.nan
    k = int(np.argmax(spread))
    across = int(np.argmin(np.abs(((angles - angles[k]) % np.pi) - np.pi / 2)))
    return float(spread[k] + pixel_m), float(spread[across] + pixel_m)


@functools.lru_cache(maxsize=8)
def _directions(step_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles every ``step_deg`` degrees in [0, 180) (radians), their cosines and sines
    (read-only, built once per step)."""
    angles = np.radians(np.arange(0.0, 180.0, step_deg))
    out = (angles, np.cos(angles), np.sin(angles))
    for array in out:
        array.flags.writeable = False
    return out


def ground_fringe_keep(
    mask: np.ndarray,
    heights: np.ndarray,
    *,
    min_height_m: float,
    reach_px: int,
    smoothing_px: int = 1,
) -> np.ndarray:
    """Which pixels of an object count for its footprint: all but its ground-level fringes.

    A sun shadow cast beside a rock is dark like the rock and often segmented with it, but
    it lies on the ground. A pixel is dropped when its height is below ``min_height_m`` and
    no pixel of the object that stands at least that high (or has no height: unknown
    pixels are kept) lies within ``reach_px`` 4-connected steps of it. The rock's own low
    rim stays: stereo heights fall off over a few pixels at a rock's edge, so the rim lies
    within reach of the raised part, while the far part of a shadow does not.

    With ``smoothing_px`` > 1 a pixel stands only when both its own height and the mean
    height of the object's pixels in a ``smoothing_px`` box around it (NaN-aware; unknown
    pixels stay unknown) reach ``min_height_m``: stereo heights scatter by 8 mm on mojave's
    and lava's ground, so one by one about a third of a flat shadow's pixels stand above
    4 mm and keep the shadow within reach of them; the mean alone would spread a rock's
    heights half a box into its shadow.

    Parameters
    ----------
    mask : (M, N) ndarray of bool
        The object (a crop around it is enough).
    heights : (K,) ndarray of float
        Height above the ground of the object's pixels in ``mask``'s row-major order
        (``heights[i]`` belongs to the i-th True pixel), metres; NaN where unknown.
    min_height_m : float
        Height that counts as standing above the ground, metres, >= 0; 0 keeps every pixel.
    reach_px : int
        Largest distance (city-block, pixels) from a raised pixel that is still kept, >= 0.
    smoothing_px : int
        Odd, >= 1: box of the mean height that must also reach ``min_height_m``; 1 reads
        every pixel's height alone.

    Returns
    -------
    (K,) ndarray of bool
        True for the pixels to keep. All True when nothing stands above ``min_height_m``
        (a flat object: nothing to tell the rock from its fringe) or when fewer than half
        of the pixels would remain (the heights are too poor to trust).
    """
    m = np.asarray(mask, dtype=bool)
    h = np.asarray(heights, dtype=np.float64)
    if h.shape != (int(np.count_nonzero(m)),):
        raise ValueError(
            f"heights must hold one value per mask pixel ({int(np.count_nonzero(m))}), got "
            f"shape {h.shape}"
        )
    if min_height_m < 0 or reach_px < 0:
        raise ValueError(
            f"min_height_m and reach_px must be >= 0, got {min_height_m!r}, {reach_px!r}"
        )
    if smoothing_px < 1 or smoothing_px % 2 == 0:
        raise ValueError(
            f"smoothing_px must be an odd number of pixels >= 1 (1: no smoothing), got "
            f"{smoothing_px!r}"
        )
    keep = np.ones(h.shape, dtype=bool)
    if min_height_m == 0 or h.size == 0:
        return keep
    raised = ~(h < min_height_m)  # NaN (unknown) counts as raised: never drop it
    if smoothing_px > 1:
        # raised alone *and* on average: the mean silences the noise of a flat shadow, the
        # pixel's own height keeps the mean from spreading a rock half a box into its shadow
        raised &= ~(_object_box_mean(m, h, smoothing_px) < min_height_m)
    if not raised.any():
        return keep
    core = np.zeros(m.shape, dtype=bool)
    core[m] = raised
    near = _dilate_diamond(core, reach_px) if reach_px > 0 else core
    keep = near[m]
    if np.count_nonzero(keep) * 2 < keep.size:
        return np.ones(h.shape, dtype=bool)
    return keep


def too_dark_to_match(
    gray: np.ndarray, *, ground_gray: float, dark_ratio: float
) -> np.ndarray:
    """Pixels too dark for stereo to measure: gray below ``dark_ratio`` x the ground's gray.

    A near-black surface has no texture for the matcher; the matching windows give its
    pixels the disparity of the textured ground next to them, so their heights read
    ground level although they are the rock's. :func:`ground_fringe_keep` then takes the
    lower half of a black rock for a ground-level fringe and cuts it off: on lab (black
    rocks on a light floor) the dropped pixels that belong to the rock have a median gray of
    0.13 of the ground ring around the object, while the dropped pixels outside the rock
    (cast shadows, lit by the sky) have per-object medians of 0.44 to 0.52 of it on lab,
    mojave and lava, none below 0.17. ``describe_objects`` passes these pixels' heights as
    unknown (NaN): never dropped, and they keep their neighbours within reach.

    Parameters
    ----------
    gray : (K,) ndarray of float or uint8
        Gray levels of the object's pixels.
    ground_gray : float
        Gray level of the ground around the object (the median of its background ring);
        NaN marks no pixel.
    dark_ratio : float
        Share of ``ground_gray`` below which a pixel counts as too dark, in [0, 1); 0 marks
        no pixel.

    Returns
    -------
    (K,) ndarray of bool
    """
    if not 0.0 <= dark_ratio < 1.0:
        raise ValueError(
            f"dark_ratio must be a share of the ground's gray in [0, 1) (0: off), got "
            f"{dark_ratio!r}"
        )
    g = np.asarray(gray, dtype=np.float64)
    if not math.isfinite(ground_gray):
        return np.zeros(g.shape, dtype=bool)
    return g < dark_ratio * ground_gray


def _object_box_mean(mask: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Mean of an object's finite ``values`` (one per mask pixel) in a ``size`` box around
    each of its pixels; NaN stays NaN."""
    grid = np.zeros(mask.shape)
    grid[mask] = np.nan_to_num(values, nan=0.0)
    known = np.zeros(mask.shape)
    known[mask] = np.isfinite(values)
    total = cv2.blur(grid, (size, size), borderType=cv2.BORDER_CONSTANT)[mask]
    count = cv2.blur(known, (size, size), borderType=cv2.BORDER_CONSTANT)[mask]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(values), total / count, np.nan)


def _dilate_diamond(mask: np.ndarray, radius: int) -> np.ndarray:
    """City-block dilation by ``radius`` pixels (``radius`` 4-connected dilations at once)."""
    return cv2.dilate(np.ascontiguousarray(mask).view(np.uint8), _diamond(radius)).view(bool)


@functools.lru_cache(maxsize=16)
def _diamond(radius: int) -> np.ndarray:
    """The city-block disk of ``radius`` as a uint8 kernel (built once per radius: the
    describe stage dilates two or three times per object; cv2 only reads it)."""
    steps = np.abs(np.arange(-radius, radius + 1))
    kernel = (steps[:, None] + steps[None, :] <= radius).astype(np.uint8)
    kernel.flags.writeable = False  # shared between calls
    return kernel

