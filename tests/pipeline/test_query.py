"""arroyo query: views over several runs, output formats, notebook API, error cases.

``make_run`` builds a run directory in the engine's exact layout (products.zarr, frames.parquet,
published hive-partitioned descriptors/relations through ``pipeline.tables.publish_table``,
quicklooks) from a small synthetic scene, so these tests do not depend on the stereo stages;
``test_report.py`` reuses it.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import xarray as xr

from pipeline.cli import main
from pipeline.errors import ParamError, RunDirError
from pipeline.lock import RunLock
from pipeline.query import (
    format_text_table,
    frame_dataset,
    load_runs,
    open_runs,
    query_command,
    query_df,
    query_runs,
)
from pipeline.stage import Product
from pipeline.store import ensure_zarr, write_frame_array
from pipeline.tables import publish_table, write_part
from stages.describe import DESCRIPTOR_SCHEMA, RELATION_SCHEMA
from stages.quicklook import encode_png, objects_image

FOCAL, BASELINE = 100.0, 0.1
STAGES = ("ingest", "depth", "segment", "describe", "quicklook")


def _ids_schema(body: pa.Schema) -> pa.Schema:
    ids = [("archive", pa.string()), ("run_id", pa.string()), ("frame_id", pa.string())]
    return pa.schema([*ids, *body])


def _scene(rng: np.random.Generator, shape: tuple[int, int], n_rocks: int):
    """Gray images, depth maps and labels of a tilted ground with elliptic rocks."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    disparity = (4.0 + 10.0 * yy / h).astype(np.float32)  # ground: nearer at the bottom
    height = np.zeros(shape, np.float32)
    labels = np.zeros(shape, np.int32)
    right = rng.normal(120, 12, size=shape)
    for k in range(1, n_rocks + 1):
        cy, cx = rng.uniform(0.2 * h, 0.9 * h), rng.uniform(0.1 * w, 0.9 * w)
        ry, rx = rng.uniform(2.5, 6), rng.uniform(3, 8)
        inside = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1
        inside &= labels == 0
        labels[inside] = k
        bump = rng.uniform(0.02, 0.3)
        height[inside] = bump
        disparity[inside] += 1.0 + 3 * bump
        right[inside] = rng.uniform(40, 80) if k % 2 else rng.uniform(180, 230)
    labels = _dense(labels)
    right = np.clip(right, 0, 255).astype(np.uint8)
    left = np.roll(right, 3, axis=1)
    rng_m = (FOCAL * BASELINE / disparity).astype(np.float32)
    residual = rng.normal(0, 4, size=shape).astype(np.float32)
    residual[:, :3] = np.nan
    return left, right, disparity, rng_m, height, residual, labels


def _dense(labels: np.ndarray) -> np.ndarray:
    ids = np.unique(labels[labels > 0])
    out = np.zeros_like(labels)
    for new, old in enumerate(ids, start=1):
        out[labels == old] = new
    return out


def _describe(labels, right, rng_m, height, shape) -> tuple[dict, dict]:
    """Descriptor and relation columns computed from the frame's own maps."""
    h, w = shape
    rows: dict[str, list] = {f.name: [] for f in DESCRIPTOR_SCHEMA}
    for k in range(1, int(labels.max()) + 1):
        ys, xs = np.nonzero(labels == k)
        r = float(np.median(rng_m[ys, xs]))
        width = (xs.max() - xs.min() + 1) * r / FOCAL
        values = {
            "object_id": k,
            "area_px": ys.size,
            "centroid_x": float(xs.mean()),
            "centroid_y": float(ys.mean()),
            "bbox_x_min": int(xs.min()),
            "bbox_x_max": int(xs.max()),
            "bbox_y_near": int(ys.max()),
            "bbox_y_far": int(ys.min()),
            "range_m": r,
            "range_err_m": r * r / (FOCAL * BASELINE) * 0.5,
            "x_m": (float(xs.mean()) - w / 2) * r / FOCAL,
            "y_m": r,
            "z_m": 0.0,
            "width_m": width,
            "length_m": width * 0.8,
            "height_m": float(height[ys, xs].max()),
            "height_max_m": float(height[ys, xs].max()),
            "height_err_m": 0.01,
            "width_err_m": 0.01,
            "depth_valid_fraction": 1.0,
            "mean_gray": float(right[ys, xs].mean()),
            "polarity": "darker" if right[ys, xs].mean() < 120 else "lighter",
            "texture_std": float(right[ys, xs].std()),
            "texture_contrast": 1.0,
            "ellipse_major_px": float(xs.max() - xs.min() + 1),
            "ellipse_minor_px": float(ys.max() - ys.min() + 1),
            "ellipse_angle_deg": 0.0,
            "size_class": "obstacle" if height[ys, xs].max() >= 0.1 else "sample",
            "size_class_borderline": bool(abs(height[ys, xs].max() - 0.1) <= 0.01),
            "touches_border": bool(xs.min() == 0 or xs.max() == w - 1),
            "occluded": False,
            "depth_unreliable": False,
        }
        for name, value in values.items():
            rows[name].append(value)
    rel: dict[str, list] = {f.name: [] for f in RELATION_SCHEMA}
    n = len(rows["object_id"])
    for a in range(n):
        for b in range(n):
            if a != b and rows["y_m"][a] > rows["y_m"][b]:
                rel["subject_id"].append(rows["object_id"][a])
                rel["relation"].append("behind")
                rel["object_id"].append(rows["object_id"][b])
                rel["distance_m"].append(rows["y_m"][a] - rows["y_m"][b])
                overlap = min(rows["bbox_x_max"][a], rows["bbox_x_max"][b]) - max(
                    rows["bbox_x_min"][a], rows["bbox_x_min"][b]
                )
                rel["overlap"].append(float(max(overlap, 0)))
                rel["shared_boundary"].append(0.0)
    return rows, rel


