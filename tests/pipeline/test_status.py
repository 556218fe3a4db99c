"""`arroyo status`: counts, and `--verify`'s checks that must never reset sound results."""

from __future__ import annotations

import shutil

import pytest

from pipeline.errors import RunDirError, RunLockedError
from pipeline.lock import RunLock
from pipeline.runner import run
from pipeline.status import format_status, status

FAKE = "arroyo_fake_stages"


def _run(catalog, out, **kw):
    return run(catalog, out, stage_package=FAKE, scheduler="synchronous", **kw)


def test_verify_during_live_run_refuses_instead_of_reporting_false_damage(archive, tmp_path):
    """Regression: `status --verify` while a run rewrote frames read chunks newer than
    their records (committed at the run's next journal flush) as damage, exited 1 and reset
    the results under the live run. It now waits for no run to hold the directory."""
    out = tmp_path / "run"
    assert _run(archive, out).done == 4
    with RunLock(out), pytest.raises(RunLockedError, match="only while no run writes it"):
        status(out, verify=True)
    report = status(out)  # counts alone still work during a run
    assert all(row["done"] == 4 for row in report.per_stage.values())
    assert status(out, verify=True).damaged == []  # the lock is free again


def test_verify_with_moved_products_root_resets_nothing(archive, tmp_path):
    """Regression: with `--products DIR` moved or unmounted, `status --verify` called every
    array damaged and reset every frame's records (a later rerun redid the whole archive).
    It now refuses, names the recorded root, and resets nothing."""
    out, shared = tmp_path / "run", tmp_path / "shared"
    assert _run(archive, out, products=shared).done == 4
    moved = tmp_path / "moved"
    shutil.move(shared, moved)
    with pytest.raises(RunDirError, match="does not exist \\(moved or unmounted\\?\\)"):
        status(out, verify=True)
    shutil.move(moved, shared)
    report = status(out, verify=True)
    assert report.damaged == []
    assert all(row["done"] == 4 for row in report.per_stage.values())


def test_verify_after_products_deleted_for_good_resets_for_rerun(archive, tmp_path):
    """The way out the message gives: an empty directory at the recorded root, then verify
    resets every frame and the next run redoes them."""
    out, shared = tmp_path / "run", tmp_path / "shared"
    _run(archive, out, products=shared)
    shutil.rmtree(shared)
    shared.mkdir()
    report = status(out, verify=True)
    assert report.damaged
    assert all(row["done"] == 0 for row in report.per_stage.values())
    assert _run(archive, out).done == 4
    assert status(out, verify=True).damaged == []


def test_frame_failed_on_rerun_is_not_also_counted_done(archive, tmp_path):
    """Regression: a frame that failed at ingest on a rerun (its file cut short) still had
    its earlier run's records, so `arroyo status` printed ingest "done 4, failed 1,
    pending -1" for 4 frames."""
    out = tmp_path / "run"
    _run(archive, out)
    image = archive.parent / "images" / "f001_left.png"
    image.write_bytes(image.read_bytes()[:60])
    _run(archive, out)
    report = status(out)
    assert report.per_stage["ingest"] == {"done": 3, "failed": 1, "pending": 0}
    assert report.per_stage["tally"] == {"done": 3, "failed": 0, "pending": 1}


def test_status_and_verify_of_a_read_only_run_directory(archive, tmp_path, readonly_view):
    """Regression: on a read-only mount (an archived survey), `arroyo status` called the
    journal damaged and advised moving it away ("the run then starts over"), and
    `status --verify` refused; verify now checks without resetting, and says so."""
    import json

    out = tmp_path / "run"
    _run(archive, out)
    meta = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**meta, "status": "running"}))  # then killed
    view = readonly_view(out)
    report = status(view)
    assert report.run_state == "interrupted"
    assert all(row["done"] == 4 for row in report.per_stage.values())
    chunk = next(p for p in (out / "products.zarr" / "blend").rglob("*") if p.is_file()
                 and p.name != "zarr.json")
    chunk.write_bytes(b"damage")
    report = status(view, verify=True)
    assert report.damaged and not report.reset
    assert "read-only, so nothing was reset" in format_status(report)
    assert all(row["done"] == 4 for row in report.per_stage.values())


