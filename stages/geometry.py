"""Geometry of the depth stage: range, pseudo-left image, ground plane, height above ground.

Conventions are those of :mod:`pipeline.camera`: the reference (right) pixel at column ``x``
with disparity ``d`` is at column ``x + d`` of the other (left) image; range ``Z = f b / d``;
camera frame X right, Y down, Z forward.

Ground plane
------------
A plane ``a X + b Y + c Z + e = 0`` in the camera frame, unit normal ``(a, b, c)`` pointing
up (towards the camera, so ``e`` > 0 is the camera's height above the plane). Seen through a
parallel-axis stereo camera a plane has a disparity *linear* in the pixel coordinates,
``d = alpha x + beta y + gamma`` (``1 / Z`` is linear in the image of a plane). The plane is
therefore fitted in disparity space, where the matching noise is about the same everywhere
(about 0.1-0.5 px), instead of in metres, where it grows with the square of the range:

* with a known camera pose (height and pitch) the pose's ground plane is the start, refined
  by iterative least squares on the pixels within ``inlier_px`` of the current plane;
* without a pose (or when the pose's plane explains too few pixels), RANSAC on random
  3-pixel planes picks the plane with the most inliers, then the same least-squares
  refinement.

Rocks stand above the ground, i.e. at larger disparity than the plane, and are outliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from pipeline.camera import Camera

__all__ = [
    "GroundFit",
    "range_from_disparity",
    "disparity_from_range",
    "pseudo_left",
    "residual",
    "plane_from_pose",
    "plane_disparity_coefficients",
    "plane_from_disparity_coefficients",
    "fit_ground_plane",
    "height_above_plane",
    "height_from_disparity",
    "ground_disparity_at_row",
    "derive_max_disparity",
    "derive_row_floor",
    "derive_row_ceiling",
]


def _coerce_disparity(disparity: np.ndarray) -> np.ndarray:
    d = np.asarray(disparity)
    if d.ndim != 2:
        raise ValueError(f"disparity must be a 2-D array, got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise TypeError(f"disparity must be a float array (NaN invalid), got dtype {d.dtype}")
    return d


def _coerce_camera(camera: Camera) -> Camera:
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a pipeline.camera.Camera, got {type(camera).__name__}")
    return camera


def range_from_disparity(disparity: np.ndarray, *, focal_px: float, baseline_m: float):
    """Range ``Z = f b / d`` in metres.

    Parameters
    ----------
    disparity : (M, N) ndarray of float
        Pixels, NaN invalid.
    focal_px, baseline_m : float
        Focal length (px) and baseline (m), both > 0.

    Returns
    -------
    range : (M, N) ndarray of float32
        Metres; NaN where the disparity is invalid or not > 0 (at or beyond infinity).
    """
    d = _coerce_disparity(disparity)
    for name, value in (("focal_px", focal_px), ("baseline_m", baseline_m)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return _range_kernel(d, float(focal_px * baseline_m))


@njit(cache=True, error_model="numpy")
def _range_kernel(disparity, k):  # pragma: no cover - numba
    # (f b) / d in float64 rounded to float32 once, as np.where(d > 0, f * b / d, nan)
    # would, without its float64 frames
    h, w = disparity.shape
    out = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            d = np.float64(disparity[y, x])
            out[y, x] = np.float32(k / d) if d > 0 else np.float32(np.nan)
    return out


def disparity_from_range(range_m: np.ndarray, *, focal_px: float, baseline_m: float):
    """Inverse of :func:`range_from_disparity`: ``d = f b / Z`` (float32, NaN invalid)."""
    z = np.asarray(range_m, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(z > 0, focal_px * baseline_m / z, np.nan)
    return d.astype(np.float32)


# ----------------------------------------------------------------------------- pseudo-left


@njit(cache=True, error_model="numpy")
def _forward_warp(image, disparity):  # pragma: no cover - numba
    # Gray levels and disparities are read as float64 (exact for uint8, float32 and float64
    # inputs, so no converted copies are needed); the z-buffer is one row's, reset per row.
    # Each disparity is read and tested once (the right neighbour's becomes the next
    # pixel's), and numpy's error model drops the zero-division check `span == 0` already
    # guards: the same operations in the same order, a fifth less time.
    h, w = image.shape
    out = np.full((h, w), np.nan, np.float32)
    zrow = np.empty(w, np.float64)
    for y in range(h):
        zrow[:] = -np.inf
        d1 = np.float64(disparity[y, 0])
        finite1 = np.isfinite(d1)
        for x in range(w):
            d0, finite0 = d1, finite1
            if x + 1 < w:
                d1 = np.float64(disparity[y, x + 1])
                finite1 = np.isfinite(d1)
            else:
                finite1 = False
            if not finite0:
                continue
            u0 = x + d0
            if finite1 and abs(d1 - d0) <= 1.0:
                # a continuous surface between two neighbours: fill the left columns
                # the segment covers, interpolating gray level and disparity
                u1 = x + 1 + d1
                lo, hi = (u0, u1) if u0 <= u1 else (u1, u0)
                c0 = max(0, int(math.ceil(lo)))
                c1 = min(w - 1, int(math.floor(hi)))
                span = u1 - u0
                g0 = np.float64(image[y, x])
                step = np.float64(image[y, x + 1]) - g0
                for c in range(c0, c1 + 1):
                    t = 0.0 if span == 0 else (c - u0) / span
                    key = d0 + t * (d1 - d0)
                    if key > zrow[c]:
                        zrow[c] = key
                        out[y, c] = g0 + t * step
            else:
                c = int(math.floor(u0 + 0.5))
                if 0 <= c < w and abs(c - u0) < 0.5 and d0 > zrow[c]:
                    zrow[c] = d0
                    out[y, c] = image[y, x]
    return out


def pseudo_left(right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """Move every reference (right) pixel by its disparity into the other (left) geometry.

    Forward warp with a z-buffer: neighbouring right pixels whose disparities differ by at
    most 1 px are one continuous surface, and the left columns between their two landing
    points get linearly interpolated gray levels; where several surfaces land on the same
    left pixel the nearer one (larger disparity) wins, as it would hide the other. Left
    pixels no right pixel lands on (seen only by the left camera, or without valid
    disparity) are NaN.

    Parameters
    ----------
    right : (M, N) ndarray of uint8 or float
        Reference image.
    disparity : (M, N) ndarray of float
        Reference-geometry disparity in px, NaN invalid.

    Returns
    -------
    pseudo : (M, N) ndarray of float32
        The left image predicted from the right image and the disparity; NaN undefined.
    """
    d = _coerce_disparity(disparity)
    img = np.asarray(right)
    if img.shape != d.shape:
        raise ValueError(
            f"right image and disparity must have the same shape, got {img.shape} and {d.shape}"
        )
    # the kernel reads uint8, float32 and float64 exactly as float64; other dtypes go
    # through the float32 gray levels and float64 disparities it was written for
    if img.dtype not in (np.uint8, np.float32):
        img = img.astype(np.float32)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    return _forward_warp(img, d)


def residual(left: np.ndarray, pseudo: np.ndarray) -> np.ndarray:
    """``left - pseudo`` in gray levels (float32), NaN where ``pseudo`` is undefined."""
    lft = np.asarray(left, dtype=np.float32)
    ps = np.asarray(pseudo, dtype=np.float32)
    if lft.shape != ps.shape:
        raise ValueError(f"left and pseudo must have the same shape, got {lft.shape}, {ps.shape}")
    return np.subtract(lft, ps, dtype=np.float32)


# ----------------------------------------------------------------------------- ground plane


def plane_from_pose(*, height_m: float, pitch_deg: float) -> np.ndarray:
    """Camera-frame ground plane ``(a, b, c, e)`` of a camera ``height_m`` up, pitched down.

    The ground frame's up axis in the camera frame is ``(0, -cos p, -sin p)``, and a point's
    height is ``e + n . P`` with ``e = height_m`` (see ``Camera.camera_to_ground``).
    """
    theta = math.radians(pitch_deg)
    return np.array([0.0, -math.cos(theta), -math.sin(theta), float(height_m)])


def plane_disparity_coefficients(
    plane: np.ndarray, *, camera: Camera, shape: tuple[int, int]
) -> np.ndarray:
    """``(alpha, beta, gamma)`` with the plane's disparity ``d = alpha x + beta y + gamma``."""
    cam = _coerce_camera(camera)
    a, b, c, e = (float(v) for v in plane)
    cx, cy = cam.principal_point(shape)
    f, base = cam.focal_px, cam.baseline_m
    # Z (a (x - cx) / f + b (y - cy) / f + c) = -e  and  d = f base / Z
    scale = -base / e
    alpha = scale * a
    beta = scale * b
    gamma = scale * (c * f - a * cx - b * cy)
    return np.array([alpha, beta, gamma])