def make_run(
    rundir: Path,
    *,
    archive: str = "lab",
    frames: int = 3,
    failed: tuple[int, ...] = (),
    rocks: int = 4,
    shape: tuple[int, int] = (48, 64),
    seed: int = 0,
    quicklooks: bool = True,
    status: str = "finished",
    evaluation: bool = False,
) -> Path:
    """Write a run directory in the engine's layout; frames in ``failed`` failed in depth."""
    rng = np.random.default_rng(seed)
    rundir.mkdir(parents=True, exist_ok=True)
    run_id = f"run-{archive}-{seed}"
    ids = [f"{archive}_{k:03d}" for k in range(frames)]
    arrays: dict[str, list[np.ndarray]] = {
        n: [] for n in ("left", "right", "disparity", "range", "height", "residual", "labels")
    }
    desc_tables, rel_tables, frame_rows = [], [], []
    desc_schema, rel_schema = _ids_schema(DESCRIPTOR_SCHEMA), _ids_schema(RELATION_SCHEMA)
    for k, fid in enumerate(ids):
        left, right, disp, rng_m, height, residual, labels = _scene(rng, shape, rocks)
        ok = k not in failed
        if not ok:  # ingest ran, depth failed: downstream maps hold fill values
            disp = np.full(shape, np.nan, np.float32)
            rng_m, height, residual = disp.copy(), disp.copy(), disp.copy()
            labels = np.zeros(shape, np.int32)
        for name, value in zip(
            arrays, (left, right, disp, rng_m, height, residual, labels), strict=True
        ):
            arrays[name].append(value)
        row = {
            "frame_id": fid,
            "index": k,
            "status": "done" if ok else "failed",
            "error": None if ok else f"depth: no valid disparity in frame {fid}",
            "failed_stage": None if ok else "depth",
            "left": f"images/{fid}_left.png",
            "right": f"images/{fid}_right.png",
            "notes": None,
            "site": f"site{k % 2}",
        }
        for i, stage in enumerate(STAGES):
            row[f"{stage}_seconds"] = 0.01 * (i + 1) + 0.001 * k if ok or i == 0 else None
        if ok:
            desc, rel = _describe(labels, right, rng_m, height, shape)
            n = len(desc["object_id"])
            desc_tables.append(_with_ids(desc, desc_schema, archive, run_id, fid))
            rel_tables.append(_with_ids(rel, rel_schema, archive, run_id, fid))
            row.update(
                describe_rock_count=n,
                describe_n_samples=desc["size_class"].count("sample"),
                describe_n_obstacles=desc["size_class"].count("obstacle"),
                describe_ground_area_m2=12.0,
                describe_rock_area_fraction=float(
                    sum(np.pi * d**2 / 4 for d in desc["width_m"]) / 12.0
                ),
            )
            if quicklooks and k % 2 == 0:  # odd frames: the report renders from the zarr
                folder = rundir / "quicklooks" / fid
                folder.mkdir(parents=True, exist_ok=True)
                (folder / "objects.png").write_bytes(encode_png(objects_image(right, labels)))
        frame_rows.append(row)
    dtypes = {"left": "uint8", "right": "uint8", "labels": "int32"}
    products = {
        name: (Product(name, dtype=dtypes.get(name, "float32")), shape, {"stage": "fixture"})
        for name in arrays
    }
    ensure_zarr(rundir, ids, products)
    for name, values in arrays.items():
        for k, value in enumerate(values):
            write_frame_array(rundir, name, k, value)
    pq.write_table(pa.Table.from_pylist(frame_rows), rundir / "frames.parquet")
    order = {fid: i for i, fid in enumerate(ids)}
    for product, tables, schema in (
        ("descriptors", desc_tables, desc_schema),
        ("relations", rel_tables, rel_schema),
    ):
        parts, live = [], {}
        for table in tables:
            part_id, rel_path, _sha = write_part(rundir, product, table)
            parts.append((part_id, rel_path))
            for fid in set(table["frame_id"].to_pylist()):
                live[fid] = part_id
        # frames without rocks still count as live in a part with no rows of theirs
        publish_table(rundir, product, archive, live, parts, schema, order)
    meta = {
        "run_id": run_id,
        "archive": archive,
        "status": status,
        "started": "2025-01-01T00:00:00+0000",
        "finished": None if status == "running" else "2025-01-01T00:00:05+0000",
        "scheduler": "synchronous",
        "catalog": {
            "source": f"/catalogs/{archive}.toml",
            "path": "",
            "sha256": "",
            "truth_dir": None,
        },
        "camera": {"focal_px": FOCAL, "baseline_m": BASELINE, "reference": "right"},
        "image_shape": list(shape),
        "stages": {s: {"version": "1", "params": {"step": 0.25}} for s in STAGES},
        "counts": {"done": frames - len(failed), "failed": len(failed), "pending": 0},
        "environment": {"python": sys.version.split()[0]},
    }
    (rundir / "run.json").write_text(json.dumps(meta, indent=2))
    if evaluation:
        rows = [
            {
                "run_id": run_id,
                "archive": archive,
                "frame_id": fr,
                "product": "depth",
                "method": method,
                "metric": metric,
                "value": float(rng.uniform(0, 1)),
            }
            for fr in ("*", ids[0])
            for method in ("arroyo", "opencv-sgbm")
            for metric in ("bad1", "epe")
        ]
        pq.write_table(pa.Table.from_pylist(rows), rundir / "evaluation.parquet")
    return rundir


