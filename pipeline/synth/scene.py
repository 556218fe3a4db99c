"""Random scenes: ground, rocks placed without interpenetration, lights, exposure.

All quantities are in the ground frame of ``pipeline.camera`` (x right, y forward, z up,
origin on the ground below the right camera). A scene depends only on the archetype and the
random generator, not on the stereo baseline, so a variant (e.g. mojave 'viking') shows the
same rocks as the default camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ._kernels import (
    GROUND_FIELDS,
    MAX_PLANES,
    ROCK_FIELDS,
    ROCK_RELIEF_BOUND,
    make_permutation,
    rock_lipschitz,
)
from .archetypes import ArchetypeSpec
from .render import camera_axes

__all__ = ["Scene", "make_scene", "ground_footprint"]

_ROCK_GAP_M = 0.004
# rocks may also lie where only a left camera up to this far to the left sees them
_LEFT_REACH_M = 1.0
_PLACEMENT_MARGIN_M = 0.3
_ROT_FIELDS = ("r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22")
_PLANE_FIELDS = tuple(f"p{i}_{k}" for i in range(MAX_PLANES) for k in ("nx", "ny", "nz", "d"))


@dataclass(frozen=True)
class Scene:
    """Packed arrays the ray caster reads, plus what the answer key needs."""

    ground: np.ndarray  # (len(GROUND_FIELDS),) float64
    perm: np.ndarray  # (512,) int64
    rocks: np.ndarray  # (n, len(ROCK_FIELDS)) float64
    lights: np.ndarray  # (L, 5) float64
    ambient: float
    exposure_gain: float  # gray levels per unit radiance
    ground_albedo: float


def ground_footprint(camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """Ground-plane points (4, 2) seen by the four image corners of the camera at x = 0."""
    h, w = shape
    cx, cy = camera.principal_point(shape)
    axes = camera_axes(float(camera.pitch_deg or 0.0))
    pts = []
    for px, py in ((0, 0), (w - 1, 0), (w - 1, h - 1), (0, h - 1)):
        d = axes[2] + (px - cx) / camera.focal_px * axes[0] + (py - cy) / camera.focal_px * axes[1]
        if d[2] >= 0:
            raise ValueError(
                f"image corner ({px}, {py}) looks above the horizon; pitch_deg "
                f"{camera.pitch_deg} is too small for focal_px {camera.focal_px}"
            )
        t = -float(camera.height_m or 0.0) / d[2]
        pts.append((d[0] * t, d[1] * t))
    return np.array(pts)


def _convex_hull(points: np.ndarray) -> np.ndarray:
    pts = sorted(map(tuple, points))
    if len(pts) <= 2:
        return np.array(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])  # counter-clockwise


def _hull_edges(hull: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(a, normal)`` per edge of a counter-clockwise hull: a vertex and the outward normal."""
    edges = []
    for i in range(len(hull)):
        a, b = hull[i], hull[(i + 1) % len(hull)]
        edge = b - a
        edges.append((a, np.array([edge[1], -edge[0]]) / np.hypot(*edge)))
    return edges


def _inside_convex(
    hull: np.ndarray, xy: np.ndarray, margin: float, *, edges: list | None = None
) -> np.ndarray:
    inside = np.ones(len(xy), dtype=bool)
    # (the edges of one hull once, not per call: rock placement tests it hundreds of times)
    for a, normal in edges if edges is not None else _hull_edges(hull):
        inside &= (xy - a) @ normal <= margin
    return inside


def _polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _scale(bounds: tuple[float, float], u: float) -> float:
    """``Generator.uniform(lo, hi)`` from its underlying draw ``u = Generator.random()``."""
    return bounds[0] + (bounds[1] - bounds[0]) * u


