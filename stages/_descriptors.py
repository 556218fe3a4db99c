"""Per-object measurements of the describe stage (pure functions, arrays in, numbers out).

Each function measures one thing on one object, given the object's pixels (rows, columns,
values) or a small crop around it, so every rule can be tested on a hand-made 20x20 array.
:func:`describe_objects` runs them over every object of a label image and returns the
descriptor columns (see ``docs/design.md``). The ground frame and the per-object depth
denoising (a robust quadratic disparity surface) live in :mod:`stages._ground`, the
footprint measurements (``width_m``, ``length_m`` without ground-level fringes) in
:mod:`stages._footprint`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from pipeline.camera import Camera

from ._border import border_largest_bound, height_width_ratio
from ._fill import border_fill
from ._footprint import (
    _dilate_diamond,
    bound_footprint_slope,
    face_rows,
    footprint_dimensions,
    footprint_disparity,
    ground_disparity_slope,
    ground_fringe_keep,
    too_dark_to_match,
    widest_row_width_m,
)
from ._ground import (
    GroundFrame,
    _median,
    fit_disparity_surface,
    frame_ground,
    pixel_points,
    silhouette_on_ground,
)
from ._small_stats import boundary_jump_counts, percentile64

__all__ = [
    "GroundFrame",
    "second_moment_ellipse",
    "cooccurrence_contrast",
    "polarity_against",
    "top_height",
    "classify_size",
    "size_class_borderline",
    "background_jump_fraction",
    "describe_objects",
    "frame_ground",
    "DESCRIPTOR_COLUMNS",
]

DESCRIPTOR_COLUMNS: dict[str, str] = {
    "object_id": "int32",
    "area_px": "int64",
    "centroid_x": "float64",
    "centroid_y": "float64",
    "bbox_x_min": "int32",
    "bbox_x_max": "int32",
    "bbox_y_near": "int32",
    "bbox_y_far": "int32",
    "range_m": "float64",
    "range_err_m": "float64",
    "x_m": "float64",
    "y_m": "float64",
    "z_m": "float64",
    "width_m": "float64",
    "length_m": "float64",
    "height_m": "float64",
    "height_max_m": "float64",
    "height_err_m": "float64",
    "width_err_m": "float64",
    "depth_valid_fraction": "float64",
    "mean_gray": "float64",
    "polarity": "str",
    "texture_std": "float64",
    "texture_contrast": "float64",
    "ellipse_major_px": "float64",
    "ellipse_minor_px": "float64",
    "ellipse_angle_deg": "float64",
    "size_class": "str",
    "size_class_borderline": "bool",
    "touches_border": "bool",
    "occluded": "bool",
    "depth_unreliable": "bool",
}
"""Descriptor column names and NumPy dtypes (``'str'``: Python/NumPy unicode strings)."""


def second_moment_ellipse(rows: np.ndarray, cols: np.ndarray) -> tuple[float, float, float]:
    """Ellipse with the same second moments as a pixel set.

    Each pixel counts as a unit square (its own variance 1/12 is added), so a filled disk
    of diameter D gives axes D.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        Pixel coordinates of the object, K >= 1.

    Returns
    -------
    major_px, minor_px : float
        Full axis lengths, pixels (4 x the square root of the inertia eigenvalues).
    angle_deg : float
        Direction of the major axis in (-90, 90], degrees from the +x (column) axis towards
        +y (down the image), i.e. clockwise on screen.
    """
    r = np.asarray(rows, dtype=np.float64)
    c = np.asarray(cols, dtype=np.float64)
    if r.size == 0 or r.shape != c.shape:
        raise ValueError(
            f"rows and cols must be equal non-empty 1-D arrays, got {r.shape}, {c.shape}"
        )
    mu20 = c.var() + 1.0 / 12.0
    mu02 = r.var() + 1.0 / 12.0
    mu11 = float(np.mean((c - c.mean()) * (r - r.mean())))
    half_sum = (mu20 + mu02) / 2.0
    root = math.sqrt(((mu20 - mu02) / 2.0) ** 2 + mu11**2)
    major = 4.0 * math.sqrt(half_sum + root)
    minor = 4.0 * math.sqrt(max(half_sum - root, 0.0))
    angle = math.degrees(0.5 * math.atan2(2.0 * mu11, mu20 - mu02))
    if angle <= -90.0:
        angle += 180.0
    return major, minor, angle


def cooccurrence_contrast(gray: np.ndarray, mask: np.ndarray) -> float:
    """Gray-level co-occurrence contrast at distance 1, horizontal and vertical pairs pooled.

    Contrast = sum over (i, j) of P(i, j) (i - j)^2 for the symmetric, normalised
    co-occurrence matrix P of pixel pairs (right and down neighbours) that both lie in the
    object; this equals the mean squared gray difference of those pairs (no quantisation).

    Parameters
    ----------
    gray : (M, N) ndarray of uint8 or float
    mask : (M, N) ndarray of bool
        The object's pixels.

    Returns
    -------
    float
        Contrast in gray levels squared; NaN when the object has no neighbour pair.
    """
    g = np.asarray(gray, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    horizontal = m[:, 1:] & m[:, :-1]
    vertical = m[1:, :] & m[:-1, :]
    dh = (g[:, 1:] - g[:, :-1])[horizontal]
    dv = (g[1:, :] - g[:-1, :])[vertical]
    n = dh.size + dv.size
    if n == 0:
        return math.nan
    return float((np.sum(dh**2) + np.sum(dv**2)) / n)


def polarity_against(mean_inside: float, background: np.ndarray) -> str:
    """``'darker'`` when the object's mean gray is below the background's median, else
    ``'lighter'``.

    Parameters
    ----------
    mean_inside : float
        Mean gray of the object.
    background : (K,) ndarray
        Gray levels of the background ring around the object (may be empty: ``'lighter'``
        is then returned only if the object is above mid-gray 127.5).
    """
    bg = np.asarray(background, dtype=np.float64)
    level = float(_median(bg)) if bg.size else 127.5
    return "darker" if mean_inside < level else "lighter"


def top_height(
    rows: np.ndarray, heights: np.ndarray, *, top_fraction: float = 0.05, min_pixels: int = 3
) -> tuple[float, int]:
    """Height of the farthest perceivable point: median height of the topmost pixels.

    The study defines a rock's height as that of its farthest perceivable point, the top
    of its silhouette (``bbox_y_far``). A single pixel there is noisy and often carries the
    disparity of the ground behind it, so the median over the topmost valid pixels is used.

    Parameters
    ----------
    rows : (K,) ndarray of int
        Image rows of the object's pixels.
    heights : (K,) ndarray of float
        Height above ground of those pixels, NaN where unknown.
    top_fraction : float
        Share of the valid pixels taken from the top, in (0, 1].
    min_pixels : int
        At least this many pixels are used (when available).

    Returns
    -------
    height : float
        Metres; NaN when no pixel has a height.
    row : int
        Median image row of the pixels used (-1 when none).
    """
    h = np.asarray(heights, dtype=np.float64)
    r = np.asarray(rows)
    valid = np.isfinite(h)
    if not valid.any():
        return math.nan, -1
    h, r = h[valid], r[valid]
    order = np.argsort(r, kind="stable")
    n = max(min_pixels, math.ceil(top_fraction * h.size))
    take = order[:n]
    return float(_median(h[take])), int(_median(r[take]))  # np.median's values


def _height_p98(heights: np.ndarray) -> float:
    """The 98th percentile of an object's finite heights (``height_max_m``), NaN if none."""
    finite = heights[np.isfinite(heights)]
    return percentile64(finite, 98) if finite.size else math.nan


