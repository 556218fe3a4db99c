"""CPU and files per frame of the product writes: one shard per frame against one file per
chunk, on a finished run's real products.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_store.py runs/eval/lab --rounds 5

Reads every per-frame array of ``RUNDIR/products.zarr`` into memory, then writes all frames
with :func:`pipeline.store.write_frame_array` into two fresh stores made by
:func:`pipeline.store.ensure_zarr` from the same products: one sharded (what a new run
gets), one with one file per chunk (a store made before shards), the two alternately for
``--rounds`` rounds so that load drift on a shared machine hits both. Reports the median CPU
seconds per frame (``time.process_time``, the writes only; the driver's ``syncfs`` is not
included) and the files and inodes per frame of each store. Stores go under ``--workdir``
(default a temporary directory, removed at the end).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import zarr

import pipeline.store
from pipeline.stage import Product
from pipeline.store import ensure_zarr, write_frame_array

__all__ = ["main"]


def _load(rundir: Path) -> tuple[list[str], dict[str, Any]]:
    group = zarr.open_group(rundir / "products.zarr", mode="r")
    frames = [str(v) for v in np.asarray(group["frame"][:]).ravel()]
    arrays: dict[str, Any] = {}
    for name, array in group.arrays():
        if name == "frame":
            continue
        product = Product(
            name,
            dtype=str(array.dtype),
            dims=tuple(array.metadata.dimension_names or ()),
            fill_value=array.fill_value,
        )
        arrays[name] = (product, tuple(array.shape[1:]), np.asarray(array[:]))
    return frames, arrays


def _write(root: Path, arrays: dict[str, Any], n: int) -> float:
    start = time.process_time()
    for k in range(n):
        for name, (_, _, data) in arrays.items():
            write_frame_array(root, name, k, data[k])
    return (time.process_time() - start) / n


def _count(root: Path) -> tuple[int, int]:
    files = dirs = 0
    for _, dirnames, filenames in os.walk(root / "products.zarr"):
        dirs += len(dirnames)
        files += sum(1 for f in filenames if f != "zarr.json")
    return files, dirs


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rundir", type=Path, help="a finished run directory")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--workdir", type=Path, default=None)
    args = parser.parse_args(argv)
    frames, arrays = _load(args.rundir)
    spec = {name: (p, shape, {}) for name, (p, shape, _) in arrays.items()}
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        stores = {"frame_shards": Path(tmp, "sharded"), "chunk_files": Path(tmp, "chunks")}
        ensure_zarr(stores["frame_shards"], frames, spec)
        with mock.patch.object(pipeline.store, "_store_is_sharded", return_value=False):
            ensure_zarr(stores["chunk_files"], frames, spec)
        cpu: dict[str, list[float]] = {layout: [] for layout in stores}
        for _ in range(args.rounds):
            for layout, root in stores.items():
                cpu[layout].append(_write(root, arrays, len(frames)))
        result: dict[str, Any] = {"rundir": str(args.rundir), "frames": len(frames)}
        for layout, root in stores.items():
            files, dirs = _count(root)
            result[layout] = {
                "cpu_s_per_frame_median": round(statistics.median(cpu[layout]), 5),
                "cpu_s_per_frame_rounds": [round(c, 5) for c in cpu[layout]],
                "files_per_frame": round(files / len(frames), 2),
                "inodes_per_frame": round((files + dirs) / len(frames), 2),
            }
        for layout in stores:  # the same values read back from both layouts
            group = zarr.open_group(stores[layout] / "products.zarr", mode="r")
            for name, (_, _, data) in arrays.items():
                if np.asarray(group[name][:]).tobytes() != data.tobytes():
                    raise AssertionError(f"{layout}: {name} does not read back bit-identical")
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
