"""Parquet tables of a run directory: staged parts as frames finish, published generations.

Layout under RUNDIR::

    .staging/<product>/<part>.parquet   table rows as frames finish (internal)
    <product>.parquet -> .published/<product>-<generation>/   published, hive-partitioned by
                                   archive; swapped atomically (symlink) at the end of a run
    frames.parquet                 one row per frame

Every file is written to a temporary name in its final directory, fsynced, then renamed (or,
for a published generation, made visible by replacing one symlink), so a reader never sees
half a table. Only the driver writes tables.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from .store import TMP_MARK, atomic_write_bytes

__all__ = [
    "FRAMES_NAME",
    "write_parquet_atomic",
    "write_part",
    "published_path",
    "publish_table",
]

FRAMES_NAME = "frames.parquet"
STAGING = ".staging"
PUBLISHED = ".published"


def write_parquet_atomic(table: pa.Table, path: Path) -> str:
    """Write a Parquet file atomically; return its sha256."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    data = sink.getvalue().to_pybytes()
    atomic_write_bytes(path, data)
    return hashlib.sha256(data).hexdigest()



def write_part(rundir: Path, product: str, table: pa.Table) -> tuple[str, str, str]:
    """Stage a batch of rows as one Parquet part; return (part_id, relative path, sha256)."""
    part_id = uuid.uuid4().hex
    rel = Path(STAGING) / product / f"{part_id}.parquet"
    sha = write_parquet_atomic(table, Path(rundir) / rel)
    return part_id, str(rel), sha


def published_path(rundir: Path, product: str) -> Path:
    """``RUNDIR/<product>.parquet``: the link to a table's published generation."""
    return Path(rundir) / f"{product}.parquet"


def publish_table(
    rundir: Path,
    product: str,
    archive: str,
    live: Mapping[str, str],
    parts: Iterable[tuple[str, str]],
    schema: pa.Schema,
    frame_order: Mapping[str, int],
    *,
    provenance: Mapping[str, str] | None = None,
    max_rows_per_file: int = 1_000_000,
) -> Path:
    """Compact the live rows of a table product into a new published generation.

    Parameters
    ----------
    live : mapping of str to str
        frame_id -> the part holding that frame's current rows.
    parts : iterable of (part_id, relative path)
        Every staged part that may hold live rows.
    schema : pyarrow.Schema
        Full schema of the published table (archive, run_id, frame_id first).
    provenance : mapping of str to str, optional
        Recorded in each file's key-value metadata (stage, version, params).
    """
    rundir = Path(rundir)
    frames_of: dict[str, list[str]] = {}
    for frame_id, part_id in live.items():
        frames_of.setdefault(part_id, []).append(frame_id)
    order_ids = pa.array(list(frame_order), pa.string())
    order_pos = np.fromiter(frame_order.values(), dtype=np.int64, count=len(frame_order))
    wanted = [(part_id, rel) for part_id, rel in parts if part_id in frames_of]
    # parts in catalog order of their first frame, rows sorted inside each part: one part in
    # memory at a time, however large the archive
    wanted.sort(key=lambda item: min(frame_order.get(f, 0) for f in frames_of[item[0]]))
    body_schema = (
        schema.remove(schema.get_field_index("archive")) if "archive" in schema.names else schema
    )
    # the archive lives in the directory name only (hive style): a column of the same name in
    # the files would clash with the partition field in pyarrow's readers
    if provenance:
        body_schema = body_schema.with_metadata({**(body_schema.metadata or {}), **provenance})
    generation = uuid.uuid4().hex[:12]
    target = rundir / PUBLISHED / f"{product}-{generation}" / f"archive={archive}"
    target.mkdir(parents=True, exist_ok=True)
    files = _RollingWriter(target, body_schema, max_rows_per_file)
    try:
        for part_id, rel in wanted:
            table = pq.read_table(rundir / rel)
            keep = pa.array(frames_of[part_id], pa.string())
            table = table.filter(pc.is_in(table["frame_id"], value_set=keep)).cast(schema)
            positions = order_pos[
                pc.index_in(table["frame_id"], value_set=order_ids).to_numpy(zero_copy_only=False)
            ]
            id_cols = [c for c in ("object_id", "subject_id") if c in table.column_names]
            keys = [table[c].to_numpy() for c in reversed(id_cols)] + [positions]
            table = table.take(pa.array(np.lexsort(keys)))
            if "archive" in table.column_names:
                table = table.drop_columns(["archive"])
            files.write(table.cast(body_schema))
    finally:
        files.close()
    link = published_path(rundir, product)
    tmp_link = link.with_name(f".{link.name}{TMP_MARK}{generation}")
    os.symlink(Path(PUBLISHED) / f"{product}-{generation}", tmp_link)
    previous = os.readlink(link) if link.is_symlink() else None
    os.replace(tmp_link, link)
    # keep the previous generation for readers that listed it a moment ago; drop older ones
    keep = {f"{product}-{generation}"} | ({Path(previous).name} if previous else set())
    for old in (rundir / PUBLISHED).glob(f"{product}-*"):
        if old.name not in keep:
            shutil.rmtree(old, ignore_errors=True)
    return link


class _RollingWriter:
    """Parquet files of at most ``max_rows`` rows, ``part-0.parquet``, ``part-1.parquet``...,
    each fsynced when closed; at least one file (possibly empty) is written."""

    def __init__(self, target: Path, schema: pa.Schema, max_rows: int) -> None:
        self.target, self.schema, self.max_rows = target, schema, max_rows
        self.index, self.rows = 0, 0
        self.writer: pq.ParquetWriter | None = None

    def _path(self) -> Path:
        return self.target / f"part-{self.index}.parquet"

    def _open(self) -> pq.ParquetWriter:
        if self.writer is None:
            self.writer = pq.ParquetWriter(self._path(), self.schema, compression="zstd")
        return self.writer

    def write(self, table: pa.Table) -> None:
        start = 0
        while start < table.num_rows:
            room = self.max_rows - self.rows
            piece = table.slice(start, room)
            self._open().write_table(piece)
            self.rows += piece.num_rows
            start += piece.num_rows
            if self.rows >= self.max_rows:
                self._finish()
                self.index, self.rows = self.index + 1, 0

    def _finish(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
            fd = os.open(self._path(), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)

    def close(self) -> None:
        if self.writer is None and self.index == 0:
            self._open()  # an empty table still publishes one typed file
        self._finish()