def plane_from_disparity_coefficients(
    coefficients: np.ndarray, *, camera: Camera, shape: tuple[int, int]
) -> np.ndarray:
    """Camera-frame plane ``(a, b, c, e)``, unit normal up (``e`` > 0), from ``(alpha, beta,
    gamma)``; NaN when the coefficients describe no plane in front of the camera."""
    cam = _coerce_camera(camera)
    alpha, beta, gamma = (float(v) for v in coefficients)
    cx, cy = cam.principal_point(shape)
    g = (gamma + alpha * cx + beta * cy) / cam.focal_px
    norm = math.sqrt(alpha * alpha + beta * beta + g * g)
    if not math.isfinite(norm) or norm == 0:
        return np.full(4, np.nan)
    e = cam.baseline_m / norm
    return np.array([-alpha / norm, -beta / norm, -g / norm, e])


@dataclass(frozen=True)
class GroundFit:
    """Result of :func:`fit_ground_plane`.

    Attributes
    ----------
    plane : (4,) ndarray of float64
        ``a, b, c, e`` (camera frame, unit normal up), NaN when no fit.
    inliers : (M, N) ndarray of bool
        Pixels within ``inlier_px`` of the plane's disparity.
    inlier_fraction : float
        Inliers over pixels with valid disparity (NaN when none).
    source : {'pose', 'ransac', 'none'}
        Where the starting plane came from.
    """

    plane: np.ndarray
    inliers: np.ndarray
    inlier_fraction: float
    source: str


