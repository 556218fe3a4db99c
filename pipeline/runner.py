"""Run a catalog through the stage graph, resumably (planning is in :mod:`pipeline.plan`,
completion bookkeeping in :mod:`pipeline.journal`)."""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ._forkserver import stop_forkserver
from .errors import ParamError, RunDirError, StoreError
from .executor import (
    check_scheduler,
    check_worker_wait,
    check_workers,
    open_executor,
    prestart_local_workers,
    terminate_as_interrupt,
)
from .journal import Journal, publish, stage_attrs, write_frames_table
from .lock import RunLock
from .notes import NotesSummary, run_notes
from .plan import RunPlan, default_rundir, plan_run, validate_request
from .provenance import environment, new_run_id, now_iso
from .stage import FrameContext
from .state import STATE_NAME, RunState
from .store import (
    atomic_write_bytes,
    check_frame_list,
    claim_products,
    coerce_products_root,
    ensure_zarr,
    is_disk_full,
    is_url,
    products_writer,
    remove_orphan_temp_files,
    zarr_location,
)
from .worker import FrameJob, FrameOutcome, process_frame

__all__ = ["RunSummary", "run", "load_run_json", "RUN_JSON"]

RUN_JSON = "run.json"


@dataclass
class RunSummary:
    rundir: Path
    run_id: str
    done: int
    failed: int
    pending: int
    failures: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    notes: NotesSummary | None = None  # the selected frames' notes (pipeline.notes)
    duplicates: dict[str, str] = field(default_factory=dict)  # RunPlan.duplicates

    @property
    def exit_code(self) -> int:
        return 1 if self.failed else 0


_EVALUATION_NAME = "evaluation.parquet"  # written by `arroyo evaluate` (pipeline.evaluate)
_OWNER_KEY = "products_owner"  # journal meta: the token the run directory's products carry


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
    products: str | os.PathLike[str] | None = None,
    worker_wait: float | None = None,
) -> RunSummary | RunPlan:
    """Run (or with ``dry_run`` only plan) a catalog into a run directory.

    ``products`` puts the array products and quicklooks under another directory (a shared
    filesystem) or an fsspec URL (``s3://bucket/prefix``) that every worker can reach; the
    journal and tables stay in the run directory. It is recorded in ``run.json``, so a
    resumed run finds it without the option. Returns the RunPlan for a dry run, else a
    RunSummary whose ``exit_code`` is 1 when some frames failed. Raises CatalogError /
    ParamError before any work, RunDirError when ``products`` differs from the root the run
    directory already uses, RunLockedError when another run holds the directory, StoreError
    when products cannot be written. A SIGTERM to the main thread stops the run as a ^C
    does: the finished frames are committed and published, then KeyboardInterrupt.
    ``worker_wait`` (seconds, > 0; default ``executor.WORKER_WAIT_SECONDS``, 60) is how long
    a run on a remote ``scheduler`` waits for its first worker before it stops with
    ParamError (workers from a batch queue may need more).
    """
    check_scheduler(scheduler)  # a typo stops the run before the run directory exists
    if worker_wait is not None:
        check_worker_wait(worker_wait)
    # checked here, not when the executor opens: `--workers 0` passed a dry run and a run
    # with nothing pending, and a run with work stopped only after writing run.json
    check_workers(workers)
    with terminate_as_interrupt():  # batch time limits, `timeout`, `docker stop`: as ^C
        return _run(
            catalog_path, out, overrides=overrides, workers=workers, scheduler=scheduler,
            frames=frames, dry_run=dry_run, progress=progress, stage_package=stage_package,
            products=products, worker_wait=worker_wait,
        )


