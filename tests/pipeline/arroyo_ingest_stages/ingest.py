"""The real ingest stage."""

from stages.ingest import STAGE

__all__ = ["STAGE"]
