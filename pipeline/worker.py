"""The task a worker runs: every pending stage of one frame, products written in place.

``process_frame`` never raises for a bad frame: it returns a ``FrameOutcome`` naming the stage
that failed and why. It raises only when the run itself cannot go on (disk full), so the
driver stops instead of failing every remaining frame.
"""

from __future__ import annotations

import contextlib
import functools
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FrameError
from .stage import FrameContext, Stage, StageResult
from .store import (
    is_disk_full,
    is_url,
    read_frame_array,
    remove_other_product_files,
    write_frame_array,
    write_product_file,
)

__all__ = ["FrameJob", "StageOutcome", "FrameOutcome", "process_frame", "process_batch"]


@dataclass(frozen=True)
class FrameJob:
    """Everything a worker needs for one frame (picklable; no open handles)."""

    rundir: str
    index: int
    context: FrameContext
    stages: tuple[tuple[str, dict[str, Any], str], ...]  # (stage, params, key) in order
    expected: dict[str, tuple[tuple[int, ...], str]]  # array product -> (shape, dtype)
    stage_package: str = "stages"
    products: str = ""  # products root (directory or fsspec URL); empty: the run directory
    run_id: str = ""


@dataclass
class StageOutcome:
    stage: str
    key: str
    seconds: float
    figures: dict[str, Any]
    notes: list[str]
    checksums: dict[str, str]
    tables: dict[str, dict[str, Any]]


@dataclass
class FrameOutcome:
    frame_id: str
    index: int
    completed: list[StageOutcome] = field(default_factory=list)
    failed_stage: str | None = None
    error: str | None = None
    fatal: str | None = None


@functools.lru_cache(maxsize=4)
def _stages(package: str) -> dict[str, Stage]:
    from .graph import build_graph, discover_stages

    return {s.name: s for s in build_graph(discover_stages(package)).stages}


def _limit_threads() -> None:
    """One worker = one core: libraries must not spawn a thread per core each."""
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover - opencv is a dependency
        pass


def _describe_error(exc: BaseException) -> str:
    if isinstance(exc, FrameError | ValueError | TypeError):
        return str(exc)
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    site = f" at {Path(where.filename).name}:{where.lineno}" if where else ""
    return f"{type(exc).__name__}: {exc}{site}"


def _check_arrays(job: FrameJob, stage: Stage, result: StageResult) -> None:
    for product in stage.outputs:
        if product.kind != "array":
            continue
        if product.name not in result.arrays:
            raise ValueError(f"stage {stage.name!r} did not return array {product.name!r}")
        data = result.arrays[product.name]
        shape, dtype = job.expected[product.name]
        if not isinstance(data, np.ndarray) or data.shape != shape or data.dtype != dtype:
            got = (
                f"{data.shape} {data.dtype}"
                if isinstance(data, np.ndarray)
                else type(data).__name__
            )
            raise ValueError(
                f"stage {stage.name!r} returned {product.name!r} as {got}; the product is "
                f"declared {shape} {dtype}"
            )


def _check_undeclared(stage: Stage, result: StageResult) -> None:
    """Arrays and tables the stage does not declare would be dropped (or, for a table, stop
    the whole run when the batch is committed): fail the frame and name the fix."""
    for kind, returned in (("array", result.arrays), ("table", result.tables)):
        declared = [p.name for p in stage.outputs if p.kind == kind]
        extra = sorted(set(returned) - set(declared))
        if extra:
            raise ValueError(
                f"stage {stage.name!r} returned {kind} {', '.join(map(repr, extra))}, which "
                f"it does not declare (its {kind} outputs: {', '.join(declared) or 'none'}); "
                f"declare Product(..., kind={kind!r}) in the stage's outputs or drop it"
            )


def _check_files(stage: Stage, result: StageResult, frame_id: str) -> None:
    """Files land only in the frame's folder of a files product the stage declares: a key
    such as ``../run.json`` or ``state.sqlite`` would overwrite the run's own records."""
    folders = [f"{p.name}/{frame_id}/" for p in stage.outputs if p.kind == "files"]
    for rel in result.files:
        parts = str(rel).split("/")
        inside = any(str(rel).startswith(folder) for folder in folders)
        if not inside or "" in parts or "." in parts or ".." in parts or "\\" in str(rel):
            where = (
                " or ".join(f"{f}NAME" for f in folders)
                or "(none: declare Product(NAME, kind='files'))"
            )
            raise ValueError(
                f"stage {stage.name!r} returned file {rel!r}; a stage's files go under "
                f"{where}, a relative path without '.', '..' or empty parts"
            )
        if not isinstance(result.files[rel], bytes | bytearray | memoryview):
            raise TypeError(
                f"stage {stage.name!r} returned file {rel!r} as "
                f"{type(result.files[rel]).__name__}; file content must be bytes"
            )


def _check_figures(stage: Stage, result: StageResult) -> None:
    """Figures become ``frames.parquet`` columns ``<stage>_<name>``: one scalar each (NumPy
    scalars turned into Python ones here); a list or array there stopped the run's table."""
    for name, value in list(result.figures.items()):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(
                f"stage {stage.name!r} returned figure {name!r}; a figure name is an "
                "identifier (it becomes the frames.parquet column "
                f"{stage.name}_NAME)"
            )
        if isinstance(value, np.generic) and value.ndim == 0:
            value = value.item()
            result.figures[name] = value
        if value is not None and not isinstance(value, bool | int | float | str):
            raise TypeError(
                f"stage {stage.name!r} returned figure {name!r} as {type(value).__name__}; a "
                "figure is one number, bool, str or None per frame (a table product holds "
                "more)"
            )


