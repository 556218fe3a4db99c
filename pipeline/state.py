"""Completion records of a run directory, in SQLite (one writer: the driver).

A (frame, stage) result counts as complete only once its row is committed here, and the
driver commits it only after the frame's arrays are in ``products.zarr``, its files are
renamed into place and its table rows are in a Parquet part on disk. Anything written but not
recorded is simply redone, and stage outputs are deterministic, so a rerun after a crash
rewrites the same bytes.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import RunDirError

__all__ = ["RunState", "StageRecord", "PartRecord", "STATE_NAME"]

STATE_NAME = "state.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS stage_done (
    frame_id TEXT NOT NULL,
    stage TEXT NOT NULL,
    key TEXT NOT NULL,
    run_id TEXT NOT NULL,
    seconds REAL NOT NULL,
    figures TEXT NOT NULL,
    notes TEXT NOT NULL,
    checksums TEXT NOT NULL,
    part_ids TEXT NOT NULL,
    finished_at REAL NOT NULL,
    PRIMARY KEY (frame_id, stage)
);
CREATE TABLE IF NOT EXISTS frame_failed (
    frame_id TEXT PRIMARY KEY,
    stage TEXT NOT NULL,
    error TEXT NOT NULL,
    run_id TEXT NOT NULL,
    at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS parts (
    part_id TEXT PRIMARY KEY,
    product TEXT NOT NULL,
    path TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    rows INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS input_hashes (
    path TEXT PRIMARY KEY,
    size INTEGER NOT NULL,
    mtime_ns INTEGER NOT NULL,
    sha256 TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""


@dataclass(frozen=True)
class StageRecord:
    frame_id: str
    stage: str
    key: str
    run_id: str
    seconds: float
    figures: dict[str, Any]
    notes: list[str]
    checksums: dict[str, str]
    part_ids: dict[str, str]


@dataclass(frozen=True)
class PartRecord:
    part_id: str
    product: str
    path: str
    sha256: str
    rows: int


class RunState:
    """The SQLite completion journal of one run directory."""

    def __init__(self, rundir: Path, *, readonly: bool = False) -> None:
        path = Path(rundir) / STATE_NAME
        try:
            if readonly:
                self._db = _connect_readonly(path)
            else:
                self._db = sqlite3.connect(path, timeout=30)
                self._db.execute("PRAGMA journal_mode=WAL")
                self._db.execute("PRAGMA synchronous=FULL")
                self._db.executescript(_SCHEMA)
                self._db.commit()
        except sqlite3.DatabaseError as exc:  # a damaged file gave sqlite3's traceback
            raise RunDirError(
                f"the run journal {path} is damaged ({exc}); move it away and rerun the "
                "catalog into this directory: the run then starts over"
            ) from None

    def close(self) -> None:
        self._db.close()


    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        with self._db:
            yield self._db

    # -- reading -------------------------------------------------------------------------
    def done(self) -> dict[tuple[str, str], StageRecord]:
        """Every completion record, keyed by (frame_id, stage)."""
        return {(r.frame_id, r.stage): r for r in self.iter_done()}

    def iter_done(self, *, integrity: bool = True) -> Iterator[StageRecord]:
        """The completion records one at a time, in the order they were recorded.

        ``integrity=False`` leaves ``checksums`` and ``part_ids`` empty: the frames table
        needs neither, and they are most of a record's size.
        """
        extra = "checksums, part_ids" if integrity else "'{}', '{}'"
        cursor = self._db.execute(
            f"SELECT frame_id, stage, key, run_id, seconds, figures, notes, {extra} "
            "FROM stage_done ORDER BY rowid"
        )
        for r in cursor:
            yield StageRecord(
                r[0],
                r[1],
                r[2],
                r[3],
                r[4],
                json.loads(r[5]),
                json.loads(r[6]),
                json.loads(r[7]),
                json.loads(r[8]),
            )

    def done_keys(self) -> dict[tuple[str, str], str]:
        """The cache key of every completed (frame_id, stage): all that planning needs."""
        rows = self._db.execute("SELECT frame_id, stage, key FROM stage_done").fetchall()
        return {(r[0], r[1]): r[2] for r in rows}

    def live_parts(self, product: str) -> dict[str, str]:
        """frame_id -> the staged part holding that frame's current rows of a table."""
        path = f'$."{product}"'
        rows = self._db.execute(
            "SELECT frame_id, json_extract(part_ids, ?) FROM stage_done "
            "WHERE json_extract(part_ids, ?) IS NOT NULL",
            (path, path),
        ).fetchall()
        return {r[0]: r[1] for r in rows}

    def failed(self) -> dict[str, tuple[str, str]]:
        rows = self._db.execute("SELECT frame_id, stage, error FROM frame_failed").fetchall()
        return {r[0]: (r[1], r[2]) for r in rows}

    def parts(self, product: str | None = None) -> list[PartRecord]:
        sql = "SELECT part_id, product, path, sha256, rows FROM parts"
        args: tuple[Any, ...] = ()
        if product is not None:
            sql += " WHERE product = ?"
            args = (product,)
        return [PartRecord(*r) for r in self._db.execute(sql + " ORDER BY part_id", args)]

    def live_part_ids(self) -> set[str]:
        live: set[str] = set()
        for (part_ids,) in self._db.execute("SELECT part_ids FROM stage_done"):
            live.update(json.loads(part_ids).values())
        return live

    def input_hash(self, path: str, size: int, mtime_ns: int) -> str | None:
        row = self._db.execute(
            "SELECT sha256 FROM input_hashes WHERE path = ? AND size = ? AND mtime_ns = ?",
            (path, size, mtime_ns),
        ).fetchone()
        return row[0] if row else None

    def get_meta(self, key: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else None

    # -- writing -------------------------------------------------------------------------
    def set_meta(self, key: str, value: str) -> None:
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    def remember_input_hashes(self, rows: Iterable[tuple[str, int, int, str]]) -> None:
        with self._db:
            self._db.executemany("INSERT OR REPLACE INTO input_hashes VALUES (?,?,?,?)", rows)

    def commit_batch(
        self,
        records: Iterable[StageRecord],
        failures: Mapping[str, tuple[str, str, str]],
        parts: Iterable[PartRecord],
        cleared: Iterable[str] = (),
    ) -> None:
        """Record finished stages, failures and new Parquet parts in one transaction.

        ``failures`` maps frame_id to (stage, error, run_id); ``cleared`` lists frames whose
        earlier failure no longer holds.
        """
        now = time.time()
        with self._db:
            self._db.executemany(
                "INSERT OR REPLACE INTO parts VALUES (?,?,?,?,?)",
                [(p.part_id, p.product, p.path, p.sha256, p.rows) for p in parts],
            )
            self._db.executemany(
                "INSERT OR REPLACE INTO stage_done VALUES (?,?,?,?,?,?,?,?,?,?)",
                [
                    (
                        r.frame_id,
                        r.stage,
                        r.key,
                        r.run_id,
                        r.seconds,
                        json.dumps(r.figures, sort_keys=True, default=_json_scalar),
                        json.dumps(r.notes),
                        json.dumps(r.checksums, sort_keys=True),
                        json.dumps(r.part_ids, sort_keys=True),
                        now,
                    )
                    for r in records
                ],
            )
            self._db.executemany(
                "DELETE FROM frame_failed WHERE frame_id = ?", [(f,) for f in cleared]
            )
            self._db.executemany(
                "INSERT OR REPLACE INTO frame_failed VALUES (?,?,?,?,?)",
                [(f, s, e, run, now) for f, (s, e, run) in failures.items()],
            )

    def forget(self, pairs: Iterable[tuple[str, str]]) -> None:
        """Drop completion records so the next run redoes those (frame, stage) results."""
        with self._db:
            self._db.executemany(
                "DELETE FROM stage_done WHERE frame_id = ? AND stage = ?", list(pairs)
            )

    def drop_parts(self, part_ids: Iterable[str]) -> None:
        with self._db:
            self._db.executemany("DELETE FROM parts WHERE part_id = ?", [(p,) for p in part_ids])


def _connect_readonly(path: Path) -> sqlite3.Connection:
    """Open the journal for reading only, also on a read-only filesystem.

    A journal in WAL mode cannot be opened read-only where its ``-shm`` file cannot be
    created (an archived run directory on a read-only mount): sqlite says "unable to open
    database file", which read as a damaged journal. Where the directory cannot be
    written, nothing can write the journal either, so it is opened as immutable.
    """
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)
    try:
        db.execute("SELECT count(*) FROM sqlite_master").fetchone()
        return db
    except sqlite3.OperationalError:
        db.close()
        if os.access(path.parent, os.W_OK):
            raise
    db = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True, timeout=30)
    db.execute("SELECT count(*) FROM sqlite_master").fetchone()
    return db


def _json_scalar(value: Any) -> Any:
    """numpy scalars in figures serialise as plain numbers."""
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"figure value {value!r} is not a JSON scalar")
