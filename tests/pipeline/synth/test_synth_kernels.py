"""The renderer's shortcuts (renderer v4) change how the scene is traced, never what is hit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.synth import ARCHETYPES
from pipeline.synth import _kernels as K
from pipeline.synth.archetypes import get_spec
from pipeline.synth.pair import make_camera
from pipeline.synth.render import camera_axes
from pipeline.synth.scene import make_scene

SIZE = 200


def _scene(name: str, seed: int = 4):
    spec = get_spec(name)
    camera = make_camera(spec, SIZE)
    scene = make_scene(spec, np.random.default_rng(seed), camera=camera, shape=(SIZE, SIZE))
    return scene, camera


def _pixel_rays(camera, rows, cols):
    """Unit directions (n, 3) of the reference camera's pixels (rows, cols)."""
    axes = camera_axes(camera.pitch_deg)
    cx, cy = camera.principal_point((SIZE, SIZE))
    rx = (np.asarray(cols, dtype=float) - cx) / camera.focal_px
    ry = (np.asarray(rows, dtype=float) - cy) / camera.focal_px
    d = axes[2] + rx[:, None] * axes[0] + ry[:, None] * axes[1]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("name", sorted(ARCHETYPES))
def test_ground_gradient_is_the_heightfield_slope(name):
    scene, _ = _scene(name)
    rng = np.random.default_rng(0)
    h = 1e-6
    for _ in range(300):
        x, y = rng.uniform(-3.0, 3.0), rng.uniform(0.5, 9.0)
        foot = float(rng.choice([0.0, 0.002, 0.01, 0.04]))
        gx, gy = K._ground_gradient(scene.ground, scene.perm, x, y, foot)
        fx = K.ground_height(scene.ground, scene.perm, x + h, y, foot)
        fx -= K.ground_height(scene.ground, scene.perm, x - h, y, foot)
        fy = K.ground_height(scene.ground, scene.perm, x, y + h, foot)
        fy -= K.ground_height(scene.ground, scene.perm, x, y - h, foot)
        assert gx == pytest.approx(fx / (2 * h), abs=1e-6)
        assert gy == pytest.approx(fy / (2 * h), abs=1e-6)


def _near_line(scene, o, d):
    """Every rock whose bounding sphere the line ``o + t d`` passes (numpy, independent)."""
    c = scene.rocks[:, [K.R_CX, K.R_CY, K.R_CZ]] - o
    along = c @ d
    dist2 = np.einsum("ij,ij->i", c, c) - along**2
    return np.flatnonzero(dist2 <= scene.rocks[:, K.R_RADIUS] ** 2)


def _first_rock_hit(scene, indices, o, d, tmax, exact):
    best, best_k = math.inf, -1
    zfloor = scene.ground[K.G_MIN]
    for k in indices:
        t = K.rock_first_hit(scene.rocks[k], scene.perm, *o, *d, 1e-6, tmax, zfloor, exact)
        if t < best:
            best, best_k = t, k
    return best, best_k


def test_source_lists_hold_every_rock_a_ray_can_meet():
    scene, camera = _scene("lava")
    origin = np.array([0.0, 0.0, camera.height_m])
    sun = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    sources = np.array([[1.0, *origin], [0.0, *sun], [1.0, 0.5, 2.5, 1.9]])
    params, start, items = K._source_grids(sources, scene.rocks, scene.ground[K.G_MIN])
    assert np.all(params[:, 0] == 1.0)  # every source projects (rocks stay below them)
    rng = np.random.default_rng(1)
    rows, cols = rng.integers(0, SIZE, 300), rng.integers(0, SIZE, 300)
    hits = 0
    for d in _pixel_rays(camera, rows, cols):
        j0, j1 = K._source_cell(params, start, 0, *origin, *d)
        listed = _first_rock_hit(scene, items[j0:j1], origin, d, 50.0, True)
        assert listed == _first_rock_hit(scene, _near_line(scene, origin, d), origin, d, 50.0, True)
        hits += listed[1] >= 0
    # shadow rays from ground points, towards the sun and towards the lamp
    for p in np.column_stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(1.0, 4.0, 300)]):
        s = np.array([p[0], p[1], 0.002])
        lamp = sources[2, 1:] - s
        for src, d, tmax in ((1, sun, 50.0), (2, lamp / np.linalg.norm(lamp), 2.0)):
            j0, j1 = K._source_cell(params, start, src, *s, *d)
            listed = _first_rock_hit(scene, items[j0:j1], s, d, tmax, False)
            every = _first_rock_hit(scene, _near_line(scene, s, d), s, d, tmax, False)
            assert listed[1] >= 0 or every[1] < 0
            hits += listed[1] >= 0
    assert hits > 20  # the rays do meet rocks: the comparison is not vacuous


