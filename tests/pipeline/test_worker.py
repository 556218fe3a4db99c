"""process_frame: a stage's returned products are checked against its declaration."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from pipeline import worker
from pipeline.camera import Camera
from pipeline.stage import FrameContext, Product, Stage, StageResult
from pipeline.worker import FrameJob, process_frame

_SCHEMA = pa.schema([pa.field("object_id", pa.int32()), pa.field("area_px", pa.int64())])


def _outcome(tmp_path, monkeypatch, tables, arrays=None, files=None):
    """One frame through a stage writing an ``areas`` table (the arrays are not written
    when a check fails, so no store is needed)."""

    def run(inputs, *, frame, params):
        return StageResult(arrays=arrays or {}, tables=tables, files=files or {})

    stage = Stage(
        name="areas",
        version="1",
        inputs=(),
        outputs=(
            Product("areas", kind="table", schema=_SCHEMA),
            Product("looks", kind="files"),
        ),
        params=(),
        run=run,
    )
    monkeypatch.setattr(worker, "_stages", lambda package: {"areas": stage})
    job = FrameJob(
        rundir=str(tmp_path),
        index=0,
        context=FrameContext("f0", "a", Camera(focal_px=100.0, baseline_m=0.1)),
        stages=(("areas", {}, "key"),),
        expected={},
    )
    return process_frame(job)


def test_worker_accepts_a_table_matching_its_schema(tmp_path, monkeypatch):
    tables = {"areas": {"object_id": np.arange(1, 3, dtype=np.int32), "area_px": [4, 9]}}
    outcome = _outcome(tmp_path, monkeypatch, tables)
    assert outcome.error is None
    assert outcome.completed[0].tables == tables


@pytest.mark.parametrize(
    ("tables", "arrays", "expected"),
    [
        ({}, None, "table 'areas': not returned"),
        ({"areas": {"object_id": [1, 2], "area_px": [3]}}, None, "unequal lengths"),
        ({"areas": {"object_id": [1]}}, None, "missing ['area_px']"),
        ({"areas": {"object_id": [1], "area_px": [2], "x": [0]}}, None, "undeclared ['x']"),
        ({"areas": {"object_id": ["a"], "area_px": [2]}}, None, "'object_id' cannot be stored"),
        ({"areas": {"object_id": [1], "area_px": [2]}, "other": {}}, None, "table 'other'"),
        (
            {"areas": {"object_id": [1], "area_px": [2]}},
            {"extra": np.zeros(3)},
            "array 'extra', which it does not declare",
        ),
    ],
)
def test_regression_bad_stage_table_fails_the_frame_not_the_run(
    tmp_path, monkeypatch, tables, arrays, expected
):
    # ragged columns or an undeclared table used to crash the run when the journal
    # committed the batch (KeyError / ArrowInvalid, exit 2); a missing table, missing or
    # extra columns were silently dropped
    outcome = _outcome(tmp_path, monkeypatch, tables, arrays)
    assert outcome.failed_stage == "areas"
    assert expected in outcome.error


def test_regression_table_product_without_schema_is_refused():
    # without a schema the journal kept only archive/run_id/frame_id: every column was lost
    with pytest.raises(ValueError, match="needs schema=pyarrow.schema"):
        Product("areas", kind="table")


@pytest.mark.parametrize(
    "rel", ["run.json", "looks/f0/../../run.json", "looks/f1/a.png", "/tmp/x.png", "looks/f0/"]
)
def test_regression_stage_file_written_outside_its_folder(tmp_path, monkeypatch, rel):
    # a stage's files were written wherever their key pointed: 'run.json' or '../x'
    # replaced the run's own records, another frame's folder its quicklooks
    tables = {"areas": {"object_id": [1], "area_px": [2]}}
    outcome = _outcome(tmp_path, monkeypatch, tables, files={rel: b"x"})
    assert outcome.failed_stage == "areas" and "a stage's files go under looks/f0/" in outcome.error
    assert not (tmp_path / "run.json").exists()


def test_stage_file_in_its_folder_is_written(tmp_path, monkeypatch):
    tables = {"areas": {"object_id": [1], "area_px": [2]}}
    outcome = _outcome(tmp_path, monkeypatch, tables, files={"looks/f0/a.png": b"x"})
    assert outcome.error is None
    assert (tmp_path / "looks" / "f0" / "a.png").read_bytes() == b"x"


@pytest.mark.parametrize(
    ("figures", "expected"),
    [
        ({"n": [1, 2]}, "figure 'n' as list"),
        ({"n": np.zeros(3)}, "figure 'n' as ndarray"),
        ({"bad name": 1}, "figure 'bad name'; a figure name is an identifier"),
    ],
)
def test_regression_non_scalar_figure_broke_frames_table(tmp_path, monkeypatch, figures, expected):
    # a list figure was recorded and made the frames view unreadable by arroyo query
    # ('Unsupported Type: list'); figures must be one scalar per frame
    tables = {"areas": {"object_id": [1], "area_px": [2]}}

    def run(inputs, *, frame, params):
        return StageResult(tables=tables, figures=dict(figures))

    stage = Stage(
        name="areas", version="1", inputs=(), params=(), run=run,
        outputs=(Product("areas", kind="table", schema=_SCHEMA),),
    )
    monkeypatch.setattr(worker, "_stages", lambda package: {"areas": stage})
    job = FrameJob(
        rundir=str(tmp_path), index=0,
        context=FrameContext("f0", "a", Camera(focal_px=100.0, baseline_m=0.1)),
        stages=(("areas", {}, "key"),), expected={},
    )
    outcome = process_frame(job)
    assert outcome.failed_stage == "areas" and expected in outcome.error


def test_numpy_scalar_figures_are_recorded_as_python_scalars(tmp_path, monkeypatch):
    tables = {"areas": {"object_id": [1], "area_px": [2]}}

    def run(inputs, *, frame, params):
        return StageResult(tables=tables, figures={"n": np.int64(3), "f": np.float32(0.5)})

    stage = Stage(
        name="areas", version="1", inputs=(), params=(), run=run,
        outputs=(Product("areas", kind="table", schema=_SCHEMA),),
    )
    monkeypatch.setattr(worker, "_stages", lambda package: {"areas": stage})
    job = FrameJob(
        rundir=str(tmp_path), index=0,
        context=FrameContext("f0", "a", Camera(focal_px=100.0, baseline_m=0.1)),
        stages=(("areas", {}, "key"),), expected={},
    )
    figures = process_frame(job).completed[0].figures
    assert figures == {"n": 3, "f": 0.5} and type(figures["n"]) is int


def test_table_columns_reach_the_journal_as_arrow_arrays_of_the_schema(tmp_path, monkeypatch):
    # the per-frame check converts every column; the driver's journal takes those arrays
    # rather than converting the Python values a second time
    outcome = _outcome(
        tmp_path, monkeypatch, {"areas": {"object_id": [1, 2], "area_px": np.array([5, 7])}}
    )
    columns = outcome.completed[0].tables["areas"]
    assert list(columns) == _SCHEMA.names
    assert all(isinstance(c, pa.Array) for c in columns.values())
    assert [columns[f.name].type for f in _SCHEMA] == list(_SCHEMA.types)
    assert columns["area_px"].to_pylist() == [5, 7]
