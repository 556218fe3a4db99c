"""End-to-end behaviour of the engine on a fake stage package (fast, no real stages)."""

from __future__ import annotations

import json
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
import xarray as xr
import zarr

from conftest import write_archive
from pipeline.errors import ParamError, RunDirError, RunLockedError
from pipeline.lock import RunLock
from pipeline.plan import RunPlan
from pipeline.query import frame_dataset
from pipeline.runner import run
from pipeline.status import format_status, status

FAKE = "arroyo_fake_stages"


def _run(catalog: Path, out: Path, **kw):
    kw.setdefault("scheduler", "synchronous")
    return run(catalog, out, stage_package=FAKE, **kw)


def test_run_writes_products_readable_by_xarray_and_duckdb(archive, tmp_path):
    out = tmp_path / "run"
    summary = _run(archive, out)
    assert (summary.done, summary.failed, summary.pending) == (4, 0, 0)
    assert summary.exit_code == 0
    data = xr.open_zarr(out / "products.zarr")
    assert list(data.frame.values) == ["f000", "f001", "f002", "f003"]
    assert data.left.dtype == np.uint8 and data.left.shape == (4, 40, 48)
    expected = (data.left.values[2] * 0.5 + data.right.values[2] * 0.5).astype(np.float32)
    np.testing.assert_array_equal(data.blend.sel(frame="f002").values, expected)
    assert data.blend.attrs["units"] == "gray" and data.blend.attrs["stage"] == "blend"
    assert data.grid.dims == ("frame", "gy", "gx")
    table = ds.dataset(out / "tallies.parquet", partitioning="hive").to_table()
    assert table.num_rows == 12
    assert pq.read_table(out / "tallies.parquet").num_rows == 12
    part = next((out / "tallies.parquet").rglob("*.parquet"))
    assert pq.read_schema(part).metadata[b"arroyo.stage_version"] == b"1"
    assert set(table["archive"].to_pylist()) == {"testarch"}
    count = duckdb.sql(
        f"SELECT archive, count(*) FROM read_parquet('{out}/tallies.parquet/**/*.parquet') "
        "GROUP BY archive"
    ).fetchall()
    assert count == [("testarch", 12)]
    frames = pq.read_table(out / "frames.parquet").to_pylist()
    assert [f["status"] for f in frames] == ["done"] * 4
    assert frames[1]["site"] == "site1" and frames[0]["blend_max"] > 0
    assert frames[0]["ingest_seconds"] >= 0
    meta = json.loads((out / "run.json").read_text())
    assert meta["status"] == "finished" and meta["stages"]["blend"]["params"] == {"weight": 0.5}
    assert len(meta["inputs"]["f000"]["left"]["sha256"]) == 64
    assert (out / "quicklooks" / "f001" / "note.txt").is_file()


def test_rerun_skips_finished_work_and_param_change_reruns_downstream_only(archive, tmp_path):
    out = tmp_path / "run"
    _run(archive, out)
    plan = run(archive, out, stage_package=FAKE, dry_run=True)
    assert isinstance(plan, RunPlan)
    assert all(not todo for todo in plan.todo.values())
    plan = run(archive, out, stage_package=FAKE, dry_run=True, overrides=["blend.weight=0.25"])
    assert plan.todo["f000"] == ["blend", "tally"]
    assert plan.counts()["ingest"]["done"] == 4 and plan.counts()["blend"]["changed"] == 4
    before = pq.read_table(out / "frames.parquet")
    _run(archive, out, overrides=["blend.weight=0.25"])
    after = pq.read_table(out / "frames.parquet")
    # ingest was not redone: its timing record is the old one
    assert before["ingest_seconds"].to_pylist() == after["ingest_seconds"].to_pylist()
    data = xr.open_zarr(out / "products.zarr")
    left, right = data.left.values[0].astype(np.float32), data.right.values[0].astype(np.float32)
    np.testing.assert_allclose(data.blend.values[0], left * 0.25 + right * 0.75)
    # the table holds exactly one generation of rows per frame
    assert ds.dataset(out / "tallies.parquet").to_table().num_rows == 12


