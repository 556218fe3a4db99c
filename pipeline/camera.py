"""Stereo camera model shared by the catalog, the stages and the renderer.

Conventions (used everywhere in arroyo):

* Pixel coordinates ``(x, y)``: column, row; origin top-left; principal point at the image
  centre ``((W - 1) / 2, (H - 1) / 2)`` unless given.
* Camera frame of the reference camera: ``X`` right, ``Y`` down, ``Z`` forward along the
  optical axis. Both cameras have parallel optical axes, separated by ``baseline_m`` along X.
* Disparity ``d > 0`` in pixels: the point seen at column ``x`` in the right (reference) image
  is at column ``x + d`` in the left image. ``Z = focal_px * baseline_m / d`` ("range" in the
  study: depth along the optical axis, metres).
* Ground frame: origin on the ground directly below the reference camera, ``x_g`` right,
  ``y_g`` forward (horizontal), ``z_g`` up. The camera is ``height_m`` above the ground and its
  optical axis is pitched down by ``pitch_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

__all__ = ["Camera", "CAMERA_FIELDS"]


@dataclass(frozen=True)
class Camera:
    """Parallel-axis stereo camera.

    Parameters
    ----------
    focal_px : float
        Focal length in pixels, > 0.
    baseline_m : float
        Separation of the two optical axes in metres, > 0.
    height_m : float, optional
        Height of the optical centre above the ground, metres.
    pitch_deg : float, optional
        Downward tilt of the optical axes, degrees in [0, 90).
    reference : {'right', 'left'}
        Which image is the reference geometry of all products ('right' in the study).
    cx, cy : float, optional
        Principal point in pixels; the image centre when not given.
    """

    focal_px: float
    baseline_m: float
    height_m: float | None = None
    pitch_deg: float | None = None
    reference: str = "right"
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        for name in ("focal_px", "baseline_m"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise TypeError(f"camera {name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise ValueError(
                    f"camera {name} must be a finite number > 0, got {value!r}; "
                    "set a positive value in the catalog's [camera] table"
                )
        if self.height_m is not None and not (math.isfinite(self.height_m) and self.height_m > 0):
            raise ValueError(f"camera height_m must be > 0 when given, got {self.height_m!r}")
        if self.pitch_deg is not None and not (0 <= self.pitch_deg < 90):
            raise ValueError(f"camera pitch_deg must be in [0, 90), got {self.pitch_deg!r}")
        if self.reference not in ("right", "left"):
            raise ValueError(f"camera reference must be 'right' or 'left', got {self.reference!r}")

    @property
    def k_m_px(self) -> float:
        """The study's constant K = focal length x baseline (range = K / disparity)."""
        return self.focal_px * self.baseline_m

    @property
    def has_pose(self) -> bool:
        """True when height and pitch are known, so ground coordinates follow directly."""
        return self.height_m is not None and self.pitch_deg is not None

    def principal_point(self, shape: tuple[int, int]) -> tuple[float, float]:
        """``(cx, cy)`` for an image of ``shape = (H, W)``."""
        h, w = shape
        cx = (w - 1) / 2.0 if self.cx is None else self.cx
        cy = (h - 1) / 2.0 if self.cy is None else self.cy
        return cx, cy

    def with_overrides(self, overrides: dict[str, Any]) -> Camera:
        """A copy with some fields replaced (per-frame overrides from the frame index)."""
        return replace(self, **overrides) if overrides else self

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def camera_points(self, disparity: np.ndarray) -> np.ndarray:
        """Back-project a disparity map to camera-frame points.

        Parameters
        ----------
        disparity : (M, N) ndarray of float
            Disparity in pixels, NaN (or <= 0) where invalid.

        Returns
        -------
        points : (M, N, 3) ndarray of float64
            ``X, Y, Z`` in metres, NaN where the disparity is invalid.
        """
        d = np.asarray(disparity, dtype=np.float64)
        if d.ndim != 2:
            raise ValueError(f"disparity must be a 2-D array, got shape {d.shape}")
        d = np.where(d > 0, d, np.nan)
        cx, cy = self.principal_point(d.shape)
        # written in place, and the pixel coordinates broadcast from one row and one column:
        # the same operations per pixel as full coordinate grids and a stack, without them
        points = np.empty((*d.shape, 3), dtype=np.float64)
        x, y, z = points[..., 0], points[..., 1], points[..., 2]
        np.divide(self.k_m_px, d, out=z)
        np.multiply(np.arange(d.shape[1], dtype=np.float64) - cx, z, out=x)
        np.divide(x, self.focal_px, out=x)
        np.multiply((np.arange(d.shape[0], dtype=np.float64) - cy)[:, None], z, out=y)
        np.divide(y, self.focal_px, out=y)
        return points

    def camera_to_ground(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(..., 3)`` to ground-frame points ``(..., 3)``.

        Needs ``height_m`` and ``pitch_deg``; raises ValueError otherwise.
        """
        if not self.has_pose:
            raise ValueError(
                "camera_to_ground needs camera height_m and pitch_deg; add them to the "
                "catalog's [camera] table or fit the ground plane from depth instead"
            )
        assert self.pitch_deg is not None and self.height_m is not None
        theta = math.radians(self.pitch_deg)
        p = np.asarray(points, dtype=np.float64)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        forward = z * math.cos(theta) - y * math.sin(theta)
        up = self.height_m - (y * math.cos(theta) + z * math.sin(theta))
        return np.stack([x, forward, up], axis=-1)


CAMERA_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(Camera))