def _with_ids(columns: dict, schema: pa.Schema, archive: str, run_id: str, fid: str):
    n = len(next(iter(columns.values())))
    data = {"archive": [archive] * n, "run_id": [run_id] * n, "frame_id": [fid] * n, **columns}
    return pa.table(data, schema=schema)


@pytest.fixture
def two_runs(tmp_path: Path) -> tuple[Path, Path]:
    lab = make_run(tmp_path / "runs" / "lab", archive="lab", frames=3, failed=(1,), seed=1)
    dunes = make_run(
        tmp_path / "runs" / "dunes", archive="dunes", frames=2, rocks=3, seed=2, evaluation=True
    )
    return lab, dunes


def _expected(rundir: Path, product: str) -> pa.Table:
    # partitioning=None: the files hold the archive column, hive inference would clash
    return pq.read_table(os.path.realpath(rundir / f"{product}.parquet"), partitioning=None)


# -- views over several runs ---------------------------------------------------------------
def test_two_runs_query_as_one_table_set_with_archive_and_run(two_runs):
    lab, dunes = two_runs
    got = query_runs(
        [lab, dunes],
        "SELECT archive, run, count(*) AS n, count(DISTINCT frame_id) AS frames "
        "FROM descriptors GROUP BY ALL ORDER BY archive",
    ).to_pylist()
    want = []
    for rundir in (dunes, lab):
        table = _expected(rundir, "descriptors")
        want.append(
            {
                "archive": rundir.name,
                "run": rundir.name,
                "n": table.num_rows,
                "frames": len(set(table["frame_id"].to_pylist())),
            }
        )
    assert got == want
    assert got[1]["frames"] == 2  # lab's failed frame has no rows


def test_the_readme_question_tall_rocks_near_per_archive(two_runs):
    lab, dunes = two_runs
    sql = (
        "SELECT archive, count(*) AS rocks FROM descriptors "
        "WHERE height_m > 0.10 AND range_m < 2.0 GROUP BY archive ORDER BY archive"
    )
    got = {r["archive"]: r["rocks"] for r in query_runs([lab, dunes], sql).to_pylist()}
    for rundir in (lab, dunes):
        rows = _expected(rundir, "descriptors").to_pylist()
        count = sum(1 for r in rows if r["height_m"] > 0.1 and r["range_m"] < 2.0)
        assert got.get(rundir.name, 0) == count


def test_frames_view_has_run_columns_and_unions_metadata(two_runs):
    lab, dunes = two_runs
    rows = query_runs(
        [lab, dunes],
        "SELECT archive, run, run_id, frame_id, status, error, site FROM frames "
        "ORDER BY archive, frame_id",
    ).to_pylist()
    assert [r["frame_id"] for r in rows] == [
        "dunes_000",
        "dunes_001",
        "lab_000",
        "lab_001",
        "lab_002",
    ]
    assert {r["run_id"] for r in rows if r["archive"] == "lab"} == {"run-lab-1"}
    failed = [r for r in rows if r["status"] == "failed"]
    assert [r["frame_id"] for r in failed] == ["lab_001"] and "no valid disparity" in failed[0][
        "error"
    ]


