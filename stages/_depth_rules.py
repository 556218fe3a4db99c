"""Depth rules R0-R3 of ``sector-histogram+depth``: height above ground against intensity.

Each rule is explainable on its own (:func:`apply_depth_rules`; the height maps they read are
in :mod:`stages._heights`). ``height`` is metres above the depth stage's fitted ground plane.
It is first smoothed with a NaN-aware 5x5 median, then made *relative* to the local ground
(R0): a coarse median over ``ground_window_px`` (72 px) removes dune swells and slopes the
plane fit cannot follow. A pixel has *valid depth* where the smoothed height is finite. The
ground's height noise ``sigma`` is measured robustly (MAD) on valid pixels the intensity
calls background, and decides between two regimes:

Precise depth (``sigma <= 5 mm``):

* **R0b far rows** -- the noise of a stereo height grows with the square of the range (a
  constant disparity error), and the range with the image row: on dunes frames whose noise
  is 5 mm overall, the ten rows bands measured 4-8 mm except the top one, near the horizon,
  at 190-250 mm. R1 and R2 therefore do not read the heights of rows whose band's noise (10
  bands of rows, MAD of the ground's heights, interpolated between band centres) is beyond
  usable (15 mm): there the intensity decision stands, as in the unusable regime. Below that
  bar a band's scatter is relief as much as noise (with the *true* heights lava's bands of
  many small rocks scatter by over 5 mm, and a 5 mm bar cost lava 0.764 -> 0.688 object F1
  with ``bench_segment.py --depth truth --frames 4``; with the 15 mm bar it is unchanged).
  Reading such rows against their own band's noise (4 band sigmas to be raised) instead, as
  before segment v21, removed 38 of 68 invented rocks on the dunes frames of seed 2
  (``catalogs/dunes.toml`` with ``seed = 2``), all near the horizon, made from noise by R1,
  but a stereo error of +14-25 cm on the smooth far sand of a seed-4 frame (band noise 36
  mm) still stood 4 of them high and made 2 invented rocks as gray as the sand, while R2
  removed 2 true rocks of that frame whose heights there read as flat. Not reading those
  rows (``bench_segment.py --rundir``, runs of the dunes catalog with ``seed =`` changed):
  dunes seed 4 0.500 -> 1.000 precision (2 false positives fewer, 2 true rocks more), seed 2
  1 true rock more (recall 0.2 -> 0.4), seeds 3, 5, 7, 11 and the catalog frames of every
  archive unchanged (the precise regime occurs only on dunes frames there); with ``--depth
  truth --frames 4`` every archetype is unchanged, with ``--depth-noise 0.5`` lab's F1 goes
  0.462 -> 0.787 and mojave, lava and dunes are unchanged.

* **R1 raised** -- a pixel with relative height > ``max(min_height_m, 4 sigma)`` is object,
  even when its gray level equals the ground's (a rock as bright as the sand it lies on).
* **R2 flat** -- an intensity-object pixel at or below ``max(flat_tol_m, 2 sigma)`` (capped
  at half the raised threshold) is background -- a shadow is dark but lies on the ground; so
  do stains, damp patches and dark texture blotches -- unless it lies within ``base_px``
  pixels of a raised pixel (the foot of a rock is low too). Of what is left, an object with
  fewer than ``min_raised_fraction`` raised pixels and most pixels below half the raised
  threshold lies on the ground and is removed whole.

Noisy depth (``5 mm < sigma <= 15 mm``, typical of window-based stereo on real texture):
pixels are not trusted one by one; no object is added from height alone (R1 off). Whole
intensity objects vote with their heights instead: rules **R2 vote**, **R2c contrast** and
**R2d bump**, in :mod:`stages._height_vote` (:func:`stages._height_vote.noisy_depth_rules`).

Unusable depth (``sigma > 15 mm``, e.g. a uniform floor the matcher cannot texture): heights
are noise at the scale of the rocks; the intensity decision stands everywhere.

* **R3 no depth** -- where depth is invalid the intensity decision stands, if it is clear
  (:func:`drop_faint_depthless`): in a frame whose heights are usable (noise <= 15 mm), an
  object with too few valid heights to vote (under 30 % or under 20 pixels, typically in the
  matcher's blind band along the frame's right or bottom border) escapes the vote that
  removes texture blotches everywhere else, so it is kept only when its median gray level
  is clear: at least ``CLEAR_CONTRAST`` (2.5) times as far from the ground level as the
  threshold that found it (:data:`stages._regions.CLEAR_CONTRAST`, shared with R5b). With
  a 10 % limit and 2 bands this removed 4 of dunes' 9 invented rocks, 14 of mojave's 47
  false positives for 1 true rock and 22 of lava's 158 for 5; the limit is now the vote's
  own since objects with 10-30 % valid heights were judged by neither rule (dunes ripple
  ends at the bottom border), and 2.5 bands instead of 2 removed dunes' last invented rock
  (a ripple trough 2.3 bands dark in the blind band) for 2 true rocks of mojave's 340 and 4
  of lava's 486 (and 2 and 3 false positives). The band counts as at least half the
  frame's median band: where a sector's ground peak is unusually narrow (smooth sand) the
  ripple shading cut by the border lay 3-6 of its bands out; on the dunes frames of seed 2
  this removed 12 of 37 invented rocks, mojave lost 2 false positives, lava 1 true rock.

Rules R4 (split at disparity jumps), R5 (streaks, R5b: unless clear in gray level), R5c
(ripple fields) and R6 (attached shadows) act on labelled objects and live in
:mod:`stages._regions` (R4), :mod:`stages._texture_rules` (R5-R5c) and
:mod:`stages._rock_parts` (R6).

**R5c ripple fields** (:func:`stages._texture_rules.drop_ripple_pieces`) is where most of the
dunes' invented rocks now go. Why: ripple crests near the camera have real relief (about 2
sigmas: they pass the R2 vote and, in frames whose noise is under 5 mm, R1/R2), and ripple
pieces in the blind border band pass R3b where the ripple shading is strong; neither their
heights nor their threshold bands tell them from the few true rocks, whose heights the
stereo windows flatten as much. Their neighbourhood does. An object lies in a field of
ripples when at least 3 streaks of the ground texture (intensity objects before these
rules, more than ``max_elongation`` times longer than wide) lie within 100 px, together at
least as large as the object, with one common direction (area-weighted mean of the doubled
axis angles of length >= 0.8), or where the gray-level gradients in a 100 px window share
one direction (structure-tensor coherence >= 0.8: ripples too faint to leave streaks).
There it must stand out of the ripple texture: its median gray at least 1.5 times as far
from its ring's median (3 to 8 px out) as the ring's 5th (dark objects) or 95th (light)
percentile. What it catches: pieces of troughs and crests (ratio 0.1-1.1 on the dunes
frames; true rocks 2-35). With ``bench_segment.py --rundir`` and ``--set
ripple_texture_ratio=0`` for the old rules, dunes seeds 1/2/3/7 (catalog with ``seed =``
changed) went from 2/31/5/6 invented rocks to 0/0/2/1, and seed 11 (looked at afterwards;
the gradient evidence was added for it) from 5 to 1, every true rock kept. The one left on
seed 7 is a true rock matched at IoU 0.45; seed 3's two are ripple pieces cut by the bottom
corners, whose ring lies on one side only (since removed by R5c at range, which also compares
an object with the streaks beside it at its range); seed 11's is a true rock at IoU 0.36. Lab and
mojave (catalog and seed 2) are unchanged, lava has 1 and 2 fewer false positives. Ratios
1.25-2 and coherences 0.7-0.9 give the same counts.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._height_vote import (
    _VOTE_VALID_FRACTION,
    _VOTE_VALID_PX,
    BumpWeights,
    _object_counts,
    noisy_depth_rules,
)
from ._heights import (
    DepthRuleStats,
    _fraction,
    _ground_heights,
    _percentile_by_label,
    _robust_sigma,
    local_ground,
    relative_height,
)
from ._regions import CLEAR_CONTRAST, _coerce_mask, _label_areas, _lookup, _renumber
from ._select import median32

# Ground height noise (MAD sigma, metres) above which single heights are not trusted.
_NOISY_SIGMA_M = 0.005
# Above this ground noise (metres) the heights are not used at all.
_UNUSABLE_SIGMA_M = 0.015
# R0b: the height noise is also measured in this many horizontal bands of rows.
_ROW_BANDS = 10
# Precise regime: raised means higher than this many ground sigmas (and min_height_m).
_RAISE_SIGMAS = 4.0
# R3b: objects with fewer valid heights than this share (the vote's) cannot be voted on ...
_DEPTHLESS_FRACTION = _VOTE_VALID_FRACTION
# ... and are kept only when their gray level is clear (threshold bands from the ground).
_DEPTHLESS_CONTRAST = CLEAR_CONTRAST
# ... in bands at least this fraction of the frame's median band.
_DEPTHLESS_BAND_FRACTION = 0.5
__all__ = [
    "apply_depth_rules",
    "drop_faint_depthless",
    "gray_contrast",
]


def _coerce_float_map(values: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    if not isinstance(values, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(values).__name__}")
    if values.shape != shape:
        raise ValueError(
            f"{name} must have the reference image's shape {shape}, got {values.shape}"
        )
    if values.dtype.kind != "f":
        raise TypeError(f"{name} must be a float array (NaN where invalid), got {values.dtype}")
    return values.astype(np.float32, copy=False)


def apply_depth_rules(
    mask: np.ndarray,
    height: np.ndarray,
    *,
    min_height_m: float = 0.008,
    flat_tol_m: float = 0.003,
    base_px: int = 2,
    smoothing_px: int = 5,
    ground_window_px: int = 72,
    min_raised_fraction: float = 0.1,
    contrast: np.ndarray | None = None,
    relative: np.ndarray | None = None,
    _weights: BumpWeights | None = None,
) -> tuple[np.ndarray, DepthRuleStats]:
    """Combine an intensity mask with height above ground (rules R0-R3 of the module doc).

    Parameters
    ----------
    mask : (M, N) ndarray of bool
        Intensity objects.
    height : (M, N) ndarray of float32
        Metres above the ground plane, NaN where invalid.
    min_height_m : float
        ``> 0``; floor of the R1 threshold.
    flat_tol_m : float
        ``>= 0``, below ``min_height_m``; floor of the R2 tolerance.
    base_px : int
        ``>= 0``; R2 spares flat pixels this close to a raised pixel.
    smoothing_px : {1, 3, 5}
        Median window of the height map.
    ground_window_px : int
        ``>= 9``; window of the local ground level (R0).
    min_raised_fraction : float
        In ``[0, 1]``; R2 removes a whole intensity object with fewer raised pixels than this
        fraction of its valid pixels and a median height within the raise threshold's half.
    contrast : (M, N) ndarray of float32, optional
        Gray-level distance from the ground level in threshold bands (:func:`gray_contrast`);
        when given, the noisy-depth vote asks less height of clear objects (R2c).
    relative : (M, N) ndarray of float32, optional
        ``relative_height(height, smoothing_px=..., ground_window_px=...)`` when the caller
        has it already (:func:`stages.segment.segment_image` reads it again for R7e);
        computed here otherwise.
    _weights : BumpWeights, optional
        Kept by R2d's bump map (noisy heights) for the frame's later ones (R8b).

    Returns
    -------
    combined : (M, N) ndarray of bool
    stats : DepthRuleStats
    """
    mask = _coerce_mask(mask)
    height = _coerce_float_map(height, mask.shape, "height")
    if contrast is not None:
        contrast = _coerce_float_map(contrast, mask.shape, "contrast")
    if not min_height_m > 0:
        raise ValueError(f"min_height_m must be > 0, got {min_height_m}")
    if not 0 <= flat_tol_m < min_height_m:
        raise ValueError(
            f"flat_tol_m must be in [0, min_height_m={min_height_m}), got {flat_tol_m}"
        )
    if base_px < 0:
        raise ValueError(f"base_px must be >= 0, got {base_px}")
    if not 0 <= min_raised_fraction <= 1:
        raise ValueError(f"min_raised_fraction must be in [0, 1], got {min_raised_fraction}")
    if relative is None:
        relative = relative_height(
            height, smoothing_px=smoothing_px, ground_window_px=ground_window_px
        )
    else:
        relative = _coerce_float_map(relative, mask.shape, "relative")
    valid = np.isfinite(relative)
    sigma = _robust_sigma(_ground_heights(relative, mask))
    if sigma > _UNUSABLE_SIGMA_M:
        stats = DepthRuleStats(
            depth_valid_fraction=_fraction(valid),
            ground_sigma_m=sigma,
            notes=[f"height noise {100 * sigma:.1f} cm: heights unusable, intensity rules only"],
        )
        return mask, stats
    if sigma > _NOISY_SIGMA_M:
        # the vote reads single unsmoothed heights: measure their noise the same way
        raw_relative = height - local_ground(height, window_px=ground_window_px)
        raw_sigma = _robust_sigma(_ground_heights(raw_relative, mask))
        return noisy_depth_rules(
            mask, raw_relative, raw_sigma, contrast=contrast, _weights=_weights
        )
    raise_m = max(min_height_m, _RAISE_SIGMAS * sigma)
    flat_m = min(max(flat_tol_m, 2.0 * sigma), 0.5 * raise_m)
    # R0b: far rows are noisier than the frame as a whole (height noise grows with range^2);
    # rows whose band's heights are unusable are not read at (the intensity decision stands
    # there, as in the unusable regime); below that bar relief (many small rocks, swells)
    # as much as noise makes a band scatter more than the frame
    usable_rows = _row_band_sigma(relative, valid & ~mask) <= _UNUSABLE_SIGMA_M
    readable = valid & usable_rows[:, None]
    with np.errstate(invalid="ignore"):
        raised = readable & (relative > raise_m)
        # at or below the local ground: shadows, stains, pits
        flat = readable & (relative < flat_m)

    # R2, pixels: flat pixels away from the raised core (shadows, attached or not)
    if base_px > 0 and raised.any():
        size = 2 * base_px + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        near_raised = cv2.dilate(raised.view(np.uint8), kernel).view(bool)
    else:
        near_raised = raised
    removed = mask & flat & ~near_raised
    # R2, whole objects: of what is left, an object where nothing stands up lies on the ground
    remaining = mask & ~removed
    count, components = cv2.connectedComponents(remaining.view(np.uint8), connectivity=8)
    n_valid = np.bincount(components[readable], minlength=count)
    n_raised = np.bincount(components[raised], minlength=count)
    n_pixels = _label_areas(components, count)
    n_low = np.bincount(components[readable & (relative < 0.5 * raise_m)], minlength=count)
    lying = (
        (n_valid >= 0.5 * n_pixels)
        & (n_raised < min_raised_fraction * np.maximum(n_valid, 1))
        & (n_low >= 0.5 * np.maximum(n_valid, 1))
    )
    lying[0] = False
    removed |= _lookup(lying, components)
    combined = (mask & ~removed) | raised
    stats = DepthRuleStats(
        raised_added_px=int(np.count_nonzero(raised & ~mask)),
        flat_removed_px=int(np.count_nonzero(removed)),
        depth_valid_fraction=_fraction(valid),
        raise_threshold_m=raise_m,
        flat_threshold_m=flat_m,
        ground_sigma_m=sigma,
    )
    return combined, stats


def _row_band_sigma(
    relative: np.ndarray,
    usable: np.ndarray,
    *,
    bands: int = _ROW_BANDS,
    _memo: dict[tuple[int, int], tuple[np.ndarray, float]] | None = None,
) -> np.ndarray:
    """Robust height noise per row (rule R0b).

    Parameters
    ----------
    relative : (M, N) ndarray of float32
        Heights relative to the local ground, NaN invalid.
    usable : (M, N) ndarray of bool
        Valid ground pixels whose heights measure the noise.
    bands : int
        Horizontal bands of rows; each gets the MAD sigma of its usable heights in every
        other column (0 with fewer than 50), interpolated linearly between band centres.
    _memo : dict, optional
        Each band's sampled ``usable`` pixels and sigma, kept across calls on one
        ``relative`` (R7e, then R7f): a band whose pixels did not change is not measured
        again. Empty on the first call; never shared between height maps.

    Returns
    -------
    sigma : (M,) ndarray of float64
        Metres; the caller takes the larger of this and the frame's noise.
    """
    # every other column: plenty of heights for a MAD, half the cost
    return _sampled_row_band_sigma(relative[:, ::2], usable[:, ::2], bands=bands, _memo=_memo)


def _sampled_row_band_sigma(
    relative: np.ndarray,
    usable: np.ndarray,
    *,
    bands: int = _ROW_BANDS,
    _memo: dict[tuple[int, int], tuple[np.ndarray, float]] | None = None,
) -> np.ndarray:
    """:func:`_row_band_sigma` of maps already sampled at every other column (``[:, ::2]``;
    R7e and R7f's row noise keeps the heights so, contiguous, and samples its mask first)."""
    rows = relative.shape[0]
    edges = np.linspace(0, rows, bands + 1).astype(int)
    centres = (edges[:-1] + edges[1:] - 1) / 2.0
    values = np.zeros(bands)
    for band, (start, stop) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        sampled = usable[start:stop]
        known = _memo.get((start, stop)) if _memo is not None else None
        if known is not None and np.array_equal(known[0], sampled):
            values[band] = known[1]
            continue
        heights = relative[start:stop][sampled]
        if heights.size >= 50:
            values[band] = _robust_sigma(heights)
        if _memo is not None:
            _memo[(start, stop)] = (sampled.copy(), values[band])
    return np.interp(np.arange(rows), centres, values)


def _frame_bands(
    background: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[float, float]:
    """Median low and high threshold bands of the frame (every fourth row and column)."""
    coarse = np.s_[::4, ::4]
    bands = (background[coarse] - low[coarse], high[coarse] - background[coarse])

    def middle(band: np.ndarray) -> float:
        if band.dtype == np.float32 and band.size and np.isfinite(band).all():
            # np.median's float32 by counting and selection, at a fraction of its cost
            return float(median32(band.ravel()))
        return float(np.median(band))

    return middle(bands[0]), middle(bands[1])


def gray_contrast(
    image: np.ndarray,
    *,
    background: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    min_band_fraction: float = _DEPTHLESS_BAND_FRACTION,
) -> np.ndarray:
    """Signed distance of each gray level from the ground level, in threshold bands.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Reference gray image.
    background, low, high : (M, N) ndarray of float32
        Interpolated ground level and low/high thresholds (gray levels).
    min_band_fraction : float
        In ``[0, 1]``; the band counts as at least this fraction of the frame's median band
        on its side: a sector whose ground peak is unusually narrow (smooth sand) is a poor
        unit.

    Returns
    -------
    contrast : (M, N) ndarray of float32
        ``(gray - ground) / band``, the band being ``ground - low`` for pixels darker than
        the ground and ``high - ground`` otherwise (at least one gray level; see
        ``min_band_fraction``): with ``min_band_fraction = 0``, below -1 a pixel is past the
        low threshold, above 1 past the high one.
    """
    if not 0 <= min_band_fraction <= 1:
        raise ValueError(f"min_band_fraction must be in [0, 1], got {min_band_fraction}")
    if not image.shape == background.shape == low.shape == high.shape:
        raise ValueError(
            f"image {image.shape}, background {background.shape}, low {low.shape} and high "
            f"{high.shape} must have one shape"
        )
    background = background.astype(np.float32, copy=False)
    low = low.astype(np.float32, copy=False)
    high = high.astype(np.float32, copy=False)
    frame_low, frame_high = _frame_bands(background, low, high) if min_band_fraction > 0 else (0, 0)
    floor_low = np.float32(max(1.0, min_band_fraction * frame_low))
    floor_high = np.float32(max(1.0, min_band_fraction * frame_high))
    contrast = np.empty(image.shape, np.float32)
    _contrast_pass(
        np.ascontiguousarray(image),
        np.ascontiguousarray(background),
        np.ascontiguousarray(low),
        np.ascontiguousarray(high),
        floor_low,
        floor_high,
        contrast,
    )
    return contrast


@njit(cache=True, error_model="numpy")
def _contrast_pass(image, background, low, high, floor_low, floor_high, out):  # pragma: no cover
    """:func:`gray_contrast` per pixel in float32, as its numpy twin did it in six passes
    (``test_depth_rules.py`` compares): a NaN band stays NaN, as ``np.maximum`` keeps it."""
    rows, cols = image.shape
    for y in range(rows):
        for x in range(cols):
            level = np.float32(image[y, x]) - background[y, x]
            if level < 0:
                band = background[y, x] - low[y, x]
                floor = floor_low
            else:
                band = high[y, x] - background[y, x]
                floor = floor_high
            if band < floor:
                band = floor
            out[y, x] = level / band


def drop_faint_depthless(
    labels: np.ndarray,
    image: np.ndarray,
    height: np.ndarray,
    *,
    background: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    max_valid_fraction: float = _DEPTHLESS_FRACTION,
    min_contrast: float = _DEPTHLESS_CONTRAST,
    min_band_fraction: float = _DEPTHLESS_BAND_FRACTION,
) -> tuple[np.ndarray, int]:
    """Rule R3b: drop objects without heights whose gray level is barely past the threshold.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    image : (M, N) ndarray of uint8
        Reference gray image.
    height : (M, N) ndarray of float32
        Metres above ground, NaN where invalid.
    background, low, high : (M, N) ndarray of float32
        Interpolated ground level and low/high thresholds (gray levels).
    max_valid_fraction : float
        In ``[0, 1]``; objects with a smaller share of valid heights are judged.
    min_contrast : float
        ``>= 1``; a judged object is kept when ``|median gray - ground|`` is at least this
        many times the distance from the ground level to the threshold on its side (its band).
    min_band_fraction : float
        In ``[0, 1]``; the band counts as at least this fraction of the frame's median band
        on that side (0: the local band alone).

    Returns
    -------
    labels : (M, N) ndarray of int32
        Renumbered 1..m without the dropped objects.
    dropped : int
    """
    if not 0 <= max_valid_fraction <= 1 or not min_contrast >= 1:
        raise ValueError(
            "need 0 <= max_valid_fraction <= 1 and min_contrast >= 1, got "
            f"{max_valid_fraction} and {min_contrast}"
        )
    if not 0 <= min_band_fraction <= 1:
        raise ValueError(f"min_band_fraction must be in [0, 1], got {min_band_fraction}")
    count = int(labels.max()) + 1
    if count == 1:
        return labels, 0
    n_pixels, n_valid = _object_counts(labels, np.isfinite(height), count)
    # every object the vote could not read (too few heights, see stages._height_vote) is judged
    judged = (n_valid < max_valid_fraction * n_pixels) | (n_valid < _VOTE_VALID_PX)
    judged[0] = False
    if not judged.any():
        return labels, 0
    # the judged objects' ids and four fields (float32), in one raster pass
    ids = np.empty(int(n_pixels[judged].sum()), labels.dtype)
    fields = np.empty((4, ids.size), np.float32)
    _judged_pass(
        np.ascontiguousarray(labels), judged, image, background, low, high, ids, fields
    )
    medians = [_percentile_by_label(field, ids, count, 50.0) for field in fields]
    # objects not judged have no values (+inf): compare the judged ones only
    gray, ground, low_m, high_m = (values[judged] for values in medians)
    band = np.where(gray < ground, ground - low_m, high_m - ground)
    # a sector whose ground peak is unusually narrow makes a poor unit: smooth sand's
    # ripple shading lies 3-6 of its bands out (dunes); the frame's median band bounds it
    frame_low, frame_high = _frame_bands(background, low, high)
    band = np.maximum(band, min_band_fraction * np.where(gray < ground, frame_low, frame_high))
    faint = np.zeros(count, dtype=bool)
    faint[judged] = np.abs(gray - ground) < min_contrast * np.maximum(band, 1.0)
    if not faint.any():
        return labels, 0
    # the faint objects to 0 (one lookup), then renumbered
    table = np.where(faint, 0, np.arange(count)).astype(labels.dtype)
    return _renumber(_lookup(table, labels), 1), int(faint.sum())


@njit(cache=True)
def _judged_pass(labels, judged, image, background, low, high, ids, fields):  # pragma: no cover
    """``labels[inside]`` and each field's ``field[inside].astype(np.float32)`` for
    ``inside = judged[labels]``, in raster order as boolean indexing gives them
    (``test_depth_rules.py`` compares)."""
    rows, cols = labels.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if judged[k]:
                ids[n] = k
                fields[0, n] = np.float32(image[y, x])
                fields[1, n] = np.float32(background[y, x])
                fields[2, n] = np.float32(low[y, x])
                fields[3, n] = np.float32(high[y, x])
                n += 1