def _run(
    catalog_path: str | os.PathLike[str],
    out: str | os.PathLike[str] | None,
    *,
    overrides: Iterable[str],
    workers: int | None,
    scheduler: str | None,
    frames: str | None,
    dry_run: bool,
    progress: Callable[[int, int, str], None] | None,
    stage_package: str | None,
    products: str | os.PathLike[str] | None,
    worker_wait: float | None,
) -> RunSummary | RunPlan:
    # local workers' imports run beside the planning (pipeline._forkserver)
    forked = not dry_run and prestart_local_workers(scheduler, workers, stage_package)
    try:
        request = validate_request(catalog_path, overrides, frames, stage_package)  # before disk
        rundir = Path(out) if out is not None else default_rundir(request.catalog)
        _check_rundir(rundir)
        root = _resolve_products(rundir, products)
        if not is_url(root):  # a dry run said what would run where the run then refused
            _check_products_owner(rundir, root, _journal_owner(rundir))
            check_frame_list(root or rundir, [f.frame_id for f in request.catalog.frames])
        if dry_run:
            return plan_run(request, rundir, products=root)
        try:
            rundir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunDirError(
                f"cannot create the run directory {rundir}: {exc.strerror or exc}; give "
                "--out a directory you can write"
            ) from None
        with RunLock(rundir):
            remove_orphan_temp_files(rundir)
            if root and not is_url(root):
                remove_orphan_temp_files(Path(root))
            state = RunState(rundir)
            try:
                plan = plan_run(request, rundir, state=state, products=root)
                return _execute(
                    plan, state, workers=workers, scheduler=scheduler, progress=progress,
                    worker_wait=worker_wait,
                )
            finally:
                state.close()
    finally:
        if forked:  # when no frame was pending, or the run failed before its cluster
            stop_forkserver()


def _check_rundir(rundir: Path) -> None:
    """Refuse a run directory path that names something else than a directory."""
    if rundir.exists() and not rundir.is_dir():
        raise RunDirError(
            f"the run directory {rundir} is a file, not a directory; give --out a new or "
            "existing run directory (default runs/<archive>)"
        )


def _resolve_products(rundir: Path, requested: str | os.PathLike[str] | None) -> str:
    """The products root of this run: '' for the run directory itself, else the canonical
    directory or URL. A run directory keeps the root it started with, since its journal
    records frames whose products are there."""
    recorded = ""
    if (rundir / RUN_JSON).is_file():
        recorded = load_run_json(rundir).get("products") or ""
    if requested is None:
        return recorded
    try:
        wanted = coerce_products_root(requested)
    except ValueError as exc:
        raise ParamError(f"--products: {exc}") from None
    if not is_url(wanted) and Path(wanted) == rundir.resolve():
        wanted = ""
    if wanted and not is_url(wanted) and Path(wanted).exists() and not Path(wanted).is_dir():
        # zarr's NotADirectoryError came out as a traceback (exit 1) after the journal
        raise ParamError(
            f"--products {requested}: {wanted} is a file, not a directory; give a new or "
            "existing directory (or a URL such as s3://bucket/prefix)"
        )
    if (rundir / RUN_JSON).is_file() and wanted != recorded:
        raise RunDirError(
            f"{rundir} keeps its products in {recorded or 'the run directory'}, not "
            f"{wanted or 'the run directory'}; rerun without --products to resume there, or "
            "give a new --out for products elsewhere"
        )
    return wanted


def _check_products_owner(rundir: Path, root: str, owner: str | None) -> None:
    """Refuse products claimed by another run directory.

    Two run directories given the same ``--products`` wrote the same slabs: the second
    silently replaced the first's maps, whose journal and tables then described other data.
    A run directory's token (``owner``, in its journal) is recorded in the products it
    writes, so a moved run directory still owns its products. Products in the run directory
    itself are its own, and so are those its ``run.json`` records when its journal has no
    token (a damaged journal moved away, as its error message advises).
    """
    if not root:
        return
    writer = products_writer(root)
    if writer is None or writer == owner:
        return
    if owner is None and (rundir / RUN_JSON).is_file():
        return  # _resolve_products made root the one run.json records
    raise RunDirError(
        f"{zarr_location(root)} holds the products of another run directory; two run "
        "directories that share a products root overwrite each other's maps. Give this run "
        f"directory its own --products, such as {root.rstrip('/')}/{rundir.resolve().name}"
    )


