"""From thresholds to labelled objects, and the depth rules of ``sector-histogram+depth``.

Intensity: a pixel is object when its gray level is below the interpolated low threshold or
above the high one (:func:`threshold_mask`). :func:`label_objects` then fills holes (background
pockets enclosed by object pixels), optionally splits components at depth discontinuities,
drops specks smaller than ``min_area_px`` and numbers the objects ``1..n`` densely.

Depth rules (:func:`apply_depth_rules`), each explainable on its own. ``height`` is metres
above the depth stage's fitted ground plane. It is first smoothed with a NaN-aware 5x5
median, then made *relative* to the local ground (R0): a coarse median over
``ground_window_px`` (72 px) removes dune swells and slopes the plane fit cannot follow. A
pixel has *valid depth* where the smoothed height is finite. The ground's height noise
``sigma`` is measured robustly (MAD) on valid pixels the intensity calls background, and
decides between two regimes:

Precise depth (``sigma <= 5 mm``):

* **R1 raised** -- a pixel with relative height > ``max(min_height_m, 4 sigma)`` is object,
  even when its gray level equals the ground's (a rock as bright as the sand it lies on).
* **R2 flat** -- an intensity-object pixel at or below ``max(flat_tol_m, 2 sigma)`` (capped
  at half the raised threshold) is background -- a shadow is dark but lies on the ground; so
  do stains, damp patches and dark texture blotches -- unless it lies within ``base_px``
  pixels of a raised pixel (the foot of a rock is low too). Of what is left, an object with
  fewer than ``min_raised_fraction`` raised pixels and most pixels below half the raised
  threshold lies on the ground and is removed whole.

Noisy depth (``sigma > 5 mm``, typical of window-based stereo on real texture):
pixels are not trusted one by one; no object is added from height alone (R1 off), and an
intensity object is removed as lying flat (R2) only when most of it has valid depth and its
median relative height plus one standard error (``1.25 sigma / sqrt(n / 225)``, one
independent sample per 15 x 15 pixels, the scale of the matching windows) stays below
11 mm. Small objects have a large standard error and keep their intensity decision.

* **R3 no depth** -- where depth is invalid the intensity decision stands.
* **R4 split** -- a pixel where the (median-smoothed) disparity drops by more than
  ``split_disparity_px`` towards a 4-neighbour is a depth edge: the surface behind an
  occluding boundary. An object made of two or more cores (4-connected pieces of at least
  ``min_area_px`` after removing its depth edges) is split into those cores; every other pixel
  of the object goes to its nearest core. Touching rocks at different ranges thus become
  separate objects.
* **R5 streaks** -- an object more than ``max_elongation`` times longer than wide (its
  equivalent ellipse) is a wind striation or ripple trough, not a rock: dropped
  (:func:`drop_streaks`). Rocks seen from a rover are compact blobs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt, median, median_filter

# Ground height noise (MAD sigma, metres) above which single heights are not trusted.
_NOISY_SIGMA_M = 0.005
# Noisy regime: an object lies flat when its median height plus one standard error stays
# below this (metres; tuned on the built-in archives with the depth stage).
_NOISY_FLAT_M = 0.011
# Precise regime: raised means higher than this many ground sigmas (and min_height_m).
_RAISE_SIGMAS = 4.0
# Stereo heights are correlated over the matching window (9 to 63 px wide in the depth stage):
# count one independent sample per 15 x 15 pixels.
_CORRELATED_PX = 225.0
__all__ = [
    "DepthRuleStats",
    "threshold_mask",
    "fill_holes",
    "smooth_height",
    "depth_edges",
    "local_ground",
    "apply_depth_rules",
    "label_objects",
    "elongation",
    "drop_streaks",
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


def _coerce_mask(mask: np.ndarray, name: str = "mask") -> np.ndarray:
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(mask).__name__}")
    if mask.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {mask.shape}")
    if mask.dtype != bool:
        raise TypeError(f"{name} must be a bool array, got dtype {mask.dtype}; use mask != 0")
    return mask


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
    coarse = median_filter(small, size=min(9, *small_shape), mode="nearest")
    return cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_LINEAR)


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

    Returns
    -------
    combined : (M, N) ndarray of bool
    stats : DepthRuleStats
    """
    mask = _coerce_mask(mask)
    height = _coerce_float_map(height, mask.shape, "height")
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
    if sigma > _NOISY_SIGMA_M:
        return _noisy_depth_rules(mask, relative, valid, sigma, min_height_m)
    raise_m = max(min_height_m, _RAISE_SIGMAS * sigma)
    flat_m = min(max(flat_tol_m, 2.0 * sigma), 0.5 * raise_m)
    with np.errstate(invalid="ignore"):
        raised = relative > raise_m
        flat = relative < flat_m  # at or below the local ground: shadows, stains, pits

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
    n_valid = np.bincount(components[valid], minlength=count)
    n_raised = np.bincount(components[raised], minlength=count)
    n_pixels = np.bincount(components.ravel(), minlength=count)
    n_low = np.bincount(components[valid & (relative < 0.5 * raise_m)], minlength=count)
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


def _noisy_depth_rules(mask, relative, valid, sigma, min_height_m):
    """R2 on whole objects only, with the noise of a median over the object's pixels."""
    count, components = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    lying = np.zeros(count, dtype=bool)
    if count > 1:
        valid_components = np.where(valid, components, 0)
        index = np.arange(1, count)
        n_valid = np.bincount(valid_components.ravel(), minlength=count)[1:]
        n_pixels = np.bincount(components.ravel(), minlength=count)[1:]
        medians = np.asarray(
            median(np.nan_to_num(relative), valid_components, index=index), dtype=np.float64
        )
        independent = np.maximum(1.0, n_valid / _CORRELATED_PX)
        standard_error = 1.25 * sigma / np.sqrt(independent)
        lying[1:] = (n_valid >= 0.5 * n_pixels) & (medians + standard_error < _NOISY_FLAT_M)
    removed = lying[components]
    stats = DepthRuleStats(
        flat_removed_px=int(np.count_nonzero(removed)),
        depth_valid_fraction=float(valid.mean()),
        ground_sigma_m=sigma,
        notes=[f"height noise {100 * sigma:.1f} cm: object-level flat rule only, no raised rule"],
    )
    return mask & ~removed, stats


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
    return ratio


def drop_streaks(labels: np.ndarray, *, max_elongation: float) -> tuple[np.ndarray, int]:
    """Remove objects longer than ``max_elongation`` times their width; renumber densely.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
    max_elongation : float
        ``> 1``; major/minor axis ratio above which an object is a streak (wind striation,
        ripple trough), not a rock.

    Returns
    -------
    labels : (M, N) ndarray of int32
    dropped : int
        Number of objects removed.
    """
    if not max_elongation > 1:
        raise ValueError(f"max_elongation must be > 1, got {max_elongation}")
    ratio = elongation(labels)
    streak = ratio > max_elongation
    if not streak.any():
        return labels, 0
    kept = np.where(streak[labels], 0, labels)
    return _renumber(kept, 1), int(streak.sum())
