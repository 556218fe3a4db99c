"""The noisy depth regime's object vote: rules R2 vote, R2c contrast and R2d bump.

Called by :func:`stages._depth_rules.apply_depth_rules`, which decides the regime from the
ground's height noise ``sigma`` (see :mod:`stages._depth_rules`) and hands over the
unsmoothed heights relative to the local ground (R0) and their own noise.

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
(:func:`stages._depth_rules.gray_contrast`: an object's median distance from the ground
level, in threshold bands). Ground texture that crosses a threshold (blotches, ripple
troughs) barely crosses it: on the built-in archives the median texture object lies 1.4-1.6
bands from the ground, the median true rock 2-2.6. So the bar of the vote is ``0.8 sigma``
for an object 1.7 bands out and moves by ``0.8 sigma`` per band: a clear rock whose stereo
heights the matching windows flattened stays, a faint blotch must stand higher to stay. On
the catalog frames (with the R3b change of :mod:`stages._depth_rules`;
``benchmarks/bench_segment.py --rundir runs/eval/<archive>``) mojave kept 17 more true rocks
for 4 more false ones, lava 34 more true rocks and 21 fewer false ones, dunes 2 fewer false
ones, lab (unusable heights) is unchanged. A band counts as at least half the frame's median
band (a sector whose ground peak is unusually narrow, smooth sand, is a poor unit); that
made mojave's catalog frames lose 4 false positives, lava's 4 (and 2 true rocks), lab 1 true
rock; seed 2 mojave 5 false positives, lava 5.

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
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._heights import (
    DepthRuleStats,
    _filled,
    _fraction,
    _percentile_by_label,
    _percentiles_by_label,
    _robust_sigma,
)
from ._regions import _lookup

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
__all__ = ["BumpWeights", "noisy_depth_rules"]


class BumpWeights:
    """The smoothed validity weights of R2d's bump map, kept for the frame's next map.

    R2d reads the unsmoothed relative heights and R8b (:mod:`stages._height_blobs`) the
    smoothed ones: their maps differ, their invalid pixels (the height map's) do not, and
    the weights' two Gaussians are a third of a map's cost. One object per frame
    (:func:`stages.segment.segment_image`); :meth:`levels` recomputes for another mask.
    """

    def __init__(self) -> None:
        self._valid: np.ndarray | None = None
        self._levels: list[np.ndarray] = []

    def levels(self, valid: np.ndarray) -> list[np.ndarray]:
        """Per bump scale, the Gaussian of ``valid`` (2-D bool) floored at 1e-3, float32;
        read only."""
        if self._valid is None or not np.array_equal(self._valid, valid):
            self._levels = _weight_levels(valid)
            self._valid = valid.copy()
        return self._levels


def noisy_depth_rules(
    mask: np.ndarray,
    relative: np.ndarray,
    sigma: float,
    *,
    contrast: np.ndarray | None = None,
    _weights: BumpWeights | None = None,
) -> tuple[np.ndarray, DepthRuleStats]:
    """R2 vote: remove whole objects whose upper heights stay within the ground noise.

    Heights are read relative to the median valid height of a ``_RING_PX`` band of ground
    around the object (the coarse local ground where the band has fewer than 10 heights).
    ``_weights`` keeps R2d's validity weights for a later bump map of the frame.
    """
    valid = np.isfinite(relative)
    count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    lying = np.zeros(count, dtype=bool)
    if count > 1:
        n_pixels, n_valid = (n[1:] for n in _object_counts(components, valid, count))
        # only objects are voted on: leave the (large) background out of the sort
        owners, values = _object_pixels(components, relative, int(n_valid.sum()), heights=True)
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
            owners, values = _object_pixels(
                components, contrast, int(n_pixels.sum()), heights=False
            )
            clear = _percentile_by_label(values, owners, count, 50.0)[1:]
            bar = _VOTE_SIGMAS + _CONTRAST_SIGMAS * (_TEXTURE_CONTRAST - clear)
        # R2d: a bump of the matching windows' scale is evidence the percentile misses
        bump = _height_bumps(relative, mask, _weights=_weights)
        peak = np.full(count, -np.inf)
        _object_peaks(components, valid, bump, peak)
        standing = (peak[1:] >= _BUMP_MIN_SIGMAS) & (peak[1:] + clear >= _BUMP_SCORE)
        flat = ((above < bar * sigma) & ~standing) | wide_flat
        voting = (n_valid >= _VOTE_VALID_FRACTION * n_pixels) & (n_valid >= _VOTE_VALID_PX)
        lying[1:] = voting & flat
    removed = _lookup(lying, components)
    stats = DepthRuleStats(
        flat_removed_px=int(np.count_nonzero(removed)),
        depth_valid_fraction=_fraction(valid),
        flat_threshold_m=_VOTE_SIGMAS * sigma,
        ground_sigma_m=sigma,
        notes=[
            f"height noise {100 * sigma:.1f} cm: object vote only ({int(lying.sum())} flat "
            "object(s) removed), no raised rule"
        ],
    )
    return mask & ~removed, stats


def _object_pixels(
    components: np.ndarray, values: np.ndarray, size: int, *, heights: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Ids and values of the object pixels (``components > 0``) in raster order, as boolean
    indexing gives them, in one compiled pass: with ``heights`` the finite values only,
    else the absolute values of all (``size``: how many there are)."""
    owners = np.empty(size, components.dtype)
    kept = np.empty(size, values.dtype)
    _object_pixel_pass(components, values, heights, owners, kept)
    return owners, kept


@njit(cache=True)
def _object_pixel_pass(components, values, heights, owners, kept):  # pragma: no cover
    rows, cols = components.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            k = components[y, x]
            if k > 0:
                value = values[y, x]
                if heights:
                    if not np.isfinite(value):
                        continue
                else:
                    value = abs(value)
                owners[n] = k
                kept[n] = value
                n += 1


def _object_counts(
    components: np.ndarray, valid: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and valid pixels of each label 0..count-1 (one compiled pass, not two
    whole-frame bincounts; ``test_height_vote.py`` compares them)."""
    counts = np.zeros((2, count), np.int64)
    _count_pass(np.ascontiguousarray(components), np.ascontiguousarray(valid), counts)
    return counts[0], counts[1]


@njit(cache=True)
def _count_pass(components, valid, counts):  # pragma: no cover - numba
    rows, cols = components.shape
    # label 0's counts in registers: ``counts[0, 0] += 1`` on most pixels makes each wait
    # for the last store (several times slower)
    ground = 0
    ground_valid = 0
    for y in range(rows):
        for x in range(cols):
            k = components[y, x]
            if k == 0:
                ground += 1
                if valid[y, x]:
                    ground_valid += 1
            else:
                counts[0, k] += 1
                if valid[y, x]:
                    counts[1, k] += 1
    counts[0, 0] += ground
    counts[1, 0] += ground_valid


@njit(cache=True)
def _object_peaks(components, valid, values, peak):  # pragma: no cover - numba
    """``np.maximum.at(peak, components[in_object], values[in_object])`` over the valid
    object pixels, in place."""
    rows, cols = components.shape
    for y in range(rows):
        for x in range(cols):
            k = components[y, x]
            if k > 0 and valid[y, x] and values[y, x] > peak[k]:
                peak[k] = values[y, x]


def _kernel_size(scale: float) -> int:
    # kernels cut at 3 sigmas (OpenCV's default for floats is 4: twice the cost)
    return 2 * round(3 * scale) + 1


def _weight_levels(valid: np.ndarray) -> list[np.ndarray]:
    """The denominators of :func:`_height_bumps`' normalised convolutions."""
    weight = valid.astype(np.float32)
    floor = np.float32(1e-3)
    levels = []
    for scale in (_BUMP_INNER_PX, _BUMP_OUTER_PX):
        size = _kernel_size(scale)
        levels.append(np.maximum(cv2.GaussianBlur(weight, (size, size), scale), floor))
    return levels


def _height_bumps(
    relative: np.ndarray, mask: np.ndarray, *, _weights: BumpWeights | None = None
) -> np.ndarray:
    """Rule R2d's map: fine minus coarse smoothed height, in its own noise on the ground.

    Parameters
    ----------
    relative : (M, N) ndarray of float32
        Heights relative to the local ground, NaN invalid.
    mask : (M, N) ndarray of bool
        Intensity objects; the other valid pixels measure the map's noise (MAD).
    _weights : BumpWeights, optional
        The frame's validity weights, reused when ``relative`` is invalid where they were
        made (the same floats as computing them here).

    Returns
    -------
    bumps : (M, N) ndarray of float32
        NaN-aware Gaussian smoothing at ``_BUMP_INNER_PX`` minus at ``_BUMP_OUTER_PX``,
        divided by its robust sigma on the ground; 0 where the height is invalid.
    """
    valid, filled = _filled(relative)
    weights = _weight_levels(valid) if _weights is None else _weights.levels(valid)
    levels = []
    for scale in (_BUMP_INNER_PX, _BUMP_OUTER_PX):
        size = _kernel_size(scale)
        levels.append(cv2.GaussianBlur(filled, (size, size), scale))
    # normalised convolutions (invalid heights neither count nor pull the level to 0), their
    # difference, and the ground's values on every other row and column: the map is smooth,
    # a quarter of the values measure its noise (MAD)
    bumps = np.empty(relative.shape, np.float32)
    ground = np.empty(((relative.shape[0] + 1) // 2) * ((relative.shape[1] + 1) // 2), np.float32)
    n = _bump_pass(levels[0], weights[0], levels[1], weights[1], valid, mask, bumps, ground)
    noise = _robust_sigma(ground[:n])
    if not noise > 0:
        return np.zeros(relative.shape, np.float32)
    _scale_valid(bumps, valid, np.float32(1.0 / noise))
    return bumps


@njit(cache=True, error_model="numpy")
def _bump_pass(  # pragma: no cover - numba
    inner, inner_weight, outer, outer_weight, valid, mask, bumps, ground
):
    """``bumps = inner / inner_weight - outer / outer_weight`` in float32, as the in-place
    numpy steps did it; ``ground`` gets ``bumps[::2, ::2][valid[::2, ::2] &
    ~mask[::2, ::2]]`` in that order; returns their count (``test_height_vote.py``
    compares)."""
    rows, cols = bumps.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            value = inner[y, x] / inner_weight[y, x] - outer[y, x] / outer_weight[y, x]
            bumps[y, x] = value
            if y % 2 == 0 and x % 2 == 0 and valid[y, x] and not mask[y, x]:
                ground[n] = value
                n += 1
    return n


@njit(cache=True)
def _scale_valid(bumps, valid, factor):  # pragma: no cover - numba
    """``bumps *= factor; bumps[~valid] = 0``, in place."""
    rows, cols = bumps.shape
    for y in range(rows):
        for x in range(cols):
            bumps[y, x] = bumps[y, x] * factor if valid[y, x] else np.float32(0.0)


def _ring_levels(
    components: np.ndarray, count: int, relative: np.ndarray, *, ring_px: int
) -> np.ndarray:
    """Median valid height in a ``ring_px`` band around each object (NaN if < 10 values)."""
    size = 2 * ring_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    # grey dilation of the ids: a ring pixel between two objects goes to the higher id
    ids = components.astype(np.uint16 if count < 2**16 else np.float32)
    grown = cv2.dilate(ids, kernel)
    # the ring: background pixels a dilated id reaches, with a height (one compiled pass)
    owners = np.empty(components.size, np.int64)
    values = np.empty(components.size, np.float32)
    n = _ring_pass(components, grown, relative, owners, values)
    owners, values = owners[:n], values[:n]
    levels = _percentile_by_label(values, owners, count, 50.0)[1:]
    n_ring = np.bincount(owners, minlength=count)[1:]
    return np.where(n_ring >= 10, levels, np.nan)


@njit(cache=True)
def _ring_pass(components, grown, relative, owners, values):  # pragma: no cover - numba
    """Ids and heights of the ring pixels in raster order, as ``grown[ring]`` and
    ``relative[ring]`` give them (``test_height_vote.py`` compares); returns their count."""
    rows, cols = components.shape
    n = 0
    for y in range(rows):
        for x in range(cols):
            if components[y, x] == 0 and grown[y, x] > 0 and np.isfinite(relative[y, x]):
                owners[n] = np.int64(grown[y, x])
                values[n] = relative[y, x]
                n += 1
    return n