def _journal_owner(rundir: Path) -> str | None:
    """The run directory's products token, read without creating a journal."""
    if not (rundir / STATE_NAME).is_file():
        return None
    state = RunState(rundir, readonly=True)
    try:
        return state.get_meta(_OWNER_KEY)
    except sqlite3.OperationalError as exc:
        if "no such table" not in str(exc):
            raise
        # a run killed between creating state.sqlite and writing its schema: nothing is
        # recorded yet, and the writable open creates the schema
        return None
    finally:
        state.close()


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
                    # written on every run: the residual's attrs follow its reference camera
                    stage_attrs(plan, stage.name, product.resolved_attrs(plan.catalog.camera)),
                )
    frame_ids = [f.frame_id for f in plan.catalog.frames]
    try:
        _check_products_owner(plan.rundir, plan.products, state.get_meta(_OWNER_KEY))
        recreated = ensure_zarr(plan.products_root, frame_ids, arrays)
    except Exception as exc:
        if isinstance(exc, RunDirError):
            raise
        if not is_url(plan.products_root):
            if not isinstance(exc, OSError):
                raise
            if is_disk_full(exc):  # exit 4 as for the frames' writes, not a traceback
                raise StoreError(
                    f"cannot write the product store {zarr_location(plan.products_root)}: "
                    f"{exc.strerror} (errno {exc.errno}); free space and rerun"
                ) from None
            raise RunDirError(  # a parent that is a file, no permission...
                f"cannot create the product store {zarr_location(plan.products_root)}: "
                f"{exc.strerror or exc}; give --out (or --products) a directory you can write"
            ) from None
        raise StoreError(
            f"cannot open the product store at {plan.products_root}: {type(exc).__name__}: "
            f"{exc}; check the URL, credentials and network, then rerun"
        ) from exc
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
        "products": plan.products or None,
        "catalog": {
            "source": str(Path(catalog.source).resolve()),
            "path": str(Path(catalog.path).resolve()),
            "sha256": catalog.sha256,
            "truth_dir": str(catalog.truth_dir) if catalog.truth_dir else None,
        },
        "camera": catalog.camera.to_dict(),
        "image_shape": list(plan.image_shape) if plan.image_shape else None,
        # which package's code made the products: a resume may name another package
        "stage_package": plan.stage_package,
        "stages": {
            s.name: {
                "version": s.version,
                "module": getattr(s.run, "__module__", None),
                "params": plan.params[s.name],
            }
            for s in plan.graph.stages
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
    atomic_write_bytes(path, (json.dumps(payload, indent=2, default=str) + "\n").encode())


def _execute(
    plan: RunPlan,
    state: RunState,
    *,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int, str], None] | None,
    worker_wait: float | None,
) -> RunSummary:
    t0 = time.monotonic()
    run_id = new_run_id()
    expected = _prepare_store(plan, state)
    executor = None
    started = now_iso()
    pending = [f for f in plan.frames if plan.todo[f.frame_id]]
    frame_jobs = (  # built lazily: the executor keeps only a window of jobs in flight
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
            products=plan.products,
            run_id=run_id,
        )
        for f in pending
    )
    # a failed frame whose every stage is current again (its missing file restored) has
    # nothing to run: its old failure went, else it stayed 'failed' with the old error
    failed = state.failed()
    recovered = [
        f.frame_id for f in plan.frames if f.frame_id in failed and not plan.todo[f.frame_id]
    ]
    if recovered:
        state.commit_batch([], {}, [], recovered)
    journal = Journal(plan, state, run_id)
    meta = _run_json(plan, run_id, "not started", started)
    # frames.parquet before run.json: `arroyo status` of a run killed before its first
    # frame finished read a run.json without the frames table and printed only its path
    write_frames_table(plan, state)
    _write_json(plan.rundir / RUN_JSON, meta)
    if expected:  # the journal holds the token first: a kill in between leaves no claim
        owner = state.get_meta(_OWNER_KEY) or run_id
        state.set_meta(_OWNER_KEY, owner)
        try:
            claim_products(plan.products_root, owner)
        except Exception as exc:
            if not is_url(plan.products_root):
                raise
            raise StoreError(
                f"cannot write to the product store at {plan.products_root}: "
                f"{type(exc).__name__}: {exc}; check the URL, credentials and network"
            ) from exc
    fatal: str | None = None
    interrupted = False
    total = len(pending)
    try:
        if pending:
            # its scores are of the products this run is about to change: `arroyo query`
            # and `arroyo report` showed the old run's figures as if they were this one's
            (plan.rundir / _EVALUATION_NAME).unlink(missing_ok=True)
            try:
                executor = open_executor(
                    scheduler=scheduler, workers=workers, stage_package=plan.stage_package,
                    worker_wait=worker_wait,
                )
            except Exception:  # no worker ran: the run stopped, not 'interrupted'
                meta.update(status="stopped", finished=now_iso())
                _write_json(plan.rundir / RUN_JSON, meta)
                raise
            meta["scheduler"] = executor.name
            _write_json(plan.rundir / RUN_JSON, meta)
            finished = 0
            try:
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
            except KeyboardInterrupt:
                # ^C: the workers stop, the finished frames' rows are published below and
                # the interrupt goes on after; unpublished, `arroyo query` showed no rows
                # of frames that frames.parquet called done
                interrupted = True
                _close_quietly(executor)
                executor = None
        journal.flush(frames_table=False)  # written in `finally`, after the tables
        for product in plan.graph.table_products:
            publish(plan, state, product.name)
    finally:
        journal.flush()
        write_frames_table(plan, state)
        if executor is not None:
            executor.close()
    failures = state.failed()
    selected = {f.frame_id for f in plan.frames}
    done_keys = state.done_keys()
    n_done = sum(
        1
        for fid in selected
        if fid not in failures
        and all(done_keys.get((fid, s)) == k for s, k in plan.keys[fid].items())
    )
    summary = RunSummary(
        rundir=plan.rundir,
        run_id=run_id,
        done=n_done,
        failed=sum(1 for fid in selected if fid in failures),
        pending=len(selected) - n_done - sum(1 for fid in selected if fid in failures),
        failures={fid: failures[fid][1] for fid in selected if fid in failures},
        seconds=time.monotonic() - t0,
        # in frames.parquet only, the notes went unseen: 12-bit images that came out dark
        # made a run that "succeeded" with no rocks
        notes=run_notes(plan, state),
        duplicates=plan.duplicates,
    )
    meta.update(
        status="stopped" if fatal else ("interrupted" if interrupted else "finished"),
        finished=now_iso(),
        counts={"done": summary.done, "failed": summary.failed, "pending": summary.pending},
        seconds=round(summary.seconds, 3),
    )
    _write_json(plan.rundir / RUN_JSON, meta)
    _write_json(plan.rundir / "provenance" / f"{run_id}.json", meta)
    if fatal:
        raise StoreError(fatal)
    if interrupted:
        raise KeyboardInterrupt
    return summary


