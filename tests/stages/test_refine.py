from __future__ import annotations

import cv2
import numpy as np
import pytest

from stages._refine import fit_disparity_plane, refine_against_ground


def _ground_pair(shape=(120, 160), beta=0.08, gamma=6.0, seed=0):
    """Smooth random texture seen as a ground plane: d = beta * y + gamma (subpixel)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + 40)).astype(np.float32), (0, 0), 1.2)
    texture = 128 + (texture - texture.mean()) * 4
    d = (beta * np.arange(h)[:, None] + gamma + np.zeros((1, w))).astype(np.float32)
    columns = np.arange(w + 40, dtype=np.float64)
    ref = texture[:, 20 : 20 + w]
    # other(y, x + d) = ref(y, x)  ->  other(y, x') = texture(y, x' - d + 20)
    other = np.stack(
        [np.interp(np.arange(w) - d[y, 0] + 20, columns, texture[y]) for y in range(h)]
    )
    to_u8 = lambda a: np.clip(np.round(a), 0, 255).astype(np.uint8)  # noqa: E731
    return to_u8(ref), to_u8(other), d


def test_plane_fit_ignores_raised_outliers():
    _, _, d = _ground_pair()
    noisy = d.copy()
    noisy[40:60, 50:80] += 5.0  # a rock
    noisy[::7, ::5] = np.nan
    coef = fit_disparity_plane(noisy, stride=1)
    assert coef is not None
    np.testing.assert_allclose(coef, [0.0, 0.08, 6.0], atol=1e-4)
    assert fit_disparity_plane(np.full((20, 20), np.nan, np.float32)) is None


def test_refinement_reduces_ground_noise_and_keeps_invalid_pixels():
    ref, other, truth = _ground_pair()
    rng = np.random.default_rng(1)
    first = (truth + rng.normal(0, 0.25, truth.shape)).astype(np.float32)
    first[:, :3] = np.nan
    refined, source = refine_against_ground(
        ref, other, first, plane=np.array([0.0, 0.08, 6.0]), ground_band=1.0
    )
    inner = (slice(25, -25), slice(30, -30))
    before = np.nanmedian(np.abs(first - truth)[inner])
    after = np.nanmedian(np.abs(refined - truth)[inner])
    assert after < 0.3 * before
    assert np.all(np.isnan(refined[:, :3])) and np.all(source[:, :3] == 0)
    assert np.mean(source[inner] == 1) > 0.5


def test_raised_patch_is_not_pulled_onto_the_ground():
    ref, other, truth = _ground_pair()
    first = truth.copy()
    first[40:80, 60:100] += 2.0  # claimed raised, the images say ground: small window decides
    refined, source = refine_against_ground(ref, other, first, plane=np.array([0.0, 0.08, 6.0]))
    assert np.all(source[45:75, 65:95] != 1)  # never the tall ground window off the plane


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"plane": np.array([0.0, np.nan, 1.0])}, "plane"),
        ({"plane": np.zeros(3), "tall_window": 4}, "tall_window"),
        ({"plane": np.zeros(3), "reach": 0.2}, "reach"),
        ({"plane": np.zeros(3), "min_ncc": 2.0}, "min_ncc"),
    ],
)
def test_bad_settings_fail_loudly(kwargs, match):
    image = np.zeros((20, 20), np.uint8)
    with pytest.raises(ValueError, match=match):
        refine_against_ground(image, image, np.zeros((20, 20), np.float32), **kwargs)


def test_shapes_must_agree():
    image = np.zeros((20, 20), np.uint8)
    with pytest.raises(ValueError, match="one shape"):
        refine_against_ground(image, image, np.zeros((20, 21), np.float32), plane=np.zeros(3))