def test_param_changing_array_shape_recreates_it(archive, tmp_path):
    out = tmp_path / "run"
    _run(archive, out)
    _run(archive, out, overrides=["tally.grid=6"])
    assert xr.open_zarr(out / "products.zarr").grid.shape == (4, 6, 6)


def test_bad_frames_are_recorded_and_the_rest_complete(archive, tmp_path):
    (archive.parent / "images" / "f001_left.png").write_bytes(b"not a png")
    (archive.parent / "images" / "f002_right.png").unlink()
    out = tmp_path / "run"
    summary = _run(archive, out)
    assert summary.exit_code == 1
    assert (summary.done, summary.failed) == (2, 2)
    assert "f001_left.png" in summary.failures["f001"]
    frames = {r["frame_id"]: r for r in pq.read_table(out / "frames.parquet").to_pylist()}
    assert frames["f001"]["status"] == "failed" and frames["f000"]["status"] == "done"
    assert frames["f002"]["failed_stage"] == "ingest"
    rows = ds.dataset(out / "tallies.parquet").to_table()
    assert sorted(set(rows["frame_id"].to_pylist())) == ["f000", "f003"]


def test_unknown_param_in_set_is_a_named_error(archive, tmp_path):
    with pytest.raises(ParamError, match="no parameter 'nope'"):
        _run(archive, tmp_path / "run", overrides=["blend.nope=1"])
    with pytest.raises(ParamError, match="unknown stage 'warp'"):
        _run(archive, tmp_path / "run", overrides=["warp.x=1"])
    with pytest.raises(ParamError, match="expects float"):
        _run(archive, tmp_path / "run", overrides=["blend.weight=heavy"])
    with pytest.raises(ParamError, match="<= 1.0"):
        _run(archive, tmp_path / "run", overrides=["blend.weight=3"])
    assert not (tmp_path / "run").exists()


