"""Ground frame and per-object depth denoising for the describe stage (pure functions).

Ground frame
------------
Positions and heights are expressed in the ground frame of ``pipeline/camera.py`` (x right,
y forward, z up, origin on the ground below the reference camera). When the camera height
and pitch are known, ``Camera.camera_to_ground`` defines it; otherwise the depth stage's
fitted ground plane does (:meth:`GroundFrame.from_plane`): z along the plane's unit normal,
y along the optical axis projected on the plane, x = y cross z, origin at the foot of the
camera on the plane.

Depth denoising
---------------
Stereo disparity carries about half a pixel of noise; at a 7 cm baseline that is several
centimetres of range, as much as a small rock's size. Extents and maxima taken over noisy
3D points are therefore inflated (the footprint of a 10 cm rock came out 50 % too wide in
the lab archive). :func:`fit_disparity_surface` replaces an object's disparities by a robust
quadratic surface in image coordinates (Huber-weighted least squares), which keeps the
rock's shape to first and second order and averages the noise over all its pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.camera import Camera

from ._small_stats import _huber_weights, _median64, back_project

try:  # the LAPACK gufunc np.linalg.solve calls, private to numpy
    from numpy.linalg import _umath_linalg

    _lapack_solve1: Any = _umath_linalg.solve1
    _lapack_eigvalsh: Any = _umath_linalg.eigvalsh_lo
except (ImportError, AttributeError):  # pragma: no cover - a numpy that moved it
    _lapack_solve1 = _lapack_eigvalsh = None  # the public calls then, same bits

__all__ = [
    "GroundFrame",
    "coerce_ground_plane",
    "frame_ground",
    "fit_disparity_surface",
    "pixel_points",
    "silhouette_on_ground",
]

_HUBER_K = 2.0  # residuals beyond 2 robust sigmas are down-weighted
_REJECT_K = 4.0  # ... and beyond 4, from the second round on, dropped


@dataclass(frozen=True)
class GroundFrame:
    """A ground-aligned frame expressed in reference-camera coordinates.

    Attributes
    ----------
    origin : (3,) ndarray of float64
        Ground-frame origin (on the ground below the camera), camera frame, metres.
    right, forward, up : (3,) ndarray of float64
        Unit axes x, y, z of the ground frame in the camera frame (right = forward x up).
    source : {'camera', 'plane'}
        Whether the camera pose or the fitted ground plane defined the frame.
    """

    origin: np.ndarray
    right: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    source: str

    @classmethod
    def from_camera(cls, camera: Camera) -> GroundFrame:
        """The frame ``Camera.camera_to_ground`` uses (needs height_m and pitch_deg)."""
        if not camera.has_pose:
            raise ValueError(
                "GroundFrame.from_camera needs camera height_m and pitch_deg; got "
                f"height_m={camera.height_m!r}, pitch_deg={camera.pitch_deg!r}; "
                "use GroundFrame.from_plane with a fitted ground plane instead"
            )
        assert camera.pitch_deg is not None and camera.height_m is not None
        theta = math.radians(camera.pitch_deg)
        up = np.array([0.0, -math.cos(theta), -math.sin(theta)])
        forward = np.array([0.0, -math.sin(theta), math.cos(theta)])
        return cls(-camera.height_m * up, np.cross(forward, up), forward, up, "camera")

    @classmethod
    def from_plane(cls, plane: np.ndarray) -> GroundFrame:
        """Frame from a plane ``a X + b Y + c Z + d = 0`` (camera frame, normal pointing up).

        Parameters
        ----------
        plane : (4,) array_like of float
            Plane coefficients; ``(a, b, c)`` is normalised here, ``d > 0`` puts the camera
            above the ground.
        """
        coef = np.asarray(plane, dtype=np.float64).reshape(-1)
        if coef.shape != (4,) or not np.all(np.isfinite(coef)):
            raise ValueError(
                f"ground plane must be 4 finite numbers (a, b, c, d), got {coef.tolist()}"
            )
        norm = float(np.linalg.norm(coef[:3]))
        if norm == 0.0:
            raise ValueError("ground plane normal (a, b, c) must not be zero")
        up, d = coef[:3] / norm, coef[3] / norm
        if d <= 0:
            raise ValueError(
                f"ground plane must have the camera above it (d > 0 with the normal up), got "
                f"d={d:.4g}; flip the sign of all four coefficients if the normal points down"
            )
        axis = np.array([0.0, 0.0, 1.0])
        forward = axis - (axis @ up) * up
        if np.linalg.norm(forward) < 1e-9:  # looking straight down: image up is forward
            axis = np.array([0.0, -1.0, 0.0])
            forward = axis - (axis @ up) * up
        forward /= np.linalg.norm(forward)
        return cls(-d * up, np.cross(forward, up), forward, up, "plane")

    @property
    def camera_height_m(self) -> float:
        """Height of the camera above the ground plane, metres."""
        return float(-(self.up @ self.origin))

    def to_ground(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(..., 3)`` to ground-frame points ``(..., 3)``."""
        rel = np.asarray(points, dtype=np.float64) - self.origin
        return _columns(rel @ self.right, rel @ self.forward, rel @ self.up)


