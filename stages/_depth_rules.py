"""Depth rules R0-R3 of ``sector-histogram+depth``: height above ground against intensity.

Each rule is explainable on its own (:func:`apply_depth_rules`). ``height`` is metres
above the depth stage's fitted ground plane. It is first smoothed with a NaN-aware 5x5
median, then made *relative* to the local ground (R0): a coarse median over
``ground_window_px`` (72 px) removes dune swells and slopes the plane fit cannot follow. A
pixel has *valid depth* where the smoothed height is finite. The ground's height noise
``sigma`` is measured robustly (MAD) on valid pixels the intensity calls background, and
decides between two regimes:

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
pixels are not trusted one by one; no object is added from height alone (R1 off). **R2
vote** -- each intensity object with at least 30 % (and 20) of its pixels valid votes with
its unsmoothed relative heights: it lies flat (shadow, stain, texture blotch) and is
removed whole when the 90th percentile of its heights stays within ``0.8 sigma`` of the
median height of a 4-pixel band of ground around it (the ground it stands on; the coarse
local ground where the band has fewer than 10 heights). 30 %, not half: a ripple or blotch
cut by the frame's border rows, where the matcher has no heights, still votes. The upper
percentile, not the median, because a rock's visible face rises from a foot at ground level
and the stereo windows pull small rocks' heights down; measured on the built-in archives it
keeps 87-97 % of the true rocks and removes 80 % of the texture objects. A large object (at
least 4 independent samples, one per 15 x 15 pixels, the scale of the matching windows) is
also flat when its 90th percentile stays below ``1.5 sigma`` and its median height plus one
standard error (``1.25 sigma / sqrt(n / 225)``) stays below 11 mm: over many pixels the
noise itself lifts the upper percentile.

**R2c contrast** -- the vote weighs the height evidence against the gray-level evidence
(:func:`gray_contrast`: an object's median distance from the ground level, in threshold
bands). Ground texture that crosses a threshold (blotches, ripple troughs) barely crosses
it: on the built-in archives the median texture object lies 1.4-1.6 bands from the ground,
the median true rock 2-2.6. So the bar of the vote is ``0.8 sigma`` for an object 1.7 bands
out and moves by ``0.8 sigma`` per band: a clear rock whose stereo heights the matching
windows flattened stays, a faint blotch must stand higher to stay. On the catalog frames
(with the R3b change below; ``benchmarks/bench_segment.py --rundir runs/eval/<archive>``)
mojave kept 17 more true rocks for 4 more false ones, lava 34 more true rocks and 21 fewer
false ones, dunes 2 fewer false ones, lab (unusable heights) is unchanged. A band counts
as at least half the frame's median band (a sector whose ground peak is unusually narrow,
smooth sand, is a poor unit); that made mojave's catalog frames lose 4 false positives,
lava's 4 (and 2 true rocks), lab 1 true rock; seed 2 mojave 5 false positives, lava 5.

**R2d bump** -- the upper percentile misses small faint rocks: the stereo windows spread a
40-pixel rock's 2 cm over their 9-15 px and pull its upper heights into the noise, and its
gray level is too faint for R2c. Of the 145 true rocks on lava's catalog frames that no
object touched at all, the vote had removed 40 (median 51 px, 1.5 bands); 66 others were
specks (threshold pixels on 39 % of the rock, in pieces under ``min_area_px``; their gray
levels sit as far from the ground as the texture specks', 1.3 and 1.2 bands), 14 R3b, 12
R5, 8 a split, 4 never crossed a threshold. What the windows leave of such a rock is a
bump of their own scale, which a blotch lying on the ground does not make: the heights
smoothed at 2 px minus smoothed at 6 px (NaN-aware Gaussians, :func:`_height_bumps`), in
that map's robust noise on the ground. An object the vote calls flat stays when its
highest bump is at least 2 and the bump plus its gray contrast (R2c's bands) at least 3.5.
Of the objects of 30-400 px the vote removed on lava's catalog frames this kept 13 true
rocks, 5 pieces of rocks, 1 object half on a rock and no texture object (seed 2: 25, 6, 1
and 2; mojave 3 rocks and 3 pieces, seed 2: 2 and 2; a diagnostic on the vote's input,
not in the repository). With ``benchmarks/bench_segment.py --rundir`` object F1 on the catalog
frames: lava 0.776 -> 0.791 (16 more true rocks, 1 more false one), mojave 0.898 -> 0.905
(5 more true rocks), lab and dunes unchanged; seed 2 (the catalogs with ``seed = 2``): lava
0.754 -> 0.773 (25 more, 7 more false), mojave 0.911 -> 0.912; dunes seeds 2, 3, 7 and 11
unchanged. Without the floor of 2 on the bump itself a ripple's shading 2 bands dark on a
weak swell (bump 1.6) became an invented rock on the dunes catalog frames. Scales of 1.5 or
3 px and 5 or 8 px, and a score of 3 or 4, give lava 0.787-0.794 and the same elsewhere
within 0.001. Seed 3: lava 0.775 -> 0.795, mojave 0.884 -> 0.892, lab unchanged; seeds 4
and 5: lava 0.781 -> 0.797 and 0.783 -> 0.801, mojave 0.865 -> 0.872 and 0.859 -> 0.860,
dunes unchanged. The
specks stay lost (before R2d, lava catalog): grown into pixels 0.7 bands out before the
vote they brought 36 false rocks for 13 true ones (0.776 -> 0.767; 0.5 bands: 0.692), and
as candidates of a bump rule (a speck near a bump of 3, grown) 26 for 15 (0.775): lava's
ground holds many rocks under 30 px, and a bump finds them as readily. With R2d, a speck
floor of 25 px (objects under 30 px dropped after R7) gained 0.002-0.006 on seeds 1 and 2
and lost up to 0.006 on seed 3 (lab).

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

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import median_filter

from ._regions import CLEAR_CONTRAST, _coerce_mask, _renumber

# Ground height noise (MAD sigma, metres) above which single heights are not trusted.
_NOISY_SIGMA_M = 0.005
# Above this ground noise (metres) the heights are not used at all.
_UNUSABLE_SIGMA_M = 0.015
# Noisy regime: an object lies flat when the 90th percentile of its heights stays below this
# many ground sigmas (tuned on the built-in archives with the depth stage).
_VOTE_PERCENTILE = 90.0
_VOTE_SIGMAS = 0.8
# An object votes when this share of its pixels (and at least this many) have a height: a
# ripple cut by the frame's bottom rows, where the matcher has no rows below, still votes.
_VOTE_VALID_FRACTION = 0.3
_VOTE_VALID_PX = 20
# R2c: the vote's bar is _VOTE_SIGMAS for an object as clear as typical ground texture
# (median gray level this many threshold bands from the ground) and moves by
# _CONTRAST_SIGMAS ground sigmas per band of contrast.
_TEXTURE_CONTRAST = 1.7
_CONTRAST_SIGMAS = 0.8
# Width of the band around an object whose median height is the object's own ground level.
_RING_PX = 4
# ... or when its median height plus one standard error stays below this (metres): large flat
# objects, whose upper percentile is lifted by the noise itself. Stereo heights are
# correlated over the matching window: one independent sample per 15 x 15 pixels.
_NOISY_FLAT_M = 0.011
_WIDE_VOTE_SIGMAS = 1.5
_WIDE_SAMPLES = 4
_CORRELATED_PX = 225.0
# R2d bump: the height map smoothed at these two scales (Gaussian sigmas, px); their
# difference peaks on a rock of the stereo windows' scale and is flat on blotches ...
_BUMP_INNER_PX = 2.0
_BUMP_OUTER_PX = 6.0
# ... and an object the vote calls flat stays when its highest bump (in that map's own
# ground noise) plus its gray contrast (threshold bands) reaches this.
_BUMP_SCORE = 3.5
# ... the bump alone at least this many (its noise's) sigmas: a weak swell under a clear
# ripple shading is no bump.
_BUMP_MIN_SIGMAS = 2.0
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
    "DepthRuleStats",
    "smooth_height",
    "local_ground",
    "apply_depth_rules",
    "drop_faint_depthless",
    "gray_contrast",
]


@dataclass
class DepthRuleStats:
    """How many pixels each depth rule changed (for the per-frame figures)."""

    raised_added_px: int = 0
    flat_removed_px: int = 0
    depth_valid_fraction: float = 0.0
    raise_threshold_m: float = float("nan")
    flat_threshold_m: float = float("nan")
    ground_sigma_m: float = float("nan")
    notes: list[str] = field(default_factory=list)


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


def smooth_height(height: np.ndarray, *, window: int = 5) -> np.ndarray:
    """NaN-aware median of the height map.

    Parameters
    ----------
    height : (M, N) ndarray of float32
        Metres above ground, NaN where invalid.
    window : {1, 3, 5}
        Median window; 1 returns the input.

    Returns
    -------
    smoothed : (M, N) ndarray of float32
        NaN where the input is NaN; elsewhere the median of the window with invalid
        neighbours counted as ground (0), which biases isolated spikes down, never up.
    """
    if window not in (1, 3, 5):
        raise ValueError(f"window must be 1, 3 or 5 (OpenCV float median), got {window}")
    height = np.asarray(height, dtype=np.float32)
    if window == 1:
        return height
    valid = np.isfinite(height)
    filled = np.where(valid, height, np.float32(0.0)).astype(np.float32)
    smoothed = cv2.medianBlur(filled, window)
    return np.where(valid, smoothed, np.float32(np.nan))


def local_ground(height: np.ndarray, *, window_px: int = 72) -> np.ndarray:
    """Large-scale ground level of a height map: a coarse NaN-aware median.

    Parameters
    ----------
    height : (M, N) ndarray of float32
        Metres above the fitted plane, NaN where invalid.
    window_px : int
        ``>= 9``; side of the median window in pixels. Objects narrower than half of it do
        not lift the estimate.

    Returns
    -------
    ground : (M, N) ndarray of float32
        Finite everywhere (0, the plane, where no valid height is near).
    """
    if window_px < 9:
        raise ValueError(f"window_px must be >= 9, got {window_px}")
    rows, cols = height.shape
    factor = max(1, window_px // 9)
    small_shape = (max(1, rows // factor), max(1, cols // factor))
    valid = np.isfinite(height)
    filled = np.where(valid, height, np.float32(0.0)).astype(np.float32)
    # invalid pixels vote for the plane itself: the fit already describes the ground
    small = cv2.resize(filled, small_shape[::-1], interpolation=cv2.INTER_AREA)
    coarse = _median_filter_nearest(small, size=min(9, *small_shape))
    return cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_LINEAR)


def _median_filter_nearest(image: np.ndarray, *, size: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(image, size, mode='nearest')``, faster for odd sizes.

    A median picks one of the window's values, so selecting it with ``np.partition`` over
    all windows at once gives the same array; scipy's rank filter is slow on floats.
    """
    if size % 2 == 0 or image.ndim != 2:
        return median_filter(image, size=size, mode="nearest")
    half = size // 2
    padded = np.pad(image, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (size, size))
    flat = windows.reshape(image.shape[0], image.shape[1], size * size)
    middle = (size * size) // 2
    return np.partition(flat, middle, axis=-1)[..., middle].astype(image.dtype, copy=False)


