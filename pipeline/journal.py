"""The driver's side of completion: batch finished frames into Parquet parts and journal
records (parts first, records last), keep ``frames.parquet`` current, publish tables."""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa

from .plan import RunPlan
from .state import PartRecord, RunState, StageRecord
from .store import (
    FRAMES_NAME,
    is_url,
    publish_table,
    sync_filesystem,
    write_parquet_atomic,
    write_part,
)
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

    def flush(self) -> None:
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
        if self.last_flush - self.last_table >= _FRAMES_TABLE_SECONDS:
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
    ids = [
        pa.field("archive", pa.string()),
        pa.field("run_id", pa.string()),
        pa.field("frame_id", pa.string()),
    ]
    return pa.schema(ids + (list(schema) if schema is not None else []))


def write_frames_table(plan: RunPlan, state: RunState) -> None:
    """``frames.parquet``: one row per catalog frame with status, error, timings, figures."""
    done = state.done()
    failed = state.failed()
    rows = []
    for i, frame in enumerate(plan.catalog.frames):
        fid = frame.frame_id
        keys = plan.keys.get(fid)
        row: dict[str, Any] = {"frame_id": fid, "index": i}
        complete = keys is not None and all(
            (fid, s) in done and done[(fid, s)].key == k for s, k in keys.items()
        )
        if keys is None:  # not selected in this run: judge by what is recorded
            complete = all((fid, s.name) in done for s in plan.graph.stages)
        row["status"] = "failed" if fid in failed else ("done" if complete else "pending")
        row["failed_stage"] = failed[fid][0] if fid in failed else None
        row["error"] = failed[fid][1] if fid in failed else None
        row["left"] = str(frame.left)
        row["right"] = str(frame.right)
        notes: list[str] = []
        for stage in plan.graph.stages:
            record = done.get((fid, stage.name))
            row[f"{stage.name}_seconds"] = record.seconds if record else None
            if record:
                notes += record.notes
                for name, value in record.figures.items():
                    row[f"{stage.name}_{name}"] = value
        row["notes"] = "; ".join(notes) or None
        for name, value in frame.metadata.items():
            row.setdefault(name, value)
        rows.append(row)
    table = pa.Table.from_pylist(rows)
    write_parquet_atomic(table, plan.rundir / FRAMES_NAME)


def publish(plan: RunPlan, state: RunState, product: str) -> None:
    live = {
        fid: rec.part_ids[product]
        for (fid, _stage), rec in state.done().items()
        if product in rec.part_ids
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
    dead = [p for p in parts if p.part_id not in set(live.values())]
    for part in dead:
        (plan.rundir / part.path).unlink(missing_ok=True)
    state.drop_parts(p.part_id for p in dead)


def stage_attrs(plan: RunPlan, stage_name: str, extra: Mapping[str, Any]) -> dict[str, Any]:
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
