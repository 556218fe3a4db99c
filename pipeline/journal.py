"""The driver's side of completion: batch finished frames into Parquet parts and journal
records (parts first, records last), keep ``frames.parquet`` current, publish tables."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa

from .plan import RunPlan
from .state import PartRecord, RunState, StageRecord
from .store import is_url, sync_filesystem
from .tables import FRAMES_NAME, publish_table, write_parquet_atomic, write_part
from .worker import FrameOutcome

__all__ = ["Journal", "table_schema", "write_frames_table", "publish", "stage_attrs"]

_FLUSH_FRAMES = 32
_FLUSH_SECONDS = 10.0
_FRAMES_TABLE_SECONDS = 30.0  # frames.parquet is rewritten whole: not after every batch


class Journal:
    """Buffers finished frames and commits them in batches: parts first, records last."""

    def __init__(self, plan: RunPlan, state: RunState, run_id: str) -> None:
        self.plan, self.state, self.run_id = plan, state, run_id
        self.outcomes: list[FrameOutcome] = []
        self.last_flush = time.monotonic()
        self.last_table = float("-inf")
        self.schemas = {p.name: table_schema(p.schema) for p in plan.graph.table_products}

    def add(self, outcome: FrameOutcome) -> None:
        self.outcomes.append(outcome)
        if (
            len(self.outcomes) >= _FLUSH_FRAMES
            or time.monotonic() - self.last_flush > _FLUSH_SECONDS
        ):
            self.flush()

    def flush(self, *, frames_table: bool = True) -> None:
        """Commit the buffered frames: their parts, then their records.

        ``frames_table=False`` leaves ``frames.parquet`` to the caller, which rewrites it
        right after (the run's last flush): it is rewritten whole, once is enough.
        """
        if not self.outcomes:
            return
        # workers' chunks on disk before they are recorded; an object store's PUTs are
        # durable once they return
        sync_filesystem(self.plan.rundir)
        if self.plan.products and not is_url(self.plan.products):
            sync_filesystem(Path(self.plan.products))
        rows: dict[str, list[pa.Table]] = {name: [] for name in self.schemas}
        for outcome in self.outcomes:
            for stage_out in outcome.completed:
                for name, columns in stage_out.tables.items():
                    rows[name].append(self._rows(name, outcome.frame_id, columns))
        parts: list[PartRecord] = []
        part_of: dict[str, str] = {}
        for name, tables in rows.items():
            if not tables:
                continue
            table = pa.concat_tables(tables)
            part_id, rel, sha = write_part(self.plan.rundir, name, table)
            parts.append(PartRecord(part_id, name, rel, sha, table.num_rows))
            part_of[name] = part_id
        records, failures, cleared = [], {}, []
        for outcome in self.outcomes:
            for s in outcome.completed:
                produced = {n: part_of[n] for n in s.tables if n in part_of}
                records.append(
                    StageRecord(
                        outcome.frame_id,
                        s.stage,
                        s.key,
                        self.run_id,
                        s.seconds,
                        s.figures,
                        s.notes,
                        s.checksums,
                        produced,
                    )
                )
            if outcome.error is not None:
                failures[outcome.frame_id] = (
                    outcome.failed_stage or "?",
                    outcome.error,
                    self.run_id,
                )
            else:
                cleared.append(outcome.frame_id)
        self.state.commit_batch(records, failures, parts, cleared)
        self.outcomes.clear()
        self.last_flush = time.monotonic()
        if frames_table and self.last_flush - self.last_table >= _FRAMES_TABLE_SECONDS:
            write_frames_table(self.plan, self.state)
            self.last_table = time.monotonic()

    def _rows(self, name: str, frame_id: str, columns: Mapping[str, Any]) -> pa.Table:
        schema = self.schemas[name]
        body = pa.table(dict(columns)) if columns else None
        n = body.num_rows if body is not None else 0
        data = {
            "archive": pa.array([self.plan.catalog.name] * n, pa.string()),
            "run_id": pa.array([self.run_id] * n, pa.string()),
            "frame_id": pa.array([frame_id] * n, pa.string()),
        }
        for fld in schema:
            if fld.name in data:
                continue
            if body is not None and fld.name in body.column_names:
                data[fld.name] = body[fld.name].cast(fld.type)
            else:
                data[fld.name] = pa.nulls(n, fld.type)
        return pa.table(data, schema=schema)


def table_schema(schema: pa.Schema | None) -> pa.Schema:
    """A table product's published schema: archive, run_id, frame_id, then ``schema``."""
    ids = [
        pa.field("archive", pa.string()),
        pa.field("run_id", pa.string()),
        pa.field("frame_id", pa.string()),
    ]
    return pa.schema(ids + (list(schema) if schema is not None else []))


def write_frames_table(plan: RunPlan, state: RunState) -> None:
    """``frames.parquet``: one row per catalog frame with status, error, timings, figures.

    Built column by column while the completion records stream from the journal, so the
    driver never holds every record (or a dict per row) at once: it rewrites this table
    after every batch, and at 2,000 frames the record dicts alone were ~30 MB.
    """
    frames = plan.catalog.frames
    n = len(frames)
    stage_order = {s.name: k for k, s in enumerate(plan.graph.stages)}
    failed = state.failed()
    matching = [0] * n  # stages whose record is current (selected) or present (others)
    notes: dict[int, list[tuple[int, list[str]]]] = {}
    stage_columns: list[dict[str, list[Any]]] = [
        {f"{s.name}_seconds": [None] * n} for s in plan.graph.stages
    ]
    for record in state.iter_done(integrity=False):
        i = plan.indices.get(record.frame_id)
        k = stage_order.get(record.stage)
        if i is None or k is None:
            continue
        keys = plan.keys.get(record.frame_id)
        if keys is not None and keys.get(record.stage) != record.key:
            # a record of other inputs or params (kept: it may match again) is not this
            # frame's: its seconds and figures made a frame failed at ingest look described
            # to `arroyo evaluate`, which then scored the earlier run's labels
            continue
        matching[i] += 1
        columns = stage_columns[k]
        columns[f"{record.stage}_seconds"][i] = record.seconds
        for name, value in record.figures.items():
            columns.setdefault(f"{record.stage}_{name}", [None] * n)[i] = value
        if record.notes:
            notes.setdefault(i, []).append((k, record.notes))
    n_stages = len(stage_order)
    out: dict[str, list[Any]] = {
        "frame_id": [f.frame_id for f in frames],
        "index": list(range(n)),
        "status": [
            "failed" if f.frame_id in failed else ("done" if matching[i] == n_stages else "pending")
            for i, f in enumerate(frames)
        ],
        "failed_stage": [failed[f.frame_id][0] if f.frame_id in failed else None for f in frames],
        "error": [failed[f.frame_id][1] if f.frame_id in failed else None for f in frames],
        "left": [str(f.left) for f in frames],
        "right": [str(f.right) for f in frames],
    }
    for columns in stage_columns:
        out.update(columns)
    out["notes"] = [
        "; ".join(note for _k, ns in sorted(notes[i], key=lambda x: x[0]) for note in ns)
        if i in notes
        else None
        for i in range(n)
    ]
    taken = set(out)  # a catalog column never replaces one of the engine's
    for i, frame in enumerate(frames):
        for name, value in frame.metadata.items():
            if name not in taken:
                out.setdefault(name, [None] * n)[i] = value
    # the engine's own columns keep one type whatever this run's values: all-None columns
    # (no frame failed, no notes yet) were Arrow's null type, a schema that changed between
    # runs of one archive
    fixed: dict[str, pa.DataType] = {
        **dict.fromkeys(
            ("frame_id", "status", "failed_stage", "error", "left", "right"), pa.string()
        ),
        "notes": pa.string(),
        "index": pa.int64(),
        **{f"{s.name}_seconds": pa.float64() for s in plan.graph.stages},
    }
    write_parquet_atomic(
        pa.table(
            {
                name: pa.array(values, fixed[name]) if name in fixed else _column(values)
                for name, values in out.items()
            }
        ),
        plan.rundir / FRAMES_NAME,
    )


def _column(values: list[Any]) -> pa.Array:
    """One frames.parquet column; a figure that is a number in one frame and a str in
    another (a user's stage) is stored as text rather than stopping the run. A NaN figure
    (describe's size-frequency fit of a frame with too few rocks) is stored as NULL, SQL's
    unknown: ``avg(describe_sfd_k)`` over an archive was NaN as soon as one frame had no
    fit."""
    values = [None if isinstance(v, float) and math.isnan(v) else v for v in values]
    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.array([None if v is None else str(v) for v in values], pa.string())


def publish(plan: RunPlan, state: RunState, product: str) -> None:
    """Publish a table product: the rows of every frame whose producing record is current
    (for this run's frames, the key the plan wants; other frames: whatever is recorded).

    A record of other inputs or params stays in the journal (its part too: the key may
    match again) but its rows are not published: a frame whose input file was deleted, or
    that failed under new params, kept its earlier run's rows while frames.parquet called it
    failed.
    """
    recorded = state.live_parts(product)
    stage = plan.graph.producer[product]
    keys = state.done_keys()
    live = {
        fid: part
        for fid, part in recorded.items()
        if fid not in plan.keys or keys.get((fid, stage)) == plan.keys[fid].get(stage)
    }
    parts = state.parts(product)
    publish_table(
        plan.rundir,
        product,
        plan.catalog.name,
        live,
        [(p.part_id, p.path) for p in parts],
        table_schema(plan.graph.product(product).schema),
        plan.indices,
        provenance={
            f"arroyo.{k}": str(v)
            for k, v in stage_attrs(plan, plan.graph.producer[product], {}).items()
        },
    )
    dead = [p for p in parts if p.part_id not in set(recorded.values())]
    for part in dead:
        (plan.rundir / part.path).unlink(missing_ok=True)
    state.drop_parts(p.part_id for p in dead)


def stage_attrs(plan: RunPlan, stage_name: str, extra: Mapping[str, Any]) -> dict[str, Any]:
    """zarr attributes of a product written by ``stage_name``: ``extra`` plus the stage's
    name, version and effective params."""
    stage = plan.graph.stage(stage_name)
    attrs = dict(extra)
    attrs.update(
        {
            "stage": stage.name,
            "stage_version": stage.version,
            "stage_params": json.dumps(plan.params[stage.name], sort_keys=True),
        }
    )
    return attrs