def classify_size(
    largest_m: float, height_m: float, *, sample_max_m: float, rover_clearance_m: float
) -> str:
    """``'sample'`` or ``'obstacle'``.

    A sample is small enough to pick up (largest cross-section <= ``sample_max_m``) and low
    enough to drive over (height <= ``rover_clearance_m``). Unknown sizes (NaN, no depth)
    give ``'obstacle'``: a rover must not assume it can drive over what it cannot measure.
    """
    if not (math.isfinite(largest_m) and math.isfinite(height_m)):
        return "obstacle"
    if largest_m <= sample_max_m and height_m <= rover_clearance_m:
        return "sample"
    return "obstacle"


def size_class_borderline(
    largest_m: float,
    height_m: float,
    *,
    sample_max_m: float,
    rover_clearance_m: float,
    borderline_fraction: float = 0.1,
) -> bool:
    """Whether the measurement cannot decide the class: a size lies within
    ``borderline_fraction`` x its limit of that limit.

    A rock's class (:func:`classify_size`) is borderline when
    ``|largest_m - sample_max_m| <= borderline_fraction * sample_max_m`` or
    ``|height_m - rover_clearance_m| <= borderline_fraction * rover_clearance_m``, unless
    one of the two lies above its band (``> (1 + borderline_fraction) x limit``): that size
    alone makes the rock an obstacle, whatever the other reads. An unknown size (NaN) is
    borderline too (unless the other lies above its band): its 'obstacle' is the rule for
    what cannot be measured, not a measurement.

    Why 0.1 by default: widths are measured with a median error of 6-9 % on the built-in
    archives' rocks within 2 m (lab 5.7 %, mojave 7.6 %, lava 9.4 %: "width err median (%)"
    under "rocks within 2 m" of ``arroyo run catalogs/<archive>.toml --out DIR`` then
    ``arroyo evaluate DIR``, describe v11): a 10 cm rock reads between 9.1 and 10.9 cm about
    half the time, so a size measured within 10 % of its limit does not tell on which side
    of the limit the rock lies.

    Parameters
    ----------
    largest_m : float
        The largest horizontal dimension that decided the class, metres (for a rock cut by
        the image border its bound from the height, :mod:`stages._border`); NaN: unknown.
    height_m : float
        ``height_max_m``, metres; NaN: unknown.
    sample_max_m, rover_clearance_m : float
        The class limits, metres, >= 0 (see :func:`classify_size`).
    borderline_fraction : float
        Half-width of the band around each limit as a share of the limit, in [0, 1];
        0: never borderline (unknown sizes included).

    Returns
    -------
    bool
    """
    fraction = _coerce_borderline_fraction(borderline_fraction)
    for name, limit in (("sample_max_m", sample_max_m), ("rover_clearance_m", rover_clearance_m)):
        if isinstance(limit, bool) or not isinstance(limit, int | float):
            raise TypeError(f"{name} must be a number of metres, got {type(limit).__name__}")
        if not (math.isfinite(limit) and limit >= 0):
            raise ValueError(f"{name} must be a finite size >= 0 in metres, got {limit!r}")
    if fraction == 0.0:
        return False
    band_w, band_h = fraction * sample_max_m, fraction * rover_clearance_m
    if largest_m - sample_max_m > band_w or height_m - rover_clearance_m > band_h:
        return False  # an obstacle by this size alone (False for NaN)
    if not (math.isfinite(largest_m) and math.isfinite(height_m)):
        return True
    return abs(largest_m - sample_max_m) <= band_w or abs(height_m - rover_clearance_m) <= band_h