def _median(values: np.ndarray) -> np.float64:
    """``np.median`` of a 1-D float array (same partition, same value) without its overhead.

    The describe stage takes thousands of medians of small arrays per frame; the generic
    ``np.median`` spends most of its time in argument handling. Float64 and integer values
    go to a compiled selection (:func:`stages._small_stats.median64`, the same value).
    """
    values = np.ravel(values)
    size = values.size
    if size == 0:
        return np.float64(np.median(values))  # NaN with numpy's own warning
    if values.dtype == np.float64 or values.dtype.kind in "iu":
        # compiled (stages._small_stats); float32 sums would be float32 here, so not those
        return np.float64(_median64(values.astype(np.float64)))  # a copy: it reorders
    half = size // 2
    kth = [half - 1, half, -1] if size % 2 == 0 else [half, -1]
    part = values.copy(order="K")  # np.partition's own steps, without its dispatch
    part.partition(kth)
    if np.isnan(part[-1]):
        return np.float64(np.nan)
    # np.mean's sum starts from +0.0: a median of -0.0 comes out as +0.0 there, and here
    if size % 2:
        return np.float64(0.0 + part[half])
    return np.float64((0.0 + part[half - 1] + part[half]) / 2.0)


def coerce_ground_plane(ground_plane: Any) -> np.ndarray | None:
    """The plane as 4 finite float64 coefficients, or None (absent or not fitted)."""
    if ground_plane is None:
        return None
    coef = np.asarray(ground_plane, dtype=np.float64).reshape(-1)
    if coef.shape != (4,):
        raise ValueError(
            f"ground_plane must hold 4 coefficients (a, b, c, d), got shape {coef.shape}"
        )
    return coef if np.all(np.isfinite(coef)) else None


def frame_ground(camera: Camera, ground_plane: np.ndarray | None) -> GroundFrame | None:
    """The ground frame of a frame: camera pose first, else fitted plane, else None.

    Parameters
    ----------
    camera : Camera
    ground_plane : (4,) array_like of float, optional
        Fitted plane; NaN coefficients mean no fit.
    """
    if camera.has_pose:
        return GroundFrame.from_camera(camera)
    plane = coerce_ground_plane(ground_plane)
    return GroundFrame.from_plane(plane) if plane is not None else None


def pixel_points(
    rows: np.ndarray, cols: np.ndarray, disparity: np.ndarray, *, camera: Camera, shape
) -> np.ndarray:
    """Camera-frame points ``(K, 3)`` of pixels with the given disparities.

    The per-pixel form of ``Camera.camera_points`` (same conventions, NaN where the
    disparity is not positive).

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
    disparity : (K,) ndarray of float
    camera : Camera
    shape : (int, int)
        Image shape, for the principal point.
    """
    cx, cy = camera.principal_point(tuple(shape))
    if np.ndim(disparity) == 1 and np.shape(rows) == np.shape(cols) == np.shape(disparity):
        # compiled (a few thousand calls per frame), numpy's arithmetic
        return back_project(
            rows, cols, disparity, k_m_px=camera.k_m_px, focal_px=camera.focal_px, cx=cx, cy=cy
        )
    d = np.asarray(disparity, dtype=np.float64)
    d = np.where(d > 0, d, np.nan)
    z = camera.k_m_px / d
    x = (np.asarray(cols, dtype=np.float64) - cx) * z / camera.focal_px
    y = (np.asarray(rows, dtype=np.float64) - cy) * z / camera.focal_px
    return _columns(x, y, z)


def _columns(*columns: np.ndarray) -> np.ndarray:
    """``np.stack(columns, axis=-1)`` of equal-shape float64 arrays, without its argument
    handling (describe stacks a few hundred small arrays per frame)."""
    first = columns[0]
    out = np.empty((*first.shape, len(columns)))
    for k, column in enumerate(columns):
        out[..., k] = column
    return out


def _weighted_least_squares(
    a: np.ndarray, b: np.ndarray, weights: np.ndarray, *, well_conditioned: bool
) -> np.ndarray:
    """Coefficients minimising sum(w (a c - b)^2).

    The describe stage fits thousands of small surfaces per frame; solving the (p, p)
    normal equations costs a fraction of an SVD of the (K, p) design. When the design is
    ill-conditioned (``well_conditioned`` False, e.g. all pixels in one row) or the
    weights make the system singular, ``np.linalg.lstsq``'s minimum-norm solution is used.
    """
    if well_conditioned:
        aw = a * weights[:, None]
        coef = _solve(aw.T @ a, aw.T @ b)
        if np.isfinite(coef).all():
            return coef
    sw = np.sqrt(weights)
    return np.linalg.lstsq(a * sw[:, None], b * sw, rcond=None)[0]