def _robust_sigma(values: np.ndarray) -> float:
    if values.size < 10:
        return 0.0
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


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
    smoothed = smooth_height(height, window=smoothing_px)
    valid = np.isfinite(smoothed)
    relative = smoothed - local_ground(smoothed, window_px=ground_window_px)
    sigma = _robust_sigma(relative[valid & ~mask])
    if sigma > _UNUSABLE_SIGMA_M:
        stats = DepthRuleStats(
            depth_valid_fraction=float(valid.mean()),
            ground_sigma_m=sigma,
            notes=[f"height noise {100 * sigma:.1f} cm: heights unusable, intensity rules only"],
        )
        return mask, stats
    if sigma > _NOISY_SIGMA_M:
        # the vote reads single unsmoothed heights: measure their noise the same way
        raw_relative = height - local_ground(height, window_px=ground_window_px)
        raw_sigma = _robust_sigma(raw_relative[np.isfinite(raw_relative) & ~mask])
        return _noisy_depth_rules(mask, raw_relative, raw_sigma, contrast=contrast)
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
    n_pixels = np.bincount(components.ravel(), minlength=count)
    n_low = np.bincount(components[readable & (relative < 0.5 * raise_m)], minlength=count)
    lying = (
        (n_valid >= 0.5 * n_pixels)
        & (n_raised < min_raised_fraction * np.maximum(n_valid, 1))
        & (n_low >= 0.5 * np.maximum(n_valid, 1))
    )
    lying[0] = False
    removed |= lying[components]
    combined = (mask & ~removed) | raised
    stats = DepthRuleStats(
        raised_added_px=int(np.count_nonzero(raised & ~mask)),
        flat_removed_px=int(np.count_nonzero(removed)),
        depth_valid_fraction=float(valid.mean()),
        raise_threshold_m=raise_m,
        flat_threshold_m=flat_m,
        ground_sigma_m=sigma,
    )
    return combined, stats


