"""Depth stage: disparity, range, pseudo-left residual, ground plane and height above it.

Matching math in :mod:`stages._stereo` (adaptive-window ZNCC by default), geometry in
:mod:`stages.geometry`. With the camera's ``reference = "left"`` both images are mirrored
and swapped, matched as if the left image were the right one, and every product is mirrored
back, so products are always in the reference image's geometry (``docs/design.md``).

Search range. ``max_disparity = 0`` (the default) derives it from the camera
(:func:`stages.geometry.derive_max_disparity`): ``f b / nearest_range_m`` when
``nearest_range_m`` is given, else the ground's disparity at the bottom image row (the
nearest visible ground point, from camera height and pitch) plus 25 % and 2 px for rocks
standing above it, else 64 px. For the built-in archives (f = 430 px, b = 0.1 m, 1.2 m up,
pitched 38 deg) that is about 51 px; for the 0.8 m Viking baseline about 380 px. A frame
without a pose notes that its ground plane comes from the disparity and, at the 64 px
default, the range that limit cuts off, saying so when over 1 % of the matches pile up
within 1 px of it (a larger or nearer camera than the built-in archives' needs more).

Search band (``adaptive``). The windows after the first are there for the weakly textured
ground, whose disparity at each row the pose gives. With a pose they search each row only
between a floor, ``(1 - floor_margin)`` times the pose plane's disparity at that row minus
2 px (nothing lies below the ground; the margins absorb a few degrees of pitch error, a 25 %
height error and hollows), and a ceiling, ``ceiling_ratio`` times it plus 2 px (objects up
to ``(1 - 1 / ceiling_ratio)`` of the camera height: 0.6 m with the default 2 at 1.2 m;
no truth pixel of the built-in archives exceeds 1.25 times the ground's disparity + 2 px).
:func:`stages.geometry.derive_row_floor` and ``derive_row_ceiling`` give them. The first
window keeps the whole range because its competitors outside the band are what flags a
small window's match as ambiguous (:mod:`stages._stereo`, "Search band").
``floor_margin = 1`` and ``ceiling_ratio = 0`` search the whole range everywhere; raise
``ceiling_ratio`` where taller objects than that must be matched on weak texture.

Border rows (``adaptive``, version 6). Near the top and bottom a tall window is shifted
vertically to fit and measures the ground around its centre row; with a pose the matcher
carries that disparity to the pixel's row along the ground's gradient
(:func:`resolve_row_gradient`); the ground's median error in row 0 was +0.9 px (lab) and
+0.5 px (mojave, lava). On the catalog runs (``benchmarks/evaluate_archives.sh``): lab bad-1
17.7 -> 16.2 %, bad-2 9.0 -> 8.7 %; EPE lab 0.450 -> 0.430, mojave 0.168 -> 0.165, lava
0.151 -> 0.149 px.

Choosing the method. ``adaptive`` (default) is the most accurate where the ground has
texture (mojave, lava: about a quarter of StereoSGBM's bad-2 rate, see
``benchmarks/bench_depth_accuracy.py``). On nearly textureless floors add a wide window
(``windows = "9,15x41,31x63,63x255"``, lab) or use ``method = "sgm"`` (lab, dunes), which
propagates matches across weak texture; ``prefilter = 15`` (a high-pass, see
:mod:`stages._stereo_filters`) helps ``sgm`` on dunes (bad-2 23.1 -> 20.9 %).

Subpixel. The ``adaptive`` method's peaks are refined by the mean of a parabola's vertex
and a V's apex through the ZNCC at the best disparity and its neighbours (``subpixel =
"blend"``, version 5), which removes most of the parabola's pull towards whole pixels
(:mod:`stages._stereo`, "Subpixel"); ``subpixel = "parabola"`` gives version 4's results.

Residual. The right (reference) image is forward-warped by its disparity into the left
image's geometry (the "pseudo-left" image); ``residual = left - pseudo_left`` lives in the
left image's geometry, NaN where no right pixel lands. (With ``reference = "left"`` the roles
swap: right minus pseudo-right, in the right image's geometry.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.stage import FrameContext, Param, Product, Stage, StageResult

from . import _refine, _stereo, _stereo_tiles
from ._depth_checks import (
    OFFSET_CHECK_BELOW,
    SWAP_CHECK_BELOW,
    limit_note,
    offset_note,
    pose_notes,
    poseless_note,
    swapped_note,
)
from ._fill import border_fill, disparity_without_fill, extend_into_fill
from ._select import median32
from ._stereo_filters import _coerce_image
from .geometry import (
    derive_max_disparity,
    derive_row_ceiling,
    derive_row_floor,
    fit_ground_plane,
    ground_disparity_at_row,
    height_from_disparity,
    pseudo_left,
    range_from_disparity,
    residual,
)

__all__ = [
    "STAGE",
    "run_depth",
    "resolve_disparity_range",
    "resolve_row_band",
    "resolve_row_gradient",
]

PARAMS: tuple[Param, ...] = (
    Param("method", str, "adaptive", "matching method", choices=_stereo.METHODS),
    Param("min_disparity", int, 0, "smallest disparity searched (px)", minimum=-1000),
    Param(
        "max_disparity",
        int,
        0,
        "largest disparity searched (px); 0 = derive from nearest_range_m, else the camera "
        "pose, else 64 (noted)",
        minimum=0,
        maximum=2000,
    ),
    Param(
        "nearest_range_m",
        float,
        0.0,
        "nearest range anything can be at (m), sets max_disparity = f*b/range; 0 = unknown",
        minimum=0.0,
    ),
    Param(
        "floor_margin",
        float,
        0.25,
        "adaptive, windows after the first: per-row search floor (1 - this) x the pose's ground "
        "disparity - 2 px; 1 = none",
        minimum=0.0,
        maximum=1.0,
    ),
    Param(
        "ceiling_ratio",
        float,
        2.0,
        "adaptive, windows after the first: per-row search ceiling this x the pose's ground "
        "disparity + 2 px (objects up to (1 - 1/this) x camera height); 0 = none",
        minimum=0.0,
    ),
    Param(
        "windows",
        str,
        _stereo.DEFAULT_WINDOWS,
        "adaptive ZNCC windows, odd px up to 255, increasing; 'RxC' = rows x columns",
    ),
    Param(
        "subpixel",
        str,
        "blend",
        "adaptive: peak subpixel estimator; 'blend' = parabola and V averaged (less pixel "
        "locking), 'parabola' = depth stage versions before 5",
        choices=_stereo.SUBPIXEL,
    ),
    Param("min_texture", float, 1.0, "least gray-level std of a matched window", minimum=0.0),
    Param("min_ncc", float, 0.1, "least ZNCC of an accepted peak", minimum=-1.0, maximum=1.0),
    Param(
        "distinctness",
        float,
        1.0,
        "least margin of the peak over the runner-up, in standard errors (1/sqrt(pixels))",
        minimum=0.0,
    ),
    Param("lr_tolerance", float, 1.0, "left-right check tolerance (px)", minimum=0.0),
    Param("speckle_size", int, 50, "largest region removed as a speckle (px); 0 = off", minimum=0),
    Param("speckle_range", float, 1.0, "disparity step joining a region (px)", minimum=0.0625),
    Param(
        "prefilter",
        int,
        0,
        "high-pass box (odd px) before adaptive/sgm matching; 0 = off",
        minimum=0,
        maximum=63,
    ),
    Param("sgm_window", int, 15, "sgm: ZNCC window (odd px)", minimum=3, maximum=63),
    Param("sgm_p1", float, 0.2, "sgm: penalty of a 1 px step (cost units)", minimum=0.0),
    Param("sgm_p2", float, 3.0, "sgm: penalty of a larger jump (cost units)", minimum=0.0),
    Param("sgm_paths", int, 8, "sgm: aggregation paths", choices=(4, 8)),
    Param(
        "tile_px",
        int,
        1024,
        "frames with a side above this are matched per tile; 0 = never",
        minimum=0,
    ),
    Param(
        "ground_refine",
        bool,
        False,
        "refine the disparity by matching relative to the fitted ground plane (stages._refine)",
    ),
    Param(
        "ground_inlier_px",
        float,
        1.0,
        "ground-plane inlier band (px of disparity)",
        minimum=0.05,
    ),
)


def _image(name: str, long_name: str, units: str) -> Product:
    return Product(name, dtype="float32", attrs={"units": units, "long_name": long_name})


def _residual_long_name(reference: str) -> str:
    """The residual's description: the non-reference image minus the reference image
    warped into its geometry by the disparity."""
    other = "left" if reference == "right" else "right"
    return (
        f"{other} minus pseudo-{other} ({reference} warped by disparity), NaN undefined"
    )


OUTPUTS: tuple[Product, ...] = (
    _image("disparity", "disparity in the reference image, NaN invalid", "px"),
    _image("range", "range Z = f*b/d along the optical axis, NaN invalid", "m"),
    Product(
        "residual",
        dtype="float32",
        attrs={"units": "gray level", "long_name": _residual_long_name("right")},
        # reference 'left' swaps the roles: right minus pseudo-right
        camera_attrs=lambda camera: {"long_name": _residual_long_name(camera.reference)},
    ),
    _image("height", "height above the fitted ground plane, NaN invalid", "m"),
    Product(
        "ground_plane",
        dtype="float64",
        dims=("frame", "coef"),
        shape=lambda image_shape, params: (4,),
        attrs={
            "units": "1, 1, 1, m",
            "long_name": "ground plane a,b,c,d in the camera frame (a*X+b*Y+c*Z+d=0, unit "
            "normal pointing up), NaN when no fit",
        },
    ),
)


def resolve_disparity_range(
    camera: Camera, shape: tuple[int, int], params: dict[str, Any]
) -> tuple[int, int]:
    """``(min_disparity, max_disparity)`` the stage searches (``max_disparity = 0`` derived).

    Raises
    ------
    ParamError
        When the range holds fewer than 3 disparities.
    """
    lo = int(params["min_disparity"])
    hi = int(params["max_disparity"])
    if hi == 0:
        hi = derive_max_disparity(
            camera, shape=shape, nearest_range_m=float(params["nearest_range_m"])
        )
    if hi - lo < 2:
        raise ParamError(
            f"depth.max_disparity ({hi}) must exceed depth.min_disparity ({lo}) by at least 2; "
            "raise max_disparity or lower min_disparity"
        )
    return lo, hi


_SETTING_KEYS = (
    "method", "windows", "min_texture", "min_ncc", "distinctness", "lr_tolerance",
    "speckle_size", "speckle_range", "sgm_window", "sgm_p1", "sgm_p2", "sgm_paths", "prefilter",
    "subpixel",
)  # fmt: skip


def _coerce_settings(params: Mapping[str, Any]) -> dict[str, Any]:
    try:
        return _stereo.check_settings(**{key: params[key] for key in _SETTING_KEYS})
    except (ValueError, TypeError) as error:
        raise ParamError(f"depth: {error}") from None


def resolve_row_band(
    camera: Camera, shape: tuple[int, int], params: dict[str, Any]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(M,) least and largest disparity the ``adaptive`` method's larger windows search per
    row, each None when not bounded.

    From the camera pose (:func:`stages.geometry.derive_row_floor`, ``derive_row_ceiling``);
    both None for other methods or without a pose; the floor None with
    ``floor_margin = 1``, the ceiling None with ``ceiling_ratio = 0``.

    Raises
    ------
    ParamError
        When ``ceiling_ratio`` is between 0 and 1 (a ceiling below the ground).
    """
    margin = float(params["floor_margin"])
    ratio = float(params["ceiling_ratio"])
    if 0.0 < ratio < 1.0:
        raise ParamError(
            f"depth.ceiling_ratio must be 0 (no ceiling) or >= 1, got {ratio}; a ceiling "
            "below the ground's disparity would exclude the ground itself"
        )
    if params["method"] != "adaptive":
        return None, None
    floor = derive_row_floor(camera, shape=shape, margin=margin) if margin < 1.0 else None
    ceiling = derive_row_ceiling(camera, shape=shape, ratio=ratio) if ratio > 0.0 else None
    return floor, ceiling


