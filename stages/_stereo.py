"""Stereo matching of rectified, parallel-axis pairs: the depth stage's math.

Geometry (``pipeline.camera``): the *reference* image is matched against the *other* image
along the same row; disparity ``d`` means the reference pixel at column ``x`` is at column
``x + d`` of the other image (reference = right, other = left in the study). Results are in
reference geometry, float32 pixels, NaN where invalid.

Methods
-------
``adaptive`` (default; the study's adaptive correlation window)
    Zero-mean normalised cross-correlation (ZNCC) over windows of increasing size, default
    ``9, 15x41, 31x63`` (rows x columns). Per pixel the windows are tried smallest
    first and the first one that passes all of these tests is kept:

    1. *texture*: the standard deviation of the reference window is at least
       ``min_texture`` gray levels (a flat window has no defined correlation);
    2. *peak*: the best ZNCC over the disparity range is at least ``min_ncc`` and lies
       strictly inside the searchable range (a peak on the range's end may be a truncated
       slope of a match outside it);
    3. *distinct*: the best ZNCC exceeds the best ZNCC more than 1 px away from it by at
       least ``distinctness`` standard errors of a correlation over the window's ``n``
       pixels, ``distinctness / sqrt(n)``. Over few pixels a correlation is noisy (about
       0.2 for 5 x 5), so a small window must win clearly; a large window's peak is
       trustworthy with a smaller margin. Repetitive or ambiguous texture, and windows of
       pure sensor noise, give several near-equal peaks and fail;
    4. *left-right consistent*: matching the found left pixel back to the reference with
       the same window lands within ``lr_tolerance`` px of the start.

    After matching, the *uniqueness* (occlusion) test invalidates pixels whose landing
    column in the other image is taken by a nearer surface (a disparity more than
    ``lr_tolerance`` px larger): the other camera cannot see them. It catches occluded
    pixels next to a depth edge whose large windows reach into visible background and
    so pass the left-right check with the background's disparity. Both tests count as
    "left-right rejected" in the status.

    Near the image's left and right sides a window that does not fit is shifted sideways
    (by at most its half-width, so it still contains the pixel) to lie inside both images,
    as in shiftable-window matching; likewise near the top and bottom rows it is shifted
    vertically (by at most its half-height). A window shifted by ``s`` rows measures the
    surface around its centre row, not the pixel's: on the ground, whose disparity changes
    from row to row, that biased the top rows of the lab's 63-row window by +0.9 px (row 0)
    and every archive's first rows by +0.5 px and last rows by -0.3 to -0.6 px. With
    ``row_gradient`` (px per row, the depth stage gives the ground's from the camera pose)
    the disparity of a shifted window is carried to the pixel's row: ``+ row_gradient * s``.
    The carry is right for the ground, which fills those rows, and off by at most the same
    amount for a rock standing in them.

    Where no window passes, the pixel is invalid, not guessed. Why smallest first: a window
    straddling a depth change or a strongly slanted surface mixes disparities and biases the
    match (the "fattening" of foreground objects), so the smallest window is the most
    accurate *if* it carries enough signal; a larger window is only used where the smaller
    one is not reliable. This is the idea of Kanade and Okutomi's adaptive window (IEEE PAMI
    16(9), 1994), which grows the window while the estimated disparity uncertainty falls;
    here the uncertainty test is the statistical peak margin above, which needs no
    disparity-variation model. Why wide windows: on the ground seen by a forward-looking
    camera the disparity changes from row to row but hardly along a row, so a window can
    grow along the row (more pixels, less noise) without mixing disparities; the weak
    texture of the lab floor and the dunes needs those pixels (windows may be up to 255 px;
    the lab catalog adds 63 x 255 for its far floor: bad-2 18.2 -> 9.2 %). The accepted disparity is
    refined to subpixel precision from the ZNCC at the best disparity and its two
    neighbours, in the reference curve and in the left-reference curve, averaged: the
    window-edge bias of one appears with the opposite sign in the other.

    *Subpixel* (``subpixel``). ``'parabola'`` takes the vertex of the parabola through the
    three samples; ``'blend'`` (default) the mean of that vertex and the apex of the
    symmetric V through them (:func:`stages._ncc.subpixel_offset`). A ZNCC peak is rounder
    than a V and sharper than a parabola: the parabola pulls every estimate towards the
    nearest integer ("pixel locking", on the mojave ground -0.05 px at a true fraction of
    0.3 and +0.05 px at 0.7) and the V pushes it away by about as much, so their mean is
    within about 0.01 px of unbiased at every fraction. Measured with
    ``bench_depth_heights.py --frames 8`` (parabola -> blend): ground height noise mojave
    0.85 -> 0.82 cm, lava 0.73 -> 0.70 cm, median rock height error 1.25 -> 1.20 and
    0.87 -> 0.84 cm, rock tops 1.15 -> 1.17 and 0.80 -> 0.73 cm, bad-2 and EPE slightly
    lower on lab, mojave and lava; near rocks' widths with the stage's depth
    (``bench_describe.py --inputs depth --frames 10``) 6.9 -> 6.3 % on mojave and 7.5 ->
    6.7 % on lava (lab 5.6 -> 5.8 %, 51 rocks); segmentation F1 (``bench_segment.py --depth
    stage --frames 4``) lava 0.667 -> 0.673, lab and mojave unchanged; no cost in speed.

    Speed: all window sums are box sums computed incrementally (O(1) per pixel, disparity
    and window), in numba kernels (:mod:`stages._ncc`); the left-right check costs no second
    matching because the left-reference cost volume is the right-reference one re-indexed:
    ``C_left(xl, d) = C_right(xl - d, d)``. Per row the curves are stored disparity-major so
    that the peak, runner-up and left-reference argmax of all columns are vectorised passes.

    Search band (optional, ``row_min_disparity`` and ``row_max_disparity``; the depth stage
    derives them from the camera pose, :func:`stages.geometry.derive_row_floor` and
    ``derive_row_ceiling``). The windows after the first exist for the weakly textured
    ground (see "why wide windows" above), and at a given row the ground's disparity is
    known from the pose: nothing lies below the ground (a floor, less a margin), and a
    point ``z`` above it has ``1 / (1 - z / h)`` times its disparity (a ceiling of twice
    the ground's admits objects up to half the camera height ``h``). So the larger windows
    search only that band, which removes most of their work near the top of a pitched
    frame (mojave, 0..63 searched: band 2..14 px in the top row, 26..63 in the bottom one).
    Why not the first window too: its search over the whole range is the evidence of
    ambiguity. A small window on weak texture often has a spurious competitor outside the
    band that makes its peak not distinct, so the pixel goes on to a larger, reliable
    window; without that competitor the small window accepted wrong peaks, which also
    knock correct neighbours out in the uniqueness test (``bench_depth_accuracy.py``, lab,
    3 frames, lab windows: bad-2 6.17 -> 6.73 % with a floor on every window; 6.25 % with
    the band on the larger windows only; mojave, lava unchanged, default windows on lab
    and dunes 0.2 % better).

``sgm``
    The same ZNCC costs of one window (``sgm_window``), ``(1 - ZNCC) / 2``, aggregated
    semi-globally over 4 or 8 paths (penalties ``sgm_p1`` for 1 px steps, ``sgm_p2`` for
    larger jumps), winner-take-all, parabola subpixel, left-right check on the re-indexed
    aggregated volume. Fills weakly textured areas (dunes) the adaptive method leaves empty.

``opencv-sgbm``
    OpenCV's StereoSGBM as a reference (:func:`stages._stereo_filters.sgbm_disparity`).

Modules. This one holds the methods, the checks of their settings and
:func:`match_disparity`; the numba kernels are in :mod:`stages._ncc` and :mod:`stages._sgm`.
Before and after matching (:mod:`stages._stereo_filters`): with ``prefilter`` > 0,
``adaptive`` and ``sgm`` match high-passed images (off by default), and every method ends
by removing speckles (``speckle_size``, ``speckle_range``). Large frames are matched tile by
tile by :mod:`stages._stereo_tiles`, bit-identical to whole-frame matching for ``adaptive``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _ncc, _sgm
from ._stereo_filters import (
    _check_prefilter_size,
    _coerce_pair,
    _coerce_range,
    _is_int,
    prefilter_image,
    sgbm_disparity,
    speckle_mask,
)

__all__ = [
    "DEFAULT_WINDOWS",
    "METHODS",
    "SUBPIXEL",
    "STATUS_VALID",
    "STATUS_NO_PEAK",
    "STATUS_LR_REJECTED",
    "STATUS_SPECKLE",
    "Matching",
    "match_disparity",
    "check_settings",
]

DEFAULT_WINDOWS = "9,15x41,31x63"
METHODS: tuple[str, ...] = ("adaptive", "sgm", "opencv-sgbm")
SUBPIXEL: tuple[str, ...] = ("blend", "parabola")

STATUS_VALID = 0
STATUS_NO_PEAK = 1
STATUS_LR_REJECTED = 2
STATUS_SPECKLE = 3

# Internal one-array encoding of the status, so a tile function returns a single array.
_SPECKLE_CODE = np.float32(np.inf)


@dataclass(frozen=True)
class Matching:
    """Result of matching one pair.

    Attributes
    ----------
    disparity : (M, N) ndarray of float32
        Pixels, reference geometry, NaN where invalid.
    status : (M, N) ndarray of int8
        ``STATUS_VALID`` (0), ``STATUS_NO_PEAK`` (1: no textured, distinct peak or no data),
        ``STATUS_LR_REJECTED`` (2: failed the left-right check), ``STATUS_SPECKLE`` (3).
    """

    disparity: np.ndarray
    status: np.ndarray

    @property
    def valid_fraction(self) -> float:
        """Share of all pixels with a valid disparity."""
        return float(np.mean(self.status == STATUS_VALID))

    @property
    def lr_consistency(self) -> float:
        """Share of pixels with a peak that passed the left-right check (NaN if none)."""
        peaks = np.count_nonzero(self.status != STATUS_NO_PEAK)
        if peaks == 0:
            return float("nan")
        return 1.0 - np.count_nonzero(self.status == STATUS_LR_REJECTED) / peaks


# ----------------------------------------------------------------------------- validation


def _coerce_windows(windows: Any) -> tuple[tuple[int, int], ...]:
    """Windows as ``((rows, cols), ...)``; ``'5,9x21'`` or ``(5, (9, 21))`` forms accepted."""
    example = "'5,11,21,41' or '5,9x21,15x41' (rows x columns)"
    if isinstance(windows, str):
        parts = [p for p in windows.replace(" ", "").split(",") if p]
        try:
            windows = [tuple(int(v) for v in p.lower().split("x")) for p in parts]
        except ValueError:
            raise ValueError(
                f"windows must be comma-separated odd sizes like {example}, got {windows!r}"
            ) from None
    sizes: list[tuple[int, int]] = []
    for item in windows:
        shape = (int(item), int(item)) if np.isscalar(item) else tuple(int(v) for v in item)  # type: ignore[arg-type]
        if len(shape) == 1:
            shape = (shape[0], shape[0])
        if len(shape) != 2:
            raise ValueError(f"a window is a size or rows x columns, got {item!r}; e.g. {example}")
        sizes.append(shape)
    if not sizes:
        raise ValueError(f"windows must name at least one window size, e.g. {example}")
    if any(v < 3 or v % 2 == 0 for shape in sizes for v in shape):
        raise ValueError(f"window sizes must be odd integers >= 3, got {sizes}")
    if any(v > 255 for shape in sizes for v in shape):
        raise ValueError(f"window sizes must be at most 255 px, got {sizes}")
    if any(b[0] < a[0] or b[1] < a[1] or b == a for a, b in zip(sizes, sizes[1:], strict=False)):
        raise ValueError(
            f"window sizes must be increasing (each window contains the previous), got {sizes}"
        )
    return tuple(sizes)


def _check_method(method: str) -> str:
    if method not in METHODS:
        raise ValueError(f"method must be one of {list(METHODS)}, got {method!r}")
    return method


def _check_positive(name: str, value: float, *, allow_zero: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
    return float(value)


def _coerce_band(
    row_min_disparity: Any, row_max_disparity: Any, rows: int, lo: int, hi: int
) -> np.ndarray | None:
    """(2, M) int64 per-row least and largest disparity, or None when neither is given."""
    if row_min_disparity is None and row_max_disparity is None:
        return None
    band = np.empty((2, rows), np.int64)
    for i, (name, value, default) in enumerate(
        (("row_min_disparity", row_min_disparity, lo), ("row_max_disparity", row_max_disparity, hi))
    ):
        if value is None:
            band[i] = default
            continue
        array = np.asarray(value)
        if array.shape != (rows,):
            raise ValueError(
                f"{name} must hold one disparity per image row, shape ({rows},), got shape "
                f"{array.shape}"
            )
        if not np.issubdtype(array.dtype, np.integer):
            raise TypeError(
                f"{name} must be integers (px), got dtype {array.dtype}; round with "
                "np.floor(values).astype(int) (np.ceil for row_max_disparity)"
            )
        band[i] = np.clip(array.astype(np.int64), lo, hi)
    return band


# ----------------------------------------------------------------------------- matching


def _centred(image: np.ndarray) -> np.ndarray:
    # Centring keeps every int32 window sum of products far from overflow (see stages._ncc).
    return image.astype(np.int32) - 128


def _margins(s: dict) -> np.ndarray:
    # The sampling noise of a correlation over n pixels is about 1 / sqrt(n): the margin a
    # peak needs is `distinctness` such standard errors.
    counts = np.array([rows * cols for rows, cols in s["windows"]], dtype=np.float64)
    return s["distinctness"] / np.sqrt(counts)


def _adaptive_coded(
    ref: np.ndarray, oth: np.ndarray, lo: int, hi: int, s: dict, band: np.ndarray | None
) -> np.ndarray:
    # Each window's disparity indices per row: the first window searches the whole range
    # (see "Search band"), the others the row's band, at least 3 disparities of the range.
    n_all = hi - lo + 1
    row_start = np.zeros((len(s["windows"]), ref.shape[0]), np.int64)
    row_end = np.full((len(s["windows"]), ref.shape[0]), n_all, np.int64)
    if band is not None:
        end = np.clip(band[1] - lo + 1, 3, n_all)
        row_end[1:] = end
        row_start[1:] = np.clip(band[0] - lo, 0, end - 3)
    hys = np.array([rows // 2 for rows, _ in s["windows"]], dtype=np.int64)
    hxs = np.array([cols // 2 for _, cols in s["windows"]], dtype=np.int64)
    r32, o32 = _centred(ref), _centred(oth)
    disparity, window = _ncc.adaptive_match(
        r32, o32, lo, n_all, row_start, row_end, hys, hxs,
        float(s["min_texture"]), float(s["min_ncc"]), _margins(s), float(s["lr_tolerance"]),
        s["subpixel"] == "blend",
    )  # fmt: skip
    if s["row_gradient"]:
        _carry_shifted_rows(disparity, window, hys, s["row_gradient"])
    return disparity


def _carry_shifted_rows(
    disparity: np.ndarray, window: np.ndarray, hys: np.ndarray, gradient: float
) -> None:
    """In place: carry the valid disparities of vertically shifted windows (the top and
    bottom ``hy`` rows of each window ``k``) to their pixels' rows along ``gradient``."""
    h = disparity.shape[0]
    for k, hy in enumerate(int(v) for v in hys):
        if hy == 0 or 2 * hy + 1 > h:
            continue  # fits everywhere, or was never used
        for rows, centre in ((np.arange(hy), hy), (np.arange(h - hy, h), h - 1 - hy)):
            block = disparity[rows]
            use = (window[rows] == k) & np.isfinite(block)
            carry = np.float32(gradient) * (rows - centre).astype(np.float32)[:, None]
            disparity[rows] = np.where(use, block + carry, block)


