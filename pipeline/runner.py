"""Plan and run a catalog through the stage graph, resumably.

A (frame, stage) result has a cache key: the stage's name, version and effective params, the
frame's camera, the keys of the stages it reads from, and (for ``ingest``) the sha256 of the
two input files. A run redoes exactly the results whose key has no completion record.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from .catalog import Catalog, FrameRecord, load_catalog
from .errors import ParamError, RunDirError, StoreError
from .executor import open_executor
from .graph import (
    StageGraph,
    build_graph,
    discover_stages,
    parse_set_overrides,
    resolve_stage_params,
    stage_package_name,
)
from .lock import RunLock
from .provenance import environment, new_run_id, now_iso
from .stage import FrameContext
from .state import PartRecord, RunState, StageRecord
from .store import (
    FRAMES_NAME,
    ensure_zarr,
    file_sha256,
    publish_table,
    remove_orphan_temp_files,
    write_parquet_atomic,
    write_part,
)
from .worker import FrameJob, FrameOutcome, process_frame

__all__ = ["RunPlan", "RunSummary", "plan_run", "run", "frame_keys", "format_plan"]

RUN_JSON = "run.json"
_FLUSH_FRAMES = 32
_FLUSH_SECONDS = 10.0


@dataclass
class RunPlan:
    """What a run will do, and why."""

    catalog: Catalog
    graph: StageGraph
    params: dict[str, dict[str, Any]]
    rundir: Path
    frames: list[FrameRecord]  # selected frames, catalog order
    indices: dict[str, int]  # frame_id -> position in the catalog (zarr index)
    keys: dict[str, dict[str, str]]  # frame_id -> stage -> key
    todo: dict[str, list[str]]  # frame_id -> stages to run, graph order
    reasons: dict[str, dict[str, str]]  # frame_id -> stage -> new|changed|failed
    image_shape: tuple[int, int] | None
    input_hashes: dict[str, tuple[str, str]]
    stage_package: str = "stages"

    def counts(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        for stage in self.graph.stages:
            row = {"new": 0, "changed": 0, "failed": 0, "done": 0}
            for frame in self.frames:
                reason = self.reasons[frame.frame_id].get(stage.name)
                row[reason or "done"] += 1
            out[stage.name] = row
        return out


@dataclass
class RunSummary:
    rundir: Path
    run_id: str
    done: int
    failed: int
    pending: int
    failures: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def exit_code(self) -> int:
        return 1 if self.failed else 0


# -- keys and plan ------------------------------------------------------------------------
def _digest(payload: Any) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def frame_keys(
    graph: StageGraph,
    params: Mapping[str, Mapping[str, Any]],
    frame: FrameRecord,
    input_hash: tuple[str, str],
    image_shape: tuple[int, int] | None,
) -> dict[str, str]:
    """Cache key of every stage for one frame."""
    keys: dict[str, str] = {}
    for stage in graph.stages:
        payload: dict[str, Any] = {
            "stage": stage.name,
            "version": stage.version,
            "params": dict(params[stage.name]),
            "upstream": {u: keys[u] for u in graph.upstream(stage)},
        }
        if not stage.inputs and not stage.optional_inputs:
            payload["files"] = list(input_hash)
            payload["shape"] = list(image_shape) if image_shape else None
        else:
            payload["camera"] = frame.camera.to_dict()
        keys[stage.name] = _digest(payload)
    return keys


def _hash_inputs(
    frames: Sequence[FrameRecord], state: RunState | None, *, remember: bool
) -> dict[str, tuple[str, str]]:
    """sha256 of both files of each frame, reusing earlier hashes of unchanged files."""
    fresh: list[tuple[str, int, int, str]] = []
    out = {}

    def one(path: Path) -> str:
        try:
            st = path.stat()
            if not path.is_file():
                return "not-a-file"
            cached = state.input_hash(str(path), st.st_size, st.st_mtime_ns) if state else None
            if cached:
                return cached
            sha = file_sha256(path)
        except OSError as exc:
            return f"unreadable:{exc.errno}"
        fresh.append((str(path), st.st_size, st.st_mtime_ns, sha))
        return sha

    for frame in frames:
        out[frame.frame_id] = (one(frame.left), one(frame.right))
    if remember and state is not None and fresh:
        state.remember_input_hashes(fresh)
    return out


def _probe_shape(catalog: Catalog) -> tuple[int, int] | None:
    """The archive's frame shape: the catalog's, else the first right image that decodes."""
    if catalog.shape:
        return catalog.shape
    from stages._imageio import read_gray

    for frame in catalog.frames[:50]:
        try:
            h, w = read_gray(frame.right).image.shape
            return int(h), int(w)
        except Exception:  # noqa: BLE001 - any unreadable frame: try the next one
            continue
    return None


def _default_rundir(catalog: Catalog) -> Path:
    return Path("runs") / catalog.name


def _validate(
    catalog_path: str | os.PathLike[str],
    overrides: Iterable[str],
    frames: str | None,
    stage_package: str | None,
) -> tuple[Catalog, StageGraph, dict[str, dict[str, Any]], list[FrameRecord]]:
    """Catalog, graph, effective params and selected frames; raises before any work."""
    catalog = load_catalog(catalog_path)
    graph = build_graph(discover_stages(stage_package_name(stage_package)))
    params = resolve_stage_params(graph, catalog.params, parse_set_overrides(graph, overrides))
    selected = [f for f in catalog.frames if frames is None or fnmatch.fnmatch(f.frame_id, frames)]
    if not selected:
        raise ParamError(
            f"--frames {frames!r} matches none of the {len(catalog.frames)} frames of "
            f"{catalog.source}; frame ids look like {catalog.frames[0].frame_id!r}"
        )
    return catalog, graph, params, selected


def plan_run(
    catalog_path: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    *,
    overrides: Iterable[str] = (),
    frames: str | None = None,
    stage_package: str | None = None,
    state: RunState | None = None,
) -> RunPlan:
    """Validate everything and work out what must run.

    With ``state`` (the run's writable journal) newly computed input hashes are remembered;
    without it the run directory is only read.
    """
    catalog, graph, params, selected = _validate(catalog_path, overrides, frames, stage_package)
    rundir = Path(out) if out is not None else _default_rundir(catalog)
    reader = state
    if reader is None and (rundir / "state.sqlite").exists():
        reader = RunState(rundir, readonly=True)
    try:
        done = reader.done() if reader else {}
        failed = reader.failed() if reader else {}
        hashes = _hash_inputs(selected, reader, remember=state is not None)
    finally:
        if reader is not None and reader is not state:
            reader.close()
    image_shape = _probe_shape(catalog)
    keys: dict[str, dict[str, str]] = {}
    todo: dict[str, list[str]] = {}
    reasons: dict[str, dict[str, str]] = {}
    for frame in selected:
        fid = frame.frame_id
        keys[fid] = frame_keys(graph, params, frame, hashes[fid], image_shape)
        todo[fid], reasons[fid] = [], {}
        for stage in graph.stages:
            record = done.get((fid, stage.name))
            if record is not None and record.key == keys[fid][stage.name]:
                continue
            todo[fid].append(stage.name)
            if fid in failed:
                reasons[fid][stage.name] = "failed"
            else:
                reasons[fid][stage.name] = "new" if record is None else "changed"
    return RunPlan(
        catalog=catalog,
        graph=graph,
        params=params,
        rundir=rundir,
        frames=selected,
        indices={f.frame_id: i for i, f in enumerate(catalog.frames)},
        keys=keys,
        todo=todo,
        reasons=reasons,
        image_shape=image_shape,
        input_hashes=hashes,
        stage_package=stage_package_name(stage_package),
    )


def format_plan(plan: RunPlan) -> str:
    """The dry-run table: per stage, how many frames are new, changed, failed or done."""
    lines = [
        f"catalog {plan.catalog.source} ({plan.catalog.name}), {len(plan.frames)} frames "
        f"selected, run directory {plan.rundir}",
        f"{'stage':<12}{'new':>8}{'changed':>9}{'failed':>8}{'done':>8}",
    ]
    for stage, row in plan.counts().items():
        lines.append(
            f"{stage:<12}{row['new']:>8}{row['changed']:>9}{row['failed']:>8}{row['done']:>8}"
        )
    work = sum(1 for f in plan.frames if plan.todo[f.frame_id])
    lines.append(
        f"{work} frame(s) would run; 'changed' = parameters, code version or inputs "
        "differ from the recorded result"
    )
    return "\n".join(lines) + "\n"


# -- running ------------------------------------------------------------------------------
def run(
    catalog_path: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    *,
    overrides: Iterable[str] = (),
    workers: int | None = None,
    scheduler: str | None = None,
    frames: str | None = None,
    dry_run: bool = False,
    progress: Callable[[int, int, str], None] | None = None,
    stage_package: str | None = None,
) -> RunSummary | RunPlan:
    """Run (or with ``dry_run`` only plan) a catalog into a run directory.

    Returns the RunPlan for a dry run, else a RunSummary whose ``exit_code`` is 1 when some
    frames failed. Raises CatalogError / ParamError before any work, RunLockedError when
    another run holds the directory, StoreError when products cannot be written.
    """
    if dry_run:
        return plan_run(
            catalog_path, out, overrides=overrides, frames=frames, stage_package=stage_package
        )
    catalog, *_ = _validate(catalog_path, overrides, frames, stage_package)  # before touching disk
    rundir = Path(out) if out is not None else _default_rundir(catalog)
    rundir.mkdir(parents=True, exist_ok=True)
    with RunLock(rundir):
        remove_orphan_temp_files(rundir)
        state = RunState(rundir)
        try:
            plan = plan_run(
                catalog_path,
                rundir,
                overrides=overrides,
                frames=frames,
                stage_package=stage_package,
                state=state,
            )
            return _execute(plan, state, workers=workers, scheduler=scheduler, progress=progress)
        finally:
            state.close()


def _stage_attrs(plan: RunPlan, stage_name: str, extra: Mapping[str, Any]) -> dict[str, Any]:
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


def _prepare_store(plan: RunPlan, state: RunState) -> dict[str, tuple[tuple[int, ...], str]]:
    if plan.image_shape is None:
        return {}
    arrays = {}
    for stage in plan.graph.stages:
        for product in stage.outputs:
            if product.kind == "array":
                shape = product.frame_shape(plan.image_shape, plan.params[stage.name])
                arrays[product.name] = (
                    product,
                    shape,
                    _stage_attrs(plan, stage.name, product.attrs),
                )
    frame_ids = [f.frame_id for f in plan.catalog.frames]
    recreated = ensure_zarr(plan.rundir, frame_ids, arrays)
    if recreated:
        stages = {plan.graph.producer[name] for name in recreated}
        redo = plan.graph.downstream(stages)
        state.forget((f, s) for f in frame_ids for s in redo)
        for frame in plan.frames:
            fid = frame.frame_id
            for s in plan.graph.stages:
                if s.name in redo and s.name not in plan.todo[fid]:
                    plan.todo[fid].append(s.name)
                    plan.reasons[fid][s.name] = "changed"
            order = [s.name for s in plan.graph.stages]
            plan.todo[fid].sort(key=order.index)
    return {name: (tuple(shape), str(p.dtype)) for name, (p, shape, _a) in arrays.items()}


def _run_json(plan: RunPlan, run_id: str, scheduler: str, started: str) -> dict[str, Any]:
    catalog = plan.catalog
    return {
        "run_id": run_id,
        "archive": catalog.name,
        "status": "running",
        "started": started,
        "finished": None,
        "scheduler": scheduler,
        "catalog": {
            "source": str(Path(catalog.source).resolve()),
            "path": str(Path(catalog.path).resolve()),
            "sha256": catalog.sha256,
            "truth_dir": str(catalog.truth_dir) if catalog.truth_dir else None,
        },
        "camera": catalog.camera.to_dict(),
        "image_shape": list(plan.image_shape) if plan.image_shape else None,
        "stages": {
            s.name: {"version": s.version, "params": plan.params[s.name]} for s in plan.graph.stages
        },
        "inputs": {
            f.frame_id: {
                "left": {"path": str(f.left), "sha256": plan.input_hashes[f.frame_id][0]},
                "right": {"path": str(f.right), "sha256": plan.input_hashes[f.frame_id][1]},
            }
            for f in plan.frames
        },
        "environment": environment(),
    }


def _write_json(path: Path, payload: Mapping[str, Any]) -> None:
    from .store import atomic_write_bytes

    atomic_write_bytes(path, (json.dumps(payload, indent=2, default=str) + "\n").encode())


class _Journal:
    """Buffers finished frames and commits them in batches: parts first, records last."""

    def __init__(self, plan: RunPlan, state: RunState, run_id: str) -> None:
        self.plan, self.state, self.run_id = plan, state, run_id
        self.outcomes: list[FrameOutcome] = []
        self.last_flush = time.monotonic()
        self.schemas = {p.name: _table_schema(p.schema) for p in plan.graph.table_products}

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
        write_frames_table(self.plan, self.state)

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


def _table_schema(schema: pa.Schema | None) -> pa.Schema:
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


def _execute(
    plan: RunPlan,
    state: RunState,
    *,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int, str], None] | None,
) -> RunSummary:
    t0 = time.monotonic()
    run_id = new_run_id()
    expected = _prepare_store(plan, state)
    executor = None
    started = now_iso()
    frame_jobs = [
        FrameJob(
            rundir=str(plan.rundir.resolve()),
            index=plan.indices[f.frame_id],
            context=FrameContext(
                frame_id=f.frame_id,
                archive=plan.catalog.name,
                camera=f.camera,
                metadata=dict(f.metadata),
                left_path=f.left,
                right_path=f.right,
                image_shape=plan.image_shape,
            ),
            stages=tuple(
                (s, plan.params[s], plan.keys[f.frame_id][s]) for s in plan.todo[f.frame_id]
            ),
            expected=expected,
            stage_package=plan.stage_package,
        )
        for f in plan.frames
        if plan.todo[f.frame_id]
    ]
    journal = _Journal(plan, state, run_id)
    meta = _run_json(plan, run_id, "not started", started)
    _write_json(plan.rundir / RUN_JSON, meta)
    fatal: str | None = None
    total = len(frame_jobs)
    try:
        if frame_jobs:
            executor = open_executor(scheduler=scheduler, workers=workers)
            meta["scheduler"] = executor.name
            _write_json(plan.rundir / RUN_JSON, meta)
            finished = 0
            for job, result in executor.map_unordered(process_frame, frame_jobs):
                if isinstance(result, BaseException):
                    result = FrameOutcome(
                        frame_id=job.context.frame_id,
                        index=job.index,
                        failed_stage=job.stages[0][0],
                        error=f"task lost: {type(result).__name__}: {result}",
                    )
                if result.fatal:
                    fatal = result.fatal
                    break
                journal.add(result)
                finished += 1
                if progress:
                    progress(finished, total, result.frame_id)
        journal.flush()
        for product in plan.graph.table_products:
            _publish(plan, state, product.name)
    finally:
        journal.flush()
        if executor is not None:
            executor.close()
    failures = state.failed()
    selected = {f.frame_id for f in plan.frames}
    done_records = state.done()
    n_done = sum(
        1
        for fid in selected
        if fid not in failures
        and all(
            done_records.get((fid, s), None) is not None and done_records[(fid, s)].key == k
            for s, k in plan.keys[fid].items()
        )
    )
    summary = RunSummary(
        rundir=plan.rundir,
        run_id=run_id,
        done=n_done,
        failed=sum(1 for fid in selected if fid in failures),
        pending=len(selected) - n_done - sum(1 for fid in selected if fid in failures),
        failures={fid: failures[fid][1] for fid in selected if fid in failures},
        seconds=time.monotonic() - t0,
    )
    meta.update(
        status="stopped" if fatal else "finished",
        finished=now_iso(),
        counts={"done": summary.done, "failed": summary.failed, "pending": summary.pending},
        seconds=round(summary.seconds, 3),
    )
    _write_json(plan.rundir / RUN_JSON, meta)
    _write_json(plan.rundir / "provenance" / f"{run_id}.json", meta)
    if fatal:
        raise StoreError(fatal)
    return summary


def _publish(plan: RunPlan, state: RunState, product: str) -> None:
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
        _table_schema(plan.graph.product(product).schema),
        plan.indices,
        provenance={
            f"arroyo.{k}": str(v)
            for k, v in _stage_attrs(plan, plan.graph.producer[product], {}).items()
        },
    )
    dead = [p for p in parts if p.part_id not in set(live.values())]
    for part in dead:
        (plan.rundir / part.path).unlink(missing_ok=True)
    state.drop_parts(p.part_id for p in dead)


def load_run_json(rundir: str | os.PathLike[str]) -> dict[str, Any]:
    path = Path(rundir) / RUN_JSON
    if not Path(rundir).is_dir():
        raise RunDirError(f"run directory {rundir} does not exist; run `arroyo run` first")
    if not path.is_file():
        raise RunDirError(f"{rundir} is not an arroyo run directory (no {RUN_JSON})")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RunDirError(f"cannot read {path}: {exc}") from None