def resolve_row_gradient(camera: Camera, shape: tuple[int, int], params: dict[str, Any]) -> float:
    """The ground's disparity change per image row (px/row) from the camera pose, along which
    the ``adaptive`` method carries the disparity of windows shifted at the top and bottom
    rows (:func:`stages._stereo.match_disparity`, ``row_gradient``); 0 without a pose or for
    the other methods."""
    if params["method"] != "adaptive" or not camera.has_pose:
        return 0.0
    top = ground_disparity_at_row(camera, row=0.0, shape=shape)
    return ground_disparity_at_row(camera, row=1.0, shape=shape) - top


def _match(
    reference: np.ndarray,
    other: np.ndarray,
    lo: int,
    hi: int,
    band: tuple[np.ndarray | None, np.ndarray | None],
    params: dict,
    row_gradient: float = 0.0,
):
    settings = {**_coerce_settings(params), "row_gradient": row_gradient}
    tile_px = int(params["tile_px"])
    if tile_px and max(reference.shape) > tile_px:
        return _stereo_tiles.match_tiled(
            reference, other, tile_px=max(tile_px, 16), min_disparity=lo, max_disparity=hi,
            row_min_disparity=band[0], row_max_disparity=band[1], **settings,
        ), True  # fmt: skip
    matching = _stereo.match_disparity(
        reference, other, min_disparity=lo, max_disparity=hi, row_min_disparity=band[0],
        row_max_disparity=band[1], **settings,
    )  # fmt: skip
    return matching, False


