"""Parameters of the built-in scene archetypes (after the study's scenes).

Each archetype fixes a camera, a ground (relief, ripples, texture), a rock population
(density, size-frequency, shape, burial, albedo relative to the ground), the lighting and
the sensor. Ranges ``(lo, hi)`` are sampled uniformly per frame or per rock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["ArchetypeSpec", "ARCHETYPES", "get_spec", "FOCAL_PX_AT_500"]

FOCAL_PX_AT_500 = 430.0
Range = tuple[float, float]


@dataclass(frozen=True)
class ArchetypeSpec:
    """Everything that distinguishes one archetype's scenes from another's."""

    name: str
    description: str
    # camera (focal scales with the image size; 430 px at 500 px)
    height_m: float
    pitch_deg: float
    baseline_m: float
    variants: dict[str, dict[str, Any]]
    # ground: albedo, geometry (m, cycles/m) and texture
    ground_albedo: Range
    relief_amp: float
    relief_freq: float
    relief_octaves: int
    tex_amp: float
    tex_freq: float
    tex_octaves: int
    stain_amp: float = 0.0
    stain_freq: float = 1.0
    pebble_amp: float = 0.0
    pebble_freq: float = 30.0
    pebble_threshold: float = 0.45
    ripple_amp: float = 0.0
    ripple_wavelength: Range = (0.1, 0.1)
    ripple_warp: float = 0.0
    ripple_warp_freq: float = 0.5
    striation_amp: float = 0.0
    undulation_amp: float = 0.0
    undulation_freq: float = 0.3
    # rocks: density per m^2 of the viewed ground, sizes (largest horizontal dimension, m)
    rock_density: float = 1.0
    max_rocks: int = 400
    size_min: float = 0.03
    size_max: float = 0.40
    size_scale: float = 0.07  # mean of the exponential size excess above size_min
    aspect: Range = (0.55, 1.0)  # b / a
    flatness: Range = (0.4, 0.8)  # c / a
    exponent: Range = (2.0, 3.2)  # superquadric exponent (2 = ellipsoid; larger = blockier)
    burial: Range = (0.2, 0.6)  # share of the vertical axis below the ground plane
    tilt_max_deg: float = 20.0
    relief: Range = (0.05, 0.12)  # surface relief, relative to the rock size
    facets: tuple[int, int] = (3, 6)  # flat cuts per rock (at most 6)
    facet_depth: Range = (0.55, 0.85)  # distance of a cut from the centre (normalised)
    dark_ratio: Range = (0.35, 0.65)  # rock / ground albedo for darker rocks
    light_ratio: Range = (1.5, 2.2)  # ... and for lighter rocks
    p_light: float = 0.5
    rock_tex_amp: float = 0.25
    rock_tex_freq: float = 30.0
    # lighting
    lighting: str = "sun"  # 'sun' or 'lamps'
    sun_elevation_deg: Range = (30.0, 60.0)
    lamps: tuple[int, int] = (3, 4)
    ambient: float = 0.3
    # sensor
    target_gray: float = 130.0
    read_noise: float = 1.2
    shot_noise: float = 0.015  # variance per gray level
    blur_px: float = 0.5
    extra: dict[str, Any] = field(default_factory=dict)


ARCHETYPES: dict[str, ArchetypeSpec] = {
    "lab": ArchetypeSpec(
        name="lab",
        description="Laboratory rock field: light uniform floor, dark rocks, several lamps",
        height_m=1.0,
        pitch_deg=42.0,
        baseline_m=0.07,
        variants={},
        ground_albedo=(0.68, 0.74),
        relief_amp=0.0008,
        relief_freq=4.0,
        relief_octaves=2,
        tex_amp=0.03,
        tex_freq=40.0,
        tex_octaves=4,
        stain_amp=0.04,
        stain_freq=0.8,
        rock_density=1.6,
        max_rocks=40,
        size_min=0.04,
        size_scale=0.09,
        dark_ratio=(0.12, 0.35),
        light_ratio=(1.22, 1.3),
        p_light=0.06,
        rock_tex_amp=0.3,
        lighting="lamps",
        lamps=(3, 4),
        ambient=0.15,
        target_gray=175.0,
        read_noise=1.0,
    ),
    "mojave": ArchetypeSpec(
        name="mojave",
        description="Mojave desert rock field: natural soil texture, sun shadows, mixed rocks",
        height_m=1.2,
        pitch_deg=38.0,
        baseline_m=0.10,
        variants={"viking": {"baseline_m": 0.8}},
        ground_albedo=(0.24, 0.30),
        relief_amp=0.008,
        relief_freq=2.5,
        relief_octaves=3,
        tex_amp=0.22,
        tex_freq=12.0,
        tex_octaves=6,
        stain_amp=0.12,
        stain_freq=0.6,
        pebble_amp=0.35,
        pebble_freq=45.0,
        pebble_threshold=0.42,
        rock_density=2.5,
        max_rocks=220,
        size_scale=0.06,
        sun_elevation_deg=(30.0, 60.0),
        ambient=0.3,
        target_gray=120.0,
    ),
    "dunes": ArchetypeSpec(
        name="dunes",
        description="Sand dunes: wind ripples and striations, little texture, few or no rocks",
        height_m=1.2,
        pitch_deg=37.0,
        baseline_m=0.10,
        variants={},
        ground_albedo=(0.42, 0.48),
        relief_amp=0.002,
        relief_freq=1.5,
        relief_octaves=2,
        tex_amp=0.03,
        tex_freq=20.0,
        tex_octaves=4,
        stain_amp=0.03,
        stain_freq=0.4,
        ripple_amp=0.008,
        ripple_wavelength=(0.09, 0.14),
        ripple_warp=0.35,
        ripple_warp_freq=0.7,
        striation_amp=0.06,
        undulation_amp=0.02,
        undulation_freq=0.25,
        rock_density=0.05,
        max_rocks=4,
        size_scale=0.05,
        sun_elevation_deg=(20.0, 35.0),
        ambient=0.3,
        target_gray=150.0,
    ),
    "lava": ArchetypeSpec(
        name="lava",
        description="Lava field: dark, heavily textured ground strewn with many small rocks",
        height_m=1.2,
        pitch_deg=40.0,
        baseline_m=0.10,
        variants={},
        ground_albedo=(0.09, 0.12),
        relief_amp=0.015,
        relief_freq=3.0,
        relief_octaves=3,
        tex_amp=0.45,
        tex_freq=15.0,
        tex_octaves=6,
        stain_amp=0.15,
        stain_freq=1.0,
        pebble_amp=0.5,
        pebble_freq=60.0,
        pebble_threshold=0.38,
        rock_density=7.0,
        max_rocks=400,
        size_min=0.03,
        size_max=0.25,
        size_scale=0.04,
        exponent=(2.5, 4.0),
        relief=(0.08, 0.16),
        dark_ratio=(0.45, 0.7),
        light_ratio=(1.6, 2.6),
        p_light=0.6,
        rock_tex_amp=0.35,
        sun_elevation_deg=(35.0, 65.0),
        ambient=0.3,
        target_gray=75.0,
    ),
}


def get_spec(archetype: str, variant: str | None = None) -> ArchetypeSpec:
    """The spec of an archetype (with a variant's overrides applied).

    Raises
    ------
    TypeError
        When ``archetype`` or ``variant`` is not a string.
    ValueError
        When the archetype or the variant is unknown.
    """
    if not isinstance(archetype, str):
        raise TypeError(f"archetype must be a str such as 'lab', got {type(archetype).__name__}")
    if archetype not in ARCHETYPES:
        raise ValueError(f"unknown archetype {archetype!r}; expected one of {sorted(ARCHETYPES)}")
    spec = ARCHETYPES[archetype]
    if variant is None:
        return spec
    if not isinstance(variant, str):
        raise TypeError(f"variant must be a str or None, got {type(variant).__name__}")
    if variant not in spec.variants:
        allowed = sorted(spec.variants) or "none"
        raise ValueError(
            f"archetype {archetype!r} has no variant {variant!r}; its variants: {allowed}"
        )
    from dataclasses import replace

    return replace(spec, **spec.variants[variant])