def test_relations_join_descriptors_samples_behind_obstacles(two_runs):
    lab, _ = two_runs
    sql = """
        SELECT s.frame_id, s.object_id AS sample, o.object_id AS obstacle
        FROM descriptors s
        JOIN relations r ON r.run = s.run AND r.frame_id = s.frame_id
             AND r.subject_id = s.object_id AND r.relation = 'behind'
        JOIN descriptors o ON o.run = r.run AND o.frame_id = r.frame_id
             AND o.object_id = r.object_id
        WHERE s.size_class = 'sample' AND o.size_class = 'obstacle'
        ORDER BY ALL"""
    got = [tuple(r.values()) for r in query_runs(lab, sql).to_pylist()]
    desc = {(r["frame_id"], r["object_id"]): r for r in _expected(lab, "descriptors").to_pylist()}
    want = sorted(
        (r["frame_id"], r["subject_id"], r["object_id"])
        for r in _expected(lab, "relations").to_pylist()
        if r["relation"] == "behind"
        and desc[(r["frame_id"], r["subject_id"])]["size_class"] == "sample"
        and desc[(r["frame_id"], r["object_id"])]["size_class"] == "obstacle"
    )
    assert got == want


def test_evaluation_view_empty_when_no_run_has_it_and_filled_otherwise(two_runs):
    lab, dunes = two_runs
    empty = query_runs(lab, "SELECT * FROM evaluation")
    assert empty.num_rows == 0 and {"archive", "run", "metric", "value"} <= set(empty.column_names)
    both = query_runs([lab, dunes], "SELECT DISTINCT run FROM evaluation").to_pylist()
    assert both == [{"run": "dunes"}]


def test_archive_filter_prunes_partition_files(two_runs):
    lab, dunes = two_runs
    con = open_runs([lab, dunes])
    try:
        plan = "\n".join(
            str(v)
            for _k, v in con.sql(
                "EXPLAIN SELECT * FROM descriptors WHERE archive = 'lab'"
            ).fetchall()
        )
    finally:
        con.close()
    # dunes' branch reads no file; lab's branch needs no filter at all
    assert "Scanning Files: 0/1" in plan and "File Filters: archive = 'lab'" in plan


def test_same_directory_name_twice_gets_distinct_run_labels(tmp_path):
    a = make_run(tmp_path / "a" / "lab", frames=1, seed=3)
    b = make_run(tmp_path / "b" / "lab", frames=1, seed=4)
    labels = {r.run for r in load_runs([a, b])}
    assert labels == {str(a), str(b)}
    rows = query_runs([a, b], "SELECT run, count(*) AS n FROM frames GROUP BY run").num_rows
    assert rows == 2


def test_run_without_rocks_has_typed_empty_descriptors(tmp_path):
    run = make_run(tmp_path / "empty", frames=2, rocks=0)
    got = query_runs(run, "SELECT count(*) AS n, avg(height_m) AS h FROM descriptors").to_pylist()
    assert got == [{"n": 0, "h": None}]


# -- notebook API ---------------------------------------------------------------------------
def test_open_runs_relation_arrow_pandas(two_runs):
    lab, dunes = two_runs
    con = open_runs([lab, dunes])
    try:
        rel = con.sql("SELECT archive, height_m FROM descriptors")
        table = rel.to_arrow_table()
        frame = rel.df()
    finally:
        con.close()
    assert (
        table.num_rows
        == len(frame)
        == sum(_expected(r, "descriptors").num_rows for r in (lab, dunes))
    )
    df = query_df(lab, "SELECT frame_id, status FROM frames ORDER BY frame_id")
    assert list(df["status"]) == ["done", "failed", "done"]


def test_frame_dataset_returns_the_frames_maps(two_runs):
    lab, _ = two_runs
    ds = frame_dataset(lab, "lab_002")
    stored = xr.open_zarr(lab / "products.zarr")
    np.testing.assert_array_equal(ds["labels"].values, stored["labels"].values[2])
    np.testing.assert_array_equal(ds["range"].values, stored["range"].values[2])
    assert ds["labels"].dims == ("y", "x") and ds.attrs["status"] == "done"
    assert frame_dataset(lab, "lab_001").attrs["status"] == "failed"
    with pytest.raises(ParamError, match="not in run"):
        frame_dataset(lab, "nope")


# -- output formats ---------------------------------------------------------------------------
SQL = "SELECT archive, run, frame_id, object_id, height_m FROM descriptors ORDER BY ALL"


def test_table_format_plain_text_when_not_a_terminal(two_runs):
    lab, dunes = two_runs
    out = io.StringIO()
    assert query_command([lab, dunes], SQL, fmt="table", stdout=out) == 0
    text = out.getvalue()
    expected = query_runs([lab, dunes], SQL)
    lines = text.splitlines()
    assert lines[0].split() == expected.column_names
    assert len(lines) == expected.num_rows + 3 and lines[-1] == f"({expected.num_rows} rows)"
    assert "\x1b[" not in text


def test_table_format_rich_on_a_terminal(two_runs):
    lab, _ = two_runs

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Tty()
    query_command(lab, "SELECT frame_id, status FROM frames ORDER BY frame_id", stdout=out)
    text = out.getvalue()
    assert "lab_001" in text and "failed" in text and "3 rows" in text
    assert any(ch in text for ch in "┃│┏━")


