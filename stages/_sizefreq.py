"""Rock size-frequency distribution: cumulative fractional area and the Golombek-Rapp model.

Golombek and Rapp (1997) model the cumulative fractional area ``F(D)`` covered by rocks of
diameter ``D`` metres or larger as ``F(D) = k exp(-q(k) D)`` with ``q(k) = 1.79 + 0.152 / k``;
``k`` is the total fractional area covered by rocks (``F(0)``).

The observed ``F(D)`` at each measured diameter is the summed plan area ``pi D^2 / 4`` of the
rocks at least that large divided by the ground area surveyed. Undetected small rocks do not
bias ``F`` above the detection limit (only larger rocks enter the sum), so fits use diameters
``>= d_min_m``. ``k`` is fitted by least squares on ``log F`` (a 1-D bounded search).

Pure functions: work on one frame's or a whole archive's diameters, e.g.
``fit_size_frequency(table["width_m"], ground_area_m2=frames["describe_ground_area_m2"].sum())``
or :func:`size_frequency_from_table`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

__all__ = [
    "q_of_k",
    "model_cfa",
    "cumulative_fractional_area",
    "SizeFrequencyFit",
    "fit_size_frequency",
    "size_frequency_from_table",
    "visible_ground_area_m2",
]

_K_BOUNDS = (1e-4, 0.99)


def q_of_k(k: float | np.ndarray) -> float | np.ndarray:
    """Golombek-Rapp decay ``q(k) = 1.79 + 0.152 / k`` (1/m)."""
    return 1.79 + 0.152 / k


def model_cfa(diameter_m: np.ndarray, k: float) -> np.ndarray:
    """Model cumulative fractional area ``k exp(-q(k) D)``.

    Parameters
    ----------
    diameter_m : ndarray of float
        Diameters, metres.
    k : float
        Total rock fraction, in (0, 1).
    """
    if not 0 < k < 1:
        raise ValueError(f"k must be in (0, 1), got {k!r}")
    return k * np.exp(-q_of_k(k) * np.asarray(diameter_m, dtype=np.float64))


def _coerce_diameters(diameters_m: Any) -> np.ndarray:
    d = np.asarray(diameters_m, dtype=np.float64).reshape(-1)
    return d[np.isfinite(d) & (d > 0)]


def cumulative_fractional_area(
    diameters_m: Any, *, ground_area_m2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Observed cumulative fractional area at each rock diameter.

    Parameters
    ----------
    diameters_m : (K,) array_like of float
        Rock diameters, metres; NaN and non-positive values are ignored.
    ground_area_m2 : float
        Ground area surveyed, m^2, > 0.

    Returns
    -------
    diameters : (K',) ndarray of float64
        Distinct diameters, decreasing.
    cfa : (K',) ndarray of float64
        Fraction of the ground covered by rocks at least that large (increasing).
    """
    if not (isinstance(ground_area_m2, int | float | np.floating) and ground_area_m2 > 0):
        raise ValueError(f"ground_area_m2 must be a number > 0, got {ground_area_m2!r}")
    d = np.sort(_coerce_diameters(diameters_m))[::-1]
    if d.size == 0:
        return d, np.array([], dtype=np.float64)
    cum = np.cumsum(math.pi * d**2 / 4.0) / float(ground_area_m2)
    # ties: every rock of equal diameter counts at that diameter
    last = np.r_[d[1:] != d[:-1], True]
    return d[last], cum[last]


@dataclass(frozen=True)
class SizeFrequencyFit:
    """Fit of the Golombek-Rapp model.

    Attributes
    ----------
    k : float
        Total rock fraction (NaN when fewer than ``min_rocks`` rocks).
    q : float
        ``q(k)``, 1/m.
    n_rocks : int
        Rocks used (diameter in [d_min_m, d_max_m]).
    rms_log : float
        RMS residual of ``log F`` (natural log).
    rock_area_fraction : float
        Observed fraction of the ground covered by the rocks used.
    """

    k: float
    q: float
    n_rocks: int
    rms_log: float
    rock_area_fraction: float


def fit_size_frequency(
    diameters_m: Any,
    *,
    ground_area_m2: float,
    d_min_m: float = 0.0,
    d_max_m: float = math.inf,
    min_rocks: int = 3,
) -> SizeFrequencyFit:
    """Fit ``k`` of ``F(D) = k exp(-q(k) D)`` to observed rocks.

    Parameters
    ----------
    diameters_m : (K,) array_like of float
        Rock diameters, metres (e.g. the descriptors' ``width_m``).
    ground_area_m2 : float
        Ground area surveyed, m^2, > 0.
    d_min_m, d_max_m : float
        Only diameters in this range enter the fit (``d_min_m``: the completeness limit).
    min_rocks : int
        Fewer rocks than this give ``k = NaN``.

    Returns
    -------
    SizeFrequencyFit
    """
    if d_min_m < 0 or d_max_m <= d_min_m:
        raise ValueError(f"need 0 <= d_min_m < d_max_m, got {d_min_m!r}, {d_max_m!r}")
    d = _coerce_diameters(diameters_m)
    d = d[(d >= d_min_m) & (d <= d_max_m)]
    diam, cfa = cumulative_fractional_area(d, ground_area_m2=ground_area_m2)
    fraction = float(cfa[-1]) if cfa.size else 0.0
    if d.size < min_rocks or diam.size < 2:
        return SizeFrequencyFit(math.nan, math.nan, int(d.size), math.nan, fraction)
    log_obs = np.log(cfa)

    def cost(log_k: float) -> float:
        k = math.exp(log_k)
        return float(np.sum((log_obs - (log_k - q_of_k(k) * diam)) ** 2))

    best = minimize_scalar(
        cost,
        bounds=(math.log(_K_BOUNDS[0]), math.log(_K_BOUNDS[1])),
        method="bounded",
        options={"xatol": 1e-6},
    )
    k = math.exp(float(best.x))
    rms = math.sqrt(float(best.fun) / diam.size)
    return SizeFrequencyFit(k, float(q_of_k(k)), int(d.size), rms, fraction)


