"""Numba kernels of the renderer, in one module on purpose.

numba's on-disk cache (``cache=True``) does not notice when a jitted function calls into
another module that changed; keeping every kernel that calls another in this one file
means an edit anywhere here invalidates the whole cache, so stale machine code never runs.

Contents: band-limited gradient noise; the scene as solids (heightfield ground, implicit
rocks) and the first hit of a ray with them; the per-view ray caster; the column sampler
that measures rocks for the answer key.

The scene is the union of solids in the ground frame (x right, y forward, z up):

* the ground, ``z < g(x, y)``: micro-relief, ripples and undulation around the plane
  ``z = 0``, bounded by ``[gmin, gmax]``;
* rocks, ``F_k(p) < 0``: superquadrics ``(|u/a|^e + |v/b|^e + |w/c|^e)^(1/e) < 1`` cut by
  a few planes (facets) with a noise relief, rotated and partly buried.

The first hit of a ray with a union is the smallest of the first hits with each solid, so
the ground and each rock are intersected separately: the ground by sphere tracing the
height gap (a primary ray starts where the ray one pixel below proves it clear), each rock
by sphere tracing its implicit function inside its bounding box, ball and facets, leaving
once its convex base rises past the relief's reach; both roots are refined with the
Illinois variant of regula falsi. The rocks a ray may meet come from a list per ray source
(camera, lamp, sun, other camera) indexed by where the ray's line crosses the plane z = 0.

Kernels compile with numba's numpy error model: a float division by zero would give
inf or nan instead of raising, which spares a zero test per division in the marches (no
division here ever has a zero divisor in a render: v4's Python error model never raised).

The hot loop of :func:`render_view` calls only small kernels: a call that passes many of
the scene's arrays costs about 0.1-0.2 us (measured), more than a shadow test itself.

Texture and shading depend only on the surface point (never on the camera), so the two
views of a pair see the same surface; noise octaves finer than a pixel fade out
(``footprint``) so far ground does not alias differently in the two views.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "NOISE_LIPSCHITZ", "ROCK_RELIEF_BOUND", "make_permutation", "perlin2", "perlin3", "fbm", "fbm2",
    "GROUND_FIELDS", "ROCK_FIELDS", "MAX_PLANES",
    "ground_height", "ground_albedo", "rock_field", "rock_albedo", "rock_first_hit",
    "rock_lipschitz", "render_view", "rock_columns", "rock_extents",
]  # fmt: skip

# ==== noise ====
# Upper bound of |grad perlin2|, |grad perlin3| (measured maximum about 2.75; kept with a
# margin) used by the sphere tracers to take steps that cannot jump over a surface.
NOISE_LIPSCHITZ = 3.5
# Bound on |perlin3 + 0.45 perlin3| (the rock relief noise; |perlin3| stays below about
# 1.04): the relief moves a rock's surface by at most this times its relief amplitude.
ROCK_RELIEF_BOUND = 1.55


def make_permutation(rng: np.random.Generator) -> np.ndarray:
    """A random permutation table of 0..255, doubled to 512 entries (int64)."""
    p = rng.permutation(256).astype(np.int64)
    return np.concatenate([p, p])


@njit(cache=True, nogil=True, error_model="numpy")
def _fade(t: float) -> float:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _grad(h: int, x: float, y: float, z: float) -> float:
    h &= 15
    u = x if h < 8 else y
    if h < 4:
        v = y
    elif h == 12 or h == 14:
        v = x
    else:
        v = z
    return (u if (h & 1) == 0 else -u) + (v if (h & 2) == 0 else -v)


@njit(cache=True, nogil=True, error_model="numpy")
def perlin3(perm: np.ndarray, x: float, y: float, z: float) -> float:
    """Improved Perlin noise at ``(x, y, z)``; values in about [-1, 1], period 256."""
    fx = math.floor(x)
    fy = math.floor(y)
    fz = math.floor(z)
    xi = int(fx) & 255
    yi = int(fy) & 255
    zi = int(fz) & 255
    x -= fx
    y -= fy
    z -= fz
    u = _fade(x)
    v = _fade(y)
    w = _fade(z)
    a = perm[xi] + yi
    aa = perm[a] + zi
    ab = perm[a + 1] + zi
    b = perm[xi + 1] + yi
    ba = perm[b] + zi
    bb = perm[b + 1] + zi
    x1 = x - 1.0
    y1 = y - 1.0
    z1 = z - 1.0
    g000 = _grad(perm[aa], x, y, z)
    g100 = _grad(perm[ba], x1, y, z)
    g010 = _grad(perm[ab], x, y1, z)
    g110 = _grad(perm[bb], x1, y1, z)
    g001 = _grad(perm[aa + 1], x, y, z1)
    g101 = _grad(perm[ba + 1], x1, y, z1)
    g011 = _grad(perm[ab + 1], x, y1, z1)
    g111 = _grad(perm[bb + 1], x1, y1, z1)
    l00 = g000 + u * (g100 - g000)
    l10 = g010 + u * (g110 - g010)
    l01 = g001 + u * (g101 - g001)
    l11 = g011 + u * (g111 - g011)
    l0 = l00 + v * (l10 - l00)
    l1 = l01 + v * (l11 - l01)
    return l0 + w * (l1 - l0)


@njit(cache=True, nogil=True, error_model="numpy")
def fbm(perm: np.ndarray, x: float, y: float, z: float, octaves: int, footprint: float) -> float:
    """Fractal sum of ``octaves`` noise octaves (gain 1/2, lacunarity 2).

    ``footprint`` is the size of a pixel on the surface in units of the first octave's
    wavelength; octaves finer than half a pixel fade out (0 keeps every octave).
    """
    total = 0.0
    amp = 1.0
    freq = 1.0
    for k in range(octaves):
        s = footprint * freq
        if s >= 0.5:
            break
        weight = 1.0 if s <= 0.25 else (0.5 - s) / 0.25
        # per-octave offsets keep lattice points of successive octaves from lining up
        total += (
            weight
            * amp
            * perlin3(perm, x * freq + 17.31 * k, y * freq + 5.17 * k, z * freq + 11.73 * k)
        )
        amp *= 0.5
        freq *= 2.0
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def perlin2(perm: np.ndarray, x: float, y: float) -> float:
    """2-D gradient noise (four diagonal gradients); values in about [-1, 1], period 256."""
    fx = math.floor(x)
    fy = math.floor(y)
    xi = int(fx) & 255
    yi = int(fy) & 255
    x -= fx
    y -= fy
    u = _fade(x)
    v = _fade(y)
    x1 = x - 1.0
    y1 = y - 1.0
    a = perm[xi] + yi
    b = perm[xi + 1] + yi
    h00 = perm[a]
    h10 = perm[b]
    h01 = perm[a + 1]
    h11 = perm[b + 1]
    g00 = (x if (h00 & 1) == 0 else -x) + (y if (h00 & 2) == 0 else -y)
    g10 = (x1 if (h10 & 1) == 0 else -x1) + (y if (h10 & 2) == 0 else -y)
    g01 = (x if (h01 & 1) == 0 else -x) + (y1 if (h01 & 2) == 0 else -y1)
    g11 = (x1 if (h11 & 1) == 0 else -x1) + (y1 if (h11 & 2) == 0 else -y1)
    l0 = g00 + u * (g10 - g00)
    l1 = g01 + u * (g11 - g01)
    return l0 + v * (l1 - l0)


@njit(cache=True, nogil=True, error_model="numpy")
def fbm2(perm: np.ndarray, x: float, y: float, octaves: int, footprint: float) -> float:
    """2-D counterpart of :func:`fbm` (cheaper: for heightfields)."""
    total = 0.0
    amp = 1.0
    freq = 1.0
    for k in range(octaves):
        s = footprint * freq
        if s >= 0.5:
            break
        weight = 1.0 if s <= 0.25 else (0.5 - s) / 0.25
        total += weight * amp * perlin2(perm, x * freq + 17.31 * k, y * freq + 5.17 * k)
        amp *= 0.5
        freq *= 2.0
    return total


# ==== geometry ====
# ---- packed parameter layouts (float64 vectors; names -> index) ----------------------------
GROUND_FIELDS: tuple[str, ...] = (
    "relief_amp", "relief_freq", "relief_octaves",
    "ripple_amp", "ripple_wavelength", "ripple_dir_x", "ripple_dir_y",
    "ripple_warp", "ripple_warp_freq",
    "undulation_amp", "undulation_freq",
    "gmin", "gmax", "lipschitz", "ripple_lipschitz", "slow_lipschitz", "fast_bound",
    "albedo", "tex_amp", "tex_freq", "tex_octaves",
    "pebble_amp", "pebble_freq", "pebble_threshold",
    "striation_amp", "stain_amp", "stain_freq",
)  # fmt: skip
ROCK_FIELDS: tuple[str, ...] = (
    "cx", "cy", "cz", "a", "b", "c", "e",
    "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22",
    "relief_amp", "relief_freq", "off_x", "off_y", "off_z",
    "albedo", "tex_amp", "tex_freq", "radius", "lipschitz", "norm_radius", "n_planes",
    *(f"p{i}_{k}" for i in range(6) for k in ("nx", "ny", "nz", "d")),
)  # fmt: skip
MAX_PLANES = 6

_G = {n: i for i, n in enumerate(GROUND_FIELDS)}
_R = {n: i for i, n in enumerate(ROCK_FIELDS)}
G_RELIEF_AMP, G_RELIEF_FREQ, G_RELIEF_OCT = (
    _G["relief_amp"],
    _G["relief_freq"],
    _G["relief_octaves"],
)
G_RIP_AMP, G_RIP_LAMBDA, G_RIP_DX, G_RIP_DY = (
    _G["ripple_amp"],
    _G["ripple_wavelength"],
    _G["ripple_dir_x"],
    _G["ripple_dir_y"],
)
G_RIP_WARP, G_RIP_WARP_F = _G["ripple_warp"], _G["ripple_warp_freq"]
G_UND_AMP, G_UND_F = _G["undulation_amp"], _G["undulation_freq"]
G_MIN, G_MAX, G_LIP = _G["gmin"], _G["gmax"], _G["lipschitz"]
G_RIP_LIP = _G["ripple_lipschitz"]
G_SLOW_LIP, G_FAST = _G["slow_lipschitz"], _G["fast_bound"]
G_ALB, G_TEX_AMP, G_TEX_F, G_TEX_OCT = (
    _G["albedo"],
    _G["tex_amp"],
    _G["tex_freq"],
    _G["tex_octaves"],
)
G_PEB_AMP, G_PEB_F, G_PEB_THR = _G["pebble_amp"], _G["pebble_freq"], _G["pebble_threshold"]
G_STRI_AMP, G_STAIN_AMP, G_STAIN_F = _G["striation_amp"], _G["stain_amp"], _G["stain_freq"]

R_CX, R_CY, R_CZ, R_A, R_B, R_C, R_E = (_R[n] for n in ("cx", "cy", "cz", "a", "b", "c", "e"))
R_ROT = _R["r00"]
R_RELIEF_AMP, R_RELIEF_F = _R["relief_amp"], _R["relief_freq"]
R_OFF = _R["off_x"]
R_ALB, R_TEX_AMP, R_TEX_F = _R["albedo"], _R["tex_amp"], _R["tex_freq"]
R_RADIUS, R_LIP, R_NORM_RADIUS = _R["radius"], _R["lipschitz"], _R["norm_radius"]
R_NPLANES, R_PLANES = _R["n_planes"], _R["p0_nx"]

_INF = np.inf


# ---- ground ------------------------------------------------------------------------------
@njit(cache=True, nogil=True, error_model="numpy")
def _ripple_phase(ground: np.ndarray, perm: np.ndarray, x: float, y: float) -> float:
    wf = ground[G_RIP_WARP_F]
    return (x * ground[G_RIP_DX] + y * ground[G_RIP_DY]) / ground[G_RIP_LAMBDA] + ground[
        G_RIP_WARP
    ] * perlin2(perm, x * wf + 3.7, y * wf + 1.9)


@njit(cache=True, nogil=True, error_model="numpy")
def ground_height(
    ground: np.ndarray, perm: np.ndarray, x: float, y: float, footprint: float
) -> float:
    """Ground height ``g(x, y)`` in metres; ``footprint`` (m) > 0 drops unresolved detail."""
    h = 0.0
    amp = ground[G_RELIEF_AMP]
    if amp > 0.0:
        f = ground[G_RELIEF_FREQ]
        h += amp * fbm2(perm, x * f, y * f, int(ground[G_RELIEF_OCT]), footprint * f)
    amp = ground[G_UND_AMP]
    if amp > 0.0:
        f = ground[G_UND_F]
        h += amp * perlin2(perm, x * f + 31.1, y * f + 7.7)
    amp = ground[G_RIP_AMP]
    if amp > 0.0:
        s_px = footprint / ground[G_RIP_LAMBDA]
        weight = 1.0 if s_px <= 0.25 else max(0.0, (0.5 - s_px) / 0.25)
        if weight > 0.0:
            s = 2.0 * math.pi * _ripple_phase(ground, perm, x, y)
            # asymmetric ripple (gentle stoss, steeper lee) whose height varies along the crest
            sin_s = math.sin(s)
            profile = sin_s * (1.0 + 0.44 * math.cos(s)) / 1.2  # sin s + 0.22 sin 2s
            crest = 0.75 + 0.35 * perlin2(perm, x * 1.3 + 5.5, y * 1.3 + 2.2)
            h += weight * amp * crest * profile
    return h


@njit(cache=True, nogil=True, error_model="numpy")
def _ground_geometry(ground: np.ndarray, perm: np.ndarray, x: float, y: float):
    """``(g, slow)``: the full-detail height ``ground_height(..., 0)`` and its slow part.

    ``slow`` (undulation and the first relief octave) changes by at most ``slow_lipschitz``
    per metre and ``|g - slow| <= fast_bound``: the ground near a point stays within a thin
    band around ``slow``, which lets rays skip the rest of the ``[gmin, gmax]`` slab.
    """
    h = 0.0
    slow = 0.0
    amp = ground[G_RELIEF_AMP]
    if amp > 0.0:
        # the sum of fbm2(footprint=0) in the same order, so g is bit-identical
        f = ground[G_RELIEF_FREQ]
        first = perlin2(perm, x * f, y * f)
        total = first
        oct_amp = 0.5
        freq = 2.0
        for k in range(1, int(ground[G_RELIEF_OCT])):
            total += oct_amp * perlin2(perm, x * f * freq + 17.31 * k, y * f * freq + 5.17 * k)
            oct_amp *= 0.5
            freq *= 2.0
        h += amp * total
        slow += amp * first
    amp = ground[G_UND_AMP]
    if amp > 0.0:
        f = ground[G_UND_F]
        und = amp * perlin2(perm, x * f + 31.1, y * f + 7.7)
        h += und
        slow += und
    amp = ground[G_RIP_AMP]
    if amp > 0.0:
        s = 2.0 * math.pi * _ripple_phase(ground, perm, x, y)
        profile = math.sin(s) * (1.0 + 0.44 * math.cos(s)) / 1.2  # sin s + 0.22 sin 2s
        crest = 0.75 + 0.35 * perlin2(perm, x * 1.3 + 5.5, y * 1.3 + 2.2)
        h += amp * crest * profile
    return h, slow


@njit(cache=True, nogil=True, error_model="numpy")
def _perlin2_grad(perm: np.ndarray, x: float, y: float):
    """:func:`perlin2` and its partial derivatives ``(value, d/dx, d/dy)``."""
    fx = math.floor(x)
    fy = math.floor(y)
    xi = int(fx) & 255
    yi = int(fy) & 255
    x -= fx
    y -= fy
    u = _fade(x)
    v = _fade(y)
    du = 30.0 * x * x * (x - 1.0) * (x - 1.0)
    dv = 30.0 * y * y * (y - 1.0) * (y - 1.0)
    x1 = x - 1.0
    y1 = y - 1.0
    a = perm[xi] + yi
    b = perm[xi + 1] + yi
    h00 = perm[a]
    h10 = perm[b]
    h01 = perm[a + 1]
    h11 = perm[b + 1]
    # each corner's gradient is (+-1, +-1)
    sx00 = 1.0 if (h00 & 1) == 0 else -1.0
    sy00 = 1.0 if (h00 & 2) == 0 else -1.0
    sx10 = 1.0 if (h10 & 1) == 0 else -1.0
    sy10 = 1.0 if (h10 & 2) == 0 else -1.0
    sx01 = 1.0 if (h01 & 1) == 0 else -1.0
    sy01 = 1.0 if (h01 & 2) == 0 else -1.0
    sx11 = 1.0 if (h11 & 1) == 0 else -1.0
    sy11 = 1.0 if (h11 & 2) == 0 else -1.0
    g00 = sx00 * x + sy00 * y
    g10 = sx10 * x1 + sy10 * y
    g01 = sx01 * x + sy01 * y1
    g11 = sx11 * x1 + sy11 * y1
    l0 = g00 + u * (g10 - g00)
    l1 = g01 + u * (g11 - g01)
    l0x = sx00 + du * (g10 - g00) + u * (sx10 - sx00)
    l1x = sx01 + du * (g11 - g01) + u * (sx11 - sx01)
    l0y = sy00 + u * (sy10 - sy00)
    l1y = sy01 + u * (sy11 - sy01)
    return (
        l0 + v * (l1 - l0),
        l0x + v * (l1x - l0x),
        l0y + dv * (l1 - l0) + v * (l1y - l0y),
    )


@njit(cache=True, nogil=True, error_model="numpy")
def _fbm2_grad(perm: np.ndarray, x: float, y: float, octaves: int, footprint: float):
    """Partial derivatives ``(d/dx, d/dy)`` of :func:`fbm2` (same octave weights)."""
    gx = 0.0
    gy = 0.0
    amp = 1.0
    freq = 1.0
    for k in range(octaves):
        s = footprint * freq
        if s >= 0.5:
            break
        weight = 1.0 if s <= 0.25 else (0.5 - s) / 0.25
        _, px, py = _perlin2_grad(perm, x * freq + 17.31 * k, y * freq + 5.17 * k)
        gx += weight * amp * freq * px
        gy += weight * amp * freq * py
        amp *= 0.5
        freq *= 2.0
    return gx, gy


@njit(cache=True, nogil=True, error_model="numpy")
def _ground_gradient(ground, perm, x, y, footprint):
    """``(dg/dx, dg/dy)`` of ``ground_height(..., footprint)``, analytically."""
    gx = 0.0
    gy = 0.0
    amp = ground[G_RELIEF_AMP]
    if amp > 0.0:
        f = ground[G_RELIEF_FREQ]
        ax, ay = _fbm2_grad(perm, x * f, y * f, int(ground[G_RELIEF_OCT]), footprint * f)
        gx += amp * f * ax
        gy += amp * f * ay
    amp = ground[G_UND_AMP]
    if amp > 0.0:
        f = ground[G_UND_F]
        _, ax, ay = _perlin2_grad(perm, x * f + 31.1, y * f + 7.7)
        gx += amp * f * ax
        gy += amp * f * ay
    amp = ground[G_RIP_AMP]
    if amp > 0.0:
        s_px = footprint / ground[G_RIP_LAMBDA]
        weight = 1.0 if s_px <= 0.25 else max(0.0, (0.5 - s_px) / 0.25)
        if weight > 0.0:
            wf = ground[G_RIP_WARP_F]
            lam = ground[G_RIP_LAMBDA]
            warp = ground[G_RIP_WARP]
            wv, wx, wy = _perlin2_grad(perm, x * wf + 3.7, y * wf + 1.9)
            phase = (x * ground[G_RIP_DX] + y * ground[G_RIP_DY]) / lam + warp * wv
            s = 2.0 * math.pi * phase
            ds_dx = 2.0 * math.pi * (ground[G_RIP_DX] / lam + warp * wf * wx)
            ds_dy = 2.0 * math.pi * (ground[G_RIP_DY] / lam + warp * wf * wy)
            sin_s = math.sin(s)
            cos_s = math.cos(s)
            profile = sin_s * (1.0 + 0.44 * cos_s) / 1.2
            dprofile = (cos_s + 0.44 * (cos_s * cos_s - sin_s * sin_s)) / 1.2
            cv, cx, cy = _perlin2_grad(perm, x * 1.3 + 5.5, y * 1.3 + 2.2)
            crest = 0.75 + 0.35 * cv
            k = weight * amp
            gx += k * (0.35 * 1.3 * cx * profile + crest * dprofile * ds_dx)
            gy += k * (0.35 * 1.3 * cy * profile + crest * dprofile * ds_dy)
    return gx, gy


@njit(cache=True, nogil=True, error_model="numpy")
def ground_albedo(
    ground: np.ndarray, perm: np.ndarray, x: float, y: float, z: float, footprint: float
) -> float:
    """Ground albedo at a surface point; ``footprint`` (m) is the pixel size there."""
    # the ground is nearly flat: 2-D texture of the surface point's (x, y) is enough
    f = ground[G_TEX_F]
    tex = ground[G_TEX_AMP] * fbm2(
        perm, x * f + 101.3, y * f + 47.9, int(ground[G_TEX_OCT]), footprint * f
    )
    f = ground[G_STAIN_F]
    stain = ground[G_STAIN_AMP] * fbm2(perm, x * f + 71.1, y * f + 3.3, 2, footprint * f)
    alb = ground[G_ALB] * (1.0 + tex + stain)
    amp = ground[G_PEB_AMP]
    if amp != 0.0:
        # pebbles: thresholded noise blobs, half darker and half lighter than the soil
        f = ground[G_PEB_F]
        s_px = footprint * f
        weight = 1.0 if s_px <= 0.25 else max(0.0, (0.5 - s_px) / 0.25)
        thr = ground[G_PEB_THR]
        # unresolved pebbles blend into their mean (about 3 % cover each); fully
        # unresolved ones need no noise (0 * x + 1 * 0.03 is exactly 0.03)
        dark = light = 0.0
        if weight > 0.0:
            n1 = perlin2(perm, x * f + 40.1, y * f + 12.7)
            n2 = perlin2(perm, x * f + 90.3, y * f + 61.9)
            dark = min(1.0, max(0.0, (n1 - thr) / 0.08))
            light = min(1.0, max(0.0, (n2 - thr) / 0.08))
        dark = weight * dark + (1.0 - weight) * 0.03
        light = weight * light + (1.0 - weight) * 0.03
        alb *= (1.0 - amp * dark) * (1.0 + amp * light)
    amp = ground[G_STRI_AMP]
    if amp != 0.0 and ground[G_RIP_AMP] > 0.0:
        # coarse dark grains collect in ripple troughs: albedo striations along the crests
        s_px = footprint / ground[G_RIP_LAMBDA]
        weight = 1.0 if s_px <= 0.25 else max(0.0, (0.5 - s_px) / 0.25)
        if weight > 0.0:  # (else the factor is exactly 1)
            s = 2.0 * math.pi * _ripple_phase(ground, perm, x, y)
            alb *= 1.0 + weight * amp * math.sin(s)
    return min(0.98, max(0.01, alb))


@njit(cache=True, nogil=True, error_model="numpy")
def _ground_first_hit(
    ground, perm, ox, oy, oz, dx, dy, dz, tmin, tmax, start_above, gap_min, any_hit
) -> float:  # pragma: no cover - numba
    """First ``t`` in [tmin, tmax] with the ray below the ground; inf when none.

    ``start_above``: the caller knows the ray is above the ground at ``tmin`` (a secondary
    ray leaving a ground point along its normal), which saves a height evaluation.
    ``gap_min`` > 0: the caller knows the ray is at least that high above the ground at
    ``tmin`` (a primary ray seeded from the ray below, a secondary ray leaving a ground
    point along its normal): the march takes its first step from
    that bound instead of evaluating the height there. 0 when unknown.
    ``any_hit``: any ``t`` below the ground will do (a shadow or occlusion ray only asks
    whether there is a hit): the first sample found below it, not refined.
    """
    gmin = ground[G_MIN]
    gmax = ground[G_MAX]
    if abs(dz) < 1e-12:
        if oz < gmin or oz > gmax:
            return _INF
        ta, tb = tmin, tmax
    else:
        t1 = (gmax - oz) / dz
        t2 = (gmin - oz) / dz
        ta = max(min(t1, t2), tmin)
        tb = min(max(t1, t2), tmax)
    if ta > tb:
        return _INF
    # the ground rises at most this fast along the (unit) ray: the ripples only across
    # their crests, the rest in any direction
    horizontal_len = math.sqrt(dx * dx + dy * dy)
    rip_lip = ground[G_RIP_LIP]
    slope = (ground[G_LIP] - rip_lip) * horizontal_len + rip_lip * abs(
        dx * ground[G_RIP_DX] + dy * ground[G_RIP_DY]
    )
    if dz >= slope and (
        (start_above and ta == tmin)
        or oz + dz * ta > ground_height(ground, perm, ox + dx * ta, oy + dy * ta, 0.0)
    ):
        return _INF  # climbing faster than the ground can rise: it never comes back down
    # so the height gap shrinks at most this fast (a rising ray gains on the ground)
    rate = slope - dz
    # above the band around the slow part the ray can only meet the ground once it sinks
    # to the band's top, which itself rises at most slow_lipschitz per metre
    slow_rate = ground[G_SLOW_LIP] * horizontal_len - dz
    fast = ground[G_FAST]
    # never step less than ~5 mm horizontally (the finest relief has wavelengths of
    # centimetres), nor less than 0.2 % of the distance travelled (a far pixel spans more)
    horizontal = max(horizontal_len, 0.2)
    min_step = min(max((tb - ta) / 32.0, max(0.005, 0.002 * ta) / horizontal), tb - ta)
    t = ta
    if gap_min > 0.0 and ta == tmin:
        # a smaller gap than the true one only shortens the first step
        gap = gap_min
        slow = _INF  # unknown: no band shortcut on the first step
    else:
        g, slow = _ground_geometry(ground, perm, ox + dx * t, oy + dy * t)
        gap = oz + dz * t - g
        if gap <= 0.0:
            return t
    while t < tb:
        step = max(gap / rate, min_step)
        above_band = oz + dz * t - slow - fast
        if above_band > 0.0:
            if slow_rate <= 0.0:
                return _INF  # rising faster than the band: never meets the ground
            step = max(step, above_band / slow_rate)
        tn = min(t + step, tb)
        g, slow = _ground_geometry(ground, perm, ox + dx * tn, oy + dy * tn)
        gap_n = oz + dz * tn - g
        if gap_n <= 0.0:
            if any_hit:
                return tn
            return _refine_ground(ground, perm, ox, oy, oz, dx, dy, dz, t, gap, tn, gap_n)
        t = tn
        gap = gap_n
    return _INF


@njit(cache=True, nogil=True, error_model="numpy")
def _refine_ground(ground, perm, ox, oy, oz, dx, dy, dz, lo, f_lo, hi, f_hi):
    # Illinois regula falsi on the height gap: f_lo > 0 >= f_hi
    side = 0
    for _ in range(24):
        t = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        f = oz + dz * t - _ground_geometry(ground, perm, ox + dx * t, oy + dy * t)[0]
        if f > 0.0:
            lo, f_lo = t, f
            if side == -1:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = t, f
            if side == 1:
                f_lo *= 0.5
            side = 1
        # 1 um of height gap: under 1e-5 m along the shallowest ray, 1e-6 of its range
        if abs(f) < 1e-6:
            return t
        if hi - lo < 1e-6:
            break
    return hi


# ---- rocks -------------------------------------------------------------------------------
@njit(cache=True, nogil=True, error_model="numpy")
def _to_local(rock, px, py, pz):
    x = px - rock[R_CX]
    y = py - rock[R_CY]
    z = pz - rock[R_CZ]
    r = R_ROT
    # local = R^T (p - c); R maps local to world, row-major
    u = rock[r + 0] * x + rock[r + 3] * y + rock[r + 6] * z
    v = rock[r + 1] * x + rock[r + 4] * y + rock[r + 7] * z
    w = rock[r + 2] * x + rock[r + 5] * y + rock[r + 8] * z
    return u, v, w


@njit(cache=True, nogil=True, error_model="numpy")
def _pow_abs(x, e):
    ax = abs(x)
    if ax == 0.0:
        return 0.0
    return math.exp(e * math.log(ax))


@njit(cache=True, nogil=True, error_model="numpy")
def rock_field(rock: np.ndarray, perm: np.ndarray, px: float, py: float, pz: float) -> float:
    """Implicit function of one rock at a world point: < 0 inside, > 0 outside."""
    return _rock_field_base(rock, perm, px, py, pz)[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _rock_field_base(rock, perm, px, py, pz):
    """``(F, B)``: :func:`rock_field` and its convex base ``B`` (the facetted superquadric).

    ``F = B - relief`` with ``|relief| <= ROCK_RELIEF_BOUND * relief_amp``.
    """
    u, v, w = _to_local(rock, px, py, pz)
    e = rock[R_E]
    un = u / rock[R_A]
    vn = v / rock[R_B]
    wn = w / rock[R_C]
    # |x|^e as exp(e log|x|): cheaper than pow; a zero coordinate contributes 0
    s = (_pow_abs(un, e) + _pow_abs(vn, e) + _pow_abs(wn, e)) ** (1.0 / e) - 1.0
    # flat cuts make facets and edges, as on broken rock
    for i in range(int(rock[R_NPLANES])):
        p = R_PLANES + 4 * i
        s = max(s, rock[p] * un + rock[p + 1] * vn + rock[p + 2] * wn - rock[p + 3])
    f = rock[R_RELIEF_F]
    o = R_OFF
    n = perlin3(perm, u * f + rock[o], v * f + rock[o + 1], w * f + rock[o + 2])
    n += 0.45 * perlin3(
        perm, 2.1 * u * f + rock[o + 1], 2.1 * v * f + rock[o + 2], 2.1 * w * f + rock[o]
    )
    return s - rock[R_RELIEF_AMP] * n, s


@njit(cache=True, nogil=True, error_model="numpy")
def rock_albedo(
    rock: np.ndarray, perm: np.ndarray, px: float, py: float, pz: float, footprint: float
) -> float:
    """Albedo of a rock at a surface point (texture fixed to the rock)."""
    u, v, w = _to_local(rock, px, py, pz)
    f = rock[R_TEX_F]
    o = R_OFF
    tex = fbm(perm, u * f + rock[o + 2], v * f + rock[o], w * f + rock[o + 1], 5, footprint * f)
    alb = rock[R_ALB] * (1.0 + rock[R_TEX_AMP] * tex)
    return min(0.98, max(0.01, alb))


@njit(cache=True, nogil=True, error_model="numpy")
def _rock_interval(rock, ox, oy, oz, dx, dy, dz, t0, t1):
    """Clip ``[t0, t1]`` to the rock's bounding polytope (box and facet planes).

    In the rock's normalised coordinates ``(u/a, v/b, w/c)`` the solid lies inside the
    cube ``|.| <= k``, the ball ``|.|_2 <= norm_radius`` and below every facet plane raised
    by ``k - 1``, with
    ``k = 1 + ROCK_RELIEF_BOUND * relief_amp`` (the relief moves the surface by at most that).
    """
    qx = ox - rock[R_CX]
    qy = oy - rock[R_CY]
    qz = oz - rock[R_CZ]
    r = R_ROT
    ia = 1.0 / rock[R_A]
    ib = 1.0 / rock[R_B]
    ic = 1.0 / rock[R_C]
    pu = (rock[r + 0] * qx + rock[r + 3] * qy + rock[r + 6] * qz) * ia
    pv = (rock[r + 1] * qx + rock[r + 4] * qy + rock[r + 7] * qz) * ib
    pw = (rock[r + 2] * qx + rock[r + 5] * qy + rock[r + 8] * qz) * ic
    du = (rock[r + 0] * dx + rock[r + 3] * dy + rock[r + 6] * dz) * ia
    dv = (rock[r + 1] * dx + rock[r + 4] * dy + rock[r + 7] * dz) * ib
    dw = (rock[r + 2] * dx + rock[r + 5] * dy + rock[r + 8] * dz) * ic
    slack = ROCK_RELIEF_BOUND * rock[R_RELIEF_AMP]
    k = 1.0 + slack
    for p0, q in ((pu, du), (pv, dv), (pw, dw)):
        if abs(q) < 1e-15:
            if abs(p0) > k:
                return 1.0, 0.0
        else:
            ta = (-k - p0) / q
            tb = (k - p0) / q
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
    for i in range(int(rock[R_NPLANES])):
        p = R_PLANES + 4 * i
        num = rock[p + 3] + slack - (rock[p] * pu + rock[p + 1] * pv + rock[p + 2] * pw)
        den = rock[p] * du + rock[p + 1] * dv + rock[p + 2] * dw
        # inside where den * t <= num
        if abs(den) < 1e-15:
            if num < 0.0:
                return 1.0, 0.0
        elif den > 0.0:
            t1 = min(t1, num / den)
        else:
            t0 = max(t0, num / den)
    # and inside the ball |.|_2 <= norm_radius, which holds the e-norm ball of radius k
    qa = du * du + dv * dv + dw * dw
    qb = pu * du + pv * dv + pw * dw
    qc = pu * pu + pv * pv + pw * pw - rock[R_NORM_RADIUS] * rock[R_NORM_RADIUS]
    disc = qb * qb - qa * qc
    if disc <= 0.0:
        return 1.0, 0.0
    sq = math.sqrt(disc)
    t0 = max(t0, (-qb - sq) / qa)
    t1 = min(t1, (-qb + sq) / qa)
    return t0, t1


@njit(cache=True, nogil=True, error_model="numpy")
def _rock_lipschitz_along(rock, dx, dy, dz):
    """Bound on ``|dF/dt|`` along the unit direction ``d`` (never above ``rock[R_LIP]``).

    ``R_LIP`` bounds the base's gradient by ``1 / min(a, b, c)`` for any direction; along
    ``d`` it changes by at most the length of ``d`` in the rock's normalised coordinates
    ``(u/a, v/b, w/c)`` (the gradients of the e-norm, e >= 2, and of the unit facet planes
    have 2-norm <= 1 there); the relief's part is isotropic.
    """
    r = R_ROT
    du = (rock[r + 0] * dx + rock[r + 3] * dy + rock[r + 6] * dz) / rock[R_A]
    dv = (rock[r + 1] * dx + rock[r + 4] * dy + rock[r + 7] * dz) / rock[R_B]
    dw = (rock[r + 2] * dx + rock[r + 5] * dy + rock[r + 8] * dz) / rock[R_C]
    base = 1.0 / min(rock[R_A], rock[R_B], rock[R_C])
    along = math.sqrt(du * du + dv * dv + dw * dw)
    return rock[R_LIP] - base + min(along, base)


@njit(cache=True, nogil=True, error_model="numpy")
def rock_first_hit(rock, perm, ox, oy, oz, dx, dy, dz, tmin, tmax, zfloor, exact) -> float:
    """First ``t`` in [tmin, tmax] where the unit ray enters the rock; inf when none.

    Without ``exact`` any ``t`` inside the rock is returned (a shadow ray needs no more), and
    the march samples the segment at least 16 times instead of 48 (the relief's bumps span
    about half the rock, so a ray can only slip through one by a sliver).

    Only the part of the rock above ``z = zfloor`` is searched (pass ``-inf`` for the whole
    solid): below the lowest ground no ray that is still above the ground can meet it.
    """
    # bounding sphere: a cheap first rejection
    qx = ox - rock[R_CX]
    qy = oy - rock[R_CY]
    qz = oz - rock[R_CZ]
    rad = rock[R_RADIUS]
    bq = qx * dx + qy * dy + qz * dz
    cq = qx * qx + qy * qy + qz * qz - rad * rad
    disc = bq * bq - cq
    if disc <= 0.0:
        return _INF
    sq = math.sqrt(disc)
    t0 = max(-bq - sq, tmin)
    t1 = min(-bq + sq, tmax)
    if t0 >= t1:
        return _INF
    if abs(dz) < 1e-12:
        if oz < zfloor:
            return _INF
    elif dz > 0.0:
        t0 = max(t0, (zfloor - oz) / dz)
    else:
        t1 = min(t1, (zfloor - oz) / dz)
    if t0 >= t1:
        return _INF
    t0, t1 = _rock_interval(rock, ox, oy, oz, dx, dy, dz, t0, t1)
    if t0 >= t1:
        return _INF
    # (primary rays keep the direction-free bound: their steps, hence the surfaces the
    # march finds, stay those of renderer v4)
    lip = rock[R_LIP] if exact else _rock_lipschitz_along(rock, dx, dy, dz)
    slack = ROCK_RELIEF_BOUND * rock[R_RELIEF_AMP]
    min_step = (t1 - t0) / (48.0 if exact else 16.0)
    t = t0
    f, b = _rock_field_base(rock, perm, ox + dx * t, oy + dy * t, oz + dz * t)
    if f < 0.0:
        return t
    while t < t1:
        tn = min(t + max(f / lip, min_step), t1)
        fn, bn = _rock_field_base(rock, perm, ox + dx * tn, oy + dy * tn, oz + dz * tn)
        if fn < 0.0:
            if not exact:
                return tn
            return _refine_rock(rock, perm, ox, oy, oz, dx, dy, dz, t, f, tn, fn)
        if bn > slack and bn > b:
            # the base is convex along the ray: rising past the relief's reach, it never
            # comes back down to the rock (the march would find nothing more)
            return _INF
        t = tn
        f = fn
        b = bn
    return _INF


@njit(cache=True, nogil=True, error_model="numpy")
def _refine_rock(rock, perm, ox, oy, oz, dx, dy, dz, lo, f_lo, hi, f_hi):
    # Illinois regula falsi on the implicit function: f_lo > 0 > f_hi
    side = 0
    for _ in range(30):
        t = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        f = rock_field(rock, perm, ox + dx * t, oy + dy * t, oz + dz * t)
        if f >= 0.0:
            lo, f_lo = t, f
            if side == -1:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = t, f
            if side == 1:
                f_lo *= 0.5
            side = 1
        if hi - lo < 1e-7:
            break
    return hi


# ---- rocks listed per ray source ---------------------------------------------------------
# A view's rays all pass through one point (its camera, a lamp, the other camera) or run
# along one direction (the sun): such a ray is one line, fixed by where it meets the plane
# z = 0, and a rock can only meet the lines through the projection of its bounding sphere's
# box onto that plane. Listing the rocks on a grid over the plane, per source, gives each
# ray its few candidate rocks with one lookup.
_SRC_VALID, _SRC_KIND, _SRC_X, _SRC_X0, _SRC_CELL, _SRC_NX = 0, 1, 2, 5, 7, 8
_SRC_START_OFF, _SRC_ITEM_OFF = 10, 11
_SRC_CELLS = 65536  # cells per source grid (about)


@njit(cache=True, nogil=True, error_model="numpy")
def _cell_meets_sphere(kind, sx, sy, sz, x0, y0, cell, ix, iy, rock):
    """Whether a line of the source through cell ``(ix, iy)`` may pass the rock's sphere.

    The line through the cell's centre passes within ``r + slack`` of the sphere's centre,
    where ``slack`` bounds how far the lines through the rest of the cell stray from it
    near the sphere (half the cell's diagonal, scaled by distance for a point source).
    """
    qx = x0 + (ix + 0.5) * cell
    qy = y0 + (iy + 0.5) * cell
    half_diag = 0.7072 * cell
    if kind == 0:
        ax, ay, az = qx, qy, 0.0
        ux, uy, uz = sx, sy, sz
    else:
        ax, ay, az = sx, sy, sz
        ux, uy, uz = qx - sx, qy - sy, -sz
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux /= norm
    uy /= norm
    uz /= norm
    vx = rock[R_CX] - ax
    vy = rock[R_CY] - ay
    vz = rock[R_CZ] - az
    along = vx * ux + vy * uy + vz * uz
    dist2 = max(vx * vx + vy * vy + vz * vz - along * along, 0.0)
    if kind == 0:
        slack = half_diag
    else:
        slack = half_diag * math.sqrt(vx * vx + vy * vy + vz * vz) / norm * 1.01
    reach = rock[R_RADIUS] + slack + 1e-6
    return dist2 <= reach * reach


@njit(cache=True, nogil=True, error_model="numpy")
def _source_grid(kind, sx, sy, sz, rocks, zfloor):
    """``(params, start, items)`` of one source (kind 0: direction, 1: point; see above).

    ``params[0]`` is 0 when a projection is impossible (a rock reaching the height of the
    source, or a direction near the horizontal): then one cell lists every rock.
    """
    n = rocks.shape[0]
    params = np.zeros(12)
    params[_SRC_KIND] = kind
    params[_SRC_X] = sx
    params[_SRC_X + 1] = sy
    params[_SRC_X + 2] = sz
    # without a projection, one cell lists every rock
    every = np.array([0, n], dtype=np.int64), np.arange(n, dtype=np.int64)
    if n == 0 or (kind == 0 and sz < 1e-3):
        return params, every[0], every[1]
    boxes = np.empty((n, 4))
    for k in range(n):
        rock = rocks[k]
        r = rock[R_RADIUS]
        zlo = max(rock[R_CZ] - r, zfloor)
        zhi = rock[R_CZ] + r
        if kind == 1 and zhi >= sz - 1e-3:
            return params, every[0], every[1]
        bx0, by0, bx1, by1 = _INF, _INF, -_INF, -_INF
        for cz in (zlo, zhi):
            for cx in (rock[R_CX] - r, rock[R_CX] + r):
                for cy in (rock[R_CY] - r, rock[R_CY] + r):
                    if kind == 0:
                        qx = cx - sx * cz / sz
                        qy = cy - sy * cz / sz
                    else:
                        f = sz / (sz - cz)
                        qx = sx + (cx - sx) * f
                        qy = sy + (cy - sy) * f
                    bx0 = min(bx0, qx)
                    by0 = min(by0, qy)
                    bx1 = max(bx1, qx)
                    by1 = max(by1, qy)
        boxes[k, 0] = bx0
        boxes[k, 1] = by0
        boxes[k, 2] = bx1
        boxes[k, 3] = by1
    x0 = boxes[:, 0].min()
    y0 = boxes[:, 1].min()
    wx = boxes[:, 2].max() - x0
    wy = boxes[:, 3].max() - y0
    cell = max(math.sqrt(wx * wy / _SRC_CELLS), max(wx, wy) / 1024.0, 1e-4)
    nx = int(wx / cell) + 1
    ny = int(wy / cell) + 1
    count = np.zeros(nx * ny + 1, dtype=np.int64)
    for k in range(n):
        ix0 = int((boxes[k, 0] - x0) / cell)
        ix1 = min(int((boxes[k, 2] - x0) / cell), nx - 1)
        iy0 = int((boxes[k, 1] - y0) / cell)
        iy1 = min(int((boxes[k, 3] - y0) / cell), ny - 1)
        for iy in range(iy0, iy1 + 1):
            for ix in range(ix0, ix1 + 1):
                if _cell_meets_sphere(kind, sx, sy, sz, x0, y0, cell, ix, iy, rocks[k]):
                    count[iy * nx + ix + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for k in range(n):
        ix0 = int((boxes[k, 0] - x0) / cell)
        ix1 = min(int((boxes[k, 2] - x0) / cell), nx - 1)
        iy0 = int((boxes[k, 1] - y0) / cell)
        iy1 = min(int((boxes[k, 3] - y0) / cell), ny - 1)
        for iy in range(iy0, iy1 + 1):
            for ix in range(ix0, ix1 + 1):
                if _cell_meets_sphere(kind, sx, sy, sz, x0, y0, cell, ix, iy, rocks[k]):
                    items[fill[iy * nx + ix]] = k
                    fill[iy * nx + ix] += 1
    params[_SRC_VALID] = 1.0
    params[_SRC_X0] = x0
    params[_SRC_X0 + 1] = y0
    params[_SRC_CELL] = cell
    params[_SRC_NX] = nx
    params[_SRC_NX + 1] = ny
    return params, start, items


@njit(cache=True, nogil=True, error_model="numpy")
def _source_grids(sources, rocks, zfloor):
    """The grids of several sources ``(m, 4)``: kind, x, y, z, packed into three arrays."""
    m = sources.shape[0]
    params = np.zeros((m, 12))
    all_starts = np.zeros(0, dtype=np.int64)
    all_items = np.zeros(0, dtype=np.int64)
    for i in range(m):
        p, start, items = _source_grid(
            int(sources[i, 0]), sources[i, 1], sources[i, 2], sources[i, 3], rocks, zfloor
        )
        params[i] = p
        params[i, _SRC_START_OFF] = all_starts.shape[0]
        params[i, _SRC_ITEM_OFF] = all_items.shape[0]
        # (concatenation, not a list of arrays: numba compiles lists of arrays slowly)
        all_starts = np.concatenate((all_starts, start))
        all_items = np.concatenate((all_items, items))
    return params, all_starts, all_items


@njit(cache=True, nogil=True, error_model="numpy")
def _source_cell(src_params, src_start, src, ox, oy, oz, dx, dy, dz):
    """``(j0, j1)``: the range of ``src_items`` listing the rocks a ray of ``src`` may meet.

    """
    off = int(src_params[src, _SRC_ITEM_OFF])
    if src_params[src, _SRC_VALID] == 0.0 or (
        src_params[src, _SRC_KIND] == 1.0 and abs(dz) < 1e-9
    ):
        # no projection: every rock is a candidate (listed once in the single cell)
        c = int(src_params[src, _SRC_START_OFF])
        return off + src_start[c], off + src_start[c + 1]
    if src_params[src, _SRC_KIND] == 1.0:
        s = -src_params[src, _SRC_X + 2] / dz
        qx = src_params[src, _SRC_X] + dx * s
        qy = src_params[src, _SRC_X + 1] + dy * s
    else:
        s = -oz / src_params[src, _SRC_X + 2]
        qx = ox + src_params[src, _SRC_X] * s
        qy = oy + src_params[src, _SRC_X + 1] * s
    cell = src_params[src, _SRC_CELL]
    fx = (qx - src_params[src, _SRC_X0]) / cell
    fy = (qy - src_params[src, _SRC_X0 + 1]) / cell
    nx = int(src_params[src, _SRC_NX])
    if not (0.0 <= fx < nx and 0.0 <= fy < src_params[src, _SRC_NX + 1]):
        return 0, 0
    c = int(src_params[src, _SRC_START_OFF]) + int(fy) * nx + int(fx)
    return off + src_start[c], off + src_start[c + 1]


@njit(cache=True, nogil=True, error_model="numpy")
def _listed_rocks_hit(
    rocks, perm, items, j0, j1, ox, oy, oz, dx, dy, dz, tmin, best_t, zfloor, any_hit
):  # fmt: skip
    """First hit ``(t, solid)`` before ``best_t`` with the rocks ``items[j0:j1]``.

    ``(best_t, -1)`` when none of them is hit earlier.
    """
    best_id = -1
    for j in range(j0, j1):
        k = items[j]
        t = rock_first_hit(
            rocks[k], perm, ox, oy, oz, dx, dy, dz, tmin, best_t, zfloor, not any_hit
        )
        if t < best_t:
            best_t = t
            best_id = k + 1
            if any_hit:
                break
    return best_t, best_id

def rock_lipschitz(a: float, b: float, c: float, relief_amp: float, relief_freq: float) -> float:
    """Bound on |grad F| per metre for a rock's implicit function (sphere-tracing step)."""
    return 1.0 / min(a, b, c) + relief_amp * relief_freq * NOISE_LIPSCHITZ * (1.0 + 0.45 * 2.1)


# ==== ray caster ====
_NORMAL_OFFSET = 5e-4  # m: secondary rays start this far off the surface
_MAX_T = 1.0e3
# m: a refined ground hit lies within this height of the surface (about 1e-6, with a margin)
_GROUND_TOL = 1e-5


@njit(cache=True, nogil=True, error_model="numpy")
def _ground_normal(ground, perm, x, y, footprint):
    # the analytic gradient of the footprint-filtered heightfield (one noise evaluation
    # with derivatives per term instead of three for finite differences)
    gx, gy = _ground_gradient(ground, perm, x, y, footprint)
    inv = 1.0 / math.sqrt(gx * gx + gy * gy + 1.0)
    return -gx * inv, -gy * inv, inv


@njit(cache=True, nogil=True, error_model="numpy")
def _rock_normal(rock, perm, x, y, z):
    h = 2e-3 * min(rock[R_A], rock[R_B], rock[R_C])
    nx = rock_field(rock, perm, x + h, y, z) - rock_field(rock, perm, x - h, y, z)
    ny = rock_field(rock, perm, x, y + h, z) - rock_field(rock, perm, x, y - h, z)
    nz = rock_field(rock, perm, x, y, z + h) - rock_field(rock, perm, x, y, z - h)
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        return 0.0, 0.0, 1.0
    return nx / norm, ny / norm, nz / norm


@njit(cache=True, nogil=True, error_model="numpy")
def _offset_clearance(ground, nx, ny, nz):
    """Height above the ground of a ground hit moved ``_NORMAL_OFFSET`` along ``n``, at least.

    The point rises ``offset * nz`` while the ground under it rises at most ``lipschitz``
    times its sideways move ``offset * |n_h|``; less the hit's own tolerance. 0 when that
    leaves nothing (the point may be below the ground).
    """
    clear = _NORMAL_OFFSET * (nz - ground[G_LIP] * math.sqrt(nx * nx + ny * ny)) - _GROUND_TOL
    return clear if clear > 0.0 else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _ground_clear_until(ground, below, dx, dy, dz):
    """A ``t`` up to which a primary ray is certainly above the ground, from the ray below.

    ``below`` holds the ground hit ``t`` and the unit direction of the ray of the same
    camera one pixel lower in the image. That ray stays above the ground up to horizontal
    distance ``s = t |h_below|``; this one climbs ``tan(elevation)`` faster per metre and
    strays sideways by ``|u - u_below|`` per metre (``u``: unit horizontal directions), and
    the ground rises at most ``lipschitz`` per metre sideways, so while the climb beats
    the stray this ray is above the ground up to the same distance ``s``.

    Returns ``(t, gap)``: that ``t`` and a lower bound of the ray's height above the ground
    there (the climb minus the stray over ``s``, less the ray below's refinement
    tolerance); ``(0, 0)`` when unknown.
    """
    t_below = below[0]
    if t_below == _INF:
        return 0.0, 0.0
    h = math.sqrt(dx * dx + dy * dy)
    bx, by, bz = below[1], below[2], below[3]
    hb = math.sqrt(bx * bx + by * by)
    if h < 1e-9 or hb < 1e-9:
        return 0.0, 0.0
    ux = dx / h - bx / hb
    uy = dy / h - by / hb
    margin = dz / h - bz / hb - ground[G_LIP] * math.sqrt(ux * ux + uy * uy)
    s = t_below * hb
    # keep a clear gap at the start (the ray below's hit is refined to about 1e-6 m)
    if margin * s < _GROUND_TOL:
        return 0.0, 0.0
    return s / h, margin * s - _GROUND_TOL


@njit(cache=True, nogil=True, error_model="numpy")
def render_view(
    origin: np.ndarray,
    axes: np.ndarray,
    focal: float,
    cx: float,
    cy: float,
    height: int,
    width: int,
    lod_origin: np.ndarray,
    lights: np.ndarray,
    ambient: float,
    ground: np.ndarray,
    perm: np.ndarray,
    rocks: np.ndarray,
    occlusion_target: np.ndarray,
    want_truth: bool,
):
    """Render one view.

    Parameters
    ----------
    origin : (3,) ndarray of float64
        Optical centre in the ground frame.
    axes : (3, 3) ndarray of float64
        Camera X, Y, Z axes (rows) in the ground frame.
    lights : (L, 5) ndarray of float64
        ``kind, x, y, z, power``: kind 0 = directional (x, y, z towards the light, power =
        irradiance), kind 1 = point lamp at (x, y, z) (power / r^2 irradiance).
    occlusion_target : (3,) ndarray of float64
        The other camera's centre; with ``want_truth`` each pixel records whether its
        surface point is hidden from there.

    Returns
    -------
    radiance : (H, W) ndarray of float64
    zcam : (H, W) ndarray of float64
        Depth along the optical axis (m).
    solid : (H, W) ndarray of int32
        0 ground, k + 1 rock k, -1 nothing hit.
    height : (H, W) ndarray of float64
        Ground-frame z of the surface point (m above the plane z = 0).
    occluded : (H, W) ndarray of bool
    """
    radiance = np.zeros((height, width))
    zcam = np.full((height, width), np.inf)
    solid = np.full((height, width), -1, dtype=np.int32)
    zup = np.zeros((height, width))
    occluded = np.zeros((height, width), dtype=np.bool_)
    ox, oy, oz = origin[0], origin[1], origin[2]
    fx, fy, fz = axes[2, 0], axes[2, 1], axes[2, 2]
    # sources: this camera (primary rays), each light, the other camera (truth rays)
    n_lights = lights.shape[0]
    sources = np.ones((n_lights + 2 if want_truth else n_lights + 1, 4))
    sources[0, 1:] = origin
    sources[1 : n_lights + 1] = lights[:, :4]
    if want_truth:
        sources[n_lights + 1, 1:] = occlusion_target
    zfloor = ground[G_MIN]
    sp, ss, si = _source_grids(sources, rocks, zfloor)
    # per column, the ground hit of the ray one row below (rows are traced bottom-up)
    below = np.full((width, 4), _INF)
    for iy in range(height - 1, -1, -1):
        ry = (iy - cy) / focal
        for ix in range(width):
            rx = (ix - cx) / focal
            dx = fx + rx * axes[0, 0] + ry * axes[1, 0]
            dy = fy + rx * axes[0, 1] + ry * axes[1, 1]
            dz = fz + rx * axes[0, 2] + ry * axes[1, 2]
            inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
            dx *= inv
            dy *= inv
            dz *= inv
            t0, gap0 = _ground_clear_until(ground, below[ix], dx, dy, dz)
            t = _ground_first_hit(
                ground, perm, ox, oy, oz, dx, dy, dz, t0, _MAX_T, False, gap0, False
            )
            below[ix, 0] = t
            sid = 0 if t < _INF else -1
            j0, j1 = _source_cell(sp, ss, 0, ox, oy, oz, dx, dy, dz)
            if j1 > j0:
                t_rock, rid = _listed_rocks_hit(
                    rocks, perm, si, j0, j1, ox, oy, oz, dx, dy, dz, 0.0, min(t, _MAX_T),
                    zfloor, False,
                )  # fmt: skip
                if rid > 0:
                    t, sid = t_rock, rid
            below[ix, 1] = dx
            below[ix, 2] = dy
            below[ix, 3] = dz
            if sid < 0:
                continue
            px = ox + dx * t
            py = oy + dy * t
            pz = oz + dz * t
            solid[iy, ix] = sid
            zcam[iy, ix] = t * (dx * fx + dy * fy + dz * fz)
            zup[iy, ix] = pz
            # texture level of detail from the midpoint of the two cameras: same in both views
            vx = px - lod_origin[0]
            vy = py - lod_origin[1]
            vz = pz - lod_origin[2]
            dist = math.sqrt(vx * vx + vy * vy + vz * vz)
            if sid == 0:
                foot = dist / focal / max(abs(vz) / dist, 0.1)
                nx, ny, nz = _ground_normal(ground, perm, px, py, foot)
                albedo = ground_albedo(ground, perm, px, py, pz, foot)
            else:
                rock = rocks[sid - 1]
                nx, ny, nz = _rock_normal(rock, perm, px, py, pz)
                cosv = abs(nx * vx + ny * vy + nz * vz) / dist
                foot = dist / focal / max(cosv, 0.2)
                albedo = rock_albedo(rock, perm, px, py, pz, foot)
            sx = px + nx * _NORMAL_OFFSET
            sy = py + ny * _NORMAL_OFFSET
            sz = pz + nz * _NORMAL_OFFSET
            # a ground point moved off the surface along its normal is above the ground
            # when the ground cannot rise that fast (the hit itself is within ~1e-6 m)
            # (and by at least gap_start: the march of a shadow or occlusion ray takes its
            # first step from that height)
            gap_start = _offset_clearance(ground, nx, ny, nz) if sid == 0 else 0.0
            above = gap_start > 0.0
            irradiance = ambient * (0.5 + 0.5 * nz)
            for li in range(lights.shape[0]):
                if lights[li, 0] == 0.0:
                    lx, ly, lz = lights[li, 1], lights[li, 2], lights[li, 3]
                    ldist = _MAX_T
                    power = lights[li, 4]
                else:
                    lx = lights[li, 1] - sx
                    ly = lights[li, 2] - sy
                    lz = lights[li, 3] - sz
                    ldist = math.sqrt(lx * lx + ly * ly + lz * lz)
                    lx /= ldist
                    ly /= ldist
                    lz /= ldist
                    power = lights[li, 4] / (ldist * ldist)
                cos_in = nx * lx + ny * ly + nz * lz
                if cos_in <= 0.0:
                    continue
                # (inline, not a helper: a call passing the scene's arrays costs more
                # than the test when nothing is in the way)
                hit = _ground_first_hit(
                    ground, perm, sx, sy, sz, lx, ly, lz, 1e-6, ldist, above, gap_start, True
                )
                if hit < _INF:
                    continue
                j0, j1 = _source_cell(sp, ss, li + 1, sx, sy, sz, lx, ly, lz)
                if j1 > j0:
                    _, rid = _listed_rocks_hit(
                        rocks, perm, si, j0, j1, sx, sy, sz, lx, ly, lz, 1e-6, ldist, zfloor, True
                    )
                    if rid > 0:
                        continue
                irradiance += power * cos_in
            radiance[iy, ix] = albedo * irradiance
            if want_truth:
                qx = occlusion_target[0] - sx
                qy = occlusion_target[1] - sy
                qz = occlusion_target[2] - sz
                qd = math.sqrt(qx * qx + qy * qy + qz * qz)
                qx /= qd
                qy /= qd
                qz /= qd
                hit = _ground_first_hit(
                    ground, perm, sx, sy, sz, qx, qy, qz, 1e-6, qd, above, gap_start, True
                )
                hidden = hit < _INF
                if not hidden:
                    j0, j1 = _source_cell(sp, ss, n_lights + 1, sx, sy, sz, qx, qy, qz)
                    if j1 > j0:
                        _, rid = _listed_rocks_hit(
                            rocks, perm, si, j0, j1, sx, sy, sz, qx, qy, qz, 1e-6, qd, zfloor, True
                        )
                        hidden = rid > 0
                occluded[iy, ix] = hidden
    return radiance, zcam, solid, zup, occluded


# ==== rock measurement ====
@njit(cache=True, nogil=True, error_model="numpy")
def rock_columns(rock, perm, ground, n, cx, cy, cz, radius):
    top = np.full((n, n), np.nan)
    bottom = np.full((n, n), np.nan)
    floor = np.zeros((n, n))
    xs = np.empty(n)
    step = 2.0 * radius / n
    for i in range(n):
        xs[i] = -radius + (i + 0.5) * step
    for iy in range(n):
        for ix in range(n):
            x = cx + xs[ix]
            y = cy + xs[iy]
            floor[iy, ix] = ground_height(ground, perm, x, y, 0.0)
            z_hi = cz + radius + 1e-3
            t = rock_first_hit(
                rock, perm, x, y, z_hi, 0.0, 0.0, -1.0, 0.0, 2.0 * radius + 2e-3, -_INF, True
            )
            if t == np.inf:
                continue
            top[iy, ix] = z_hi - t
            z_lo = cz - radius - 1e-3
            t = rock_first_hit(
                rock, perm, x, y, z_lo, 0.0, 0.0, 1.0, 0.0, 2.0 * radius + 2e-3, -_INF, True
            )
            bottom[iy, ix] = z_lo + t
    return xs, top, bottom, floor


@njit(cache=True, nogil=True, error_model="numpy")
def rock_extents(xs, top, bottom, floor, cos, sin):
    """Sums over the columns of :func:`rock_columns` (one pass instead of numpy's many).

    Returns ``(volume, below, top_max, extents)``: the solid's volume and its part below
    the ground (per unit column area), the highest top above the ground (``nan`` when no
    column rises above it) and the extent of those columns along each ``(cos, sin)``
    direction (zeros when none).
    """
    n = xs.shape[0]
    m = cos.shape[0]
    cell = xs[1] - xs[0]
    volume = 0.0
    below = 0.0
    top_max = np.nan
    lo = np.full(m, np.inf)
    hi = np.full(m, -np.inf)
    for iy in range(n):
        for ix in range(n):
            t = top[iy, ix]
            if np.isnan(t):
                continue
            volume += t - bottom[iy, ix]
            below += max(min(t, floor[iy, ix]) - bottom[iy, ix], 0.0)
            if t > floor[iy, ix]:
                top_max = t if np.isnan(top_max) else max(top_max, t)
                for k in range(m):
                    proj = xs[ix] * cos[k] + xs[iy] * sin[k]
                    lo[k] = min(lo[k], proj)
                    hi[k] = max(hi[k], proj)
    extents = np.zeros(m)
    if not np.isnan(top_max):
        extents = hi - lo + cell
    return volume, below, top_max, extents