@pytest.mark.parametrize("fmt", ["csv", "json", "parquet"])
def test_each_format_to_a_file_round_trips(two_runs, tmp_path, fmt):
    lab, dunes = two_runs
    target = tmp_path / f"out.{fmt}"
    assert query_command([lab, dunes], SQL, fmt=fmt, output=target) == 0
    expected = query_runs([lab, dunes], SQL)
    if fmt == "csv":
        import pyarrow.csv as pacsv

        got = pacsv.read_csv(target)
        assert got.column_names == expected.column_names
        assert got["frame_id"].to_pylist() == expected["frame_id"].to_pylist()
        np.testing.assert_allclose(got["height_m"].to_numpy(), expected["height_m"].to_numpy())
    elif fmt == "json":
        rows = json.loads(target.read_text())
        assert rows == expected.to_pylist()
    else:
        assert pq.read_table(target).equals(expected)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_csv_and_json_to_stdout(two_runs):
    lab, _ = two_runs
    out = io.StringIO()
    query_command(lab, "SELECT frame_id, status FROM frames ORDER BY 1", fmt="csv", stdout=out)
    assert out.getvalue().splitlines() == [
        '"frame_id","status"',
        '"lab_000","done"',
        '"lab_001","failed"',
        '"lab_002","done"',
    ]
    out = io.StringIO()
    query_command(lab, "SELECT 1.5 AS x, 'nan'::DOUBLE AS y", fmt="json", stdout=out)
    assert json.loads(out.getvalue()) == [{"x": 1.5, "y": None}]


def test_parquet_to_redirected_stdout_through_the_cli(two_runs, tmp_path):
    lab, _ = two_runs
    target = tmp_path / "piped.parquet"
    with open(target, "wb") as fh:
        proc = subprocess.run(
            [sys.executable, "-m", "pipeline", "query", str(lab), SQL, "--format", "parquet"],
            stdout=fh,
            stderr=subprocess.PIPE,
            cwd=Path(__file__).resolve().parents[2],
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
            check=False,
        )
    assert proc.returncode == 0, proc.stderr
    assert pq.read_table(target).equals(query_runs(lab, SQL))


def test_parquet_to_a_terminal_is_refused(two_runs):
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    with pytest.raises(ParamError, match="--output"):
        query_command([two_runs[0]], SQL, fmt="parquet", stdout=Tty())


def test_text_table_formats_numbers_and_nulls():
    table = pa.table({"name": ["a", None], "v": [0.123456, 12345678.0], "n": [1, 22]})
    lines = format_text_table(table).splitlines()
    assert lines[0].split() == ["name", "v", "n"]
    assert lines[2].split() == ["a", "0.1235", "1"]
    assert lines[3].split() == ["1.235e+07", "22"]


# -- errors: clear message, exit 2, nothing written ---------------------------------------------
@pytest.mark.parametrize(
    ("sql", "message"),
    [
        ("SELEC * FROM descriptors", "invalid SQL"),
        ("SELECT nope FROM descriptors", "query failed"),
        ("SELECT * FROM rocks", "query failed"),
        ("SELECT 1; SELECT 2", "exactly one"),
        ("COPY descriptors TO 'x.csv'", "read-only"),
        ("CREATE TABLE t AS SELECT 1", "read-only"),
        ("", "empty SQL"),
    ],
)
def test_bad_sql_exits_2_and_writes_nothing(two_runs, tmp_path, capsys, sql, message):
    lab, _ = two_runs
    target = tmp_path / "out.csv"
    code = main(["query", str(lab), sql, "--format", "csv", "--output", str(target)])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.startswith("arroyo: error:")
    assert not target.exists() and not (Path.cwd() / "x.csv").exists()


def test_missing_run_directory_exits_2(two_runs, tmp_path, capsys):
    code = main(["query", str(two_runs[0]), str(tmp_path / "nope"), "SELECT 1"])
    captured = capsys.readouterr()
    assert code == 2 and "does not exist" in captured.err and captured.out == ""
    (tmp_path / "notarun").mkdir()
    with pytest.raises(RunDirError, match="not an arroyo run directory"):
        query_runs(tmp_path / "notarun", "SELECT 1")
    with pytest.raises(ParamError, match="twice"):
        query_runs([two_runs[0], two_runs[0]], "SELECT 1")


def test_regression_output_under_a_file_said_the_directory_does_not_exist(
    two_runs, tmp_path, capsys
):
    """Bug: `query --output /etc/passwd/x` said "directory /etc/passwd does not exist";
    the parent is a file, and the message says so (also for a file further up)."""
    lab, _ = two_runs
    plain = tmp_path / "plain.txt"
    plain.write_text("not a directory\n")
    for target in (plain / "x.csv", plain / "deeper" / "x.csv"):
        code = main(["query", str(lab), "SELECT 1", "--format", "csv", "--output", str(target)])
        err = capsys.readouterr().err
        assert code == 2 and f"{plain} is a file, not a directory" in err, err
        assert "does not exist" not in err
    assert plain.read_text() == "not a directory\n"
    with pytest.raises(ParamError, match=f"directory {tmp_path / 'nope'} does not exist"):
        query_command([lab], "SELECT 1", fmt="csv", output=tmp_path / "nope" / "x.csv")