def _row_band_sigma(
    relative: np.ndarray, usable: np.ndarray, *, bands: int = _ROW_BANDS
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

    Returns
    -------
    sigma : (M,) ndarray of float64
        Metres; the caller takes the larger of this and the frame's noise.
    """
    rows = relative.shape[0]
    edges = np.linspace(0, rows, bands + 1).astype(int)
    centres = (edges[:-1] + edges[1:] - 1) / 2.0
    values = np.zeros(bands)
    for band, (start, stop) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        # every other column: plenty of heights for a MAD, half the cost
        heights = relative[start:stop, ::2][usable[start:stop, ::2]]
        if heights.size >= 50:
            values[band] = _robust_sigma(heights)
    return np.interp(np.arange(rows), centres, values)


def _noisy_depth_rules(
    mask: np.ndarray, relative: np.ndarray, sigma: float, *, contrast: np.ndarray | None = None
) -> tuple[np.ndarray, DepthRuleStats]:
    """R2 vote: remove whole objects whose upper heights stay within the ground noise.

    Heights are read relative to the median valid height of a ``_RING_PX`` band of ground
    around the object (the coarse local ground where the band has fewer than 10 heights).
    """
    valid = np.isfinite(relative)
    count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    lying = np.zeros(count, dtype=bool)
    if count > 1:
        valid_components = np.where(valid, components, 0)
        n_valid = np.bincount(valid_components.ravel(), minlength=count)[1:]
        n_pixels = np.bincount(components.ravel(), minlength=count)[1:]
        # only objects are voted on: leave the (large) background out of the sort
        in_object = valid_components > 0
        values, owners = relative[in_object], valid_components[in_object]
        upper, middle = _percentiles_by_label(values, owners, count, (_VOTE_PERCENTILE, 50.0))[
            :, 1:
        ]
        standard_error = 1.25 * sigma / np.sqrt(np.maximum(1.0, n_valid / _CORRELATED_PX))
        wide_flat = (
            (n_valid >= _WIDE_SAMPLES * _CORRELATED_PX)
            & (upper < _WIDE_VOTE_SIGMAS * sigma)
            & (middle + standard_error < _NOISY_FLAT_M)
        )
        # the upper heights are read against the ground right around the object, not the
        # coarse local ground: a blotch on a swell the 72 px median does not follow is flat
        ring_level = _ring_levels(components, count, relative, ring_px=_RING_PX)
        above = upper - np.where(np.isfinite(ring_level), ring_level, 0.0)
        bar = np.full(count - 1, _VOTE_SIGMAS)
        clear = np.zeros(count - 1)
        if contrast is not None:
            # R2c: the clearer an object's gray level, the less height it needs to stay
            inside = components > 0
            clear = _percentile_by_label(
                np.abs(contrast[inside]), components[inside], count, 50.0
            )[1:]
            bar = _VOTE_SIGMAS + _CONTRAST_SIGMAS * (_TEXTURE_CONTRAST - clear)
        # R2d: a bump of the matching windows' scale is evidence the percentile misses
        bump = _height_bumps(relative, mask)
        peak = np.full(count, -np.inf)
        np.maximum.at(peak, owners, bump[in_object])
        standing = (peak[1:] >= _BUMP_MIN_SIGMAS) & (peak[1:] + clear >= _BUMP_SCORE)
        flat = ((above < bar * sigma) & ~standing) | wide_flat
        voting = (n_valid >= _VOTE_VALID_FRACTION * n_pixels) & (n_valid >= _VOTE_VALID_PX)
        lying[1:] = voting & flat
    removed = lying[components]
    stats = DepthRuleStats(
        flat_removed_px=int(np.count_nonzero(removed)),
        depth_valid_fraction=float(valid.mean()),
        flat_threshold_m=_VOTE_SIGMAS * sigma,
        ground_sigma_m=sigma,
        notes=[
            f"height noise {100 * sigma:.1f} cm: object vote only ({int(lying.sum())} flat "
            "object(s) removed), no raised rule"
        ],
    )
    return mask & ~removed, stats


def _height_bumps(relative: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Rule R2d's map: fine minus coarse smoothed height, in its own noise on the ground.

    Parameters
    ----------
    relative : (M, N) ndarray of float32
        Heights relative to the local ground, NaN invalid.
    mask : (M, N) ndarray of bool
        Intensity objects; the other valid pixels measure the map's noise (MAD).

    Returns
    -------
    bumps : (M, N) ndarray of float32
        NaN-aware Gaussian smoothing at ``_BUMP_INNER_PX`` minus at ``_BUMP_OUTER_PX``,
        divided by its robust sigma on the ground; 0 where the height is invalid.
    """
    valid = np.isfinite(relative)
    weight = valid.astype(np.float32)
    filled = np.where(valid, relative, np.float32(0.0)).astype(np.float32)
    floor = np.float32(1e-3)
    levels = []
    for scale in (_BUMP_INNER_PX, _BUMP_OUTER_PX):
        # kernels cut at 3 sigmas (OpenCV's default for floats is 4: twice the cost)
        size = 2 * round(3 * scale) + 1
        # normalised convolution: invalid heights neither count nor pull the level to 0
        level = cv2.GaussianBlur(filled, (size, size), scale)
        level /= np.maximum(cv2.GaussianBlur(weight, (size, size), scale), floor)
        levels.append(level)
    bumps = levels[0]
    bumps -= levels[1]
    # every other row and column: the map is smooth, a quarter of the values measure its noise
    ground = (valid & ~mask)[::2, ::2]
    noise = _robust_sigma(bumps[::2, ::2][ground])
    if not noise > 0:
        return np.zeros(relative.shape, np.float32)
    bumps *= np.float32(1.0 / noise)
    bumps[~valid] = 0.0
    return bumps


def _ring_levels(
    components: np.ndarray, count: int, relative: np.ndarray, *, ring_px: int
) -> np.ndarray:
    """Median valid height in a ``ring_px`` band around each object (NaN if < 10 values)."""
    size = 2 * ring_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    # grey dilation of the ids: a ring pixel between two objects goes to the higher id
    ids = components.astype(np.uint16 if count < 2**16 else np.float32)
    grown = cv2.dilate(ids, kernel).astype(np.int64)
    ring = (components == 0) & (grown > 0) & np.isfinite(relative)
    owners = grown[ring]
    levels = _percentile_by_label(relative[ring], owners, count, 50.0)[1:]
    n_ring = np.bincount(owners, minlength=count)[1:]
    return np.where(n_ring >= 10, levels, np.nan)


def _percentile_by_label(
    values: np.ndarray, labels: np.ndarray, count: int, percentile: float
) -> np.ndarray:
    """Nearest-rank (lower) ``percentile`` of ``values`` per label 0..count-1 (+inf if empty)."""
    return _percentiles_by_label(values, labels, count, (percentile,))[0]


def _percentiles_by_label(
    values: np.ndarray, labels: np.ndarray, count: int, percentiles: tuple[float, ...]
) -> np.ndarray:
    """Nearest-rank percentiles per label, shape ``(len(percentiles), count)``; one sort."""
    result = np.full((len(percentiles), count), np.inf)
    if values.size == 0:
        return result
    values = np.asarray(values, dtype=np.float64)
    low, high = float(values.min()), float(values.max())
    if np.isfinite(low) and np.isfinite(high):
        # one sort of a combined key (label, then value) instead of a lexsort: 7x faster;
        # a label's keys span less than one unit, so labels never interleave
        order = np.argsort(labels * (high - low + 1.0) + (values - low))
    else:
        order = np.lexsort((values, labels))
    sorted_labels, sorted_values = labels[order], values[order]
    starts = np.searchsorted(sorted_labels, np.arange(count), side="left")
    stops = np.searchsorted(sorted_labels, np.arange(count), side="right")
    sizes = stops - starts
    present = sizes > 0
    for row, percentile in zip(result, percentiles, strict=True):
        # nearest-rank percentile: cheap and exact enough for a vote
        rank = starts + np.floor((percentile / 100.0) * (sizes - 1)).astype(np.int64)
        row[present] = sorted_values[rank[present]]
    return result


def _frame_bands(
    background: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[float, float]:
    """Median low and high threshold bands of the frame (every fourth row and column)."""
    coarse = np.s_[::4, ::4]
    return (
        float(np.median(background[coarse] - low[coarse])),
        float(np.median(high[coarse] - background[coarse])),
    )


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
    contrast = image.astype(np.float32)
    contrast -= background
    darker = contrast < 0
    band = np.where(darker, background - low, high - background)
    frame_low, frame_high = _frame_bands(background, low, high) if min_band_fraction > 0 else (0, 0)
    # float32 scalars keep the arrays float32 (half the memory traffic of float64)
    floor_low = np.float32(max(1.0, min_band_fraction * frame_low))
    floor_high = np.float32(max(1.0, min_band_fraction * frame_high))
    np.maximum(band, np.where(darker, floor_low, floor_high), out=band)
    contrast /= band
    return contrast


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
    owners = labels.ravel()
    n_pixels = np.bincount(owners, minlength=count)
    n_valid = np.bincount(owners[np.isfinite(height).ravel()], minlength=count)
    # every object the vote could not read (too few heights, see _noisy_depth_rules) is judged
    judged = (n_valid < max_valid_fraction * n_pixels) | (n_valid < _VOTE_VALID_PX)
    judged[0] = False
    if not judged.any():
        return labels, 0
    inside = judged[labels]
    ids = labels[inside]
    medians = [
        _percentile_by_label(field[inside].astype(np.float64), ids, count, 50.0)
        for field in (image, background, low, high)
    ]
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
    return _renumber(np.where(faint[labels], 0, labels), 1), int(faint.sum())
