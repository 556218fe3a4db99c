"""Height maps for the tests of stages._depth_rules and stages._height_vote (not a test
module: those tests import it)."""

from __future__ import annotations

import numpy as np

__all__ = ["correlated_noise"]


def correlated_noise(shape, sigma_m, block_px=6, seed=0):
    """Stereo-like height noise: constant over blocks of the matching-window scale."""
    rng = np.random.default_rng(seed)
    blocks = rng.normal(0, sigma_m, (shape[0] // block_px, shape[1] // block_px))
    return np.kron(blocks, np.ones((block_px, block_px))).astype(np.float32)