def test_run_in_progress_is_refused_unless_allowed(tmp_path, capsys):
    run = make_run(tmp_path / "live", frames=2, status="running")
    target = tmp_path / "out.json"
    with RunLock(run):
        code = main(
            ["query", str(run), "SELECT * FROM frames", "-o", str(target), "--format", "json"]
        )
        err = capsys.readouterr().err
        assert code == 2 and "still in progress" in err and not target.exists()
        assert "--allow-running" in err  # it named the Python argument only
        rows = query_runs(run, "SELECT count(*) AS n FROM descriptors", allow_running=True)
        assert rows.to_pylist() == [{"n": _expected(run, "descriptors").num_rows}]
    # the lock's holder is gone (finished or killed): its published rows are readable
    assert query_runs(run, "SELECT count(*) AS n FROM frames").to_pylist() == [{"n": 2}]


def test_frame_dataset_with_moved_products_root_says_so(tmp_path):
    """Regression: with the run's --products directory moved or unmounted, frame_dataset
    said the run "wrote no array products yet"."""
    run = make_run(tmp_path / "lab", frames=1)
    shared = tmp_path / "shared"
    shared.mkdir()
    (run / "products.zarr").rename(shared / "products.zarr")
    meta = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps({**meta, "products": str(shared)}))
    assert int(frame_dataset(run, "lab_000").labels.max()) > 0
    shared.rename(tmp_path / "moved")
    with pytest.raises(RunDirError, match="which does not exist \\(moved or unmounted\\?\\)"):
        frame_dataset(run, "lab_000")


def test_query_output_into_a_read_only_directory(tmp_path, readonly_view):
    """Regression: `arroyo query -o` into a read-only directory was an EROFS traceback."""
    run = make_run(tmp_path / "lab", frames=1)
    view = readonly_view(run)
    with pytest.raises(ParamError, match="is not writable"):
        query_command([view], "SELECT 1", fmt="csv", output=view / "x.csv")
    assert query_runs([view], "SELECT count(*) AS n FROM frames").to_pylist() == [{"n": 1}]


def test_regression_own_stage_table_not_queryable(archive, tmp_path):
    # a table product of a --stage-package stage was published as RUNDIR/<name>.parquet but
    # `arroyo query` only knew descriptors/relations: "Table with name tallies does not exist"
    from pipeline.runner import run

    out = tmp_path / "run"
    assert run(archive, out, scheduler="synchronous", stage_package="arroyo_fake_stages").done
    table = query_runs(out, "SELECT frame_id, count(*) AS n FROM tallies GROUP BY ALL")
    assert sorted(table["n"].to_pylist()) == [3] * 4  # tally.rows = 3 rows per frame
    with pytest.raises(ParamError, match="views: .*tallies"):
        query_runs(out, "SELECT * FROM tally")


def test_regression_table_of_a_stage_no_longer_run_stays_queryable(archive, tmp_path, monkeypatch):
    # after a rerun with another stage package the earlier package's table stayed published
    # and was queried as if current
    from pipeline.runner import run

    package = tmp_path / "arroyo_no_tally_stages"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name in ("load", "blend"):
        (package / f"{name}.py").write_text(
            f"from arroyo_fake_stages.{name} import STAGE  # noqa: F401\n"
        )
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "run"
    run(archive, out, scheduler="synchronous", stage_package="arroyo_fake_stages")
    run(archive, out, scheduler="synchronous", stage_package=package.name)
    with pytest.raises(ParamError, match="tallies does not exist"):
        query_runs(out, "SELECT * FROM tallies")


