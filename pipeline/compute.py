"""Compute dask collections from inside a stage, on whatever scheduler runs the frame."""

from __future__ import annotations

from typing import Any

import dask

__all__ = ["compute"]


def compute(*collections: Any) -> tuple[Any, ...]:
    """Compute dask collections inside a running task.

    On a dask.distributed worker the tiles go back to the cluster (the task secedes while it
    waits, so it does not hold a worker thread); elsewhere the local threaded scheduler runs
    them.
    """
    try:
        from distributed import get_worker, worker_client

        get_worker()
    except (ImportError, ValueError):
        return tuple(dask.compute(*collections, scheduler="threads"))
    with worker_client() as client:
        futures = client.compute(list(collections))
        return tuple(client.gather(futures))