def _solve(lhs: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(lhs, rhs)`` for a (p, p) float64 system and (p,) right-hand side:
    the LAPACK gufunc it calls, without its argument checks (a quarter of a fit's time, at
    thousands of fits per frame), so the same bits. A singular system gives NaN here instead
    of a LinAlgError; the caller runs under ``np.errstate(invalid='ignore')``.
    """
    if _lapack_solve1 is None:  # see the import
        try:
            return np.linalg.solve(lhs, rhs)
        except np.linalg.LinAlgError:
            return np.full(rhs.shape, np.nan)
    return _lapack_solve1(lhs, rhs, signature="dd->d")


def _std(values: np.ndarray) -> float:
    """``np.std`` of a non-empty 1-D float64 array: numpy's own steps (``_methods._var``),
    without its argument handling, so the same bits."""
    mean = np.add.reduce(values, keepdims=True)
    np.true_divide(mean, values.size, out=mean)
    dev = np.subtract(values, mean)
    np.square(dev, out=dev)
    return math.sqrt(np.add.reduce(dev) / values.size)


def _well_conditioned(a: np.ndarray) -> bool:
    """Whether the normal equations of design ``a`` have a condition number below 1e10."""
    normal = a.T @ a
    eig = None
    if _lapack_eigvalsh is not None:
        # np.linalg.eigvalsh's gufunc without its argument handling (one call per fit);
        # NaN where LAPACK did not converge: the public call then raises as it would
        with np.errstate(invalid="ignore"):
            eig = _lapack_eigvalsh(normal, signature="d->d")
        if not np.isfinite(eig).all():
            eig = None
    if eig is None:
        eig = np.linalg.eigvalsh(normal)  # ascending
    return bool(eig[0] > 1e-10 * eig[-1])


def fit_disparity_surface(
    rows: np.ndarray,
    cols: np.ndarray,
    disparity: np.ndarray,
    *,
    iterations: int = 5,
    min_quadratic: int = 12,
    row_only: bool = False,
) -> np.ndarray:
    """Robust quadratic surface ``d(col, row)`` through an object's disparities.

    Huber-weighted least squares (residuals beyond 2 robust sigmas down-weighted; from the
    second round on, beyond 4 robust sigmas dropped, such as a run of pixels that took the
    ground's disparity), ``iterations`` reweighting rounds. The model degrades with the
    support: a quadratic (6 terms) from ``min_quadratic`` valid pixels, a plane from 4, a
    constant (the median) below. Values
    are clamped to the range the fit takes on the valid pixels, so pixels without a valid
    disparity get a bounded extrapolation.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The object's pixels.
    disparity : (K,) ndarray of float
        Measured disparity, NaN (or <= 0) where invalid.
    iterations : int
        Reweighting rounds, >= 1.
    min_quadratic : int
        Fewest valid pixels for the quadratic terms, >= 6.
    row_only : bool
        Fit a straight line in rows, ``d = a + b row``, instead (``min_quadratic`` does not
        apply): the disparity is constant along each image row. The footprint of
        :func:`stages._descriptors.describe_objects` asks for it, see
        :func:`stages._footprint.footprint_disparity`.

    Returns
    -------
    (K,) ndarray of float64
        Smoothed disparity for every pixel; all NaN when none is valid.
    """
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations!r}")
    if min_quadratic < 6:
        raise ValueError(
            f"min_quadratic must be >= 6 (a quadratic has 6 terms), got {min_quadratic!r}"
        )
    d = np.asarray(disparity, dtype=np.float64)
    r = np.asarray(rows, dtype=np.float64)
    c = np.asarray(cols, dtype=np.float64)
    if not (d.shape == r.shape == c.shape) or d.ndim != 1:
        raise ValueError(
            f"rows, cols and disparity must be equal 1-D arrays, got {r.shape}, {c.shape}, "
            f"{d.shape}"
        )
    ok = np.isfinite(d) & (d > 0)
    n = int(ok.sum())
    if n == 0:
        return np.full(d.shape, np.nan)
    if n < 4:
        return np.full(d.shape, float(_median(d[ok])))
    scale = max(_std(c), _std(r), 1.0)
    # np.mean of a float64 array is its add.reduce over the count, in float64
    x, y = (c - np.add.reduce(c) / c.size) / scale, (r - np.add.reduce(r) / r.size) / scale
    if row_only:
        terms = [y]
    else:
        terms = [x, y]
        if n >= min_quadratic:
            terms += [x * x, x * y, y * y]
    # filled column by column: the array np.stack(axis=1) made, without its overhead
    design = np.empty((d.size, 1 + len(terms)))
    design[:, 0] = 1.0
    for k, term in enumerate(terms, start=1):
        design[:, k] = term
    a, b = design[ok], d[ok]
    weights = np.ones(n)
    coef = np.zeros(design.shape[1])
    conditioned = _well_conditioned(a)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
        for round_ in range(iterations):  # (np.linalg.solve's error state, see _solve)
            coef = _weighted_least_squares(a, b, weights, well_conditioned=conditioned)
            # residuals beyond _HUBER_K robust sigmas down-weighted; once the fit is near
            # (round >= 1), beyond _REJECT_K dropped: gross outliers get no say at all
            # (compiled, numpy's arithmetic; the products a @ coef stay numpy's BLAS)
            weights = _huber_weights(
                b, a @ coef, _HUBER_K, _REJECT_K, round_ >= 1
            )
    fitted = design @ coef
    on_valid = fitted[ok]
    return np.clip(fitted, on_valid.min(), on_valid.max())


def silhouette_on_ground(
    rows: np.ndarray, cols: np.ndarray, *, camera: Camera, ground: GroundFrame, shape
) -> dict[str, float]:
    """Size and place of an object without depth, from its silhouette and the ground plane.

    The object is assumed to stand on the ground: the ray through the middle of its lowest
    row (at the pixel's lower edge) meets the ground at its base point B. Its width is the
    widest row span at B's depth. Its height comes from the ray through the top of the
    silhouette, which grazes the rock: the rock is taken as a half-ellipse in the vertical
    plane of the line of sight, as deep as it is wide (horizontal semi-axis width / 2,
    centred that far beyond B), and its height is the one that makes the ellipse tangent
    to that ray (0 when the ray meets the ground before the centre). Reading the height off
    the ray straight above B instead treats the rock as a wall facing the camera and
    overstates low rocks seen from above several times. A rough fallback for objects the
    matcher left without depth.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The object's pixels, K >= 1.
    camera : Camera
    ground : GroundFrame
    shape : (int, int)
        Image shape.

    Returns
    -------
    dict
        ``range_m`` (camera Z of B), ``x_m``, ``y_m`` (B on the ground), ``width_m``,
        ``height_m``; NaN values where the rays miss (base above the horizon).
    """
    r = np.asarray(rows, dtype=np.int64)
    c = np.asarray(cols, dtype=np.int64)
    nan = {k: math.nan for k in ("range_m", "x_m", "y_m", "width_m", "height_m")}
    if r.size == 0:
        return nan
    cx, cy = camera.principal_point(tuple(shape))
    f = camera.focal_px
    centre = ground.to_ground(np.zeros(3))

    def ray(col: float, row: float) -> np.ndarray:
        direction = np.array([(col - cx) / f, (row - cy) / f, 1.0])
        return np.array(
            [direction @ ground.right, direction @ ground.forward, direction @ ground.up]
        )

    bottom, top = int(r.max()), int(r.min())
    base_dir = ray(float(c[r == bottom].mean()), bottom + 0.5)
    if base_dir[2] >= 0:
        return nan
    t_base = -centre[2] / base_dir[2]  # ray parameter = camera depth Z
    base = centre + t_base * base_dir
    uniq, inverse = np.unique(r, return_inverse=True)
    cmin = np.full(uniq.size, np.iinfo(np.int64).max)
    cmax = np.full(uniq.size, np.iinfo(np.int64).min)
    np.minimum.at(cmin, inverse, c)
    np.maximum.at(cmax, inverse, c)
    width = float((cmax - cmin + 1).max() * t_base / f)
    top_dir = ray(float(c[r == top].mean()), top - 0.5)
    height = math.nan
    run = math.hypot(top_dir[0], top_dir[1])  # horizontal progress per unit of Z
    if run > 0 and top_dir[2] < 0:
        # the rock as a half-ellipse in the vertical plane of the line of sight, as deep as
        # it is wide (semi-axis R = width / 2, centre R beyond the base point B), tangent to
        # the ray through the top of the silhouette: for a line z = z0 - m (s - s_c) and
        # the ellipse (s - s_c)^2 / R^2 + z^2 / h^2 = 1, tangency means z0^2 = h^2 + m^2 R^2
        semi = width / 2.0
        slope = -top_dir[2] / run
        s_centre = math.hypot(base[0] - centre[0], base[1] - centre[1]) + semi
        z0 = float(centre[2]) - slope * s_centre
        height = math.sqrt(max(z0 * z0 - (slope * semi) ** 2, 0.0)) if z0 > 0 else 0.0
    return {
        "range_m": float(t_base),
        "x_m": float(base[0]),
        "y_m": float(base[1]),
        "width_m": width,
        "height_m": height,
    }
