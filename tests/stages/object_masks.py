"""Object masks for the tests of stages._regions, _texture_rules and _rock_parts (not a
test module: those tests import it)."""

from __future__ import annotations

import numpy as np

__all__ = ["disk"]


def disk(shape, cy, cx, r):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r