def _check_tables(stage: Stage, result: StageResult) -> None:
    """Each declared table: columns of equal length, exactly the schema's, castable to it.

    Checked here so that a bad frame fails alone (an error when the journal commits a batch
    would stop the run). The columns are replaced by the Arrow arrays the check built, cast
    to the schema's types, so the driver's journal does not convert them again.
    """
    import pyarrow as pa

    for product in stage.outputs:
        if product.kind != "table":
            continue
        where = f"stage {stage.name!r} table {product.name!r}"
        if product.name not in result.tables:
            raise ValueError(
                f"{where}: not returned; return its columns (of length 0 for a frame without rows)"
            )
        columns = result.tables[product.name]
        if not isinstance(columns, dict):
            raise TypeError(
                f"{where}: expected a dict of column name to values, got {type(columns).__name__}"
            )
        lengths = {name: len(values) for name, values in columns.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(
                f"{where}: columns of unequal lengths {lengths}; every column "
                "needs one value per row"
            )
        declared = list(product.schema.names)
        if set(columns) != set(declared):
            missing = [n for n in declared if n not in columns]
            unknown = [n for n in columns if n not in declared]
            raise ValueError(
                f"{where}: columns {sorted(columns)} do not match the declared schema "
                f"{declared} (missing {missing}, undeclared {unknown}); return exactly the "
                "schema's columns or change Product(schema=...)"
            )
        converted = {}
        for field_ in product.schema:
            try:
                converted[field_.name] = pa.array(columns[field_.name]).cast(field_.type)
            except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError) as exc:
                raise ValueError(
                    f"{where}: column {field_.name!r} cannot be stored as {field_.type} "
                    f"(declared in the schema): {exc}"
                ) from None
        result.tables[product.name] = converted


class _StoreUnreachable(Exception):
    """Reading or writing a remote products root failed: every other frame would fail alike,
    so the run stops (as for a full disk) instead of recording each frame as failed."""


@contextlib.contextmanager
def _store_io(root: str, doing: str) -> Iterator[None]:
    try:
        yield
    except Exception as exc:
        if is_url(root):
            raise _StoreUnreachable(f"{doing} {root} failed: {type(exc).__name__}: {exc}") from exc
        raise


def process_frame(job: FrameJob) -> FrameOutcome:
    """Run the job's stages on one frame, writing arrays and files as each stage finishes."""
    _limit_threads()
    stages = _stages(job.stage_package)
    root = job.products or job.rundir
    ctx = job.context
    outcome = FrameOutcome(frame_id=ctx.frame_id, index=job.index)
    produced: dict[str, np.ndarray] = {}
    for stage_name, params, key in job.stages:
        stage = stages[stage_name]
        try:
            inputs = {}
            for name in stage.inputs + stage.optional_inputs:
                if name in produced:
                    inputs[name] = produced[name]
                elif name in job.expected:
                    with _store_io(root, "reading"):
                        inputs[name] = read_frame_array(root, name, job.index, token=job.run_id)
            start = time.perf_counter()
            result = stage.run(inputs, frame=ctx, params=dict(params))
            seconds = time.perf_counter() - start
            if not isinstance(result, StageResult):
                raise TypeError(
                    f"stage {stage.name!r} returned {type(result).__name__}, expected StageResult"
                )
            _check_undeclared(stage, result)
            _check_arrays(job, stage, result)
            _check_tables(stage, result)
            _check_files(stage, result, ctx.frame_id)
            _check_figures(stage, result)
            checksums = {}
            with _store_io(root, "writing"):
                for product in stage.outputs:
                    if product.kind == "array":
                        data = result.arrays[product.name]
                        checksums[product.name] = write_frame_array(
                            root, product.name, job.index, data, token=job.run_id
                        )
                        produced[product.name] = data
                for rel, content in result.files.items():
                    write_product_file(root, rel, content)
                for product in stage.outputs:
                    if product.kind == "files":  # the frame's folder: this result's only
                        folder = f"{product.name}/{ctx.frame_id}"
                        remove_other_product_files(root, folder, result.files)
        except Exception as exc:
            if isinstance(exc, _StoreUnreachable):
                outcome.fatal = (
                    f"products of frame {ctx.frame_id!r}: {exc}; check the URL, credentials "
                    "and network, then rerun: finished frames are kept"
                )
                return outcome
            if is_disk_full(exc):
                outcome.fatal = (
                    f"cannot write products of frame {ctx.frame_id!r} under {root}: "
                    f"{exc.strerror} (errno {exc.errno}); free space and rerun: finished "  # type: ignore[attr-defined]
                    "frames are kept"
                )
                return outcome
            outcome.failed_stage = stage.name
            outcome.error = f"{stage.name}: {_describe_error(exc)}"
            return outcome
        outcome.completed.append(
            StageOutcome(
                stage=stage.name,
                key=key,
                seconds=seconds,
                figures=dict(result.figures),
                notes=list(result.notes),
                checksums=checksums,
                tables=dict(result.tables),
            )
        )
    return outcome


def process_batch(jobs: list[FrameJob]) -> list[FrameOutcome]:
    """Several small frames in one task, so each task does enough work to be worth it."""
    return [process_frame(job) for job in jobs]