def _median_range(finite_range: np.ndarray) -> float:
    """``np.median`` of the finite ranges (NaN if none): by bucket counting for float32,
    the same value at a fraction of an introselect over ~250 000 values."""
    if finite_range.size == 0:
        return float("nan")
    if finite_range.dtype == np.float32 and finite_range.ndim == 1:
        return float(median32(finite_range))
    return float(np.median(finite_range))


def _pitch_deg(plane: np.ndarray) -> float:
    if not np.all(np.isfinite(plane)):
        return float("nan")
    return float(math.degrees(math.atan2(-plane[2], -plane[1])))


def run_depth(
    inputs: dict[str, np.ndarray], *, frame: FrameContext, params: dict[str, Any]
) -> StageResult:
    """Depth products of one frame.

    Parameters
    ----------
    inputs : dict
        ``left``, ``right``: (M, N) ndarray of uint8 (other integers in 0..255 are
        converted), rectified gray pair.
    frame : FrameContext
        ``frame.camera`` gives focal length, baseline, optional pose and the reference.
    params : dict
        Validated values of :data:`PARAMS`.

    Returns
    -------
    StageResult
        Arrays ``disparity``, ``range``, ``residual``, ``height`` (M, N) float32 and
        ``ground_plane`` (4,) float64; figures ``rms_residual``, ``valid_fraction``,
        ``lr_consistency``, ``ground_fit_inliers``, ``min_disparity``, ``max_disparity``,
        ``ground_height_m``, ``ground_pitch_deg``, ``ground_fit``, ``ground_refined_fraction``,
        ``median_range_m``.
    """
    left = np.asarray(inputs["left"])
    right = np.asarray(inputs["right"])
    if left.shape != right.shape or left.ndim != 2:
        raise ValueError(
            f"depth needs two 2-D images of one shape, got left {left.shape}, right {right.shape}"
        )
    # integer gray levels in 0..255 as uint8, as the matcher takes them: the fill and the
    # pair checks read uint8 only
    left, right = _coerce_image(left, "left"), _coerce_image(right, "right")
    camera = frame.camera
    _coerce_settings(params)  # bad settings fail before any work
    notes: list[str] = []
    mirrored = camera.reference == "left"
    if mirrored:
        # Mirroring turns "left x matches right x - d" into "x matches x + d", the
        # right-reference convention the matcher implements.
        reference = np.ascontiguousarray(left[:, ::-1])
        other = np.ascontiguousarray(right[:, ::-1])
        notes.append("reference 'left': images mirrored for matching, products mirrored back")
    else:
        reference, other = right, left
    lo, hi = resolve_disparity_range(camera, right.shape, params)
    band = resolve_row_band(camera, right.shape, params)
    gradient = resolve_row_gradient(camera, right.shape, params)
    # rectification fill: matched smoothly extended (its edge would draw every window
    # across it), then given no disparity (stages._fill)
    fill_ref, fill_oth = border_fill(reference), border_fill(other)
    ref_m = reference if fill_ref is None else extend_into_fill(reference, fill_ref)
    oth_m = other if fill_oth is None else extend_into_fill(other, fill_oth)
    has_fill = fill_ref is not None or fill_oth is not None
    matching, tiled = _match(ref_m, oth_m, lo, hi, band, params, gradient)
    disparity_m, valid_fraction = matching.disparity, matching.valid_fraction
    if has_fill:
        disparity_m = disparity_without_fill(disparity_m, fill_ref, fill_oth)
        imaged = np.ones(reference.shape, bool) if fill_ref is None else ~fill_ref
        valid_fraction = float(np.mean(np.isfinite(disparity_m[imaged])))
        notes.append(
            "black fill along the border: matched smoothly extended, no disparity on it or "
            "where a match lands on it; valid_fraction counts the imaged pixels only"
        )
    if tiled:
        notes.append(f"matched in tiles of {params['tile_px']} px")
    if not camera.has_pose:
        notes.append(poseless_note(camera, disparity_m, hi, params))
    if camera.has_pose or int(params["max_disparity"]) or float(params["nearest_range_m"]):
        notes.extend(limit_note(disparity_m, hi, params))
    refined_fraction = 0.0
    if params["ground_refine"] and params["method"] != "opencv-sgbm":
        plane_px = _refine.fit_disparity_plane(disparity_m)
        if plane_px is not None:
            disparity_m, source = _refine.refine_against_ground(
                ref_m, oth_m, disparity_m, plane=plane_px
            )
            if has_fill:  # the refinement may have matched the fill again
                disparity_m = disparity_without_fill(disparity_m, fill_ref, fill_oth)
            refined_fraction = float(np.mean(source > 0))
    pseudo = pseudo_left(reference, disparity_m)
    diff = residual(other, pseudo)
    if fill_oth is not None:
        diff[fill_oth] = np.nan  # no image to compare with there
    disparity = disparity_m[:, ::-1] if mirrored else disparity_m
    diff = diff[:, ::-1] if mirrored else diff
    disparity = np.ascontiguousarray(disparity, dtype=np.float32)
    diff = np.ascontiguousarray(diff, dtype=np.float32)

    range_m = range_from_disparity(
        disparity, focal_px=camera.focal_px, baseline_m=camera.baseline_m
    )
    fit = fit_ground_plane(disparity, camera=camera, inlier_px=float(params["ground_inlier_px"]))
    if np.all(np.isfinite(fit.plane)):
        height = height_from_disparity(disparity, fit.plane, camera=camera)
        mismatch = pose_notes(camera, fit.source, float(fit.plane[3]), _pitch_deg(fit.plane))
    else:
        height = np.full(disparity.shape, np.nan, np.float32)
        notes.append("no ground plane fitted: height is NaN")
        mismatch = []
    # a poorly matched frame, or one whose ground disagrees with the pose (sgm fills an
    # exchanged pair 90 %), is checked for exchanged images; only a frame matched very
    # poorly for a vertical offset (that check misreads some dunes frames)
    if valid_fraction < SWAP_CHECK_BELOW or mismatch:
        notes.extend(swapped_note(left, right, hi))
    if valid_fraction < OFFSET_CHECK_BELOW:
        notes.extend(offset_note(left, right, hi))
    notes.extend(mismatch)

    defined = np.isfinite(diff)
    rms = float(np.sqrt(np.mean(np.square(diff[defined])))) if defined.any() else float("nan")
    finite_range = range_m[np.isfinite(range_m)]
    figures = {
        "rms_residual": rms,
        "valid_fraction": valid_fraction,
        "lr_consistency": float(matching.lr_consistency),
        "ground_fit_inliers": fit.inlier_fraction,
        "ground_fit": fit.source,
        "ground_height_m": float(fit.plane[3]),
        "ground_pitch_deg": _pitch_deg(fit.plane),
        "min_disparity": lo,
        "max_disparity": hi,
        "ground_refined_fraction": refined_fraction,
        "median_range_m": _median_range(finite_range),
    }
    return StageResult(
        arrays={
            "disparity": disparity,
            "range": range_m,
            "residual": diff,
            "height": np.ascontiguousarray(height, dtype=np.float32),
            "ground_plane": np.asarray(fit.plane, dtype=np.float64),
        },
        figures=figures,
        notes=notes,
    )


STAGE = Stage(
    name="depth",
    version="7",
    inputs=("left", "right"),
    outputs=OUTPUTS,
    params=PARAMS,
    run=run_depth,
    doc="stereo disparity (adaptive-window ZNCC), range, pseudo-left residual, ground height",
    check_params=_coerce_settings,  # windows' syntax, odd sizes: before any work
)