def _coerce_borderline_fraction(value: float) -> float:
    """``borderline_fraction`` as a float in [0, 1], or a TypeError/ValueError saying so."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(
            "borderline_fraction must be a number in [0, 1] (a share of the class limit), "
            f"got {type(value).__name__} {value!r}"
        )
    if not 0.0 <= value <= 1.0:
        raise ValueError(
            "borderline_fraction must be a share of the class limit in [0, 1] (0: never "
            f"borderline, 0.1: within 10 % of the limit), got {value!r}"
        )
    return float(value)


def _decide_size_class(
    largest_m: float,
    height_m: float,
    *,
    sample_max_m: float,
    rover_clearance_m: float,
    borderline_fraction: float,
) -> tuple[str, bool]:
    """``size_class`` and ``size_class_borderline`` from the same sizes: every place that
    decides the class calls this."""
    kwargs = {"sample_max_m": sample_max_m, "rover_clearance_m": rover_clearance_m}
    return (
        classify_size(largest_m, height_m, **kwargs),
        size_class_borderline(
            largest_m, height_m, borderline_fraction=borderline_fraction, **kwargs
        ),
    )


def background_jump_fraction(
    mask: np.ndarray, labels: np.ndarray, disparity: np.ndarray, *, jump_px: float
) -> float:
    """Share of the object's boundary where the background just outside is nearer.

    For every 4-neighbour pair (inside pixel, outside background pixel) with both
    disparities valid, the pair counts as a depth discontinuity hiding the object when the
    outside disparity exceeds the inside one by more than ``jump_px`` (something nearer,
    not segmented, covers the object there).

    Parameters
    ----------
    mask : (M, N) ndarray of bool
        The object.
    labels : (M, N) ndarray of int
        Label image of the same crop (0 = background).
    disparity : (M, N) ndarray of float
        Disparity, NaN where invalid.
    jump_px : float
        Disparity jump threshold in pixels, > 0.

    Returns
    -------
    float
        Fraction in [0, 1]; 0 when no valid boundary pair exists.
    """
    # compiled: one pass over the crop instead of four shifted-array passes
    total, hidden = boundary_jump_counts(
        mask, np.asarray(labels) == 0, disparity, jump_px=jump_px
    )
    return hidden / total if total else 0.0


def _object_slices(labels: np.ndarray) -> list:
    """``scipy.ndimage.find_objects`` of a label image, values <= 0 as background."""
    lab = np.asarray(labels)
    return ndimage.find_objects(np.where(lab > 0, lab, 0))


def _coerce_frame_inputs(
    labels: np.ndarray,
    gray: np.ndarray,
    disparity: np.ndarray,
    range_m: np.ndarray,
    height: np.ndarray,
) -> tuple[np.ndarray, ...]:
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ValueError(f"labels must be a 2-D (M, N) array, got shape {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise TypeError(f"labels must hold integers (int32 object ids), got dtype {lab.dtype}")
    out = [lab]
    for name, arr in (
        ("gray", gray),
        ("disparity", disparity),
        ("range", range_m),
        ("height", height),
    ):
        a = np.asarray(arr)
        if a.shape != lab.shape:
            raise ValueError(
                f"{name} must have the labels' shape {lab.shape}, got {a.shape}; pass arrays "
                "of the same frame in reference-image geometry"
            )
        out.append(a)
    return tuple(out)


def _float_crop(values: np.ndarray, crop: tuple[slice, slice]) -> np.ndarray:
    """A crop in float64: converting crops, not whole frames, keeps the per-object cost low."""
    return values[crop].astype(np.float64)


def _empty_columns() -> dict[str, np.ndarray]:
    return {
        name: np.array([], dtype=str if kind == "str" else kind)
        for name, kind in DESCRIPTOR_COLUMNS.items()
    }


def describe_objects(
    labels: np.ndarray,
    gray: np.ndarray,
    disparity: np.ndarray,
    range_m: np.ndarray,
    height: np.ndarray,
    *,
    camera: Camera,
    ground_plane: np.ndarray | None = None,
    sample_max_m: float = 0.10,
    rover_clearance_m: float = 0.10,
    min_valid_fraction: float = 0.5,
    background_jump_px: float = 1.0,
    disparity_error_px: float = 0.5,
    ring_px: int = 3,
    fringe_height_m: float = 0.004,
    fringe_reach_px: int = 3,
    fringe_smoothing_px: int = 7,
    fringe_dark_ratio: float = 0.15,
    border_height_quantile: float = 0.9,
    borderline_fraction: float = 0.1,
    object_slices: list | None = None,
) -> dict[str, np.ndarray]:
    """Descriptor columns of every object of a label image.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 = background, k = object k.
    gray : (M, N) ndarray of uint8
        Reference image.
    disparity : (M, N) ndarray of float32
        Pixels, NaN (or <= 0) where invalid.
    range_m : (M, N) ndarray of float32
        Z = f b / d, metres, NaN where invalid.
    height : (M, N) ndarray of float32
        Height above the ground plane, metres, NaN where unknown; with a ground frame it
        also sets the ground level under each object (``z_m``). When it has no finite
        value, heights are the ground frame's z. Objects
        with fewer than 3 valid-depth pixels but a ground frame are measured by
        :func:`stages._ground.silhouette_on_ground` (range, position, width and height from
        the ground plane under their lowest pixel; ``range_err_m`` NaN).
    camera : Camera
    ground_plane : (4,) ndarray of float64, optional
        Fitted plane (camera frame, normal up); used when the camera pose is unknown.
    sample_max_m, rover_clearance_m : float
        Size classes, see :func:`classify_size`.
    min_valid_fraction : float
        ``depth_unreliable`` when less than this share of the object has valid disparity.
    background_jump_px : float
        Disparity jump (pixels) by which nearer background just outside the object counts as
        hiding it (``occluded`` when more than 10 % of the boundary pairs show one).
    disparity_error_px : float
        Disparity uncertainty behind ``range_err_m`` (0.5 px: half a pixel of matching).
    ring_px : int
        Width of the background ring for polarity.
    fringe_height_m, fringe_reach_px : float, int
        ``width_m`` and ``length_m`` leave out the object's ground-level fringes (pixels
        below ``fringe_height_m`` farther than ``fringe_reach_px`` from its raised part,
        such as a sun shadow segmented with the rock; :func:`ground_fringe_keep`).
        ``fringe_height_m = 0`` keeps every pixel.
    fringe_smoothing_px : int
        Odd, >= 1: heights are averaged over this box of the object's pixels first
        (:func:`ground_fringe_keep`).
    fringe_dark_ratio : float
        In [0, 1): pixels darker than this share of the gray of the background ring around
        the object are too dark for stereo (their heights are the ground's next to them) and
        count as of unknown height for the fringe decision (:func:`too_dark_to_match`);
        0 reads every pixel's height.
    border_height_quantile : float
        In [0, 1): an object cut by the image border is classed with the larger of its
        visible width and its height over this quantile of height / width of the frame's
        objects seen whole (:mod:`stages._border`; at least 5 of them, 0.03 m wide or
        more); 0 classes it on its visible width.
    borderline_fraction : float
        In [0, 1]: ``size_class_borderline`` when a size that decided the class lies within
        this share of its limit, or is unknown (:func:`size_class_borderline`; 0: never).
    object_slices : list of (slice, slice) or None, optional
        ``scipy.ndimage.find_objects`` of ``labels`` with values <= 0 as background, when
        the caller has it (describe does, for the relations too); computed if None.

    Returns
    -------
    dict of str to (K,) ndarray
        :data:`DESCRIPTOR_COLUMNS`, one row per object in increasing id order; ``occluded``
        here only reflects background discontinuities (describe adds occluding objects).
    """
    lab, g, disp, rng, hgt = _coerce_frame_inputs(labels, gray, disparity, range_m, height)
    if ring_px < 1:
        raise ValueError(f"ring_px must be >= 1 (background ring width, pixels), got {ring_px!r}")
    if fringe_smoothing_px < 1 or fringe_smoothing_px % 2 == 0:
        raise ValueError(
            "fringe_smoothing_px must be an odd number of pixels >= 1 (1: no smoothing), got "
            f"{fringe_smoothing_px!r}"
        )
    if not 0.0 <= fringe_dark_ratio < 1.0:
        raise ValueError(
            "fringe_dark_ratio must be a share of the ground ring's gray in [0, 1) (0: off), "
            f"got {fringe_dark_ratio!r}"
        )
    if not 0.0 <= border_height_quantile < 1.0:
        raise ValueError(
            "border_height_quantile must be a quantile in [0, 1) (0: off), got "
            f"{border_height_quantile!r}"
        )
    _coerce_borderline_fraction(borderline_fraction)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a pipeline.camera.Camera, got {type(camera).__name__}")
    ground = frame_ground(camera, ground_plane)
    has_height_map = bool(np.isfinite(hgt).any())
    # a rectified frame's black fill (stages._fill) is no ground for the ring, and an object
    # against it is cut like one at the border
    fill = border_fill(g) if g.dtype == np.uint8 and g.ndim == 2 else None
    near_fill = None if fill is None else ndimage.binary_dilation(fill)
    slices = object_slices if object_slices is not None else _object_slices(lab)
    rows_out: list[dict[str, object]] = []
    h_img, w_img = shape = lab.shape
    cx, cy = camera.principal_point(lab.shape)
    f = camera.focal_px
    kb = camera.k_m_px
    for index, sl in enumerate(slices, start=1):
        if sl is None:
            continue
        y0 = max(sl[0].start - ring_px, 0)
        y1 = min(sl[0].stop + ring_px, h_img)
        x0 = max(sl[1].start - ring_px, 0)
        x1 = min(sl[1].stop + ring_px, w_img)
        crop = (slice(y0, y1), slice(x0, x1))
        lab_c = lab[crop]
        mask = lab_c == index
        rr, cc = np.nonzero(mask)
        rows, cols = rr + y0, cc + x0
        gray_c = _float_crop(g, crop)
        disp_c = _float_crop(disp, crop)
        disp_c[~(disp_c > 0)] = np.nan
        gray_px = gray_c[mask]
        ring = _dilate_diamond(mask, ring_px) & (lab_c == 0)
        if fill is not None:
            ring &= ~fill[crop]
        ground_gray = float(_median(gray_c[ring])) if ring.any() else math.nan
        disp_px = disp_c[mask]
        range_px = _float_crop(rng, crop)[mask]
        valid = np.isfinite(disp_px) & np.isfinite(range_px)
        valid_fraction = float(valid.mean())
        z_med = float(_median(range_px[valid])) if valid.any() else math.nan
        range_err = z_med**2 / kb * disparity_error_px
        heights = _float_crop(hgt, crop)[mask]
        x_m = y_m = z_m = length = height_err = math.nan
        h_max: float | None = None  # set where the heights are final: the face bound reads it
        if ground is not None and np.count_nonzero(valid) >= _MIN_DEPTH_PX:
            # ground level under the object: the height map's reference in this frame
            raw = ground.to_ground(
                pixel_points(rows[valid], cols[valid], disp_px[valid], camera=camera, shape=shape)
            )
            level = raw[:, 2] - heights[valid] if has_height_map else np.zeros(0)
            level = level[np.isfinite(level)]
            z_m = float(_median(level)) if level.size else 0.0
            # footprint and position on the denoised surface (see stages._ground); heights
            # stay per pixel: the surface flattens the peaks of large rocks
            smooth = ground.to_ground(
                pixel_points(
                    rows,
                    cols,
                    fit_disparity_surface(rows, cols, disp_px),
                    camera=camera,
                    shape=shape,
                )
            )
            if not has_height_map:
                heights = np.full(rows.shape, np.nan)
                heights[valid] = raw[:, 2]
            x_m, y_m = float(_median(smooth[:, 0])), float(_median(smooth[:, 1]))
            # the footprint: without ground-level fringes (shadows), on a disparity fitted to
            # the pixels kept, constant along rows (see footprint_disparity)
            dark = too_dark_to_match(gray_px, ground_gray=ground_gray, dark_ratio=fringe_dark_ratio)
            keep = ground_fringe_keep(
                mask,
                np.where(dark, np.nan, heights),
                min_height_m=fringe_height_m,
                reach_px=fringe_reach_px,
                smoothing_px=fringe_smoothing_px,
            )
            if np.count_nonzero(valid & keep) < _MIN_DEPTH_PX:  # kept only depthless pixels
                keep = np.ones(rows.shape, dtype=bool)
            fitted = footprint_disparity(rows[keep], cols[keep], disp_px[keep])
            if np.isfinite(fitted).all():
                # a face read as ground: bound the slope (see bound_footprint_slope)
                h_max = _height_p98(heights)
                face_px = face_rows(
                    float(_median(rows[keep])),
                    float(_median(cols[keep])),
                    float(_median(fitted)),
                    h_max if math.isfinite(h_max) else 0.0,
                    camera=camera,
                    ground=ground,
                    shape=shape,
                )
                fitted = bound_footprint_slope(
                    rows[keep],
                    cols[keep],
                    fitted,
                    ground_slope_px=ground_disparity_slope(ground, camera),
                    face_px=face_px,
                    focal_px=f,
                )
            foot = ground.to_ground(
                pixel_points(rows[keep], cols[keep], fitted, camera=camera, shape=shape)
            )
            width, length = footprint_dimensions(foot[:, 0], foot[:, 1], pixel_m=z_med / f)
        elif ground is not None:  # no depth: stand the silhouette on the ground plane
            sil = silhouette_on_ground(rows, cols, camera=camera, ground=ground, shape=shape)
            z_med, x_m, y_m, z_m, width = (
                sil["range_m"], sil["x_m"], sil["y_m"], 0.0, sil["width_m"],
            )  # fmt: skip
            heights = np.where(rows == rows.min(), sil["height_m"], np.nan)
        else:  # no ground frame: the widest image row at its own depth
            width = widest_row_width_m(
                rows, cols, np.where(valid, range_px, np.nan), focal_px=f, fallback_z=z_med
            )
        h_top, top_row = top_height(rows, heights)
        if h_max is None:
            h_max = _height_p98(heights)
        width_err = math.hypot(width * range_err / z_med, z_med / f) if valid.any() else math.nan
        if ground is not None and top_row >= 0 and math.isfinite(h_top):
            top = rows == top_row
            z_top = float(_median(range_px[top][valid[top]])) if valid[top].any() else z_med
            ray = np.array([(np.mean(cols[top]) - cx) / f, (top_row - cy) / f, 1.0])
            height_err = abs(float(ray @ ground.up)) * z_top**2 / kb * disparity_error_px
        mean_gray = float(gray_px.mean())
        major, minor, angle = second_moment_ellipse(rows, cols)
        # np.nanmax([width, length]) when one is finite, in Python floats (a few us an object)
        largest = (
            max(v for v in (width, length) if not math.isnan(v))
            if math.isfinite(width) or math.isfinite(length)
            else math.nan
        )
        jump = background_jump_fraction(mask, lab_c, disp_c, jump_px=background_jump_px)
        size_class, borderline = _decide_size_class(
            float(largest),
            h_max,
            sample_max_m=sample_max_m,
            rover_clearance_m=rover_clearance_m,
            borderline_fraction=borderline_fraction,
        )
        rows_out.append(
            {
                "object_id": index,
                "area_px": rows.size,
                "centroid_x": float(cols.mean()),
                "centroid_y": float(rows.mean()),
                "bbox_x_min": int(cols.min()),
                "bbox_x_max": int(cols.max()),
                "bbox_y_near": int(rows.max()),
                "bbox_y_far": int(rows.min()),
                "range_m": z_med,
                "range_err_m": range_err,
                "x_m": x_m,
                "y_m": y_m,
                "z_m": z_m,
                "width_m": width,
                "length_m": length,
                "height_m": h_top,
                "height_max_m": h_max,
                "height_err_m": height_err,
                "width_err_m": width_err,
                "depth_valid_fraction": valid_fraction,
                "mean_gray": mean_gray,
                "polarity": polarity_against(mean_gray, gray_c[ring]),
                "texture_std": float(gray_px.std()),
                "texture_contrast": cooccurrence_contrast(gray_c, mask),
                "ellipse_major_px": major,
                "ellipse_minor_px": minor,
                "ellipse_angle_deg": angle,
                "size_class": size_class,
                "size_class_borderline": borderline,
                "touches_border": bool(
                    rows.min() == 0
                    or cols.min() == 0
                    or rows.max() == h_img - 1
                    or cols.max() == w_img - 1
                    or (near_fill is not None and near_fill[rows, cols].any())
                ),
                "occluded": jump > _BACKGROUND_OCCLUSION_SHARE,
                "depth_unreliable": valid_fraction < min_valid_fraction,
            }
        )
    if not rows_out:
        return _empty_columns()
    if border_height_quantile > 0:
        _class_border_objects(
            rows_out,
            quantile=border_height_quantile,
            sample_max_m=sample_max_m,
            rover_clearance_m=rover_clearance_m,
            borderline_fraction=borderline_fraction,
        )
    return {
        name: np.array([row[name] for row in rows_out], dtype=str if kind == "str" else kind)
        for name, kind in DESCRIPTOR_COLUMNS.items()
    }


def _class_border_objects(
    rows: list[dict[str, Any]],
    *,
    quantile: float,
    sample_max_m: float,
    rover_clearance_m: float,
    borderline_fraction: float,
) -> None:
    """Class the border-cut objects of one frame's rows again, in place, with the largest
    dimension bounded from their height (:mod:`stages._border`); their
    ``size_class_borderline`` is of that bound."""
    whole = [
        r for r in rows if not r["touches_border"] and math.isfinite(float(r["length_m"]))
    ]  # seen whole and measured on depth (a finite length)
    ratio = height_width_ratio(
        np.array([float(r["height_max_m"]) for r in whole]),
        np.array([float(r["width_m"]) for r in whole]),
        quantile=quantile,
    )
    if not math.isfinite(ratio):
        return
    for r in rows:
        if not r["touches_border"]:
            continue
        width, length = float(r["width_m"]), float(r["length_m"])
        largest = max(width, length) if math.isfinite(length) else width
        h_max = float(r["height_max_m"])
        r["size_class"], r["size_class_borderline"] = _decide_size_class(
            border_largest_bound(largest, h_max, ratio=ratio),
            h_max,
            sample_max_m=sample_max_m,
            rover_clearance_m=rover_clearance_m,
            borderline_fraction=borderline_fraction,
        )


_BACKGROUND_OCCLUSION_SHARE = 0.1
"""Share of boundary pairs with a nearer background above which an object is occluded."""
_MIN_DEPTH_PX = 3
"""Objects with fewer valid-depth pixels are measured from their silhouette on the ground."""