def _close_quietly(executor: Any) -> None:
    """Close an executor whose workers may have died with the driver's ^C."""
    try:
        executor.close()
    except Exception:  # noqa: BLE001 - closing must not hide the interrupt
        pass


def load_run_json(rundir: str | os.PathLike[str]) -> dict[str, Any]:
    """The run directory's ``run.json``; RunDirError when ``rundir`` is not a run directory."""
    path = Path(rundir) / RUN_JSON
    if Path(rundir).exists() and not Path(rundir).is_dir():
        raise RunDirError(f"{rundir} is a file, not a run directory; give the --out of a run")
    if not Path(rundir).is_dir():
        raise RunDirError(f"run directory {rundir} does not exist; run `arroyo run` first")
    if not path.is_file() and (Path(rundir) / STATE_NAME).is_file():
        raise RunDirError(
            f"{rundir} holds a run stopped while planning, before its {RUN_JSON}; rerun "
            "`arroyo run CATALOG --out DIR` to start it"
        )
    if not path.is_file():
        raise RunDirError(f"{rundir} is not an arroyo run directory (no {RUN_JSON})")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RunDirError(
            f"cannot read {path}: {exc}; `arroyo run` writes it anew: remove the file and "
            "rerun the catalog into this directory (with the same --products, if any)"
        ) from None