def test_regression_read_only_verify_listed_no_damage(tmp_path):
    """Regression: `status --verify` on a read-only run directory said how many problems it
    found but listed none of them (the list was printed only where verify could reset)."""
    from pipeline.status import RunStatus

    damaged = ["f001 tally: products.zarr/blend/c/1/0/0 checksum differs"]
    report = RunStatus(
        rundir=tmp_path, run_id="r", archive="a", run_state="finished", frames=1,
        per_stage={}, failures={}, damaged=damaged, verified=True, reset=False,
    )
    text = format_status(report)
    assert "read-only, so nothing was reset" in text
    assert f"  - {damaged[0]}" in text


def _frame_files(out, name, frame):
    return [p for p in (out / "products.zarr" / name / "c" / str(frame)).rglob("*") if p.is_file()]


def test_verify_finds_a_damaged_and_a_missing_frame_shard(archive, tmp_path):
    """A new run's arrays hold one shard file per frame: verify finds a shard with altered
    bytes (its index's crc32c or its chunks no longer match) and a removed one, and the
    next run writes them anew."""
    out = tmp_path / "run"
    _run(archive, out)
    damaged, missing = _frame_files(out, "blend", 1), _frame_files(out, "blend", 2)
    assert len(damaged) == len(missing) == 1  # the frame's one shard
    raw = bytearray(damaged[0].read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    damaged[0].write_bytes(bytes(raw))
    missing[0].unlink()
    report = status(out, verify=True)
    assert sorted(d for d in report.damaged if d.startswith("blend")) == [
        "blend of frame f001 does not match its checksum",
        "blend of frame f002 does not match its checksum",
    ]
    assert report.per_stage["blend"]["done"] == 2
    assert _run(archive, out).done == 4
    assert status(out, verify=True).damaged == []


def test_a_run_directory_made_before_shards_keeps_its_chunk_files(archive, tmp_path):
    """A run directory whose products.zarr has one file per chunk (made by the code before
    shards) is resumed, rerun with another parameter and verified in that layout."""
    from unittest import mock

    import zarr

    import pipeline.store

    out = tmp_path / "run"
    with mock.patch.object(pipeline.store, "_store_is_sharded", return_value=False):
        _run(archive, out, frames="f00[01]")
    per_frame = len(_frame_files(out, "blend", 0))
    assert _run(archive, out).done == 4  # resumed: the other two frames
    assert _run(archive, out, overrides=["blend.weight=0.25"]).done == 4  # rerun
    group = zarr.open_group(out / "products.zarr", mode="r")
    assert all(group[name].shards is None for name in ("left", "blend", "grid"))
    assert [len(_frame_files(out, "blend", k)) for k in range(4)] == [per_frame] * 4
    assert status(out, verify=True).damaged == []
    _frame_files(out, "blend", 3)[0].unlink()
    assert status(out, verify=True).damaged == ["blend of frame f003 does not match its checksum"]


def test_regression_truncated_frames_table_printed_a_bare_pyarrow_error(archive, tmp_path):
    # `arroyo status` of a run whose frames.parquet was cut short printed "Parquet magic
    # bytes not found in footer" without the file or what to do
    out = tmp_path / "run"
    _run(archive, out)
    frames = out / "frames.parquet"
    frames.write_bytes(frames.read_bytes()[:300])
    for verify in (False, True):
        with pytest.raises(RunDirError, match=f"cannot read {frames}: .*rerun the catalog"):
            status(out, verify=verify)
    assert _run(archive, out).done == 4  # the way out the message gives
    assert status(out).frames == 4


def test_regression_verify_missed_deleted_published_files(archive, tmp_path):
    # the published generation's files deleted (or the generation with them): `--verify`
    # said "every recorded checksum matches" while `arroyo query` read an empty table
    out = tmp_path / "run"
    _run(archive, out)
    generation = (out / "tallies.parquet").resolve()
    for part in generation.rglob("*.parquet"):
        part.unlink()
    report = status(out, verify=True)
    assert [d for d in report.damaged if "tallies.parquet holds no Parquet file" in d], report
    shutil.rmtree(generation)
    assert any("holds no Parquet file" in d for d in status(out, verify=True).damaged)
    _run(archive, out)  # the next run publishes it again
    assert status(out, verify=True).damaged == []
