"""Synthetic stereo pairs with known disparity for the stereo matching tests (not a test
module: the tests of stages._stereo, _stereo_filters, _stereo_tiles and _ncc import it)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["texture", "u8", "shifted_pair", "occlusion_scene"]


def texture(shape: tuple[int, int], seed: int, blur: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(128.0, 45.0, shape), blur)


def u8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def shifted_pair(shape, d, seed):
    """(right, left) with right(x) = left(x + d) for an integer d: right is the reference."""
    h, w = shape
    world = u8(texture((h, w + d), seed))
    left = world[:, :w]
    right = world[:, d : d + w]
    return right, left


def occlusion_scene(seed=3, shape=(64, 120), d_back=4, d_front=12, square=(20, 44, 40, 70)):
    """Background at d_back and a foreground square at d_front, built from the left view.

    Returns right, left, true disparity and the mask of right pixels the left camera cannot
    see (background just right of the square).
    """
    h, w = shape
    back = u8(texture((h, w + 40), seed))
    front = u8(texture((h, w + 40), seed + 100))
    y0, y1, x0, x1 = square
    ys, xs = np.indices(shape)
    in_square = (ys >= y0) & (ys < y1) & (xs >= x0) & (xs < x1)
    right = np.where(in_square, front[:, :w], back[:, d_back : d_back + w])
    left = back[:, :w].copy()
    for y in range(y0, y1):
        cols = np.arange(x0, x1) + d_front
        keep = cols < w
        left[y, cols[keep]] = front[y, np.arange(x0, x1)[keep]]
    truth = np.where(in_square, d_front, d_back).astype(np.float32)
    occluded = (ys >= y0) & (ys < y1) & (xs >= x1) & (xs < x1 + d_front - d_back) & ~in_square
    return right, left, truth, occluded
