"""Camera geometry of the renderer; the per-view ray caster lives in ``_kernels``."""

from __future__ import annotations

import math

import numpy as np

from ._kernels import render_view

__all__ = ["render_view", "camera_axes"]


def camera_axes(pitch_deg: float) -> np.ndarray:
    """Rows: camera X (right), Y (down), Z (forward) in the ground frame (x, y, z up).

    Matches :meth:`pipeline.camera.Camera.camera_to_ground`.
    """
    th = math.radians(pitch_deg)
    return np.array(
        [
            [1.0, 0.0, 0.0],
            [0.0, -math.sin(th), -math.cos(th)],
            [0.0, math.cos(th), -math.sin(th)],
        ]
    )
