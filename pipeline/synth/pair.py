"""One stereo pair of an archetype, with its ground truth: ``render_pair``."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from ..camera import Camera
from .archetypes import FOCAL_PX_AT_500, ArchetypeSpec, get_spec
from .render import camera_axes, render_view
from .scene import Scene, make_scene
from .truth import dense_labels, rock_table

__all__ = ["render_pair", "make_camera"]

_MIN_SIZE = 32
_MAX_SIZE = 4096


def _coerce_size(size: Any) -> int:
    if isinstance(size, bool) or not isinstance(size, numbers.Integral):
        raise TypeError(f"size must be an int (pixels), got {type(size).__name__} {size!r}")
    if not _MIN_SIZE <= int(size) <= _MAX_SIZE:
        raise ValueError(f"size must be in [{_MIN_SIZE}, {_MAX_SIZE}] pixels, got {size}")
    return int(size)


def _coerce_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise TypeError(f"seed must be a non-negative int, got {type(seed).__name__} {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed}")
    return int(seed)


def make_camera(spec: ArchetypeSpec, size: int) -> Camera:
    """The archetype's stereo camera for ``size`` x ``size`` frames (focal scales with size)."""
    return Camera(
        focal_px=FOCAL_PX_AT_500 * size / 500.0,
        baseline_m=spec.baseline_m,
        height_m=spec.height_m,
        pitch_deg=spec.pitch_deg,
        reference="right",
    )


def _render(scene: Scene, camera: Camera, shape: tuple[int, int], origin, other, truth: bool):
    cx, cy = camera.principal_point(shape)
    assert camera.pitch_deg is not None  # synth cameras have a pose
    axes = camera_axes(camera.pitch_deg)
    lod_origin = 0.5 * (origin + other)
    return render_view(
        origin, axes, camera.focal_px, cx, cy, shape[0], shape[1], lod_origin,
        scene.lights, scene.ambient, scene.ground, scene.perm, scene.rocks, other, truth,
    )  # fmt: skip


def _expose(
    radiance: np.ndarray, scene: Scene, spec: ArchetypeSpec, rng: np.random.Generator
) -> np.ndarray:
    signal = gaussian_filter(radiance, spec.blur_px, mode="nearest") * scene.exposure_gain
    sigma = np.sqrt(spec.read_noise**2 + spec.shot_noise * np.clip(signal, 0.0, None))
    noisy = signal + sigma * rng.standard_normal(signal.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def render_pair(
    archetype: str, *, seed: int, size: int = 500, variant: str | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], list[dict], dict[str, Any]]:
    """Render one stereo pair of a random scene of an archetype, with its ground truth.

    Pure: no files; the same arguments give the same arrays.

    Parameters
    ----------
    archetype : {'lab', 'mojave', 'dunes', 'lava'}
    seed : int
        Non-negative; fixes the scene and the sensor noise.
    size : int
        Frames are ``size`` x ``size`` pixels (32..4096); the focal length scales with it.
    variant : {None, 'viking'}
        'viking' (mojave only): the same scene seen with a 0.8 m baseline.

    Returns
    -------
    left, right : (size, size) ndarray of uint8
        Gray images; the right image is the reference.
    truth : dict
        In right-image geometry: ``disparity``, ``range``, ``height`` (float32, px / m / m
        above the plane z = 0), ``labels`` (int32, 0 ground, 1..n rocks, nearest first),
        ``occluded`` (bool, surface point not seen by the left camera).
    rocks : list of dict
        One row per visible rock (columns in docs/synth.md), ``rock_id`` = label.
    camera : dict
        ``focal_px, baseline_m, height_m, pitch_deg, reference``.
    """
    spec = get_spec(archetype, variant)
    seed = _coerce_seed(seed)
    size = _coerce_size(size)
    camera = make_camera(spec, size)
    shape = (size, size)
    scene_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
    scene = make_scene(spec, np.random.default_rng(scene_seq), camera=camera, shape=shape)
    assert camera.height_m is not None  # synth cameras have a pose
    right_c = np.array([0.0, 0.0, camera.height_m])
    left_c = right_c - [camera.baseline_m, 0.0, 0.0]
    rad_r, zcam, solid, zup, occluded = _render(scene, camera, shape, right_c, left_c, True)
    rad_l, *_ = _render(scene, camera, shape, left_c, right_c, False)
    if (solid < 0).any():
        raise RuntimeError("internal error: a pixel ray missed the ground (horizon in view)")
    noise_rng = np.random.default_rng(noise_seq)
    right = _expose(rad_r, scene, spec, noise_rng)
    left = _expose(rad_l, scene, spec, noise_rng)
    disparity = camera.k_m_px / zcam
    cols = np.arange(size, dtype=np.float64)[None, :]
    occluded = occluded | (cols + disparity > size - 0.5)
    labels, rock_index = dense_labels(solid, zcam)
    rows = rock_table(
        labels, rock_index, zcam, scene.rocks, scene.perm, scene.ground, scene.ground_albedo
    )
    truth = {
        "disparity": disparity.astype(np.float32),
        "range": zcam.astype(np.float32),
        "height": zup.astype(np.float32),
        "labels": labels,
        "occluded": occluded,
    }
    cam = {k: v for k, v in camera.to_dict().items() if k not in ("cx", "cy")}
    return left, right, truth, rows, cam