def _refine(design, ds, coef, inlier_px, iterations=5):
    mask = np.abs(design @ coef - ds) <= inlier_px
    for _ in range(iterations):
        if np.count_nonzero(mask) < 3:
            break
        # the inliers' rows by index: the same arrays as boolean indexing, at a tenth of
        # its cost (a boolean row gather over a random mask is the slowest step here)
        rows = np.flatnonzero(mask)
        coef, *_ = np.linalg.lstsq(design.take(rows, axis=0), ds.take(rows), rcond=None)
        new_mask = np.abs(design @ coef - ds) <= inlier_px
        if np.array_equal(new_mask, mask):
            break
        mask = new_mask
    return coef, mask


def _ransac(design, ds, inlier_px, iterations, rng):
    n = ds.size
    best_coef, best_count = None, -1
    for _ in range(iterations):
        pick = rng.choice(n, size=3, replace=False)
        try:
            coef = np.linalg.solve(design[pick], ds[pick])
        except np.linalg.LinAlgError:
            continue
        count = np.count_nonzero(np.abs(design @ coef - ds) <= inlier_px)
        if count > best_count:
            best_coef, best_count = coef, count
    return best_coef


def fit_ground_plane(
    disparity: np.ndarray,
    *,
    camera: Camera,
    inlier_px: float = 1.0,
    ransac_iterations: int = 200,
    sample_px: int = 20000,
    min_pose_inliers: float = 0.3,
    seed: int = 0,
) -> GroundFit:
    """Fit the ground plane to a disparity map (see the module docstring).

    Parameters
    ----------
    disparity : (M, N) ndarray of float
        Reference-geometry disparity, NaN invalid.
    camera : pipeline.camera.Camera
        Focal length, baseline, optional pose (height and pitch).
    inlier_px : float
        Largest |disparity - plane disparity| (px) of a ground pixel, > 0.
    ransac_iterations : int
        Random 3-pixel planes tried without a usable pose.
    sample_px : int
        At most this many valid pixels (a fixed-seed random sample) enter the fit.
    min_pose_inliers : float in [0, 1]
        The pose's plane must explain this share of the valid pixels to be the start;
        otherwise RANSAC is used.
    seed : int
        Seed of the sampling (the fit is deterministic).

    Returns
    -------
    GroundFit
    """
    # no float64 copy of the frame: float32 (or float64) values compare and convert alike
    d = _coerce_disparity(disparity)
    cam = _coerce_camera(camera)
    if not (math.isfinite(inlier_px) and inlier_px > 0):
        raise ValueError(f"inlier_px must be a finite number > 0, got {inlier_px!r}")
    shape = d.shape
    valid = np.isfinite(d) & (d > 0)
    flat = np.flatnonzero(valid)  # row-major, as np.nonzero; rows and columns of the sample only
    n_valid = int(flat.size)
    none = GroundFit(np.full(4, np.nan), np.zeros(shape, bool), float("nan"), "none")
    if n_valid < 3:
        return none
    rng = np.random.default_rng(seed)
    if n_valid > sample_px:
        flat = flat[np.sort(rng.choice(n_valid, size=sample_px, replace=False))]
    ys_s, xs_s = np.divmod(flat, shape[1])
    xs, ys, ds = xs_s.astype(float), ys_s.astype(float), d.ravel().take(flat).astype(np.float64)
    design = np.column_stack([xs, ys, np.ones_like(xs)])
    coef, source = None, "none"
    if cam.has_pose:
        assert cam.height_m is not None and cam.pitch_deg is not None
        start = plane_disparity_coefficients(
            plane_from_pose(height_m=cam.height_m, pitch_deg=cam.pitch_deg),
            camera=cam, shape=shape,
        )  # fmt: skip
        # a generous first band absorbs a slightly wrong pose before narrowing
        refined, _ = _refine(design, ds, start, 3.0 * inlier_px)
        refined, mask = _refine(design, ds, refined, inlier_px)
        if np.count_nonzero(mask) >= min_pose_inliers * xs.size:
            coef, source = refined, "pose"
    if coef is None:
        start = _ransac(design, ds, inlier_px, ransac_iterations, rng)
        if start is None:
            return none
        coef, _ = _refine(design, ds, start, inlier_px)
        source = "ransac"
    plane = plane_from_disparity_coefficients(coef, camera=cam, shape=shape)
    if not np.all(np.isfinite(plane)):
        return none
    inliers, count = _plane_inliers(d, *(float(v) for v in coef), float(inlier_px))
    return GroundFit(plane, inliers, float(count) / n_valid, source)


