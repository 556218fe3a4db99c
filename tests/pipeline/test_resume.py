"""Interrupted, damaged and concurrent runs end with exactly the products of a clean run."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pytest
import zarr

import pipeline.runner
import pipeline.worker
from conftest import write_archive
from pipeline.errors import StoreError
from pipeline.lock import LOCK_NAME
from pipeline.runner import run
from pipeline.status import status

FAKE = "arroyo_fake_stages"
HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def _run(catalog, out, **kw):
    kw.setdefault("scheduler", "synchronous")
    return run(catalog, out, stage_package=FAKE, **kw)


def _snapshot(out: Path) -> tuple[dict[str, np.ndarray], list[dict]]:
    group = zarr.open_group(out / "products.zarr", mode="r")
    arrays = {name: np.asarray(arr[:]) for name, arr in group.arrays() if name != "frame"}
    rows = ds.dataset(out / "tallies.parquet").to_table().drop_columns(["run_id"]).to_pylist()
    return arrays, sorted(rows, key=lambda r: (r["frame_id"], r["object_id"]))


def _assert_same_products(a: Path, b: Path) -> None:
    arrays_a, rows_a = _snapshot(a)
    arrays_b, rows_b = _snapshot(b)
    assert arrays_a.keys() == arrays_b.keys()
    for name in arrays_a:
        np.testing.assert_array_equal(arrays_a[name], arrays_b[name], err_msg=name)
    assert rows_a == rows_b


_CHILD = """
import sys
sys.path[:0] = [{here!r}, {root!r}]
from pipeline.runner import run
run({catalog!r}, {out!r}, stage_package="arroyo_fake_stages", scheduler="synchronous",
    overrides=["ingest.sleep=0.1"])
"""


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_sigkill_at_random_moments_then_rerun_equals_clean_run(tmp_path, seed):
    catalog = write_archive(tmp_path / "archive", frames=10)
    clean = tmp_path / "clean"
    _run(catalog, clean, overrides=["ingest.sleep=0.1"])
    out = tmp_path / "killed"
    script = _CHILD.format(here=str(HERE), root=str(ROOT), catalog=str(catalog), out=str(out))
    rng = np.random.default_rng(seed)
    for _attempt in range(2):  # kill twice at different moments
        child = subprocess.Popen([sys.executable, "-c", script])
        time.sleep(float(rng.uniform(0.6, 2.4)))
        child.send_signal(signal.SIGKILL)
        child.wait()
    summary = _run(catalog, out, overrides=["ingest.sleep=0.1"])
    assert summary.exit_code == 0 and summary.done == 10
    _assert_same_products(clean, out)
    leftovers = [p for p in out.rglob("*") if ".tmp-" in p.name]
    assert leftovers == []


def test_stale_lock_of_a_dead_process_is_taken_over(archive, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / LOCK_NAME).write_text(json.dumps({"pid": 999999, "host": "gone", "since": "then"}))
    assert _run(archive, out).done == 4


def test_verify_detects_deleted_chunk_and_truncated_part_and_rerun_repairs(archive, tmp_path):
    out = tmp_path / "run"
    _run(archive, out)
    clean = tmp_path / "clean"
    _run(archive, clean)
    chunk = next((out / "products.zarr" / "blend" / "c" / "2").rglob("*"))
    while chunk.is_dir():
        chunk = next(chunk.iterdir())
    chunk.unlink()
    part = next((out / ".staging" / "tallies").glob("*.parquet"))
    part.write_bytes(part.read_bytes()[:20])
    report = status(out, verify=True)
    assert any("blend of frame f002" in d for d in report.damaged)
    assert any("table part" in d for d in report.damaged)
    assert report.per_stage["blend"]["done"] == 3
    summary = _run(archive, out)
    assert summary.done == 4
    assert status(out, verify=True).damaged == []
    _assert_same_products(clean, out)


def test_disk_full_stops_cleanly_and_rerun_completes(archive, tmp_path, monkeypatch):
    out = tmp_path / "run"
    real = pipeline.worker.write_frame_array
    calls = {"n": 0}

    def flaky(root, name, index, data, **kw):
        calls["n"] += 1
        if calls["n"] > 5:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(root, name, index, data, **kw)

    monkeypatch.setattr(pipeline.worker, "write_frame_array", flaky)
    with pytest.raises(StoreError, match="No space left"):
        _run(archive, out)
    monkeypatch.setattr(pipeline.worker, "write_frame_array", real)
    summary = _run(archive, out)
    assert summary.done == 4
    clean = tmp_path / "clean"
    _run(archive, clean)
    _assert_same_products(clean, out)


def test_unreachable_product_store_stops_the_run_and_keeps_finished_frames(
    archive, tmp_path, monkeypatch
):
    root = f"memory://arroyo-{uuid.uuid4().hex}"
    out = tmp_path / "run"
    real = pipeline.worker.write_product_file
    calls = {"n": 0}

    def outage(*args, **kw):
        calls["n"] += 1
        if calls["n"] > 2:  # the store goes away after two frames
            raise ConnectionError("connection reset by peer")
        return real(*args, **kw)

    monkeypatch.setattr(pipeline.worker, "write_product_file", outage)
    with pytest.raises(StoreError, match=f"writing {root} failed: ConnectionError"):
        _run(archive, out, products=root)
    assert status(out).per_stage["tally"] == {"done": 2, "failed": 0, "pending": 2}
    monkeypatch.setattr(pipeline.worker, "write_product_file", real)
    assert _run(archive, out).done == 4  # the rerun finds the recorded root


def test_product_store_that_cannot_be_opened_is_a_store_error(archive, tmp_path, monkeypatch):
    def refuse(*args, **kw):
        raise ConnectionError("no route to host")

    monkeypatch.setattr(pipeline.runner, "ensure_zarr", refuse)
    with pytest.raises(StoreError, match="cannot open the product store at memory://x/y"):
        _run(archive, tmp_path / "run", products="memory://x/y")


def test_threads_scheduler_gives_the_same_products(archive, tmp_path):
    a, b = tmp_path / "sync", tmp_path / "threads"
    _run(archive, a)
    _run(archive, b, scheduler="threads", workers=2)
    _assert_same_products(a, b)


@pytest.mark.slow
def test_local_process_cluster_gives_the_same_products(archive, tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), str(ROOT)]))
    a, b = tmp_path / "sync", tmp_path / "procs"
    _run(archive, a)
    _run(archive, b, scheduler=None, workers=2)
    _assert_same_products(a, b)
