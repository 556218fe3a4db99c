"""What a run directory holds: per-stage counts, failures, and integrity checks."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from .errors import RunDirError, RunLockedError
from .lock import RunLock
from .notes import NotesSummary, format_notes, summarize_notes
from .state import STATE_NAME, RunState
from .store import (
    check_products_reachable,
    file_sha256,
    frame_checksum,
    products_root,
    read_frame_array,
)

__all__ = ["RunStatus", "status", "format_status"]


@dataclass
class RunStatus:
    rundir: Path
    run_id: str
    archive: str
    run_state: str  # running | finished | stopped
    frames: int
    per_stage: dict[str, dict[str, int]]  # stage -> done/failed/pending
    failures: dict[str, str]
    damaged: list[str] = field(default_factory=list)  # what --verify found
    verified: bool = False
    products: str = ""  # products root when not the run directory
    reset: bool = True  # whether --verify reset the damaged results (not on a read-only dir)
    notes: NotesSummary | None = None  # the frames' notes (pipeline.notes)


def status(rundir: str | os.PathLike[str], *, verify: bool = False) -> RunStatus:
    """Per-stage counts of a run directory; with ``verify``, also check every recorded
    checksum and reset what is damaged so the next ``arroyo run`` redoes it.

    ``verify`` takes the run directory's lock: it raises RunLockedError while a run writes
    the directory (whose chunks can be newer than their records until its next journal
    flush), and RunDirError / StoreError, resetting nothing, when the products root that
    ``run.json`` records elsewhere cannot be reached (a moved or unmounted directory, an
    object store without credentials). A read-only run directory (an archive) is checked
    and nothing is reset (``RunStatus.reset`` False).
    """
    from .runner import load_run_json

    rundir = Path(rundir)
    meta = load_run_json(rundir)
    if not (rundir / STATE_NAME).exists():
        raise RunDirError(f"{rundir} has no {STATE_NAME}; the run never started")
    if not (rundir / "frames.parquet").is_file():
        raise RunDirError(
            f"{rundir} has no frames.parquet: its run stopped before recording its frames; "
            "rerun `arroyo run CATALOG --out DIR` to resume it"
        )
    frames_table = _read_frames_table(rundir)
    columns = set(frames_table.column_names)
    image_files = [
        str(p) for c in ("left", "right") if c in columns for p in frames_table[c].to_pylist()
    ]
    frame_ids = frames_table["frame_id"].to_pylist()
    index = dict(zip(frame_ids, frames_table["index"].to_pylist(), strict=True))
    stages = list(meta.get("stages", {}))
    damaged: list[str] = []
    reset = True
    if verify:
        root = products_root(rundir, meta)
        if meta.get("products"):
            check_products_reachable(
                rundir,
                root,
                doing="nothing was checked or reset",
                hint=f"; if they are lost for good, create the empty directory {root} and "
                "verify again to reset every frame for the next run",
            )
        with _verify_lock(rundir) as locked:
            # a read-only run directory (an archive) is checked, not reset: no run writes it
            state = RunState(rundir, readonly=not locked)
            try:
                damaged = _verify(rundir, root, state, index, stages, reset=locked)
            finally:
                state.close()
        reset = locked
    # read-only: `status` of an archived run directory on a read-only mount called its
    # journal damaged ("move it away ... the run then starts over")
    state = RunState(rundir, readonly=True)
    try:
        done = state.done()
        failed = state.failed()
    finally:
        state.close()
    per_stage = {}
    order = {s: i for i, s in enumerate(stages)}
    # a frame failed at stage S keeps the records of S and later stages of earlier inputs
    # (they may match again): counted as done, ingest read "done 2, failed 1, pending -1"
    stale = {
        (f, s) for f, (failed_stage, _e) in failed.items() for s in stages
        if order[s] >= order.get(failed_stage, 0)
    }
    for stage in stages:
        n_done = sum(1 for f in frame_ids if (f, stage) in done and (f, stage) not in stale)
        n_failed = sum(1 for f in frame_ids if f in failed and failed[f][0] == stage)
        per_stage[stage] = {
            "done": n_done,
            "failed": n_failed,
            "pending": len(frame_ids) - n_done - n_failed,
        }
    notes = summarize_notes(
        # the records counted as done above: a failed frame keeps its earlier stages' notes
        (
            [
                (stage, note)
                for stage in stages
                if (f, stage) in done and (f, stage) not in stale
                for note in done[f, stage].notes
            ]
            for f in frame_ids
        ),
        stages=stages,
        files=image_files,
    )
    lock_state = meta.get("status", "?")
    from .lock import lock_holder

    if lock_state == "running" and lock_holder(rundir) is None:
        # read again: a run that ended since run.json was read wrote its final state
        # before releasing the lock (a status at a run's end said 'interrupted')
        lock_state = load_run_json(rundir).get("status", "?")
        if lock_state == "running":
            lock_state = "interrupted"
    return RunStatus(
        rundir=rundir,
        run_id=meta.get("run_id", "?"),
        archive=meta.get("archive", "?"),
        run_state=lock_state,
        frames=len(frame_ids),
        per_stage=per_stage,
        failures={f: e for f, (_s, e) in failed.items()},
        damaged=damaged,
        verified=verify,
        reset=reset,
        products=str(meta.get("products") or ""),
        notes=notes,
    )


def _read_frames_table(rundir: Path) -> pa.Table:
    """The columns of ``frames.parquet`` that status needs; a truncated or garbled file
    printed pyarrow's "Parquet magic bytes not found" without the file or the fix."""
    path = rundir / "frames.parquet"
    try:
        names = pq.read_schema(path).names
        return pq.read_table(
            path, columns=[c for c in ("frame_id", "index", "left", "right") if c in names]
        )
    except (OSError, pa.ArrowInvalid) as exc:
        raise RunDirError(
            f"cannot read {path}: {exc}; the frames table of a run is written anew when a "
            "run starts: rerun the catalog into this directory (`arroyo run CATALOG --out "
            f"{rundir}`), which recomputes only results that are not current"
        ) from None


