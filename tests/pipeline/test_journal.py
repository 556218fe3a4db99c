"""The driver's completion journal: batches, parts, frames.parquet rewrites."""

from __future__ import annotations

import pyarrow.parquet as pq

import pipeline.journal
import pipeline.runner
from pipeline.runner import run

FAKE = "arroyo_fake_stages"


def _figure_stage_package(tmp_path, monkeypatch, name: str, figure_expr: str) -> str:
    """A stage package of the fake load and blend stages plus a stage ``name`` whose one
    figure is ``figure_expr`` (Python, of ``frame``), importable for this test."""
    package = tmp_path / f"arroyo_{name}_figure_stages"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for stage in ("load", "blend"):
        (package / f"{stage}.py").write_text(f"from {FAKE}.{stage} import STAGE  # noqa: F401\n")
    (package / f"{name}.py").write_text(
        "from pipeline.stage import Product, Stage, StageResult\n"
        "def run(inputs, *, frame, params):\n"
        f"    figures = {figure_expr}\n"
        "    return StageResult(arrays={'flag': inputs['blend'] > 0}, figures=figures)\n"
        f"STAGE = Stage('{name}', '1', ('blend',), (Product('flag', dtype='bool'),), (), run)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    return package.name


def test_a_short_run_writes_frames_table_at_start_and_end_only(archive, tmp_path, monkeypatch):
    # the run's last flush wrote frames.parquet and the runner rewrote it right after, the
    # whole table twice in a row; the flush before publishing now leaves it to the runner
    writes: list[str] = []
    original = pipeline.journal.write_frames_table

    def counting(plan, state):
        writes.append("frames")
        original(plan, state)

    monkeypatch.setattr(pipeline.journal, "write_frames_table", counting)
    monkeypatch.setattr(pipeline.runner, "write_frames_table", counting)
    out = tmp_path / "run"
    summary = run(archive, out, scheduler="synchronous", stage_package=FAKE)
    assert summary.done == 4
    assert len(writes) == 2  # before run.json, and after the tables were published
    frames = pq.read_table(out / "frames.parquet").to_pylist()
    assert [f["status"] for f in frames] == ["done"] * 4
    assert all(f["blend_seconds"] is not None for f in frames)


def test_regression_frames_table_columns_of_null_type_when_no_frame_failed(archive, tmp_path):
    # with no failure (and no note) the all-None columns were Arrow's null type, and a run
    # with one failure wrote them as strings: one archive's frames table changed schema
    import pyarrow as pa

    out = tmp_path / "run"
    assert run(archive, out, scheduler="synchronous", stage_package=FAKE).done == 4
    schema = pq.read_schema(out / "frames.parquet")
    for name in ("status", "failed_stage", "error", "notes", "left", "right"):
        assert schema.field(name).type == pa.string(), name
    assert schema.field("index").type == pa.int64()
    assert all(
        schema.field(f"{s}_seconds").type == pa.float64() for s in ("ingest", "blend", "tally")
    )


def test_regression_nan_figure_made_sql_averages_nan(archive, tmp_path, monkeypatch):
    # describe's size-frequency k of a frame with too few rocks is NaN: stored as NaN, it
    # made avg(describe_sfd_k) NaN for the whole archive; stored as NULL, avg skips it
    package = _figure_stage_package(
        tmp_path, monkeypatch, "fit", "{'k': float('nan') if frame.frame_id.endswith('0') else 0.5}"
    )
    out = tmp_path / "run"
    assert run(archive, out, scheduler="synchronous", stage_package=package).done == 4
    assert pq.read_table(out / "frames.parquet")["fit_k"].to_pylist() == [None, 0.5, 0.5, 0.5]


def test_frame_failed_on_rerun_has_no_stale_stage_figures(archive, tmp_path):
    """Regression: a frame that failed at ingest on a rerun (its file cut short) kept the
    earlier run's `<stage>_seconds`, figures and notes in frames.parquet, so `arroyo
    evaluate` took its stages for done and scored the earlier run's products."""
    out = tmp_path / "run"
    assert run(archive, out, scheduler="synchronous", stage_package=FAKE).done == 4
    image = archive.parent / "images" / "f001_left.png"
    image.write_bytes(image.read_bytes()[:60])
    summary = run(archive, out, scheduler="synchronous", stage_package=FAKE)
    assert (summary.done, summary.failed) == (3, 1)
    rows = {r["frame_id"]: r for r in pq.read_table(out / "frames.parquet").to_pylist()}
    assert rows["f001"]["status"] == "failed" and rows["f001"]["failed_stage"] == "ingest"
    stale = ("ingest_seconds", "ingest_mean", "blend_seconds", "tally_seconds", "tally_rows")
    assert [rows["f001"][c] for c in stale] == [None] * len(stale)
    assert all(rows["f000"][c] is not None for c in stale)


def test_regression_figure_of_mixed_types_stopped_the_run(archive, tmp_path, monkeypatch):
    # a user's figure that was a number in one frame and a str in another made
    # pa.table(frames columns) raise: the run stopped (exit 2) and frames.parquet went stale
    package = _figure_stage_package(
        tmp_path, monkeypatch, "mixed", "{'n': 'many' if frame.frame_id.endswith('1') else 3}"
    )
    out = tmp_path / "run"
    summary = run(archive, out, scheduler="synchronous", stage_package=package)
    assert (summary.done, summary.failed) == (4, 0)
    rows = pq.read_table(out / "frames.parquet").to_pylist()
    assert [r["mixed_n"] for r in rows] == ["3", "many", "3", "3"]
