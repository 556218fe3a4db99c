"""Shared fixtures: small on-disk archives of PNG stereo pairs with a catalog."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import settings

# CI explores the same examples on every run (a red CI then always reproduces); developers
# keep hypothesis' random exploration and its example database.
settings.register_profile("ci", derandomize=True, database=None)
if os.environ.get("CI"):
    settings.load_profile("ci")


def write_archive(
    root: Path,
    *,
    frames: int = 4,
    shape: tuple[int, int] = (40, 48),
    name: str = "testarch",
    seed: int = 0,
    extra_toml: str = "",
) -> Path:
    """PNG pairs (right = left shifted by 3 px) + frames.csv + catalog.toml; returns the TOML."""
    rng = np.random.default_rng(seed)
    images = root / "images"
    images.mkdir(parents=True, exist_ok=True)
    lines = ["frame_id,left,right,site"]
    for k in range(frames):
        texture = rng.integers(0, 256, size=(shape[0], shape[1] + 3), dtype=np.uint8)
        left, right = texture[:, 3:], texture[:, :-3]
        cv2.imwrite(str(images / f"f{k:03d}_left.png"), np.ascontiguousarray(left))
        cv2.imwrite(str(images / f"f{k:03d}_right.png"), np.ascontiguousarray(right))
        lines.append(f"f{k:03d},images/f{k:03d}_left.png,images/f{k:03d}_right.png,site{k % 2}")
    (root / "frames.csv").write_text("\n".join(lines) + "\n")
    catalog = root / "catalog.toml"
    catalog.write_text(
        f'[archive]\nname = "{name}"\ndescription = "test archive"\n\n'
        "[camera]\nfocal_px = 100.0\nbaseline_m = 0.1\n\n"
        '[frames]\nindex = "frames.csv"\n' + extra_toml
    )
    return catalog


@pytest.fixture
def archive(tmp_path: Path) -> Path:
    return write_archive(tmp_path / "archive")
