"""The real ingest stage, declared without ``sample_bits`` as it was up to arroyo 206f596."""

from __future__ import annotations

import dataclasses

from stages.ingest import STAGE as _CURRENT

__all__ = ["STAGE"]

STAGE = dataclasses.replace(
    _CURRENT,
    params=tuple(p for p in _CURRENT.params if p.name != "sample_bits"),
    check_params=None,
)