def _make_ground(spec: ArchetypeSpec, rng: np.random.Generator) -> np.ndarray:
    from ._kernels import NOISE_LIPSCHITZ as lip

    g = dict.fromkeys(GROUND_FIELDS, 0.0)
    g.update(
        relief_amp=spec.relief_amp,
        relief_freq=spec.relief_freq,
        relief_octaves=float(spec.relief_octaves),
        ripple_amp=spec.ripple_amp,
        ripple_wavelength=_uniform(rng, spec.ripple_wavelength),
        ripple_warp=spec.ripple_warp,
        ripple_warp_freq=spec.ripple_warp_freq,
        undulation_amp=spec.undulation_amp,
        undulation_freq=spec.undulation_freq,
        albedo=_uniform(rng, spec.ground_albedo),
        tex_amp=spec.tex_amp,
        tex_freq=spec.tex_freq,
        tex_octaves=float(spec.tex_octaves),
        pebble_amp=spec.pebble_amp,
        pebble_freq=spec.pebble_freq,
        pebble_threshold=spec.pebble_threshold,
        striation_amp=spec.striation_amp,
        stain_amp=spec.stain_amp,
        stain_freq=spec.stain_freq,
    )
    angle = rng.uniform(0.0, math.pi)
    g["ripple_dir_x"], g["ripple_dir_y"] = math.cos(angle), math.sin(angle)
    relief_bound = 1.05 * spec.relief_amp * sum(0.5**k for k in range(spec.relief_octaves))
    ripple_bound = 1.15 * spec.ripple_amp
    bound = relief_bound + ripple_bound + 1.05 * spec.undulation_amp + 1e-4
    g["gmin"], g["gmax"] = -bound, bound
    lam = g["ripple_wavelength"]
    slope = spec.relief_amp * spec.relief_freq * lip * spec.relief_octaves
    slope += spec.undulation_amp * spec.undulation_freq * lip
    if spec.ripple_amp > 0:
        dphase = 1.0 / lam + spec.ripple_warp * spec.ripple_warp_freq * lip
        slope += spec.ripple_amp * (0.35 * 1.3 * lip * 1.02 + 1.12 * 2 * math.pi * dphase * 1.2)
    g["lipschitz"] = 1.1 * slope + 1e-3
    # the part of that bound due to the phase running across the crests: only a path
    # across the crests meets it in full (rays along them see the ripples barely change)
    if spec.ripple_amp > 0:
        g["ripple_lipschitz"] = 1.1 * spec.ripple_amp * 1.12 * 2 * math.pi * 1.2 / lam
    # slow part: undulation and the first relief octave; the rest stays within fast_bound
    slow_slope = spec.relief_amp * spec.relief_freq * lip
    slow_slope += spec.undulation_amp * spec.undulation_freq * lip
    g["slow_lipschitz"] = 1.1 * slow_slope + 1e-4
    fast = 1.05 * spec.relief_amp * sum(0.5**k for k in range(1, spec.relief_octaves))
    g["fast_bound"] = fast + ripple_bound + 1e-4
    return np.array([g[n] for n in GROUND_FIELDS], dtype=np.float64)


def _rotation(yaw: float, tilt: float, tilt_axis: float) -> np.ndarray:
    cz, sz = math.cos(yaw), math.sin(yaw)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ax = np.array([math.cos(tilt_axis), math.sin(tilt_axis), 0.0])
    k = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
    rt = np.eye(3) + math.sin(tilt) * k + (1 - math.cos(tilt)) * (k @ k)
    return rt @ rz


def _make_rocks(
    spec: ArchetypeSpec, rng: np.random.Generator, region: np.ndarray, ground_albedo: float
) -> np.ndarray:
    area = _polygon_area(region)
    n = int(min(rng.poisson(spec.rock_density * area), spec.max_rocks))
    span = spec.size_max - spec.size_min
    u = rng.uniform(0.0, 1.0 - math.exp(-span / spec.size_scale), size=n)
    sizes = np.sort(spec.size_min - spec.size_scale * np.log1p(-u))[::-1]
    lo, hi = region.min(axis=0), region.max(axis=0)
    edges = _hull_edges(region)
    placed: list[np.ndarray] = []
    # placed centres and radii in preallocated arrays (a growing copy per rock costs more)
    centres_all = np.empty((len(sizes), 2))
    radii_all = np.empty(len(sizes))
    n_placed = 0
    for size in sizes:
        a = 0.5 * float(size)
        # the rock's 13 scalar draws in one call: the same stream of doubles, each mapped
        # to its range as Generator.uniform does (lo + (hi - lo) * u)
        u = rng.random(13).tolist()
        b = a * _scale(spec.aspect, u[0])
        c = a * _scale(spec.flatness, u[1])
        e = _scale(spec.exponent, u[2])
        relief = _scale(spec.relief, u[3])
        relief_freq = 1.0 / a
        radius = max(a, b, c) * 3.0 ** (0.5 - 1.0 / e) * (1.0 + 1.5 * relief)
        rot = _rotation(
            _scale((0, 2 * math.pi), u[4]),
            math.radians(_scale((0, spec.tilt_max_deg), u[5])),
            _scale((0, 2 * math.pi), u[6]),
        )
        burial = _scale(spec.burial, u[7])
        cz = c * (1.0 - 2.0 * burial)
        lighter = u[8] < spec.p_light
        ratio = _scale(spec.light_ratio if lighter else spec.dark_ratio, u[9])
        albedo = min(0.92, ground_albedo * ratio)
        offsets = [_scale((0, 200), v) for v in u[10:13]]
        candidates = rng.uniform(lo, hi, size=(40, 2))
        ok = _inside_convex(region, candidates, 0.0, edges=edges)
        centres = centres_all[:n_placed]
        radii = radii_all[:n_placed]
        for xy in candidates[ok]:
            if n_placed == 0 or np.all(
                np.hypot(*(centres - xy).T) >= radii + radius + _ROCK_GAP_M
            ):
                break
        else:
            continue
        centres_all[n_placed] = xy
        radii_all[n_placed] = radius
        n_placed += 1
        values = {
            "cx": xy[0], "cy": xy[1], "cz": cz, "a": a, "b": b, "c": c, "e": e,
            "relief_amp": relief, "relief_freq": relief_freq,
            "off_x": offsets[0], "off_y": offsets[1], "off_z": offsets[2],
            "albedo": albedo, "tex_amp": spec.rock_tex_amp, "tex_freq": spec.rock_tex_freq,
            "radius": radius, "lipschitz": rock_lipschitz(a, b, c, relief, relief_freq),
            # |x|_2 <= 3^(1/2 - 1/e) |x|_e: a ball (in the rock's normalised coordinates)
            # around the solid, however blocky
            "norm_radius": (1.0 + ROCK_RELIEF_BOUND * relief) * 3.0 ** (0.5 - 1.0 / e) * 1.001,
        }  # fmt: skip
        values.update(zip(_ROT_FIELDS, rot.ravel().tolist(), strict=True))
        values.update(_facets(rng, spec))
        placed.append(np.array([values[f] for f in ROCK_FIELDS], dtype=np.float64))
    if not placed:
        return np.zeros((0, len(ROCK_FIELDS)))
    return np.array(placed)


