"""Renderer of arroyo's built-in survey archives: synthetic stereo rock fields with truth.

``synthesize_archive`` writes an archive (images, ground truth, frames.csv, catalog.toml;
layout in docs/synth.md), ``render_pair`` renders one pair in memory, ``ensure_archive``
renders a cached archive on first use (catalogs with a ``[synth]`` table).
"""

from __future__ import annotations

from .archetypes import ARCHETYPES
from .io import RENDERER_VERSION, ensure_archive, frame_seed, synthesize_archive
from .pair import render_pair

__all__ = [
    "ARCHETYPES",
    "RENDERER_VERSION",
    "ensure_archive",
    "frame_seed",
    "render_pair",
    "synthesize_archive",
]
