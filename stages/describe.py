"""Feature analysis: per-rock descriptors in metres and the relational scene graph.

Reads the reference image, the labels and the depth products of a frame and writes two
tables: ``descriptors`` (one row per object, columns in ``docs/design.md``; measurement rules
in :mod:`stages._descriptors`) and ``relations`` (one row per edge, definitions in
:mod:`stages._relations`). Per-frame figures: rock count, the fraction of the ground covered
by rocks and the Golombek-Rapp size-frequency fit (:mod:`stages._sizefreq`).

Example: which samples lie behind an obstacle, in line with it as seen from the camera
(``overlap > 0``) and within ``relation_radius_m`` of it on the ground (ordering edges are
local, see :mod:`stages._relations`); DuckDB over the run's Parquet files::

    SELECT s.frame_id, s.object_id AS sample_id, o.object_id AS obstacle_id, r.overlap
    FROM descriptors s
    JOIN relations r ON r.run_id = s.run_id AND r.frame_id = s.frame_id
                    AND r.subject_id = s.object_id AND r.relation = 'behind'
    JOIN descriptors o ON o.run_id = r.run_id AND o.frame_id = r.frame_id
                      AND o.object_id = r.object_id
    WHERE s.size_class = 'sample' AND o.size_class = 'obstacle' AND r.overlap > 0
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.camera import Camera
from pipeline.stage import FrameContext, Param, Product, Stage, StageResult

from ._descriptors import DESCRIPTOR_COLUMNS, _object_slices, describe_objects, frame_ground
from ._ground import coerce_ground_plane
from ._relations import RELATION_COLUMNS, relate_objects
from ._sizefreq import fit_size_frequency, visible_ground_area_m2

__all__ = [
    "STAGE",
    "DESCRIPTOR_SCHEMA",
    "RELATION_SCHEMA",
    "describe_frame",
    "run_describe",
]

_ARROW_TYPES = {
    "int32": pa.int32(),
    "int64": pa.int64(),
    "float64": pa.float64(),
    "bool": pa.bool_(),
    "str": pa.string(),
}

DESCRIPTOR_SCHEMA: pa.Schema = pa.schema(
    [(name, _ARROW_TYPES[kind]) for name, kind in DESCRIPTOR_COLUMNS.items()]
)
"""Arrow schema of the descriptor columns the stage returns (without archive/run_id/frame_id)."""

RELATION_SCHEMA: pa.Schema = pa.schema(
    [(name, _ARROW_TYPES[kind]) for name, kind in RELATION_COLUMNS.items()]
)
"""Arrow schema of the relation columns the stage returns (without archive/run_id/frame_id)."""


def describe_frame(
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
    occlusion_jump_px: float = 0.1,
    margin_m: float = 0.05,
    relation_radius_m: float = 1.0,
    gap_px: int = 2,
    contact_gap_px: int = 0,
    band_px: int = 3,
    sfd_max_range_m: float = 5.0,
    sfd_min_diameter_m: float = 0.0,
    fringe_height_m: float = 0.004,
    fringe_reach_px: int = 3,
    fringe_smoothing_px: int = 7,
    border_height_quantile: float = 0.9,
    borderline_fraction: float = 0.1,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """Descriptors, relations and per-frame figures of one frame.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 = background, k = object k.
    gray : (M, N) ndarray of uint8
        Reference (right) image.
    disparity, range_m, height : (M, N) ndarray of float32
        Depth products, NaN where invalid.
    camera : Camera
    ground_plane : (4,) ndarray of float64, optional
        Fitted ground plane (camera frame, unit normal up); NaN or None when not fitted.
    sample_max_m, rover_clearance_m, min_valid_fraction, background_jump_px : float
        See :func:`stages._descriptors.describe_objects`.
    occlusion_jump_px : float
        Disparity difference (px) across a contact that makes the nearer region occlude.
    margin_m : float
        Near-tie margin of left/right and front/behind, metres.
    relation_radius_m : float
        left/right and front/behind edges link only objects at most this far apart on the
        ground, metres, > 0 (a value beyond the scene, e.g. 1e6, orders every pair; see
        :mod:`stages._relations`).
    gap_px, contact_gap_px, band_px : int
        Adjacency gap, contact gap and occlusion band, pixels
        (see :mod:`stages._relations`).
    sfd_max_range_m : float
        Ground area and rocks beyond this range are left out of the size-frequency figures
        (far rocks are under-resolved and would bias ``k`` low).
    sfd_min_diameter_m : float
        Completeness limit of the size-frequency fit.
    fringe_height_m, fringe_reach_px : float, int
        Footprint (``width_m``, ``length_m``) without ground-level fringes such as a sun
        shadow segmented with the rock: pixels lower than ``fringe_height_m`` (m, >= 0; 0
        keeps all) and more than ``fringe_reach_px`` pixels from the rock's raised part are
        left out (see :func:`stages._footprint.ground_fringe_keep`).
    fringe_smoothing_px : int
        Odd, >= 1: the heights that decide it are first averaged over this box of the
        object's pixels (1: each pixel alone).
    border_height_quantile : float
        In [0, 1): objects cut by the image border are classed with their width bounded
        from below by their height over this quantile of height / width of the frame's
        objects seen whole (0: their visible width alone; see :mod:`stages._border`).
    borderline_fraction : float
        In [0, 1]: ``size_class_borderline`` is true when a size that decided the class
        lies within this share of its limit, or is unknown (0: never; see
        :func:`stages._descriptors.size_class_borderline`).

    Returns
    -------
    descriptors : dict of str to (K,) ndarray
        Columns of :data:`DESCRIPTOR_SCHEMA`.
    relations : dict of str to (E,) ndarray
        Columns of :data:`RELATION_SCHEMA`.
    figures : dict of str to number or str
        Per-frame figures.
    """
    plane = coerce_ground_plane(ground_plane)
    # one whole-frame find_objects for both tables (other inputs: describe_objects' errors)
    lab = np.asarray(labels)
    slices = _object_slices(lab) if lab.ndim == 2 and lab.dtype.kind in "iu" else None
    desc = describe_objects(
        labels,
        gray,
        disparity,
        range_m,
        height,
        camera=camera,
        ground_plane=plane,
        sample_max_m=sample_max_m,
        rover_clearance_m=rover_clearance_m,
        min_valid_fraction=min_valid_fraction,
        background_jump_px=background_jump_px,
        fringe_height_m=fringe_height_m,
        fringe_reach_px=fringe_reach_px,
        fringe_smoothing_px=fringe_smoothing_px,
        border_height_quantile=border_height_quantile,
        borderline_fraction=borderline_fraction,
        object_slices=slices,
    )
    rel = relate_objects(
        labels,
        disparity,  # converted and cleaned (<= 0: NaN) crop by crop there
        object_ids=desc["object_id"],
        x_m=desc["x_m"],
        y_m=desc["y_m"],
        bbox_x_min=desc["bbox_x_min"],
        bbox_x_max=desc["bbox_x_max"],
        margin_m=margin_m,
        radius_m=relation_radius_m,
        gap_px=gap_px,
        band_px=band_px,
        contact_gap_px=contact_gap_px,
        occlusion_jump_px=occlusion_jump_px,
        object_slices=slices,
    )
    hidden = np.unique(rel["object_id"][rel["relation"] == "occludes"])
    desc["occluded"] = desc["occluded"] | np.isin(desc["object_id"], hidden)
    figures = _frame_figures(
        desc,
        rel,
        np.asarray(labels),
        camera=camera,
        plane=plane,
        sfd_max_range_m=sfd_max_range_m,
        sfd_min_diameter_m=sfd_min_diameter_m,
    )
    return desc, rel, figures


def _frame_figures(
    desc: dict[str, np.ndarray],
    rel: dict[str, np.ndarray],
    labels: np.ndarray,
    *,
    camera: Camera,
    plane: np.ndarray | None,
    sfd_max_range_m: float,
    sfd_min_diameter_m: float,
) -> dict[str, Any]:
    ground = frame_ground(camera, plane)
    area = math.nan
    if ground is not None:
        area = visible_ground_area_m2(
            labels.shape,
            focal_px=camera.focal_px,
            principal_point=camera.principal_point(labels.shape),
            up=ground.up,
            camera_height_m=float(-(ground.up @ ground.origin)),
            max_range_m=sfd_max_range_m,
        )
    with np.errstate(invalid="ignore"):
        near = desc["range_m"] <= sfd_max_range_m
    fit = None
    if math.isfinite(area) and area > 0:
        fit = fit_size_frequency(
            desc["width_m"][near], ground_area_m2=area, d_min_m=sfd_min_diameter_m
        )
    return {
        "rock_count": int(desc["object_id"].size),
        "n_samples": int(np.sum(desc["size_class"] == "sample")),
        "n_obstacles": int(np.sum(desc["size_class"] == "obstacle")),
        "n_relations": int(rel["subject_id"].size),
        "rock_pixel_fraction": float(np.mean(labels > 0)) if labels.size else 0.0,
        "ground_area_m2": area,
        "rock_area_fraction": fit.rock_area_fraction if fit else math.nan,
        "sfd_k": fit.k if fit else math.nan,
        "sfd_q": fit.q if fit else math.nan,
        "sfd_n_rocks": fit.n_rocks if fit else 0,
        "ground_source": ground.source if ground is not None else "none",
    }


def run_describe(
    inputs: dict[str, np.ndarray], *, frame: FrameContext, params: dict[str, Any]
) -> StageResult:
    """Stage entry point: see :func:`describe_frame`."""
    desc, rel, figures = describe_frame(
        inputs["labels"],
        inputs[frame.camera.reference],
        inputs["disparity"],
        inputs["range"],
        inputs["height"],
        camera=frame.camera,
        ground_plane=inputs.get("ground_plane"),
        **params,
    )
    notes = []
    if figures["ground_source"] == "none" and desc["object_id"].size:
        # a frame with neither a camera pose nor a fitted ground plane: every object came
        # out an 'obstacle' with NaN positions, and only depth's note said why
        notes.append(
            "no ground frame (no camera pose and no ground plane fitted): ground positions, "
            "lengths, ordering relations and the size-frequency fit are missing, and an "
            "object without a height is classed obstacle; give [camera] height_m and pitch_deg"
        )
    return StageResult(
        tables={"descriptors": desc, "relations": rel}, figures=figures, notes=notes
    )


STAGE = Stage(
    name="describe",
    version="11",
    inputs=("left", "right", "labels", "disparity", "range", "height", "ground_plane"),
    outputs=(
        Product(
            "descriptors",
            kind="table",
            schema=DESCRIPTOR_SCHEMA,
            attrs={"long_name": "per-object descriptors"},
        ),
        Product(
            "relations",
            kind="table",
            schema=RELATION_SCHEMA,
            attrs={"long_name": "scene-graph edges"},
        ),
    ),
    params=(
        Param("sample_max_m", float, 0.10, "largest cross-section of a sample, m", minimum=0),
        Param(
            "rover_clearance_m",
            float,
            0.10,
            "rocks higher than this are obstacles, m",
            minimum=0,
        ),
        Param(
            "min_valid_fraction",
            float,
            0.5,
            "depth_unreliable below this valid share",
            minimum=0,
            maximum=1,
        ),
        Param(
            "background_jump_px",
            float,
            1.0,
            "nearer background by this much: occluded, px",
            minimum=0,
        ),
        Param(
            "occlusion_jump_px",
            float,
            0.1,
            "disparity step across a contact: occludes, px",
            minimum=0,
        ),
        Param("margin_m", float, 0.05, "near-tie margin of left_of/behind..., m", minimum=0),
        Param(
            "relation_radius_m",
            float,
            1.0,
            "left_of/behind... only between rocks this close on the ground, m (1e6: all)",
            minimum=0,
        ),
        Param("gap_px", int, 2, "largest gap between adjacent regions, px", minimum=0),
        Param("contact_gap_px", int, 0, "gap still counted as contact, px", minimum=0),
        Param("band_px", int, 3, "boundary band of the occlusion test, px", minimum=1),
        Param(
            "sfd_max_range_m",
            float,
            5.0,
            "size-frequency: farthest range counted, m",
            minimum=0,
        ),
        Param(
            "sfd_min_diameter_m",
            float,
            0.0,
            "size-frequency: completeness limit, m",
            minimum=0,
        ),
        Param(
            "fringe_height_m",
            float,
            0.004,
            "width/length leave out pixels lower than this far from the raised part, m (0: off)",
            minimum=0,
        ),
        Param(
            "fringe_reach_px",
            int,
            3,
            "... farther than this from a raised pixel (shadows beside a rock), px",
            minimum=0,
        ),
        Param(
            "fringe_smoothing_px",
            int,
            7,
            "... judged on heights averaged over this odd box of the object's pixels (1: off)",
            minimum=1,
        ),
        Param(
            "border_height_quantile",
            float,
            0.9,
            "border-cut rocks: width >= height / this quantile of whole rocks' h/w (0: off)",
            minimum=0,
            maximum=0.99,
        ),
        Param(
            "borderline_fraction",
            float,
            0.1,
            "size_class_borderline: a deciding size within this share of its limit (0: never)",
            minimum=0,
            maximum=1,
        ),
    ),
    run=run_describe,
    doc="per-rock descriptors in metres, scene-graph relations, size-frequency fit",
)
