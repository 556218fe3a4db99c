"""Named errors of the arroyo engine; the CLI maps each family to an exit code."""

from __future__ import annotations

__all__ = [
    "ArroyoError",
    "CatalogError",
    "GraphError",
    "GraphCycleError",
    "DuplicateOutputError",
    "MissingProductError",
    "ParamError",
    "FrameError",
    "RunLockedError",
    "RunDirError",
    "StoreError",
]


class ArroyoError(Exception):
    """Base class of every error arroyo raises on purpose."""


class CatalogError(ArroyoError, ValueError):
    """A survey catalog (TOML or its frame index) is invalid.

    The message names the file, the field (and line where known) and what was expected.
    """


class GraphError(ArroyoError, ValueError):
    """The stage graph cannot be built."""


class GraphCycleError(GraphError):
    """Stages depend on each other in a cycle."""


class DuplicateOutputError(GraphError):
    """Two stages declare the same output product."""


class MissingProductError(GraphError):
    """A stage reads a product that no stage writes."""


class ParamError(ArroyoError, ValueError):
    """A stage parameter override names an unknown stage/parameter or has a bad value."""


class FrameError(ArroyoError):
    """One frame cannot be processed (unreadable file, wrong shape...); the run goes on."""


class RunLockedError(ArroyoError):
    """Another live arroyo process holds the run directory."""


class RunDirError(ArroyoError):
    """A run directory is missing, incomplete or not an arroyo run."""


class StoreError(ArroyoError, OSError):
    """Writing a product failed (disk full, permissions); the run stops cleanly."""
