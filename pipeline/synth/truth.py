"""The answer key of a rendered frame: dense labels and the rock table.

Rock dimensions are measured on the rock solids themselves (vertical rays through a grid of
columns over each rock), independently of any image, so tests can check the per-pixel
ground truth against them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._kernels import ROCK_FIELDS, rock_columns, rock_extents

__all__ = ["measure_rock", "dense_labels", "rock_table", "SAMPLE_MAX_M"]

SAMPLE_MAX_M = 0.10  # 'sample' when both width and height are at most this; else 'obstacle'
_COLUMNS = 24
_IDX = {n: i for i, n in enumerate(ROCK_FIELDS)}
_ANGLES = np.radians(np.arange(0.0, 180.0, 3.0))  # 60 directions for the extents
_COS, _SIN = np.cos(_ANGLES), np.sin(_ANGLES)


def measure_rock(rock: np.ndarray, perm: np.ndarray, ground: np.ndarray) -> dict[str, float]:
    """Dimensions of one rock from vertical rays through a grid of columns.

    Parameters
    ----------
    rock : (len(ROCK_FIELDS),) ndarray of float64
    perm : (512,) ndarray of int64
    ground : (len(GROUND_FIELDS),) ndarray of float64

    Returns
    -------
    dict
        ``x_m, y_m, z_m`` (base centre: rock centre on the ground), ``width_m`` (largest
        horizontal dimension of the part above the ground), ``length_m`` (dimension across
        it), ``extent_x_m``, ``extent_y_m`` (along the ground axes), ``height_m`` (highest
        point above the plane z = 0), ``buried_fraction`` (volume share below the ground).
    """
    cx, cy, cz = (float(rock[_IDX[k]]) for k in ("cx", "cy", "cz"))
    radius = float(rock[_IDX["radius"]])
    xs, top, bottom, floor = rock_columns(rock, perm, ground, _COLUMNS, cx, cy, cz, radius)
    volume, below, top_max, extents_arr = rock_extents(xs, top, bottom, floor, _COS, _SIN)
    k = int(np.argmax(extents_arr))
    return {
        "x_m": cx,
        "y_m": cy,
        "z_m": float(floor[_COLUMNS // 2, _COLUMNS // 2]),
        "width_m": float(extents_arr[k]),
        "length_m": float(extents_arr[(k + 30) % 60]),
        "extent_x_m": float(extents_arr[0]),
        "extent_y_m": float(extents_arr[30]),
        "height_m": 0.0 if np.isnan(top_max) else float(top_max),
        "buried_fraction": float(below / volume) if volume > 0 else 1.0,
    }


def dense_labels(solid: np.ndarray, zcam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Relabel ray-caster solids (0 ground, k + 1 rock k) to 1..n, nearest rock first.

    Returns
    -------
    labels : (H, W) ndarray of int32
    rock_index : (n,) ndarray of int64
        Scene index of the rock behind label ``i + 1``.
    """
    rock_px = solid > 0
    ids = solid[rock_px].astype(np.int64) - 1
    if ids.size == 0:
        return np.zeros(solid.shape, dtype=np.int32), np.zeros(0, dtype=np.int64)
    present, inverse, counts = np.unique(ids, return_inverse=True, return_counts=True)
    mean_z = np.bincount(inverse, weights=zcam[rock_px]) / counts
    order = np.lexsort((present, mean_z))
    new_label = np.empty(len(present), dtype=np.int32)
    new_label[order] = np.arange(1, len(present) + 1, dtype=np.int32)
    labels = np.zeros(solid.shape, dtype=np.int32)
    labels[rock_px] = new_label[inverse]
    return labels, present[order]


def rock_table(
    labels: np.ndarray,
    rock_index: np.ndarray,
    zcam: np.ndarray,
    rocks: np.ndarray,
    perm: np.ndarray,
    ground: np.ndarray,
    ground_albedo: float,
) -> list[dict]:
    """One row per rock visible in the reference image (see docs/synth.md for columns)."""
    rows = []
    n = len(rock_index)
    flat = labels.ravel()
    # per-label pixel lists in one pass (a mask per rock costs a full-frame scan each)
    order = np.argsort(flat, kind="stable")
    bounds = np.searchsorted(flat[order], np.arange(1, n + 2))
    zflat = zcam.ravel()
    border = np.zeros_like(labels, dtype=bool)
    border[0, :] = border[-1, :] = border[:, 0] = border[:, -1] = True
    on_border = np.zeros(n + 1, dtype=bool)
    on_border[labels[border]] = True
    for i, k in enumerate(rock_index):
        pixels = order[bounds[i] : bounds[i + 1]]  # row-major order, as a boolean mask takes them
        rock = rocks[k]
        row: dict[str, Any] = {"rock_id": i + 1}
        row.update(measure_rock(rock, perm, ground))
        albedo = float(rock[_IDX["albedo"]])
        width, height = row["width_m"], row["height_m"]
        row.update(
            range_m=float(zflat[pixels].mean()),
            albedo=albedo,
            polarity="lighter" if albedo > ground_albedo else "darker",
            visible_px=len(pixels),
            size_class="sample" if width <= SAMPLE_MAX_M and height <= SAMPLE_MAX_M else "obstacle",
            touches_border=bool(on_border[i + 1]),
        )
        rows.append(row)
    return rows