def test_second_run_on_a_locked_directory_refuses(archive, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    with RunLock(out):
        with pytest.raises(RunLockedError, match="in use by arroyo pid"):
            _run(archive, out)


def test_frames_pattern_restricts_the_run(archive, tmp_path):
    out = tmp_path / "run"
    summary = _run(archive, out, frames="f00[01]")
    assert summary.done == 2
    statuses = pq.read_table(out / "frames.parquet")["status"].to_pylist()
    assert statuses == ["done", "done", "pending", "pending"]


# -- products elsewhere: a shared directory or an fsspec URL ---------------------------------
def _arrays(location: str) -> dict[str, bytes]:
    group = zarr.open_group(location, mode="r")
    return {name: np.asarray(array[:]).tobytes() for name, array in group.arrays()}


def test_products_in_another_directory_are_found_on_resume(archive, tmp_path):
    plain, out, shared = tmp_path / "plain", tmp_path / "run", tmp_path / "shared"
    _run(archive, plain)
    summary = _run(archive, out, products=shared)
    assert (summary.done, summary.failed) == (4, 0)
    assert not (out / "products.zarr").exists() and (shared / "products.zarr").is_dir()
    assert (shared / "quicklooks" / "f001" / "note.txt").is_file()
    assert _arrays(str(shared / "products.zarr")) == _arrays(str(plain / "products.zarr"))
    meta = json.loads((out / "run.json").read_text())
    assert meta["products"] == str(shared.resolve())
    # resuming without the option uses the recorded root: nothing to redo
    plan = run(archive, out, stage_package=FAKE, dry_run=True)
    assert isinstance(plan, RunPlan) and plan.products == str(shared.resolve())
    assert all(not todo for todo in plan.todo.values())
    frame = frame_dataset(out, "f002")
    np.testing.assert_array_equal(frame.left.values, xr.open_zarr(plain / "products.zarr").left[2])


def test_resuming_with_another_products_root_is_refused(archive, tmp_path):
    out = tmp_path / "run"
    _run(archive, out)
    with pytest.raises(RunDirError, match="keeps its products in the run directory"):
        _run(archive, out, products=tmp_path / "elsewhere")
    # naming the run directory itself is the same root
    assert _run(archive, out, products=out).done == 4


def test_products_url_with_an_unknown_protocol_is_a_param_error(archive, tmp_path):
    with pytest.raises(ParamError, match="unknown storage protocol 'nosuch'"):
        _run(archive, tmp_path / "run", products="nosuch://bucket/run")
    assert not (tmp_path / "run").exists()  # refused before touching disk


def test_products_on_s3_equal_a_local_run_and_every_reader_finds_them(
    archive, tmp_path, s3_products
):
    import fsspec

    local, out = tmp_path / "local", tmp_path / "run"
    _run(archive, local)
    summary = _run(archive, out, products=s3_products)
    assert (summary.done, summary.failed) == (4, 0)
    assert not (out / "products.zarr").exists()
    assert _arrays(f"{s3_products}/products.zarr") == _arrays(str(local / "products.zarr"))
    s3 = fsspec.filesystem("s3")
    note = s3.cat_file(f"{s3_products}/quicklooks/f001/note.txt")
    assert note == (local / "quicklooks" / "f001" / "note.txt").read_bytes()
    # readers: one frame's maps, checksum verification, the tables stay local
    frame = frame_dataset(out, "f003")
    expected = xr.open_zarr(local / "products.zarr").blend[3]
    np.testing.assert_array_equal(frame.blend.values, expected)
    verified = status(out, verify=True)
    assert verified.damaged == [] and verified.per_stage["tally"]["done"] == 4
    assert f"products at {s3_products}" in format_status(verified)
    assert pq.read_table(out / "tallies.parquet").num_rows == 12
    # a resumed run with changed parameters rewrites the frames in the bucket
    _run(archive, out, overrides=["blend.weight=0.25"])
    data = xr.open_zarr(f"{s3_products}/products.zarr")
    left, right = data.left.values[0].astype(np.float32), data.right.values[0].astype(np.float32)
    np.testing.assert_allclose(data.blend.values[0], left * 0.25 + right * 0.75)


def test_interrupt_publishes_the_finished_frames_rows(archive, tmp_path):
    """Bug: after ^C, frames.parquet called the finished frames done while the published
    tables (what `arroyo query` reads) held none of their rows until the next run."""
    out = tmp_path / "run"

    def interrupt_after_two(done, total, frame_id):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(archive, out, progress=interrupt_after_two)
    frames = pq.read_table(out / "frames.parquet").to_pylist()
    done = sorted(f["frame_id"] for f in frames if f["status"] == "done")
    assert len(done) == 2
    rows = pq.read_table(out / "tallies.parquet").to_pylist()
    assert sorted({r["frame_id"] for r in rows}) == done and len(rows) == 6
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    assert _run(archive, out).done == 4
    assert pq.read_table(out / "tallies.parquet").num_rows == 12


def _fail_f001_on_rerun(archive, out):
    assert _run(archive, out).done == 4
    left = archive.parent / "images" / "f001_left.png"
    saved = left.read_bytes()
    left.unlink()
    summary = _run(archive, out)
    assert (summary.done, summary.failed) == (3, 1)
    return left, saved


def test_a_frame_failing_on_rerun_loses_its_old_rows(archive, tmp_path):
    """Bug: a frame whose input was deleted after a finished run failed on the rerun, but
    its earlier rows stayed in the published tables (frames.parquet: failed)."""
    out = tmp_path / "run"
    _fail_f001_on_rerun(archive, out)
    rows = pq.read_table(out / "tallies.parquet").to_pylist()
    assert "f001" not in {r["frame_id"] for r in rows} and len(rows) == 9


def test_a_failed_frame_whose_file_is_restored_is_done_again(archive, tmp_path):
    """Bug: with the deleted file restored, the frame's old records were current again, so
    nothing ran, and it stayed 'failed' with the old error (exit 1)."""
    out = tmp_path / "run"
    left, saved = _fail_f001_on_rerun(archive, out)
    left.write_bytes(saved)
    plan = _run(archive, out, dry_run=True)
    assert sum(bool(t) for t in plan.todo.values()) == 0
    summary = _run(archive, out)
    assert (summary.done, summary.failed, summary.exit_code) == (4, 0, 0)
    assert pq.read_table(out / "tallies.parquet").num_rows == 12
    frames = pq.read_table(out / "frames.parquet").to_pylist()
    assert [f["status"] for f in frames] == ["done"] * 4 and frames[1]["error"] is None


def test_rerun_that_changes_products_removes_stale_evaluation(archive, tmp_path):
    """Regression: `evaluation.parquet` outlived a rerun that changed the products, so
    `arroyo query ... FROM evaluation` and `arroyo report` showed the old run's scores as
    the run directory's. A run that recomputes frames removes it; one with nothing to do
    keeps it."""
    import pyarrow as pa

    from pipeline.evaluate import EVALUATION_SCHEMA
    from pipeline.query import query_runs

    out = tmp_path / "run"
    first = _run(archive, out)
    row = {"run_id": first.run_id, "archive": "testarch", "frame_id": "*"}
    row |= {"product": "depth", "method": "arroyo", "metric": "epe", "value": 0.5}
    scores = pa.Table.from_pylist([row], schema=EVALUATION_SCHEMA)
    pq.write_table(scores, out / "evaluation.parquet")
    assert _run(archive, out).done == 4  # nothing recomputed: the scores still hold
    assert query_runs([out], "SELECT * FROM evaluation").num_rows == 1
    assert _run(archive, out, overrides=["blend.weight=0.3"]).done == 4
    assert not (out / "evaluation.parquet").exists()
    assert query_runs([out], "SELECT * FROM evaluation").num_rows == 0


@pytest.mark.parametrize("workers", [0, -2, 1.5, True])
def test_bad_workers_stop_before_any_work(archive, tmp_path, workers):
    """Regression: `--workers 0` passed a dry run and a run with nothing pending (exit 0);
    with frames pending it failed only after writing run.json as a new 'stopped' run."""
    out = tmp_path / "run"
    with pytest.raises(ParamError, match="--workers"):
        run(archive, out, stage_package=FAKE, workers=workers, dry_run=True)
    assert not out.exists()
    assert _run(archive, out).done == 4
    meta = json.loads((out / "run.json").read_text())
    with pytest.raises(ParamError, match="--workers"):
        run(archive, out, stage_package=FAKE, workers=workers)
    assert json.loads((out / "run.json").read_text()) == meta


def test_other_frame_list_is_refused_by_the_dry_run_too(archive, tmp_path):
    """Regression: a catalog whose frames differ from the run directory's (another archive,
    a reordered index) planned fine with --dry-run ('4 frame(s) would run') while the run
    refused it (exit 2), with a message of numpy reprs (`np.str_('f000')`)."""
    out = tmp_path / "run"
    _run(archive, out)
    index = archive.parent / "frames.csv"
    header, *rows = index.read_text().splitlines()
    index.write_text("\n".join([header, rows[1], rows[0], *rows[2:]]) + "\n")
    for dry_run in (True, False):
        with pytest.raises(RunDirError, match="frame 0 is 'f000' where the catalog has 'f001'"):
            _run(archive, out, dry_run=dry_run)
    index.write_text("\n".join([header, *rows, rows[0].replace("f000,", "f004,")]) + "\n")
    assert _run(archive, out, dry_run=True).todo["f004"]  # extended at the end: fine
    assert _run(archive, out).done == 5


def test_regression_frame_removed_from_the_index_was_told_only_to_start_over(archive, tmp_path):
    # a user who dropped a pair from the index of a run was told only to use a new --out
    # directory, losing every finished frame; the README's answer is --frames
    out = tmp_path / "run"
    _run(archive, out)
    index = archive.parent / "frames.csv"
    header, *rows = index.read_text().splitlines()
    index.write_text("\n".join([header, *rows[:-1]]) + "\n")
    with pytest.raises(RunDirError) as info:
        _run(archive, out, dry_run=True)
    message = str(info.value)
    assert "the catalog's 3, then 'f003'..., which the catalog no longer lists" in message
    assert "--frames PATTERN" in message and "new --out" in message
    index.write_text("\n".join([header, *rows]) + "\n")
    assert _run(archive, out, frames="f00[0-2]").done == 3


def test_two_run_directories_cannot_share_a_products_root(archive, tmp_path):
    """Regression: a second run directory given the same --products rewrote the first's
    maps without a word; the first's descriptors then described other labels and its
    `status --verify` found every rewritten slab damaged."""
    shared = tmp_path / "shared"
    first, second = tmp_path / "a", tmp_path / "b"
    assert _run(archive, first, products=shared).done == 4
    for dry_run in (True, False):
        with pytest.raises(RunDirError, match="holds the products of another run directory"):
            _run(archive, second, products=shared, overrides=["blend.weight=0.3"],
                 dry_run=dry_run)
    assert status(first, verify=True).damaged == []
    moved = tmp_path / "moved"
    first.rename(moved)  # a moved run directory still owns its products
    assert _run(archive, moved, overrides=["blend.weight=0.3"]).done == 4
    assert status(moved, verify=True).damaged == []
    assert _run(archive, second, products=shared / "b").done == 4


def test_sigterm_stops_the_run_as_ctrl_c_does(archive, tmp_path):
    """Regression: SIGTERM (a batch system's time limit, `timeout`, `docker stop`) killed the
    driver outright: the frames finished since the journal's last commit were redone and
    no finished frame's rows were published until a rerun. It now stops the run as ^C."""
    import os
    import signal

    out = tmp_path / "run"
    handler = signal.getsignal(signal.SIGTERM)

    def terminated_after_two(done, total, frame_id):
        if done == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        _run(archive, out, progress=terminated_after_two)
    assert signal.getsignal(signal.SIGTERM) is handler
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    frames = pq.read_table(out / "frames.parquet").to_pylist()
    done = sorted(f["frame_id"] for f in frames if f["status"] == "done")
    assert len(done) == 2
    rows = pq.read_table(out / "tallies.parquet").to_pylist()
    assert sorted({r["frame_id"] for r in rows}) == done
    assert _run(archive, out).done == 4


def test_frame_files_a_rerun_does_not_write_are_removed(archive, tmp_path):
    """Regression: with `--set quicklook.every=4` a rerun drew 3 of lab's 12 frames and
    left the other 9 frames' quicklooks of the earlier run, outlines of earlier labels
    that the report showed as current. A files product's frame folder now holds only what
    the stage returned for the frame's current result."""
    out = tmp_path / "run"
    _run(archive, out)
    notes = sorted(p.relative_to(out).as_posix() for p in (out / "quicklooks").rglob("*.txt"))
    assert notes == [f"quicklooks/f00{k}/note.txt" for k in range(4)]
    (out / "quicklooks" / "f001" / "old.png").write_bytes(b"an earlier stage version's file")
    assert _run(archive, out, overrides=["tally.note=false"]).done == 4
    assert list((out / "quicklooks").iterdir()) == []  # no files, no empty frame folders


def test_frame_files_a_rerun_does_not_write_are_removed_from_an_object_store(
    archive, tmp_path, s3_products
):
    import fsspec

    out = tmp_path / "run"
    _run(archive, out, products=s3_products)
    s3 = fsspec.filesystem("s3")
    assert s3.exists(f"{s3_products}/quicklooks/f002/note.txt")
    _run(archive, out, overrides=["tally.note=false"])
    s3.invalidate_cache()
    assert not s3.exists(f"{s3_products}/quicklooks/f002/note.txt")


def test_products_root_that_is_a_file_or_under_one_is_a_clear_error(archive, tmp_path):
    """Regression: `--products FILE` (and a root under a file) ended in zarr's
    NotADirectoryError traceback, exit 1, after the journal was created."""
    afile = tmp_path / "afile"
    afile.write_text("")
    with pytest.raises(ParamError, match="is a file, not a directory"):
        _run(archive, tmp_path / "a", products=afile)
    assert not (tmp_path / "a").exists()
    with pytest.raises(RunDirError, match="cannot create the product store"):
        _run(archive, tmp_path / "b", products=afile / "below")


def test_run_into_a_read_only_run_directory_is_a_clear_error(archive, tmp_path, readonly_view):
    """Regression: `arroyo run` into a read-only run directory was an EROFS traceback."""
    out = tmp_path / "run"
    _run(archive, out)
    with pytest.raises(RunDirError, match="cannot lock the run directory .*Read-only"):
        _run(archive, readonly_view(out))


def test_run_directory_with_its_journal_moved_away_still_owns_its_products(archive, tmp_path):
    """The damaged-journal recovery ("move it away and rerun") must not lock a run
    directory out of the products its run.json records."""
    out, shared = tmp_path / "run", tmp_path / "shared"
    _run(archive, out, products=shared)
    (out / "state.sqlite").rename(tmp_path / "damaged.sqlite")
    assert _run(archive, out).done == 4
    assert status(out, verify=True).damaged == []
    with pytest.raises(RunDirError, match="holds the products of another run directory"):
        _run(archive, tmp_path / "other", products=shared)


def test_regression_residual_attrs_said_left_minus_pseudo_left_for_reference_left(tmp_path):
    """Bug (user audit): ``products.zarr``'s ``residual`` said "left minus pseudo-left"
    whatever the catalog's reference camera; with reference "left" the depth stage stores
    right minus pseudo-right. The attribute follows the run's camera, also when a rerun of
    the run directory changes it (the store is prepared before any frame: 4x4 frames fail
    at ingest, which keeps the test fast)."""
    catalog = write_archive(tmp_path / "archive", frames=1, shape=(4, 4))
    toml = catalog.read_text()
    out = tmp_path / "run"
    names = {}
    for reference in ("left", "right"):
        catalog.write_text(
            toml.replace("baseline_m = 0.1\n", f'baseline_m = 0.1\nreference = "{reference}"\n')
        )
        assert run(catalog, out, scheduler="synchronous").failures
        residual = zarr.open_group(str(out / "products.zarr"), mode="r")["residual"]
        names[reference] = residual.attrs["long_name"]
    assert names["left"].startswith("right minus pseudo-right (left warped")
    assert names["right"].startswith("left minus pseudo-left (right warped")


def test_regression_run_json_did_not_record_the_stage_package(archive, tmp_path):
    # provenance named each stage's version and params but not whose code it was: a user's
    # --stage-package run and a shipped run were indistinguishable
    out = tmp_path / "run"
    _run(archive, out)
    meta = json.loads((out / "run.json").read_text())
    assert meta["stage_package"] == FAKE
    assert meta["stages"]["tally"]["module"] == f"{FAKE}.tally"


def test_regression_run_killed_before_its_journal_schema_could_not_resume(archive, tmp_path):
    # a SIGKILL between sqlite creating state.sqlite and the schema being written left an
    # empty file: every rerun failed with "sqlite3.OperationalError: no such table: meta"
    out = tmp_path / "run"
    out.mkdir()
    (out / "state.sqlite").write_bytes(b"")
    summary = _run(archive, out)
    assert (summary.exit_code, summary.done) == (0, 4)