@contextmanager
def _verify_lock(rundir: Path) -> Iterator[bool]:
    """Hold the run lock while verifying, with a message of its own when a run holds it;
    yield whether it is held (False: a read-only run directory, which no run can write)."""
    if not os.access(rundir, os.W_OK):  # no run can write it either: check, not reset
        yield False
        return
    try:
        lock = RunLock(rundir).__enter__()
    except RunLockedError as exc:
        # a live run's chunks are ahead of their records until its next journal flush:
        # verify read them as damage (exit 1) and reset results the run then recorded
        holder = str(exc).split("; wait")[0]
        raise RunLockedError(
            f"{holder}; `arroyo status --verify` checks a run directory only while no run "
            "writes it: wait for that run to finish (plain `arroyo status` works meanwhile)"
        ) from None
    try:
        yield True
    finally:
        lock.__exit__(None, None, None)


def _verify(
    rundir: Path,
    root: str,
    state: RunState,
    index: dict[str, int],
    stages: list[str],
    *,
    reset: bool = True,
) -> list[str]:
    """Recompute checksums of recorded arrays and Parquet parts; with ``reset``, forget the
    damaged results."""
    damaged: list[str] = []
    forget: set[tuple[str, str]] = set()
    bad_parts = set()
    for part in state.parts():
        path = rundir / part.path
        if not path.is_file() or file_sha256(path) != part.sha256:
            bad_parts.add(part.part_id)
            damaged.append(f"table part {part.path} is missing or altered")
    for (fid, stage), record in state.done().items():
        if fid not in index:
            continue
        for name, expected in record.checksums.items():
            try:
                actual = frame_checksum(read_frame_array(root, name, index[fid]))
            except Exception as exc:  # noqa: BLE001 - any read failure is damage
                actual = f"unreadable: {exc}"
            if actual != expected:
                damaged.append(f"{name} of frame {fid} does not match its checksum")
                forget.add((fid, stage))
        if any(p in bad_parts for p in record.part_ids.values()):
            forget.add((fid, stage))
    # what depends on a damaged result is suspect too
    order = {s: i for i, s in enumerate(stages)}
    for fid, stage in list(forget):
        forget.update((fid, s) for s in stages if order[s] > order.get(stage, 0))
    if reset:
        state.forget(forget)
        state.drop_parts(bad_parts)
    for published in rundir.glob("*.parquet"):
        if published.is_symlink() or published.is_dir():
            if not any(published.rglob("*.parquet")):  # verify said every checksum matched
                damaged.append(
                    f"published table {published} holds no Parquet file (deleted?; published "
                    "again by next run)"
                )
            for file in published.rglob("*.parquet"):
                try:
                    pq.read_metadata(file)
                except Exception:  # noqa: BLE001 - truncated or garbage
                    damaged.append(f"published file {file} is unreadable (rebuilt by next run)")
    return damaged


def format_status(st: RunStatus) -> str:
    """The text ``arroyo status`` prints: frames done / failed / pending per stage, notes."""
    lines = [
        f"run {st.run_id} of archive {st.archive} in {st.rundir}: {st.run_state}, "
        f"{st.frames} frames" + (f", products at {st.products}" if st.products else ""),
        f"{'stage':<12}{'done':>8}{'failed':>8}{'pending':>9}",
    ]
    for stage, row in st.per_stage.items():
        lines.append(f"{stage:<12}{row['done']:>8}{row['failed']:>8}{row['pending']:>9}")
    for fid, error in sorted(st.failures.items()):
        lines.append(f"failed {fid}: {error}")
    if st.notes is not None:
        text = format_notes(st.notes, st.rundir, running=st.run_state == "running")
        lines += text.splitlines()
    if st.verified:
        if st.damaged and not st.reset:
            lines.append(
                f"verify: {len(st.damaged)} problem(s); the run directory is read-only, so "
                "nothing was reset (verify a writable copy for the next run to redo them):"
            )
        elif st.damaged:
            lines.append(
                f"verify: {len(st.damaged)} problem(s); the next `arroyo run` redoes them:"
            )
        if st.damaged:
            lines += [f"  - {d}" for d in st.damaged]
        else:
            lines.append("verify: every recorded checksum matches")
    return "\n".join(lines) + "\n"