@pytest.mark.parametrize("name", sorted(ARCHETYPES))
def test_clear_start_from_the_ray_below_never_passes_the_ground(name):
    # regression guard for the bottom-up seeding of the primary ground march: the start it
    # proves clear must lie before the ray's own first ground hit found from the camera
    scene, camera = _scene(name)
    origin = np.array([0.0, 0.0, camera.height_m])
    seeded = 0
    for col in (0, SIZE // 3, SIZE - 1):
        rows = np.arange(SIZE - 1, -1, -1)
        dirs = _pixel_rays(camera, rows, np.full(SIZE, col))
        below = np.full(4, np.inf)
        for d in dirs:
            t_hit = K._ground_first_hit(
                scene.ground, scene.perm, *origin, *d, 0.0, 1e3, False, 0.0, False
            )
            t0, gap = K._ground_clear_until(scene.ground, below, *d)
            assert t0 <= t_hit
            # and the height it vouches for at t0 (the seeded march's first step) is there
            p = origin + t0 * d
            assert p[2] - K.ground_height(scene.ground, scene.perm, p[0], p[1], 0.0) >= gap
            assert K._ground_first_hit(
                scene.ground, scene.perm, *origin, *d, t0, 1e3, False, gap, False
            ) == pytest.approx(t_hit, abs=1e-4)
            seeded += gap > 0
            below[:] = (t_hit, *d)
    assert seeded > 0.9 * 3 * SIZE


@pytest.mark.parametrize("name", ["dunes", "lava"])
def test_any_hit_ground_march_answers_as_the_refined_one(name):
    # shadow and occlusion rays skip the refinement of a ground hit: they must find a
    # hit exactly when the refined march does, at a point below the ground
    scene, _ = _scene(name)
    rng = np.random.default_rng(2)
    hits = 0
    for _ in range(400):
        x, y = rng.uniform(-2.0, 2.0), rng.uniform(0.5, 6.0)
        z = K.ground_height(scene.ground, scene.perm, x, y, 0.0) + 5e-4
        el = math.radians(rng.uniform(0.5, 12.0))
        az = rng.uniform(0.0, 2.0 * math.pi)
        d = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
        args = (scene.ground, scene.perm, x, y, z, *d, 1e-6, 5.0, False, 0.0)
        exact = K._ground_first_hit(*args, False)
        fast = K._ground_first_hit(*args, True)
        assert (fast < math.inf) == (exact < math.inf)
        if fast < math.inf:
            hits += 1
            assert fast >= exact
            p = np.array([x, y, z]) + fast * np.array(d)
            assert p[2] <= K.ground_height(scene.ground, scene.perm, p[0], p[1], 0.0)
    assert hits > 40  # low rays over rough ground do meet it: the comparison is not vacuous


@pytest.mark.parametrize("name", ["lab", "lava"])
def test_rock_step_bound_along_a_ray_bounds_the_field_slope(name):
    # shadow and occlusion rays step by F / (slope bound along their direction): the
    # bound must hold for the rock function's actual slope along the ray
    scene, _ = _scene(name)
    rng = np.random.default_rng(5)
    worst = 0.0
    for k in rng.integers(0, len(scene.rocks), 20):
        rock = scene.rocks[k]
        centre = rock[[K.R_CX, K.R_CY, K.R_CZ]]
        radius = rock[K.R_RADIUS]
        for _ in range(10):
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            lip = K._rock_lipschitz_along(rock, *d)
            assert lip <= rock[K.R_LIP]
            ts = np.linspace(-radius, radius, 300)
            h = ts[1] - ts[0]
            start = centre + rng.uniform(-0.5, 0.5, 3) * radius
            f = [K.rock_field(rock, scene.perm, *(start + t * d)) for t in ts]
            worst = max(worst, float(np.max(np.abs(np.diff(f)))) / h / lip)
    assert 0.2 < worst <= 1.0  # the bound holds, and is not vacuous


@pytest.mark.parametrize(("name", "wavelength_field"), [("mojave", "pebble"), ("dunes", "ripple")])
def test_albedo_skips_only_detail_that_has_faded_out(name, wavelength_field):
    # pebbles and striations skip their noise once the footprint fades them out entirely:
    # the albedo there must be the limit of the faded-in albedo (continuous at the cut)
    scene, _ = _scene(name)
    g = scene.ground
    if wavelength_field == "pebble":
        cut = 0.5 / g[K.G_PEB_F]
    else:
        cut = 0.5 * g[K.G_RIP_LAMBDA]
    rng = np.random.default_rng(6)
    for _ in range(200):
        x, y = rng.uniform(-3.0, 3.0), rng.uniform(0.5, 9.0)
        skipped = K.ground_albedo(g, scene.perm, x, y, 0.0, cut)
        faded = K.ground_albedo(g, scene.perm, x, y, 0.0, cut * (1.0 - 1e-9))
        assert skipped == pytest.approx(faded, abs=1e-6)


@pytest.mark.parametrize("name", ["dunes", "lava"])
def test_offset_clearance_is_below_the_true_height(name):
    # shadow and occlusion rays from a ground hit start their march from this bound
    scene, _ = _scene(name)
    g, perm = scene.ground, scene.perm
    rng = np.random.default_rng(7)
    used = 0
    for _ in range(500):
        x, y = rng.uniform(-3.0, 3.0), rng.uniform(0.5, 9.0)
        # a hit lies within the refinement tolerance of the surface (here: just below it)
        z = K.ground_height(g, perm, x, y, 0.0) - 1e-6
        n = rng.normal(size=3)
        n[2] = abs(n[2]) + 1.0
        n /= np.linalg.norm(n)
        bound = K._offset_clearance(g, *n)
        s = np.array([x, y, z]) + K._NORMAL_OFFSET * n
        assert s[2] - K.ground_height(g, perm, s[0], s[1], 0.0) >= bound
        used += bound > 0.0
    assert used > 100