@pytest.mark.parametrize("fmt", ["table", "csv", "json", "parquet"])
def test_regression_duplicate_result_column_names_crashed_or_lost_a_column(
    two_runs, tmp_path, capsys, fmt
):
    # a self-join selecting a.area_px, b.area_px: the text table raised a KeyError
    # traceback, JSON kept one of the two columns, Parquet wrote a file pyarrow cannot read
    lab, _ = two_runs
    sql = (
        "SELECT a.area_px, b.area_px FROM descriptors a JOIN descriptors b "
        "ON a.run = b.run AND a.frame_id = b.frame_id AND a.object_id = b.object_id"
    )
    target = tmp_path / f"out.{fmt}"
    code = main(["query", str(lab), sql, "--format", fmt, "--output", str(target)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("arroyo: error:")
    assert "'area_px'" in err and "AS a_area_px" in err
    assert not target.exists()
    # named apart, the same join works
    named = sql.replace("a.area_px, b.area_px", "a.area_px AS a_area_px, b.area_px AS b_px")
    assert main(["query", str(lab), named, "--format", fmt, "--output", str(target)]) == 0
    assert target.exists()


# -- found by the audit of query / report / status (each test names the bug) ------------------
class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_regression_output_inside_the_queried_run_replaced_its_frames_table(tmp_path, capsys):
    # `arroyo query RUN ... -o RUN/frames.parquet --format parquet` replaced the run's own
    # frames table with the query's two rows: "arroyo query never changes a run"
    run = make_run(tmp_path / "lab", frames=2)
    (tmp_path / "link").symlink_to(run)
    before = (run / "frames.parquet").read_bytes()
    inside = (run / "frames.parquet", run / "quicklooks" / ".." / "x.csv", tmp_path / "link" / "y")
    for target in inside:
        code = main(["query", str(run), "SELECT frame_id FROM frames", "-o", str(target)])
        err = capsys.readouterr().err
        assert code == 2 and "inside the queried run directory" in err and "outside" in err
    assert (run / "frames.parquet").read_bytes() == before
    assert not (run / "x.csv").exists() and not (run / "y").exists()
    assert main(["query", str(run), "SELECT 1 AS x", "-o", str(tmp_path / "x.csv")]) == 0


def test_regression_a_url_in_a_query_reached_for_the_network(tmp_path):
    # a URL made DuckDB try to download the httpfs extension (a hang offline); the query
    # connection loads no extension, while local files of the user's own stay readable
    run = make_run(tmp_path / "lab", frames=1)
    with pytest.raises(ParamError, match="httpfs extension.*loads none.*local path"):
        query_runs(run, "SELECT * FROM 'https://example.invalid/x.parquet'")
    with pytest.raises(ParamError):  # nor can a statement lift it
        query_runs(run, "SET autoload_known_extensions = true")
    picked = tmp_path / "picked.csv"
    picked.write_text("frame_id,note\nlab_000,picked up\n")
    joined = query_runs(
        run,
        f"SELECT f.frame_id, p.note FROM frames f JOIN read_csv('{picked}') p USING (frame_id)",
    )
    assert joined.to_pylist() == [{"frame_id": "lab_000", "note": "picked up"}]


def test_regression_output_dash_wrote_a_file_named_dash(two_runs, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    query_command([two_runs[0]], "SELECT 1 AS x", fmt="csv", output="-", stdout=out)
    assert out.getvalue().splitlines() == ['"x"', "1"]
    assert not (tmp_path / "-").exists()


def test_regression_output_suffix_was_ignored_and_a_text_table_written_to_x_parquet(
    two_runs, tmp_path, capsys
):
    lab, _ = two_runs
    for suffix in ("parquet", "csv", "json"):
        target = tmp_path / f"out.{suffix}"
        assert main(["query", str(lab), SQL, "-o", str(target)]) == 0
        if suffix == "parquet":
            assert pq.read_table(target).equals(query_runs(lab, SQL))
        elif suffix == "json":
            assert len(json.loads(target.read_text())) == query_runs(lab, SQL).num_rows
        else:
            assert target.read_text().startswith('"archive","run"')
    assert main(["query", str(lab), SQL, "-o", str(tmp_path / "t.txt")]) == 0
    assert (tmp_path / "t.txt").read_text().splitlines()[1].startswith("-------")
    # a suffix naming another format than --format is refused, nothing written
    code = main(["query", str(lab), SQL, "-o", str(tmp_path / "x.json"), "--format", "csv"])
    err = capsys.readouterr().err
    assert code == 2 and "names a json file but --format is csv" in err
    assert not (tmp_path / "x.json").exists()


@pytest.mark.parametrize(
    ("fmt", "sql", "columns"),
    [
        ("csv", "SELECT 1 AS n, INTERVAL 3 DAY AS i, [1, 2] AS l", "columns 'i'"),
        ("csv", "SELECT frame_id, list(object_id) AS ids FROM descriptors GROUP BY 1", "'ids'"),
        ("parquet", "SELECT 1 AS n, INTERVAL 3 DAY AS i", "column 'i'"),
    ],
)
def test_regression_a_column_the_format_cannot_hold_was_a_traceback(
    two_runs, tmp_path, capsys, fmt, sql, columns
):
    # INTERVAL in CSV or Parquet: an ArrowNotImplementedError traceback (exit 1); a list in
    # CSV: "arroyo: error: Unsupported Type:list<l: int32>" without the column or a fix
    lab, _ = two_runs
    target = tmp_path / f"out.{fmt}"
    assert main(["query", str(lab), sql, "--format", fmt, "-o", str(target)]) == 2
    err = capsys.readouterr().err
    assert columns in err and "CAST(" in err and "--format json" in err
    assert not target.exists()
    out = io.StringIO()
    query_command([lab], sql, fmt="json", stdout=out)  # json takes every type
    assert json.loads(out.getvalue())


def test_regression_json_integer_sums_were_floats(two_runs):
    # sum() of an integer column is a HUGEINT (a decimal of scale 0 in Arrow): JSON printed
    # 61902.0, and lost digits beyond 2**53
    lab, _ = two_runs
    out = io.StringIO()
    sql = (
        "SELECT sum(object_id) AS s, 12345678901234567891::HUGEINT AS big, "
        "1.25::DECIMAL(6, 2) AS d FROM descriptors"
    )
    query_command([lab], sql, fmt="json", stdout=out)
    expected = sum(_expected(lab, "descriptors")["object_id"].to_pylist())
    row = json.loads(out.getvalue())[0]
    assert row == {"s": expected, "big": 12345678901234567891, "d": 1.25}
    assert isinstance(row["s"], int)


def test_json_written_batch_by_batch_is_the_whole_list_dumped_at_once(two_runs, monkeypatch):
    # JSON of 524,000 rows took 5.4 GB: the rows are now encoded a batch at a time
    import pipeline.query as query

    table = query_runs(list(two_runs), "SELECT * FROM descriptors ORDER BY ALL")
    whole = json.dumps(
        [query._json_value(r) for r in table.to_pylist()], indent=1, default=str, allow_nan=False
    )
    for rows in (1, 3, table.num_rows + 1):
        monkeypatch.setattr(query, "_JSON_BATCH_ROWS", rows)
        assert query._encode(table, "json").decode() == whole + "\n"
    assert query._encode(table.slice(0, 0), "json") == b"[]\n"


def test_regression_a_wide_table_on_a_terminal_was_all_ellipses(two_runs, monkeypatch):
    # `SELECT * FROM descriptors` on a 120-column terminal: rich squeezed 36 columns until
    # every cell read '…'; a table too wide is printed as plain text instead
    lab, _ = two_runs
    monkeypatch.setenv("COLUMNS", "120")
    out = _Tty()
    query_command([lab], "SELECT * FROM descriptors ORDER BY ALL", stdout=out)
    text = out.getvalue()
    expected = query_runs(lab, "SELECT * FROM descriptors ORDER BY ALL")
    assert text.splitlines()[0].split() == expected.column_names
    assert "wider than the terminal's 120 columns" in text and "less -S" in text
    out = _Tty()  # a narrow result is still the rich table
    query_command([lab], "SELECT frame_id, status FROM frames", stdout=out)
    assert "┃" in out.getvalue() and "wider" not in out.getvalue()


def test_regression_lost_frames_table_gave_an_empty_frames_view(two_runs):
    # frames.parquet deleted: `SELECT count(*) FROM frames` said 0 while descriptors had rows
    lab, dunes = two_runs
    (lab / "frames.parquet").unlink()
    for rundirs in ([lab], [dunes, lab]):
        with pytest.raises(RunDirError, match="no frames.parquet.*silently empty.*arroyo run"):
            query_runs(rundirs, "SELECT count(*) FROM frames")


@pytest.mark.parametrize("damage", ["files", "generation"])
def test_regression_deleted_published_files_gave_an_empty_view(two_runs, damage):
    # the published generation's part files (or the whole generation) deleted: the
    # relations view was silently empty, the symlink left dangling
    import shutil

    lab, _ = two_runs
    generation = (lab / "relations.parquet").resolve()
    if damage == "files":
        for part in generation.rglob("*.parquet"):
            part.unlink()
    else:
        shutil.rmtree(generation)
    with pytest.raises(RunDirError, match="holds no Parquet file.*relations view.*arroyo run"):
        query_runs(lab, "SELECT count(*) FROM relations")


def test_regression_garbled_run_json_said_nothing_of_the_fix(tmp_path):
    run = make_run(tmp_path / "lab", frames=1)
    (run / "run.json").write_text('{"run_id": ')
    with pytest.raises(RunDirError, match="cannot read .*run.json.*rerun the catalog"):
        query_runs(run, "SELECT 1")


def test_regression_sql_before_the_run_directory_said_the_sql_does_not_exist(two_runs, capsys):
    # `arroyo query "SELECT ..." RUNDIR`: "run directory SELECT ... does not exist"
    lab, _ = two_runs
    assert main(["query", "SELECT count(*) FROM frames", str(lab)]) == 2
    err = capsys.readouterr().err
    assert "the SQL comes last" in err and 'RUNDIR... "SQL"' in err
    assert "does not exist" not in err


def test_regression_sql_longer_than_a_file_name_crashed_the_argument_order_check(
    two_runs, capsys
):
    # the check above asked the file system about the SQL as a path: a query of more than
    # 255 bytes (the README's second question) raised OSError ENAMETOOLONG, exit 1
    lab, _ = two_runs
    sql = "SELECT frame_id FROM frames WHERE " + " OR ".join(
        f"frame_id = 'lab_{i:03d}'" for i in range(40)
    )
    assert len(sql) > 300
    assert main(["query", str(lab), sql, "--format", "csv"]) == 0
    assert '"frame_id"' in capsys.readouterr().out
    assert main(["query", sql, str(lab)]) == 2
    assert "the SQL comes last" in capsys.readouterr().err
