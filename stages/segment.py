"""Segmentation stage: the study's adaptive sector-histogram method, strengthened by depth.

``method = 'sector-histogram'`` reproduces the study on the reference (right) image alone:
sector histograms, nine-point smoothing, modes with a prominence rule, background chosen by
continuity with phantom peaks, thresholds at the valleys on both sides interpolated between
sector centres (Chow and Kaneko), connected components, speck removal, hole filling. The math
is in :mod:`stages._sectors` (histograms, modes, interpolation), :mod:`stages._continuity`
(background by continuity, phantom peaks, thresholds), :mod:`stages._regions` (masks,
components, split), :mod:`stages._texture_rules` (streaks), :mod:`stages._rock_parts` (shadows,
halves), :mod:`stages._outlines` (necks, rims), :mod:`stages._shadow_sides` (shaded faces),
:mod:`stages._height_grow` (raised rests), :mod:`stages._blobs` (compact blobs),
:mod:`stages._height_blobs` (faint blobs standing as height bumps),
:mod:`stages._two_face_blobs` (blobs of a lit and a shaded face),
:mod:`stages._depth_rules` (height rules) and :mod:`stages._height_vote` (the
noisy-height vote), all documented rule by rule.

``method = 'sector-histogram+depth'`` (default) adds the depth stage's ``height`` (metres
above the fitted ground plane) and ``disparity`` (rules R0-R3 in :mod:`stages._depth_rules`
and :mod:`stages._height_vote`, R4 in :mod:`stages._regions`, R5-R5d in
:mod:`stages._texture_rules`, R6-R7c in :mod:`stages._rock_parts`, R6b, R6c and R7g in
:mod:`stages._sun_shadows`, R4b and R7d in :mod:`stages._outlines`, R7e in
:mod:`stages._shadow_sides`, R7f in :mod:`stages._height_grow`, R7h in
:mod:`stages._rock_parts`, R8 in :mod:`stages._blobs`,
R8b in :mod:`stages._height_blobs`, R8c in :mod:`stages._two_face_blobs`):
raised pixels are object even when their gray equals the ground's, flat intensity objects
(shadows, stains, texture blotches) are background, touching objects split at disparity
jumps or, at one range, at narrow necks (R4b), streaks (ripple troughs) are dropped unless
they stand clearly out of the ground (R5b, R5d) and so are, in a field of parallel streaks,
objects that do not stand out of the ripple texture around them, objects whose other half
lies just inside the thresholds grow into it when they stay compact (R7), a lighter and a
darker half of one rock are joined (R7b), pieces of the other side lying where the sun
puts no face of the rock go (R7g), near the camera a lit face takes the raised part
of a dark neighbour and the flat rest, its cast shadow, goes (R7e; for clearly raised faces also
before R7b, which would join face and shadow whole), a
raised object grows over the raised rest of its rock on its gray side (R7f: a large object
clearly above the ground, a mid-sized one a little out on its side, a large flat one by broad
areas only), and the
intensity decision stands where depth is invalid -- for the whole frame when fewer than
``min_depth_valid_fraction`` of its heights are valid. How much the height rules trust
single pixels depends on the measured height noise of the ground (precise, noisy and
unusable regimes).

The reference image is the product ``right``, or ``left`` when the catalog's camera says
``reference = "left"`` (the depth products are then in left-image geometry too).

The extension to the study's intensity rule (``merge_ratio``: ripple facets merged into the
ground) is in :mod:`stages._continuity`; ``merge_ratio = 1`` restores the study exactly.

Frames larger than ``tile_px`` on a side get their sector histograms per tile on dask
(chunks aligned to sector edges); the continuity pass runs on the small sector grid.

Both methods leave a rectified frame's black fill (regions of gray 0 touching the border,
over 1 % of the frame: :mod:`stages._fill`) out of the sector histograms, the thresholds
and every object, and say so in a note; frames without fill are segmented as before.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from pipeline.compute import compute
from pipeline.stage import FrameContext, Param, Product, Stage, StageResult

from ._blobs import add_compact_blobs, blob_scales
from ._continuity import SectorAnalysis, analyse_sectors
from ._depth_rules import (
    _NOISY_SIGMA_M,
    _sampled_row_band_sigma,
    apply_depth_rules,
    drop_faint_depthless,
    gray_contrast,
)
from ._depth_rules import _UNUSABLE_SIGMA_M as _USABLE_SIGMA_M
from ._fill import border_fill, histograms_without_fill
from ._height_blobs import add_height_blobs
from ._height_grow import grow_raised_parts
from ._height_vote import BumpWeights
from ._heights import DepthRuleStats, _fraction, relative_height
from ._outlines import split_at_necks, trim_faint_rims
from ._regions import depth_edges, label_objects, threshold_mask
from ._rock_parts import (
    grow_other_faces,
    grow_weak_halves,
    join_grown_pieces,
    join_opposite_halves,
    trim_attached_shadows,
)
from ._sectors import (
    N_LEVELS,
    _histograms_between,
    interpolate_sector_grid,
    sector_edges,
    sector_histograms,
)
from ._shadow_sides import split_shadow_sides
from ._sun_shadows import trim_flat_shadow_sides, trim_off_side_pieces, trim_sun_shadows
from ._texture_rules import drop_ripple_pieces, drop_streaks
from ._two_face_blobs import add_two_faced_blobs

__all__ = [
    "METHODS",
    "STAGE",
    "Segmentation",
    "segment_image",
    "tiled_sector_histograms",
    "run_segment",
]

METHODS = ("sector-histogram", "sector-histogram+depth")
_SECTOR_DIMS = ("frame", "sector_y", "sector_x")


@dataclass
class Segmentation:
    """Result of :func:`segment_image`.

    Attributes
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects (dense).
    sectors : SectorAnalysis
        Per-sector background, thresholds, mode counts, phantom and seed flags.
    depth : DepthRuleStats or None
        What the depth rules changed; None when depth was not used.
    streaks_dropped : int
        Objects removed as streaks (rule R5).
    notes : list of str
    """

    labels: np.ndarray
    sectors: SectorAnalysis
    depth: DepthRuleStats | None = None
    streaks_dropped: int = 0
    notes: list[str] = field(default_factory=list)


def _coerce_depth(values: Any, shape: tuple[int, int], name: str) -> np.ndarray | None:
    if values is None:
        return None
    if not isinstance(values, np.ndarray):
        raise TypeError(f"{name} must be a numpy array or None, got {type(values).__name__}")
    if values.shape != shape:
        raise ValueError(
            f"{name} has shape {values.shape} but the reference image has {shape}; "
            "depth products must be in reference-image geometry"
        )
    if values.dtype.kind != "f":
        raise TypeError(f"{name} must be float (NaN where invalid), got dtype {values.dtype}")
    return values.astype(np.float32, copy=False)


def segment_image(
    image: np.ndarray,
    *,
    method: str = "sector-histogram+depth",
    height: np.ndarray | None = None,
    disparity: np.ndarray | None = None,
    histograms: np.ndarray | None = None,
    sectors: int = 16,
    smoothing: int = 1,
    prominence: float = 0.1,
    seed_dominance: float = 0.3,
    continuity_range: float = 24.0,
    band_sigmas: float = 3.5,
    min_band: float = 6.0,
    merge_ratio: float = 0.35,
    min_area_px: int = 30,
    fill_holes: bool = True,
    min_height_m: float = 0.008,
    flat_tol_m: float = 0.003,
    ground_window_px: int = 72,
    min_raised_fraction: float = 0.1,
    base_px: int = 2,
    height_smoothing_px: int = 5,
    split_disparity_px: float = 3.0,
    max_elongation: float = 3.0,
    ripple_texture_ratio: float = 1.5,
    min_depth_valid_fraction: float = 0.5,
    weak_bands: float = 0.7,
    weak_growth_px: int = 12,
    join_gap_px: int = 5,
    piece_gap_px: int = 2,
    face_bands: float = 0.5,
    face_side_deg: float = 105.0,
    join_side_deg: float = 60.0,
    off_side_deg: float = 105.0,
    neck_ratio: float = 0.5,
    blob_sigmas: float = 0.0,
    height_blob_sigmas: float = 0.0,
    two_face_sigmas: float = 0.0,
    rim_fraction: float = 0.3,
    shadow_noise_m: float = 0.0075,
    height_grow_fraction: float = 0.5,
    sun_shadow_angle_deg: float = 45.0,
) -> Segmentation:
    """Segment one reference image into background and numbered objects.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Reference (right) gray image.
    method : {'sector-histogram', 'sector-histogram+depth'}
        Faithful study method, or with the depth rules (:mod:`stages._depth_rules`,
        :mod:`stages._regions`, :mod:`stages._texture_rules`, :mod:`stages._rock_parts`).
    height : (M, N) ndarray of float32, optional
        Metres above the ground plane, NaN invalid. Ignored by the faithful method.
    disparity : (M, N) ndarray of float32, optional
        Pixels, NaN invalid; used to split touching objects. Ignored by the faithful method.
    histograms : (S, S, 256) ndarray of int, optional
        Precomputed :func:`stages._sectors.sector_histograms` (e.g. computed per tile).
    sectors : int
        Sectors per axis, ``2 <= sectors <= min(M, N) // 4``.
    smoothing, prominence, seed_dominance, continuity_range, band_sigmas, min_band, merge_ratio
        See :func:`stages._continuity.analyse_sectors`.
    min_area_px : int
        ``>= 1``; smaller objects are specks.
    fill_holes : bool
        Fill enclosed background pockets.
    min_height_m, flat_tol_m, base_px, height_smoothing_px, ground_window_px
    min_raised_fraction
        See :func:`stages._depth_rules.apply_depth_rules`.
    split_disparity_px : float
        ``>= 0`` px; disparity jump that splits touching objects; 0 disables the split.
    min_depth_valid_fraction : float
        In ``[0, 1]``: below this share of valid heights the ground plane (and every height
        measured from it) is not trusted and the height rules are skipped.
    max_elongation : float
        Depth method only: objects longer than this times their width are streaks (rule R5
        of :mod:`stages._texture_rules`); 0 disables.
    ripple_texture_ratio : float
        Depth method only, ``>= 0``: in a field of ripples an object must stand this many
        times beyond the gray-level texture around it (rule R5c of
        :mod:`stages._texture_rules`); 0 disables.
    weak_bands, weak_growth_px : float, int
        Depth method only: objects grow up to ``weak_growth_px`` pixels into pixels past
        neither threshold but at least ``weak_bands`` threshold bands from the ground on their
        own side, when that leaves them at least as solid (rule R7 of
        :mod:`stages._rock_parts`); either 0 disables.
    join_gap_px : int
        Depth method only, ``>= 0``: a lighter and a darker object this close, facing each
        other, are joined when their union is about as solid as either (rule R7b of
        :mod:`stages._rock_parts`); 0 disables.
    face_bands : float
        Depth method only, ``>= 0``: objects grow up to ``weak_growth_px`` pixels into pixels
        this many bands from the ground on the other side, when that leaves them about as
        solid (rule R7c of :mod:`stages._rock_parts`); 0 disables.
    face_side_deg : float
        Depth method only, in ``[0, 180]`` degrees: where the frame's sun direction is known
        (rule R6b), R7c drops the pieces of a growth lying more than this far from the side
        the object's other face lies on (rule R7c of :mod:`stages._rock_parts`); 0 or 180
        disables.
    join_side_deg : float
        Depth method only, in ``[0, 180]`` degrees: where the frame's sun direction is known
        (rule R6b), R7b joins a lighter and a darker object only when the darker one lies
        at most this far from the direction away from the sun, seen from the lighter one
        (rule R7b of :mod:`stages._rock_parts`; R7h's pairs of opposite sides too); 0 or
        180 disables the test.
    piece_gap_px : int
        Depth method only, ``>= 0``: after R7f, two objects of either side this close,
        facing each other, are joined when their union is at most 0.02 less solid than the
        more solid (rule R7h of :mod:`stages._rock_parts`); 0 disables.
    off_side_deg : float
        Depth method only, in ``[0, 180]`` degrees: after R7d, where the frame's sun
        direction is known, an object's pieces past the other side's threshold lying more
        than this far from the side its other face would lie on are dropped (rule R7g of
        :mod:`stages._sun_shadows`); 0 or 180 disables.
    neck_ratio : float
        Depth method only, in ``[0, 1)``: an object that narrows to this fraction of the
        depth of two compact lobes is split there (rule R4b of :mod:`stages._outlines`);
        0 disables.
    rim_fraction : float
        Depth method only, in ``[0, 1)``: after R7c, outline pixels nearer the ground's gray
        level than this fraction of their object's median contrast are dropped (rule R7d of
        :mod:`stages._outlines`); 0 disables.
    shadow_noise_m : float
        Depth method only, ``>= 0`` metres: in rows whose ground height noise is at most this,
        a light object takes the raised part of a dark neighbour and the flat rest (its cast
        shadow) is dropped (rule R7e of :mod:`stages._shadow_sides`); 0 disables.
    height_grow_fraction : float
        Depth method only, in ``[0, 1]``: in rows whose ground height noise is at most 10
        mm, a large object standing clearly above the ground grows over connected
        background pixels raised above this fraction of its core height and on its side of
        the ground's gray level (rule R7f of :mod:`stages._height_grow`; its second and
        third cases, smaller and flatter objects, have their own fractions there); 0
        disables all three.
    sun_shadow_angle_deg : float
        Depth method only, in ``[0, 90]`` degrees: where heights are not precise, a dark
        object's lighter pieces within this angle of the frame's direction away from the sun
        (from its lit objects' dark sides), at most half the ground's gray, are dropped as
        its cast shadow (rule R6b of :mod:`stages._sun_shadows`); 0 disables, R6c too (a
        dark object's flat, darker pixels on that side, where heights are precise).
    blob_sigmas : float
        Depth method only, ``>= 0``: compact blobs this many ground spreads (at their own
        scale) darker or lighter than the ground that no object touches are added (rule R8
        of :mod:`stages._blobs`); 0 disables.
    height_blob_sigmas : float
        Depth method only, ``>= 0``: after R8, compact blobs this many ground spreads out
        that no object touches are added when they stand as a height bump and their edges
        are crisper than the ground's texture (rule R8b of :mod:`stages._height_blobs`);
        0 disables, and so do heights the depth rules do not use or find unusable.
    two_face_sigmas : float
        Depth method only, ``>= 0``: after R7f and before R8, solid blobs made of a darker
        and a lighter face side by side, each this many ground spreads out at R8's scale,
        that no object touches are added (rule R8c of :mod:`stages._two_face_blobs`); 0
        disables.

    Returns
    -------
    Segmentation
    """
    if not isinstance(image, np.ndarray):
        raise TypeError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(
            f"image must be a 2-D uint8 gray image, got shape {image.shape} dtype {image.dtype}"
        )
    if method not in METHODS:
        raise ValueError(f"method must be one of {list(METHODS)}, got {method!r}")
    if not isinstance(sectors, int | np.integer) or isinstance(sectors, bool):
        raise TypeError(f"sectors must be an int, got {type(sectors).__name__}")
    if min(image.shape) < 8:
        raise ValueError(
            f"an image of shape {image.shape} is too small to segment: sectors need at least "
            "4x4 pixels and there must be 2x2 of them (at least 8x8 pixels)"
        )
    if not 2 <= sectors <= min(image.shape) // 4:
        raise ValueError(
            f"sectors must be in [2, {min(image.shape) // 4}] for an image of shape "
            f"{image.shape} (at least 4x4 pixels per sector), got {sectors}; pass fewer "
            f"(arroyo run: --set segment.sectors={min(image.shape) // 4})"
        )
    if max_elongation != 0 and not max_elongation > 1:
        raise ValueError(f"max_elongation must be 0 (off) or > 1, got {max_elongation}")
    if not ripple_texture_ratio >= 0:
        raise ValueError(
            f"ripple_texture_ratio must be >= 0 (0 disables), got {ripple_texture_ratio}"
        )
    if split_disparity_px < 0:
        raise ValueError(f"split_disparity_px must be >= 0 (0 disables), got {split_disparity_px}")
    if not 0 <= neck_ratio < 1 or not 0 <= rim_fraction < 1:
        raise ValueError(
            f"neck_ratio and rim_fraction must be in [0, 1) (0 disables), got {neck_ratio} "
            f"and {rim_fraction}"
        )
    if not shadow_noise_m >= 0:
        raise ValueError(f"shadow_noise_m must be >= 0 (0 disables), got {shadow_noise_m}")
    if not 0 <= height_grow_fraction <= 1:
        raise ValueError(
            f"height_grow_fraction must be in [0, 1] (0 disables), got {height_grow_fraction}"
        )
    if not all(0 <= deg <= 180 for deg in (face_side_deg, off_side_deg, join_side_deg)):
        raise ValueError(
            "face_side_deg, off_side_deg and join_side_deg must be in [0, 180] (0 disables), "
            f"got {face_side_deg}, {off_side_deg} and {join_side_deg}"
        )
    if not 0 <= sun_shadow_angle_deg <= 90:
        raise ValueError(
            f"sun_shadow_angle_deg must be in [0, 90] (0 disables), got {sun_shadow_angle_deg}"
        )
    if not blob_sigmas >= 0 or not height_blob_sigmas >= 0:
        raise ValueError(
            "blob_sigmas and height_blob_sigmas must be >= 0 (0 disables), got "
            f"{blob_sigmas} and {height_blob_sigmas}"
        )
    if not two_face_sigmas >= 0:
        raise ValueError(f"two_face_sigmas must be >= 0 (0 disables), got {two_face_sigmas}")
    if not weak_bands >= 0 or weak_growth_px < 0 or join_gap_px < 0 or not face_bands >= 0:
        raise ValueError(
            "weak_bands, weak_growth_px, join_gap_px and face_bands must be >= 0 (0 disables), "
            f"got {weak_bands}, {weak_growth_px}, {join_gap_px} and {face_bands}"
        )
    if piece_gap_px < 0:
        raise ValueError(f"piece_gap_px must be >= 0 (0 disables), got {piece_gap_px}")
    shape = image.shape
    if histograms is None:
        histograms = sector_histograms(image, sectors=sectors)
    elif histograms.shape != (sectors, sectors, N_LEVELS):
        raise ValueError(
            f"histograms must have shape {(sectors, sectors, N_LEVELS)}, got {histograms.shape}"
        )
    notes: list[str] = []
    # a rectified frame's black fill is no ground and no rock: out of the histograms, the
    # threshold mask and every object (rules may grow into it: cleared again at the end)
    fill = border_fill(image)
    if fill is not None:
        histograms = histograms_without_fill(
            histograms,
            fill,
            row_edges=sector_edges(shape[0], sectors),
            col_edges=sector_edges(shape[1], sectors),
        )
        notes.append(
            f"{np.count_nonzero(fill) / fill.size:.1%} of the frame is black fill along the "
            "border: left out"
        )
    analysis = analyse_sectors(
        histograms,
        smoothing=smoothing,
        prominence=prominence,
        seed_dominance=seed_dominance,
        continuity_range=continuity_range,
        band_sigmas=band_sigmas,
        min_band=min_band,
        merge_ratio=merge_ratio,
    )
    low = interpolate_sector_grid(analysis.low, shape)
    high = interpolate_sector_grid(analysis.high, shape)
    mask = threshold_mask(image, low, high)
    if fill is not None:
        mask &= ~fill
    strong = mask  # past a threshold (R7 grows into the other pixels only)

    # R2d's bump-map weights, kept for R8b's map (both read the height map's valid pixels)
    bump_weights = BumpWeights()
    depth_stats = None
    edges = None
    contrast = None
    texture = None
    relative = None
    if method == "sector-histogram+depth":
        if ripple_texture_ratio > 0 and max_elongation > 0:
            # R5c's evidence: the ground texture's objects, before the depth rules thin them
            texture = label_objects(mask, min_area_px=min_area_px, fill=False)
        background = interpolate_sector_grid(analysis.background, shape)
        contrast = gray_contrast(image, background=background, low=low, high=high)
        height = _coerce_depth(height, shape, "height")
        disparity = _coerce_depth(disparity, shape, "disparity")
        valid_fraction = _fraction(np.isfinite(height)) if height is not None else 0.0
        if height is not None and valid_fraction >= min_depth_valid_fraction:
            # R0's relative heights, read by the depth rules and again by R7e
            relative = relative_height(
                height, smoothing_px=height_smoothing_px, ground_window_px=ground_window_px
            )
            mask, depth_stats = apply_depth_rules(
                mask,
                height,
                min_height_m=min_height_m,
                flat_tol_m=flat_tol_m,
                base_px=base_px,
                smoothing_px=height_smoothing_px,
                ground_window_px=ground_window_px,
                min_raised_fraction=min_raised_fraction,
                contrast=contrast,
                relative=relative,
                _weights=bump_weights,
            )
        else:
            notes.append(
                f"height valid on {100 * valid_fraction:.0f}% of the frame (< "
                f"{100 * min_depth_valid_fraction:.0f}%): intensity rules only"
            )
        if disparity is not None and split_disparity_px > 0 and np.isfinite(disparity).any():
            edges = depth_edges(disparity, jump_px=split_disparity_px)
    labels = label_objects(mask, min_area_px=min_area_px, fill=fill_holes, edges=edges)
    if depth_stats is not None and depth_stats.ground_sigma_m <= _USABLE_SIGMA_M:
        # R3b: where the vote could not judge an object, its gray level must be clear
        labels, faint = drop_faint_depthless(
            labels,
            image,
            height,
            background=background,
            low=low,
            high=high,
        )
        if faint:
            notes.append(f"{faint} faint object(s) without heights dropped")
    if method == "sector-histogram+depth" and neck_ratio > 0:
        # R4b: touching rocks at one range, which R4's depth edges cannot part
        labels, necks = split_at_necks(labels, neck_ratio=neck_ratio, min_lobe_px=min_area_px)
        if necks:
            notes.append(f"{necks} object(s) split at a neck")
    streaks = 0
    heights_precise = depth_stats is not None and depth_stats.ground_sigma_m <= _NOISY_SIGMA_M
    if method == "sector-histogram+depth" and not heights_precise:
        # R6: precise heights already removed shadows (R2); otherwise gray levels do
        trimmed = trim_attached_shadows(labels, image)
        if contrast is not None and sun_shadow_angle_deg > 0:
            # R6b: the shadows R6 cannot tell from a lit face by gray, by the sun's side
            # (the objects R6 trimmed are left as it left them)
            cut = np.bincount(labels[(labels > 0) & (trimmed == 0)], minlength=labels.max() + 1)
            trimmed, sun = trim_sun_shadows(
                trimmed,
                image,
                contrast,
                skip=cut > 0,
                max_angle_deg=sun_shadow_angle_deg,
                min_area_px=min_area_px,
            )
            if sun:
                notes.append(f"{sun} cast shadow(s) on the frame's shadow side dropped")
        # relabel (a trimmed shadow may have joined two rocks) but keep the R4 splits
        labels = label_objects(
            trimmed > 0, min_area_px=min_area_px, fill=False, edges=_seams(trimmed)
        )
    if method == "sector-histogram+depth" and max_elongation > 0:
        labels, streaks = drop_streaks(
            labels, max_elongation=max_elongation, contrast=contrast, image=image
        )
        if streaks:
            notes.append(f"{streaks} streak(s) longer than {max_elongation:g}x their width dropped")
    if texture is not None:
        # after R5: the streaks themselves are gone, only compact objects are judged
        labels, ripples = drop_ripple_pieces(
            labels,
            texture=texture,
            image=image,
            max_elongation=max_elongation,
            min_texture_ratio=ripple_texture_ratio,
        )
        if ripples:
            notes.append(f"{ripples} object(s) not standing out of the ripples around dropped")
    if contrast is not None and weak_bands > 0 and weak_growth_px > 0:
        # R7, last: only the objects every other rule kept are completed
        labels, grown = grow_weak_halves(
            labels, contrast, between=~strong, min_contrast=weak_bands, max_steps=weak_growth_px
        )
        if grown:
            notes.append(f"{grown} px of weak halves joined to their objects")
    heights_usable = depth_stats is not None and depth_stats.ground_sigma_m <= _USABLE_SIGMA_M
    row_noise = _RowNoise(relative) if relative is not None else None
    r7e = contrast is not None and row_noise is not None and heights_usable and shadow_noise_m > 0
    shadows = None
    if r7e:
        before = labels
        # R7e's first case, before R7b, on dark neighbours clearly raised next to the lit
        # face: else R7b joins face and cast shadow to it whole (mojave_0011 rock 4)
        labels, faces = _on_row_heights(
            split_shadow_sides,
            labels,
            contrast,
            row_noise,
            max_noise_m=shadow_noise_m,
            min_height_m=min_height_m,
            flat_tol_m=flat_tol_m,
            cases=(1,),
            facing_only=True,
        )
        if faces:
            notes.append(f"{faces} px of shaded faces split from cast shadows")
            # the cast shadows dropped: R7c would take them back as the rock's other face
            shadows = (before > 0) & (labels == 0)
    if contrast is not None and join_gap_px > 0:
        # R7b: a lit half and a shaded half of one rock, each found on its own
        labels, joined = join_opposite_halves(
            labels,
            contrast,
            gap_px=join_gap_px,
            max_side_deg=join_side_deg if 0 < join_side_deg < 180 else 180.0,
        )
        if joined:
            notes.append(f"{joined} pair(s) of a lighter and a darker half joined")
    if contrast is not None and face_bands > 0 and weak_growth_px > 0:
        # R7c: the other face of a rock, on the other side of the ground's gray level
        labels, faced = grow_other_faces(
            labels,
            contrast,
            min_contrast=face_bands,
            max_steps=weak_growth_px,
            barrier=shadows,
            max_side_deg=face_side_deg,
        )
        if faced:
            notes.append(f"{faced} px of other faces joined to their objects")
    if contrast is not None and rim_fraction > 0:
        # R7d, after R7c (R8's whole blobs come after it): a blurred rim the rules took
        labels, rims = trim_faint_rims(labels, contrast, fraction=rim_fraction)
        if rims:
            notes.append(f"{rims} px of faint rims dropped")
    if contrast is not None and 0 < off_side_deg < 180:
        # R7g, after R7b-R7d (whose faces it judges too): the other side's pieces where no
        # face of the rock can lie are ground texture the threshold took with it
        labels, off_side = trim_off_side_pieces(labels, contrast, max_side_deg=off_side_deg)
        if off_side:
            notes.append(f"{off_side} px of the other side off the sun's side dropped")
    if r7e:
        # R7e, after R7d: where heights are precise, a shaded face and its cast shadow
        labels, faces = _on_row_heights(
            split_shadow_sides,
            labels,
            contrast,
            row_noise,
            max_noise_m=shadow_noise_m,
            min_height_m=min_height_m,
            flat_tol_m=flat_tol_m,
            cases=(1, 2),
            facing_only=False,
        )
        if faces:
            notes.append(f"{faces} px of shaded faces joined to lit ones")
        if sun_shadow_angle_deg > 0:
            # R6c, after R7e (which splits the shadows beside a lit face it found): a dark
            # rock whose lit face no rule found keeps its flat, darker cast shadow
            labels, flat_cut = _on_row_heights(
                trim_flat_shadow_sides,
                labels,
                contrast,
                row_noise,
                max_noise_m=shadow_noise_m,
                min_height_m=min_height_m,
                flat_tol_m=flat_tol_m,
                min_area_px=min_area_px,
            )
            if flat_cut:
                notes.append(f"{flat_cut} px of flat shadow sides dropped")
    if contrast is not None and row_noise is not None and heights_usable and height_grow_fraction:
        # R7f, after R7e (whose joined faces count as the object's own): the raised rest
        labels, raised = grow_raised_parts(
            labels,
            contrast,
            row_noise.relative,
            row_noise(labels),
            fraction=height_grow_fraction,
            min_height_m=min_height_m,
        )
        if raised:
            notes.append(f"{raised} px of raised rock joined to partial objects")
    if contrast is not None and piece_gap_px > 0:
        # R7h, after R7f (whose growth brings the pieces of a large rock together) and before
        # R8-R8c (which add only blobs no object touches)
        labels, pieces = join_grown_pieces(
            labels,
            contrast,
            gap_px=piece_gap_px,
            max_side_deg=join_side_deg if 0 < join_side_deg < 180 else 180.0,
        )
        if pieces:
            notes.append(f"{pieces} pair(s) of touching pieces of one rock joined")
    run_r8 = method == "sector-histogram+depth" and blob_sigmas > 0
    run_r8b = relative is not None and heights_usable and height_blob_sigmas > 0
    run_r8c = method == "sector-histogram+depth" and two_face_sigmas > 0
    # R8, R8b and R8c's candidates search one image: its smoothed maps are made once
    scales = blob_scales(image) if sum((run_r8, run_r8b, run_r8c)) > 1 else None
    if run_r8c:
        # R8c, before R8: a lit and a shaded face side by side, which R8 and R8b, one side
        # of the ground's gray level at a time, find as pieces (whose ring then keeps the
        # whole rock out) or not at all
        labels, faced = add_two_faced_blobs(
            labels, image, min_sigmas=two_face_sigmas, min_area_px=min_area_px, _scales=scales
        )
        if faced:
            notes.append(f"{faced} two-faced blob(s) added")
    if run_r8:
        # R8, after every rule (R8c's two-faced blobs first): only rocks no object touches
        # are added
        labels, blobs = add_compact_blobs(
            labels, image, min_sigmas=blob_sigmas, min_area_px=min_area_px, _scales=scales
        )
        if blobs:
            notes.append(f"{blobs} compact blob(s) no threshold reached added")
    if run_r8b:
        # R8b, after R8: fainter blobs, kept on the heights' and the edges' word (R2d's
        # bump map means nothing where the heights are unusable)
        labels, bumps = add_height_blobs(
            labels,
            image,
            relative,
            min_sigmas=height_blob_sigmas,
            min_area_px=min_area_px,
            _scales=scales,
            _weights=bump_weights,
        )
        if bumps:
            notes.append(f"{bumps} faint blob(s) standing as height bumps added")
    if fill is not None and np.any(labels[fill]):
        labels = label_objects(
            (labels > 0) & ~fill, min_area_px=min_area_px, fill=False, edges=_seams(labels)
        )
    return Segmentation(
        labels=labels, sectors=analysis, depth=depth_stats, streaks_dropped=streaks, notes=notes
    )


class _RowNoise:
    """R0b's band noise of the ground as the objects stand (every other column), for R7e
    and R7f: a band is measured again only when its ground pixels changed between them."""

    def __init__(self, relative: np.ndarray) -> None:
        self.relative = relative
        # R0b reads every other column: those, contiguous, and only those compared
        self._sampled = np.ascontiguousarray(relative[:, ::2])
        self._valid = np.isfinite(self._sampled)
        self._memo: dict[tuple[int, int], tuple[np.ndarray, float]] = {}

    def __call__(self, labels: np.ndarray) -> np.ndarray:
        """Per row of ``labels`` (0 ground), the noise of the valid ground heights, m."""
        usable = self._valid & (labels[:, ::2] == 0)
        return _sampled_row_band_sigma(self._sampled, usable, _memo=self._memo)


def _on_row_heights(
    rule: Callable[..., tuple[np.ndarray, int]],
    labels: np.ndarray,
    contrast: np.ndarray,
    row_noise: _RowNoise,
    **settings: Any,
) -> tuple[np.ndarray, int]:
    """A height rule (R6c, R7e) on the heights the depth rules read: relative to R0's local
    ground, with R0b's noise per row; nothing to do on a frame without objects."""
    if not labels.any():
        return labels, 0
    return rule(labels, contrast, row_noise.relative, row_noise(labels), **settings)


def _seams(labels: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour of another object: where touching objects meet (the lower
    or right pixel of each such pair; one compiled pass, ``test_segment.py`` compares it
    with the whole-frame comparisons it replaced)."""
    seams = np.empty(labels.shape, dtype=bool)
    _seam_pass(np.ascontiguousarray(labels), seams)
    return seams


@njit(cache=True)
def _seam_pass(labels, seams):  # pragma: no cover - numba
    rows, cols = labels.shape
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            left = labels[y, x - 1] if x > 0 else 0
            up = labels[y - 1, x] if y > 0 else 0
            seams[y, x] = k > 0 and ((left > 0 and left != k) or (up > 0 and up != k))


def _sector_chunks(edges: np.ndarray, tile_px: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Group consecutive sectors into tiles of about ``tile_px`` pixels (at least one sector)."""
    sizes = np.diff(edges)
    pixel_chunks: list[int] = []
    sector_chunks: list[int] = []
    start = 0
    while start < sizes.size:
        stop = start + 1
        while stop < sizes.size and sizes[start : stop + 1].sum() <= tile_px:
            stop += 1
        pixel_chunks.append(int(sizes[start:stop].sum()))
        sector_chunks.append(stop - start)
        start = stop
    return tuple(pixel_chunks), tuple(sector_chunks)


def tiled_sector_histograms(image: np.ndarray, *, sectors: int, tile_px: int) -> np.ndarray:
    """Sector histograms computed per tile on dask; equal to ``sector_histograms``.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
    sectors : int
        Sectors per axis.
    tile_px : int
        ``>= 1``; tiles hold whole sectors and are at most this many pixels on a side unless
        one sector is larger.

    Returns
    -------
    hist : (sectors, sectors, 256) ndarray of int64
    """
    if tile_px < 1:
        raise ValueError(f"tile_px must be >= 1, got {tile_px}")
    sector_histograms(image[:sectors, :sectors], sectors=sectors)  # validates the arguments
    row_edges = sector_edges(image.shape[0], sectors)
    col_edges = sector_edges(image.shape[1], sectors)
    row_px, row_sectors = _sector_chunks(row_edges, tile_px)
    col_px, col_sectors = _sector_chunks(col_edges, tile_px)

    def tile_histograms(block: np.ndarray, block_info: dict | None = None) -> np.ndarray:
        (r0, r1), (c0, c1) = block_info[0]["array-location"]
        local_rows = row_edges[(row_edges >= r0) & (row_edges <= r1)] - r0
        local_cols = col_edges[(col_edges >= c0) & (col_edges <= c1)] - c0
        return _histograms_between(block, local_rows, local_cols)

    import dask.array as da  # here: only large frames need it, ~0.4 s to import

    tiles = da.from_array(image, chunks=(row_px, col_px))
    hist = tiles.map_blocks(
        tile_histograms,
        chunks=(row_sectors, col_sectors, (N_LEVELS,)),
        new_axis=2,
        dtype=np.int64,
    )
    (result,) = compute(hist)
    return np.asarray(result)


def run_segment(
    inputs: Mapping[str, np.ndarray], *, frame: FrameContext, params: Mapping[str, Any]
) -> StageResult:
    """Stage entry point: segment the frame's reference image (see :func:`segment_image`).

    The reference is ``right`` unless the catalog's camera says ``reference = "left"``, so
    that labels share the depth products' geometry.
    """
    reference = frame.camera.reference
    image = inputs[reference]
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(
            f"segment expects product {reference!r} as 2-D uint8, got {image.shape} {image.dtype}"
        )
    settings = {key: value for key, value in params.items() if key != "tile_px"}
    sectors = settings["sectors"]
    if max(image.shape) > params["tile_px"] and 2 <= sectors <= min(image.shape) // 4:
        settings["histograms"] = tiled_sector_histograms(
            image, sectors=sectors, tile_px=params["tile_px"]
        )
    result = segment_image(
        image, height=inputs.get("height"), disparity=inputs.get("disparity"), **settings
    )
    notes = list(result.notes)
    analysis = result.sectors
    labels = result.labels
    figures: dict[str, Any] = {
        "method": params["method"],
        "n_objects": int(labels.max()),
        "object_fraction": float(np.count_nonzero(labels) / labels.size),
        "n_phantom_sectors": int(analysis.phantom.sum()),
        "n_seed_sectors": int(analysis.seed.sum()),
        "mean_background": float(analysis.background.mean()),
        "mean_modes": float(analysis.modes.mean()),
        "depth_used": result.depth is not None,
        "raised_added_px": result.depth.raised_added_px if result.depth else 0,
        "flat_removed_px": result.depth.flat_removed_px if result.depth else 0,
        "depth_valid_fraction": result.depth.depth_valid_fraction if result.depth else 0.0,
        "height_noise_m": result.depth.ground_sigma_m if result.depth else float("nan"),
        "streaks_dropped": result.streaks_dropped,
    }
    if result.depth is not None:
        notes.extend(result.depth.notes)
    return StageResult(
        arrays={
            "labels": labels.astype(np.int32, copy=False),
            "sector_background": analysis.background,
            "sector_low": analysis.low,
            "sector_high": analysis.high,
            "sector_modes": analysis.modes,
            "sector_phantom": analysis.phantom,
        },
        figures=figures,
        notes=notes,
    )


def _sector_shape(image_shape: tuple[int, int], params: Mapping[str, Any]) -> tuple[int, int]:
    return (params["sectors"], params["sectors"])


def _sector_product(name: str, dtype: str, long_name: str, units: str = "") -> Product:
    attrs = {"long_name": long_name}
    if units:
        attrs["units"] = units
    return Product(name, dtype=dtype, dims=_SECTOR_DIMS, shape=_sector_shape, attrs=attrs)


STAGE = Stage(
    name="segment",
    version="41",
    inputs=("left", "right", "disparity", "height"),
    outputs=(
        Product(
            "labels",
            dtype="int32",
            attrs={"long_name": "object labels, 0 background, 1..n objects"},
        ),
        _sector_product("sector_background", "float32", "background gray level", "gray"),
        _sector_product("sector_low", "float32", "low threshold (darker is object)", "gray"),
        _sector_product("sector_high", "float32", "high threshold (lighter is object)", "gray"),
        _sector_product("sector_modes", "int8", "modes found in the smoothed histogram"),
        _sector_product("sector_phantom", "bool", "background was a phantom peak"),
    ),
    params=(
        Param("method", str, "sector-histogram+depth", "faithful or with depth rules", METHODS),
        Param("sectors", int, 16, "sectors per axis (the study: 16; 8 also works)", None, 2, 128),
        Param("smoothing", int, 1, "passes of the nine-point histogram filter", None, 0, 10),
        Param("prominence", float, 0.1, "mode prominence / sector's highest bin", None, 0, 1),
        Param("seed_dominance", float, 0.3, "other modes below this x top: seed", None, 0, 1),
        Param(
            "continuity_range", float, 24.0, "gray levels searched around prediction", None, 1, 255
        ),
        Param(
            "band_sigmas",
            float,
            3.5,
            "threshold distance without a neighbour mode, sigmas",
            None,
            0.1,
            50,
        ),
        Param("min_band", float, 6.0, "smallest threshold distance, gray levels", None, 0, 128),
        Param(
            "merge_ratio",
            float,
            0.35,
            "shallower valleys merge modes into ground; 1 = off",
            None,
            0,
            1,
        ),
        Param("min_area_px", int, 30, "objects smaller than this are specks", None, 1),
        Param("fill_holes", bool, True, "fill background pockets inside objects"),
        Param("min_height_m", float, 0.008, "depth: floor of the raised threshold", None, 1e-4),
        Param("flat_tol_m", float, 0.003, "depth: floor of the flat tolerance", None, 0),
        Param("ground_window_px", int, 72, "depth: window of the local ground level", None, 9),
        Param(
            "min_raised_fraction", float, 0.1, "depth: below this an object lies flat", None, 0, 1
        ),
        Param(
            "base_px", int, 2, "depth: flat pixels this close to raised ones are kept", None, 0, 50
        ),
        Param("height_smoothing_px", int, 5, "median window of the height map", (1, 3, 5)),
        Param(
            "split_disparity_px", float, 3.0, "disparity jump splitting objects; 0 = off", None, 0
        ),
        Param(
            "min_depth_valid_fraction",
            float,
            0.5,
            "depth: fewer valid heights: skip height rules",
            None,
            0,
            1,
        ),
        Param(
            "max_elongation",
            float,
            3.0,
            "depth: longer/width above this is a streak; 0 = off",
            None,
            0,
        ),
        Param(
            "ripple_texture_ratio",
            float,
            1.5,
            "depth: in a ripple field objects stand out of its texture this much; 0 = off",
            None,
            0,
        ),
        Param(
            "weak_bands",
            float,
            0.7,
            "depth: objects grow into pixels this many bands out on their side; 0 = off",
            None,
            0,
        ),
        Param(
            "weak_growth_px", int, 12, "depth: farthest growth into weak pixels", None, 0, 100
        ),
        Param(
            "join_gap_px",
            int,
            5,
            "depth: lighter and darker halves this close may join; 0 = off",
            None,
            0,
            50,
        ),
        Param(
            "piece_gap_px",
            int,
            2,
            "depth: after R7f, pieces this close join when their union is as solid; 0 = off",
            None,
            0,
            50,
        ),
        Param(
            "face_bands",
            float,
            0.5,
            "depth: objects grow into pixels this many bands out on the other side; 0 = off",
            None,
            0,
        ),
        Param(
            "face_side_deg",
            float,
            105.0,
            "depth: R7c drops growth this many degrees off the sun's side; 0 = off",
            None,
            0,
            180,
        ),
        Param(
            "join_side_deg",
            float,
            60.0,
            "depth: R7b joins no pair whose darker half lies this many degrees off the "
            "sun's far side; 0 = off",
            None,
            0,
            180,
        ),
        Param(
            "off_side_deg",
            float,
            105.0,
            "depth: R7g drops other-side pieces this many degrees off the sun's side; 0 = off",
            None,
            0,
            180,
        ),
        Param(
            "neck_ratio",
            float,
            0.5,
            "depth: objects narrower than this x their lobes' depth split there; 0 = off",
            None,
            0,
            0.99,
        ),
        Param(
            "blob_sigmas",
            float,
            0.0,
            "depth: add compact blobs this many ground spreads out at their scale; 0 = off",
            None,
            0,
        ),
        Param(
            "height_blob_sigmas",
            float,
            0.0,
            "depth: add fainter blobs this many spreads out that stand as height bumps; 0 = off",
            None,
            0,
        ),
        Param(
            "two_face_sigmas",
            float,
            0.0,
            "depth: add blobs of a darker and a lighter face this many spreads out; 0 = off",
            None,
            0,
        ),
        Param(
            "rim_fraction",
            float,
            0.3,
            "depth: outline pixels nearer ground gray than this x the object's contrast go",
            None,
            0,
            0.99,
        ),
        Param(
            "shadow_noise_m",
            float,
            0.0075,
            "depth: rows this precise (m) split a lit rock's dark neighbour by height; 0 = off",
            None,
            0,
        ),
        Param(
            "height_grow_fraction",
            float,
            0.5,
            "depth: near raised objects grow over pixels above this x their core height; 0 = off",
            None,
            0,
            1,
        ),
        Param(
            "sun_shadow_angle_deg",
            float,
            45.0,
            "depth: dark objects lose lighter pieces this close to the anti-sun side; 0 = off",
            None,
            0,
            90,
        ),
        Param(
            "tile_px",
            int,
            1024,
            "frames larger than this are histogrammed per tile on dask",
            None,
            16,
        ),
    ),
    run=run_segment,
    doc="adaptive sector-histogram segmentation of the reference image, with depth rules",
)