def _facets(rng: np.random.Generator, spec: ArchetypeSpec) -> dict[str, float]:
    """Flat cuts of the superquadric (in its normalised coordinates): facets and edges."""
    count = int(rng.integers(spec.facets[0], spec.facets[1] + 1))
    values = dict.fromkeys(_PLANE_FIELDS, 0.0)
    values["n_planes"] = float(count)
    u = rng.random(3 * count).tolist()  # as the scalar draws plane by plane (see _scale)
    for i in range(count):
        az = _scale((0, 2 * math.pi), u[3 * i])
        el = math.radians(_scale((-20.0, 70.0), u[3 * i + 1]))
        nx, ny, nz, d = _PLANE_FIELDS[4 * i : 4 * i + 4]
        values[nx] = math.cos(el) * math.cos(az)
        values[ny] = math.cos(el) * math.sin(az)
        values[nz] = math.sin(el)
        values[d] = _scale(spec.facet_depth, u[3 * i + 2])
    return values


def _make_lights(spec: ArchetypeSpec, rng: np.random.Generator, centre: np.ndarray) -> np.ndarray:
    if spec.lighting == "sun":
        el = math.radians(_uniform(rng, spec.sun_elevation_deg))
        az = rng.uniform(0, 2 * math.pi)
        d = (math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el))
        return np.array([[0.0, *d, 1.0]])
    count = int(rng.integers(spec.lamps[0], spec.lamps[1] + 1))
    lamps = []
    for i in range(count):
        # lamps spread around the viewed floor, at ceiling-stand height
        angle = 2 * math.pi * (i + rng.uniform(0.1, 0.9)) / count
        dist = rng.uniform(1.0, 2.2)
        z = rng.uniform(1.6, 2.4)
        x = centre[0] + dist * math.cos(angle)
        y = max(centre[1] + dist * math.sin(angle), 0.2)
        lamps.append([1.0, x, y, z, rng.uniform(0.5, 0.9) * z * z])
    return np.array(lamps)


def _irradiance_at(point: np.ndarray, lights: np.ndarray, ambient: float) -> float:
    total = ambient
    for kind, x, y, z, power in lights:
        if kind == 0.0:
            total += power * max(z, 0.0)
        else:
            v = np.array([x, y, z]) - point
            r = float(np.linalg.norm(v))
            total += power / r**2 * max(v[2] / r, 0.0)
    return total


def make_scene(
    spec: ArchetypeSpec, rng: np.random.Generator, *, camera: Camera, shape: tuple[int, int]
) -> Scene:
    """Draw one random scene of an archetype.

    Parameters
    ----------
    spec : ArchetypeSpec
    rng : numpy.random.Generator
        The only source of randomness; the same state gives the same scene.
    camera : Camera
        Needs ``height_m`` and ``pitch_deg``; its baseline does not change the scene.
    shape : (int, int)
        Image shape ``(H, W)``; fixes the viewed ground region.
    """
    ground = _make_ground(spec, rng)
    perm = make_permutation(rng)
    right = ground_footprint(camera, shape)
    region = _convex_hull(np.vstack([right, right - [_LEFT_REACH_M, 0.0]]))
    region = _expand(region, _PLACEMENT_MARGIN_M)
    rocks = _make_rocks(spec, rng, region, float(ground[GROUND_FIELDS.index("albedo")]))
    assert camera.height_m is not None and camera.pitch_deg is not None  # synth cameras have a pose
    ref = np.array([0.0, camera.height_m / math.tan(math.radians(camera.pitch_deg)), 0.0])
    lights = _make_lights(spec, rng, ref[:2])
    albedo = float(ground[GROUND_FIELDS.index("albedo")])
    gain = spec.target_gray / (albedo * _irradiance_at(ref, lights, spec.ambient))
    return Scene(
        ground=ground,
        perm=perm,
        rocks=rocks,
        lights=lights,
        ambient=spec.ambient,
        exposure_gain=gain,
        ground_albedo=albedo,
    )


def _expand(hull: np.ndarray, margin: float) -> np.ndarray:
    centre = hull.mean(axis=0)
    offsets = hull - centre
    norms = np.hypot(offsets[:, 0], offsets[:, 1])[:, None]
    return centre + offsets * (1.0 + margin / np.maximum(norms, 1e-9))