@njit(cache=True)
def _plane_inliers(disparity, alpha, beta, gamma, inlier_px):  # pragma: no cover - numba
    """Valid pixels within ``inlier_px`` of the plane's disparity and their count: per pixel
    ``|((alpha x + beta y) + gamma) - d| <= inlier_px`` in float64, the operations and order
    of the broadcast numpy expression it replaces."""
    h, w = disparity.shape
    inliers = np.zeros((h, w), np.bool_)
    count = 0
    for y in range(h):
        row = beta * np.float64(y)
        for x in range(w):
            d = np.float64(disparity[y, x])
            near = abs(alpha * np.float64(x) + row + gamma - d) <= inlier_px
            inside = np.isfinite(d) and d > 0 and near
            inliers[y, x] = inside
            count += inside
    return inliers, count


def height_above_plane(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Signed distance (m) of camera-frame points ``(..., 3)`` above ``plane`` (float32)."""
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"points must have a last axis of 3 (X, Y, Z), got shape {p.shape}")
    a, b, c, e = (float(v) for v in plane)
    return (p[..., 0] * a + p[..., 1] * b + p[..., 2] * c + e).astype(np.float32)


def height_from_disparity(
    disparity: np.ndarray, plane: np.ndarray, *, camera: Camera
) -> np.ndarray:
    """Height (m) above ``plane`` of each pixel's back-projected point.

    ``height_above_plane(camera.camera_points(disparity), plane)`` without the (M, N, 3)
    points: the same operations per pixel in the same order, so the same float32 bits
    (``tests/stages/test_geometry.py`` compares them), in one numba pass without float64
    frames (the depth stage's height product).

    Parameters
    ----------
    disparity : (M, N) ndarray of float
        Pixels, NaN (or <= 0) where invalid.
    plane : (4,) array of float
        ``a, b, c, e`` in the camera frame.
    camera : pipeline.camera.Camera

    Returns
    -------
    (M, N) ndarray of float32
        NaN where the disparity is invalid.
    """
    cam = _coerce_camera(camera)
    d = np.asarray(disparity)
    if d.dtype not in (np.float32, np.float64):  # the kernel reads these exactly as float64
        d = d.astype(np.float64)
    if d.ndim != 2:
        raise ValueError(f"disparity must be a 2-D array, got shape {d.shape}")
    a, b, c, e = (float(v) for v in plane)
    cx, cy = cam.principal_point(d.shape)
    return _height_kernel(d, cam.k_m_px, cam.focal_px, float(cx), float(cy), a, b, c, e)


@njit(cache=True, error_model="numpy")
def _height_kernel(disparity, k, f, cx, cy, a, b, c, e):  # pragma: no cover - numba
    # x = (col - cx) z / f and y = (row - cy) z / f as in Camera.camera_points, then
    # ((x a + y b) + z c) + e as in height_above_plane: the same float64 operations in the
    # same order per pixel, rounded to float32 once; NaN where d is not > 0
    h, w = disparity.shape
    out = np.empty((h, w), np.float32)
    for y in range(h):
        row = np.float64(y) - cy
        for x in range(w):
            d = np.float64(disparity[y, x])
            z = k / d
            px = (np.float64(x) - cx) * z / f
            py = row * z / f
            height = px * a + py * b + z * c + e
            out[y, x] = np.float32(height) if d > 0 else np.float32(np.nan)
    return out


# ----------------------------------------------------------------------------- search range


def ground_disparity_at_row(camera: Camera, *, row: float, shape: tuple[int, int]) -> float:
    """Disparity (px) of the ground seen at image row ``row`` (pose required; <= 0 above
    the horizon)."""
    cam = _coerce_camera(camera)
    if not cam.has_pose:
        raise ValueError("ground_disparity_at_row needs camera height_m and pitch_deg")
    assert cam.height_m is not None and cam.pitch_deg is not None
    plane = plane_from_pose(height_m=cam.height_m, pitch_deg=cam.pitch_deg)
    alpha, beta, gamma = plane_disparity_coefficients(plane, camera=cam, shape=shape)
    cx, _ = cam.principal_point(shape)
    return float(alpha * cx + beta * row + gamma)


def derive_max_disparity(
    camera: Camera,
    *,
    shape: tuple[int, int],
    nearest_range_m: float = 0.0,
    margin: float = 0.25,
    fallback: int = 64,
) -> int:
    """Largest disparity worth searching, from the camera.

    Parameters
    ----------
    camera : pipeline.camera.Camera
    shape : (int, int)
        Image shape ``(M, N)``.
    nearest_range_m : float
        Nearest range (m) anything can be at; 0 = unknown. Gives ``f b / nearest_range_m``.
    margin : float
        Relative margin for objects standing above the ground (rocks are nearer than the
        ground behind them), applied to the pose-derived value.
    fallback : int
        Used when neither a nearest range nor a pose is known.

    Returns
    -------
    max_disparity : int
        With a nearest range: ``ceil(f b / nearest_range_m)``. Otherwise, with a pose: the
        ground's disparity at the bottom image row (the nearest visible ground point) times
        ``1 + margin``, plus 2 px. Otherwise ``fallback``. Never more than ``N - 1``.
    """
    cam = _coerce_camera(camera)
    h, w = shape
    if nearest_range_m > 0:
        value = math.ceil(cam.k_m_px / nearest_range_m)
    elif cam.has_pose:
        bottom = ground_disparity_at_row(cam, row=h - 1, shape=shape)
        value = math.ceil(max(bottom, 1.0) * (1.0 + margin)) + 2
    else:
        value = fallback
    return int(max(3, min(value, w - 1)))


def derive_row_floor(
    camera: Camera,
    *,
    shape: tuple[int, int],
    margin: float = 0.25,
    slack_px: float = 2.0,
) -> np.ndarray | None:
    """Least disparity worth searching in each image row (the row's *floor*), from the pose.

    Why: nothing the camera sees lies below the ground, so at a given row nothing is
    farther than the ground seen there, and no disparity is smaller than the ground's (rocks
    stand above it: nearer, larger). Near the top of a forward-pitched frame that rules out
    most of the range (mojave: ground 5.7 px at the top row, 38 px at the bottom, range up
    to 51 px). The margin keeps ground that dips below the pose's plane (a wrong pitch or
    height, hollows): the floor is ``(1 - margin) g(y) - slack_px`` rounded down, ``g(y)``
    the pose plane's least disparity along the row (:func:`ground_disparity_at_row`).

    Parameters
    ----------
    camera : pipeline.camera.Camera
    shape : (int, int)
        Image shape ``(M, N)``.
    margin : float in [0, 1]
        Relative margin below the ground's disparity; 1 gives no floor above ``-slack_px``.
    slack_px : float
        Absolute margin (px), >= 0.

    Returns
    -------
    floor : (M,) ndarray of int64 or None
        None without a pose (height and pitch).
    """
    cam = _coerce_camera(camera)
    if not 0.0 <= margin <= 1.0 or not slack_px >= 0.0:
        raise ValueError(
            f"margin must be in [0, 1] and slack_px >= 0, got margin={margin}, "
            f"slack_px={slack_px}"
        )
    rows = _pose_ground_by_row(cam, shape)
    if rows is None:
        return None
    lowest, _highest = rows
    return np.floor((1.0 - margin) * lowest - slack_px).astype(np.int64)


def derive_row_ceiling(
    camera: Camera,
    *,
    shape: tuple[int, int],
    ratio: float = 2.0,
    slack_px: float = 2.0,
) -> np.ndarray | None:
    """Largest disparity worth searching for ground-like surfaces in each row (its *ceiling*).

    Why: along the ray of a row, a point ``z`` above the ground has ``1 / (1 - z / h)``
    times the disparity of the ground seen there (``h`` the camera height), so a ceiling of
    ``ratio`` times the ground's disparity admits objects up to ``(1 - 1 / ratio) h`` tall
    (ratio 2: half the camera height, 0.6 m in the built-in archives, where no truth pixel
    exceeds 1.25 times the ground's disparity + 2 px). The stage's ``max_disparity``
    already assumes 1.25 times the ground's disparity at the bottom row.

    Parameters
    ----------
    camera : pipeline.camera.Camera
    shape : (int, int)
        Image shape ``(M, N)``.
    ratio : float
        >= 1; the ceiling is ``ratio g(y) + slack_px`` rounded up, ``g(y)`` the pose plane's
        largest disparity along the row.
    slack_px : float
        Absolute margin (px), >= 0.

    Returns
    -------
    ceiling : (M,) ndarray of int64 or None
        None without a pose (height and pitch).
    """
    cam = _coerce_camera(camera)
    if not ratio >= 1.0 or not slack_px >= 0.0:
        raise ValueError(
            f"ratio must be >= 1 and slack_px >= 0, got ratio={ratio}, slack_px={slack_px}"
        )
    rows = _pose_ground_by_row(cam, shape)
    if rows is None:
        return None
    _lowest, highest = rows
    return np.ceil(ratio * np.maximum(highest, 0.0) + slack_px).astype(np.int64)


def _pose_ground_by_row(
    cam: Camera, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray] | None:
    """The pose plane's least and largest disparity along each image row; None without a
    pose. (With the pose's zero roll the column term ``alpha`` is 0 and both are equal.)"""
    if not cam.has_pose:
        return None
    assert cam.height_m is not None and cam.pitch_deg is not None
    plane = plane_from_pose(height_m=cam.height_m, pitch_deg=cam.pitch_deg)
    alpha, beta, gamma = plane_disparity_coefficients(plane, camera=cam, shape=shape)
    base = beta * np.arange(shape[0]) + gamma
    across = alpha * (shape[1] - 1)
    return base + min(0.0, across), base + max(0.0, across)