# sgm's two (H, W, D) float32 volumes, kept per thread for the next frame of the same
# shape: fresh ones cost more in page faults (~30 ms of system time each at 500 x 500 x 64)
# than the kernels spend filling them. Per thread, because a threaded worker matches
# several frames at once. Only up to _KEEP_MAX_BYTES each: a 1024 px tile with 256
# disparities takes 1.1 GB a volume, which a worker must not hold between frames (and whose
# page faults are small next to its matching time).
_VOLUMES = threading.local()
_KEEP_MAX_BYTES = 256 * 2**20


def _sgm_volumes(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The calling thread's cost and aggregation volumes of ``shape`` (new when it changes;
    not kept for the next frame above ``_KEEP_MAX_BYTES`` each)."""
    volumes = getattr(_VOLUMES, "arrays", None)
    if volumes is None or volumes[0].shape != shape:
        _VOLUMES.arrays = None  # the old pair is freed before the new one is allocated
        volumes = (np.empty(shape, np.float32), np.empty(shape, np.float32))
        if volumes[0].nbytes <= _KEEP_MAX_BYTES:
            _VOLUMES.arrays = volumes
    return volumes


def _sgm_coded(
    ref: np.ndarray, oth: np.ndarray, lo: int, hi: int, s: dict, band: np.ndarray | None
) -> np.ndarray:
    hw = int(s["sgm_window"]) // 2
    r32, o32 = _centred(ref), _centred(oth)
    hws = np.array([hw], dtype=np.int64)
    rs, ri, _ = _ncc.window_stats(r32, hws, hws, False)
    os_, oi, _ = _ncc.window_stats(o32, hws, hws, False)
    cost, total = _sgm_volumes((*ref.shape, hi - lo + 1))
    _ncc.ncc_cost_volume(
        r32, o32, lo, hi - lo + 1, hw,
        rs[0], ri[0], os_[0], oi[0], cost,
    )  # fmt: skip
    _sgm.aggregate(cost, float(s["sgm_p1"]), float(s["sgm_p2"]), int(s["sgm_paths"]), total)
    return _sgm.select(total, lo, hw, float(s["lr_tolerance"]))


def _sgbm_coded(
    ref: np.ndarray, oth: np.ndarray, lo: int, hi: int, s: dict, band: np.ndarray | None
) -> np.ndarray:
    return sgbm_disparity(oth, ref, min_disparity=lo, max_disparity=hi)


_MATCHERS = {"adaptive": _adaptive_coded, "sgm": _sgm_coded, "opencv-sgbm": _sgbm_coded}


_DEFAULTS: dict[str, Any] = {
    "method": "adaptive", "windows": DEFAULT_WINDOWS, "min_texture": 1.0, "min_ncc": 0.1,
    "distinctness": 1.0, "lr_tolerance": 1.0, "speckle_size": 50, "speckle_range": 1.0,
    "sgm_window": 15, "sgm_p1": 0.2, "sgm_p2": 3.0, "sgm_paths": 8, "prefilter": 0,
    "subpixel": "blend", "row_gradient": 0.0,
}  # fmt: skip


def _settings(
    method: str,
    windows: Any,
    min_texture: float,
    min_ncc: float,
    distinctness: float,
    lr_tolerance: float,
    speckle_size: int,
    speckle_range: float,
    sgm_window: int,
    sgm_p1: float,
    sgm_p2: float,
    sgm_paths: int,
    prefilter: int,
    subpixel: str = "blend",
    row_gradient: float = 0.0,
) -> dict[str, Any]:
    if not -1.0 <= min_ncc <= 1.0:
        raise ValueError(f"min_ncc must be in [-1, 1], got {min_ncc!r}")
    if isinstance(speckle_size, bool) or not isinstance(speckle_size, int) or speckle_size < 0:
        raise ValueError(f"speckle_size must be an int >= 0 (0 disables), got {speckle_size!r}")
    if sgm_paths not in (4, 8):
        raise ValueError(f"sgm_paths must be 4 or 8, got {sgm_paths!r}")
    if not (_is_int(prefilter) and prefilter == 0):
        _check_prefilter_size("prefilter", prefilter, off="0 (off) or ")
    if subpixel not in SUBPIXEL:
        raise ValueError(
            f"subpixel must be one of {list(SUBPIXEL)}, got {subpixel!r}; 'parabola' gives "
            "the results of depth stage versions before 5"
        )
    if isinstance(row_gradient, bool) or not (
        isinstance(row_gradient, int | float) and math.isfinite(row_gradient)
    ):
        raise ValueError(
            f"row_gradient must be a finite number of px per row (0: no carry), got "
            f"{row_gradient!r}"
        )
    if sgm_window < 3 or sgm_window % 2 == 0 or sgm_window > 63:
        raise ValueError(f"sgm_window must be an odd integer in [3, 63], got {sgm_window!r}")
    return {
        "method": _check_method(method),
        "windows": _coerce_windows(windows),
        "min_texture": _check_positive("min_texture", min_texture),
        "min_ncc": float(min_ncc),
        "distinctness": _check_positive("distinctness", distinctness),
        "lr_tolerance": _check_positive("lr_tolerance", lr_tolerance),
        "speckle_size": int(speckle_size),
        "speckle_range": _check_positive("speckle_range", speckle_range, allow_zero=False),
        "sgm_window": int(sgm_window),
        "sgm_p1": _check_positive("sgm_p1", sgm_p1),
        "sgm_p2": _check_positive("sgm_p2", sgm_p2),
        "sgm_paths": int(sgm_paths),
        "prefilter": int(prefilter),
        "subpixel": subpixel,
        "row_gradient": float(row_gradient),
    }


def check_settings(**settings: Any) -> dict[str, Any]:
    """Validate matching settings (keywords of :func:`match_disparity` other than the images
    and the range), filling defaults; raises ValueError/TypeError naming the bad one."""
    unknown = set(settings) - set(_DEFAULTS)
    if unknown:
        raise TypeError(f"unknown matching settings {sorted(unknown)}; known: {sorted(_DEFAULTS)}")
    return _settings(**{**_DEFAULTS, **settings})


def _match_coded(
    ref: np.ndarray, oth: np.ndarray, lo: int, hi: int, s: dict, band: np.ndarray | None = None
) -> np.ndarray:
    """Disparity with status codes: NaN no peak, -inf LR-rejected, +inf speckle.

    ``band``: (2, M) least and largest disparity per row (``adaptive`` only), or None.
    """
    if s["method"] != "opencv-sgbm" and s["prefilter"]:
        ref = prefilter_image(ref, size=s["prefilter"])
        oth = prefilter_image(oth, size=s["prefilter"])
    # the matchers return a fresh float32 array, coded in place below; both filters read
    # only its finite pixels, so the codes need not be masked first
    coded = np.ascontiguousarray(_MATCHERS[s["method"]](ref, oth, lo, hi, s, band), np.float32)
    if s["method"] != "opencv-sgbm":
        _ncc.flag_occluded(coded, np.float32(max(s["lr_tolerance"], 0.5)), _ncc.LR_REJECTED)
    if s["speckle_size"] > 0:
        removed = speckle_mask(coded, max_size=s["speckle_size"], max_diff=s["speckle_range"])
        coded[removed] = _SPECKLE_CODE
    return coded


def _decode(coded: np.ndarray) -> Matching:
    disparity, status = _ncc.decode_status(np.ascontiguousarray(coded, np.float32))
    return Matching(disparity=disparity, status=status)


def match_disparity(
    reference: np.ndarray,
    other: np.ndarray,
    *,
    min_disparity: int,
    max_disparity: int,
    method: str = "adaptive",
    windows: Any = DEFAULT_WINDOWS,
    min_texture: float = 1.0,
    min_ncc: float = 0.1,
    distinctness: float = 1.0,
    lr_tolerance: float = 1.0,
    speckle_size: int = 50,
    speckle_range: float = 1.0,
    sgm_window: int = 15,
    sgm_p1: float = 0.2,
    sgm_p2: float = 3.0,
    sgm_paths: int = 8,
    prefilter: int = 0,
    subpixel: str = "blend",
    row_min_disparity: Any = None,
    row_max_disparity: Any = None,
    row_gradient: float = 0.0,
) -> Matching:
    """Match a rectified pair along rows.

    Parameters
    ----------
    reference, other : (M, N) ndarray of uint8
        Gray images; the reference pixel at column ``x`` is at ``x + d`` in ``other``.
    min_disparity, max_disparity : int
        Inclusive disparity search range in px, ``max_disparity >= min_disparity + 2``.
    method : {'adaptive', 'sgm', 'opencv-sgbm'}
        See the module docstring.
    windows : str or sequence of int or (int, int)
        Adaptive windows, odd px, increasing: ``'5,11,15x41,31x63'`` (rows x columns; a
        single number is a square), or ``(5, 11, (15, 41), (31, 63))``.
    min_texture : float
        Minimum standard deviation (gray levels) of a reference window to be matched.
    min_ncc : float in [-1, 1]
        Minimum ZNCC of an accepted peak.
    distinctness : float
        Minimum margin of the peak over the best ZNCC more than 1 px from it, in standard
        errors of a correlation over the window (``1 / sqrt(pixels)``).
    lr_tolerance : float
        Largest left-right disagreement in px that still counts as consistent.
    speckle_size : int
        Largest connected region (px) removed as a speckle; 0 disables.
    speckle_range : float
        Disparity step (px) that still connects neighbours in a region.
    sgm_window, sgm_p1, sgm_p2, sgm_paths : int, float, float, {4, 8}
        ``sgm`` method: ZNCC window, penalties (cost units, cost in [0, 1]), path count.
    prefilter : int
        Box size (odd px) of the high-pass applied before ``adaptive`` and ``sgm`` matching
        (:func:`stages._stereo_filters.prefilter_image`); 0 matches the raw images.
    subpixel : {'blend', 'parabola'}
        ``adaptive`` only: the peak's subpixel estimator, see "Subpixel" in the module
        docstring.
    row_min_disparity, row_max_disparity : (M,) array_like of int, optional
        ``adaptive`` only: the least and largest disparity the windows after the first
        search in each row (the row's *band*, see "Search band" in the module docstring),
        within ``[min_disparity, max_disparity]`` and at least 3 disparities wide; None
        searches from ``min_disparity`` / up to ``max_disparity``.
    row_gradient : float
        ``adaptive`` only: disparity change per image row (px/row, positive when it grows
        down the image) of the surface seen in the top and bottom rows, where tall windows
        are shifted vertically; their disparity is carried to the pixel's row along it (see
        the module docstring). 0 (default) keeps the shifted windows' disparity.

    Returns
    -------
    Matching
        ``disparity`` (M, N) float32 with NaN invalid, and the per-pixel ``status``.
    """
    ref, oth = _coerce_pair(reference, other)
    lo, hi = _coerce_range(min_disparity, max_disparity)
    settings = _settings(
        method, windows, min_texture, min_ncc, distinctness, lr_tolerance,
        speckle_size, speckle_range, sgm_window, sgm_p1, sgm_p2, sgm_paths, prefilter, subpixel,
        row_gradient,
    )  # fmt: skip
    band = _coerce_band(row_min_disparity, row_max_disparity, ref.shape[0], lo, hi)
    return _decode(_match_coded(ref, oth, lo, hi, settings, band))