def size_frequency_from_table(
    table: Any,
    *,
    ground_area_m2: float,
    diameter_column: str = "width_m",
    d_min_m: float = 0.0,
    d_max_m: float = math.inf,
    max_range_m: float = math.inf,
    min_rocks: int = 3,
) -> SizeFrequencyFit:
    """Fit the model to a whole archive's descriptor table.

    Parameters
    ----------
    table : pyarrow.Table, pandas.DataFrame or mapping of column name to sequence
        Descriptor rows (``descriptors.parquet`` of one archive or run).
    ground_area_m2 : float
        Total ground area of the frames the rows come from (sum of the frames'
        ``describe_ground_area_m2``), m^2.
    diameter_column : str
        Column holding rock diameters, metres.
    max_range_m : float
        Only rows with ``range_m <= max_range_m`` (use the value the frames' ground area was
        computed with).
    d_min_m, d_max_m, min_rocks
        See :func:`fit_size_frequency`.
    """
    columns = _table_columns(table, (diameter_column, "range_m"))
    d = np.asarray(columns[diameter_column], dtype=np.float64)
    rng = np.asarray(columns["range_m"], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        keep = rng <= max_range_m if math.isfinite(max_range_m) else np.ones(d.shape, bool)
    return fit_size_frequency(
        d[keep],
        ground_area_m2=ground_area_m2,
        d_min_m=d_min_m,
        d_max_m=d_max_m,
        min_rocks=min_rocks,
    )


def _table_columns(table: Any, names: tuple[str, ...]) -> dict[str, Any]:
    if hasattr(table, "column_names") and hasattr(table, "column"):  # pyarrow.Table
        available = list(table.column_names)
        get = lambda name: table.column(name).to_numpy(zero_copy_only=False)  # noqa: E731
    elif isinstance(table, Mapping) or hasattr(table, "columns"):  # mapping / DataFrame
        available = list(table.keys()) if isinstance(table, Mapping) else list(table.columns)
        get = lambda name: np.asarray(table[name])  # noqa: E731
    else:
        raise TypeError(
            "table must be a pyarrow.Table, a pandas.DataFrame or a mapping of columns, got "
            f"{type(table).__name__}"
        )
    missing = [n for n in names if n not in available]
    if missing:
        raise ValueError(f"table lacks column(s) {missing}; it has {available}")
    return {n: get(n) for n in names}


def visible_ground_area_m2(
    shape: tuple[int, int],
    *,
    focal_px: float,
    principal_point: tuple[float, float],
    up: np.ndarray,
    camera_height_m: float,
    max_range_m: float = math.inf,
) -> float:
    """Ground area seen by the image: summed footprints of the pixels whose rays hit the
    ground plane at range (Z) up to ``max_range_m``.

    A pixel's footprint on the plane is ``Z^2 / (f^2 |n . r|)`` with ``r = (u, v, 1)`` its
    ray and ``n`` the unit up normal: its solid angle times the squared distance, over the
    cosine of the incidence angle.

    Parameters
    ----------
    shape : (int, int)
        Image shape (M, N).
    focal_px : float
    principal_point : (float, float)
        ``(cx, cy)``.
    up : (3,) ndarray of float
        Unit ground normal in the camera frame.
    camera_height_m : float
        Camera height above the plane, > 0.
    max_range_m : float
        Farthest range counted.
    """
    if camera_height_m <= 0:
        raise ValueError(f"camera_height_m must be > 0, got {camera_height_m!r}")
    # frames of one archive share the camera: the area is computed once per geometry
    return _visible_ground_area_m2(
        tuple(int(v) for v in shape),
        float(focal_px),
        tuple(float(v) for v in principal_point),
        tuple(float(v) for v in np.asarray(up, dtype=np.float64).reshape(-1)),
        float(camera_height_m),
        float(max_range_m),
    )


@functools.lru_cache(maxsize=32)
def _visible_ground_area_m2(
    shape: tuple[int, ...],
    focal_px: float,
    principal_point: tuple[float, ...],
    up: tuple[float, ...],
    camera_height_m: float,
    max_range_m: float,
) -> float:
    h, w = shape
    cx, cy = principal_point
    u = (np.arange(w, dtype=np.float64) - cx) / focal_px
    v = (np.arange(h, dtype=np.float64) - cy) / focal_px
    n = np.asarray(up, dtype=np.float64)
    down = -(n[0] * u[None, :] + n[1] * v[:, None] + n[2])  # -(n . r) > 0 for rays hitting
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(down > 1e-9, camera_height_m / down, np.inf)
        area = np.where(z <= max_range_m, z**2 / (focal_px**2 * down), 0.0)
    return float(np.sum(area))
