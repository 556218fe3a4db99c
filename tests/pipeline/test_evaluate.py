from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import xarray as xr

from pipeline._baselines import otsu_labels, sgbm_disparity
from pipeline.errors import RunDirError
from pipeline.evaluate import AGGREGATE, EVALUATION_SCHEMA, evaluate_run, format_evaluation
from pipeline.metrics import wilson_interval
from stages._sizefreq import fit_size_frequency

H, W, D = 64, 96, 6  # frame size and the constant ground disparity of the fixture
ROCKS = [(10, 30, 10, 30), (30, 50, 50, 80)]  # (y0, y1, x0, x1) of rocks 1 and 2


def _scene(seed: int) -> dict[str, np.ndarray]:
    """A fronto-parallel textured scene with two dark rocks, and its exact left image."""
    rng = np.random.default_rng(seed)
    right = rng.integers(140, 220, size=(H, W)).astype(np.uint8)
    labels = np.zeros((H, W), dtype=np.int32)
    for k, (y0, y1, x0, x1) in enumerate(ROCKS, start=1):
        labels[y0:y1, x0:x1] = k
        right[y0:y1, x0:x1] = rng.integers(20, 70, size=(y1 - y0, x1 - x0))
    left = rng.integers(140, 220, size=(H, W)).astype(np.uint8)
    left[:, D:] = right[:, :-D]  # left(x + d) = right(x)
    disparity = np.full((H, W), D, dtype=np.float32)
    occluded = np.zeros((H, W), dtype=bool)
    occluded[:, W - D :] = True  # seen by the right camera only
    rng_m = (430.0 * 0.1 / disparity).astype(np.float32)
    rng_m[labels == 1] -= 0.2  # rock 1 is nearer
    return {
        "left": left,
        "right": right,
        "disparity": disparity,
        "range": rng_m,
        "height": np.zeros((H, W), dtype=np.float32),
        "labels": labels,
        "occluded": occluded,
    }


def _rocks(frame_id: str) -> list[dict]:
    return [
        {
            "frame_id": frame_id,
            "rock_id": 1,
            "x_m": -0.3,
            "y_m": 1.5,
            "z_m": 0.0,
            "width_m": 0.12,
            "length_m": 0.1,
            "height_m": 0.05,
            "range_m": 1.6,
            "albedo": 0.1,
            "polarity": "darker",
            "visible_px": 400,
            "size_class": "sample",
            "buried_fraction": 0.2,
            "touches_border": False,
        },
        {
            "frame_id": frame_id,
            "rock_id": 2,
            "x_m": 0.4,
            "y_m": 2.5,
            "z_m": 0.0,
            "width_m": 0.3,
            "length_m": 0.25,
            "height_m": 0.2,
            "range_m": 2.6,
            "albedo": 0.1,
            "polarity": "darker",
            "visible_px": 600,
            "size_class": "obstacle",
            "buried_fraction": 0.1,
            "touches_border": True,
        },
    ]


def _descriptor_rows(frame_id: str) -> list[dict]:
    rows = []
    for rock in _rocks(frame_id):
        rows.append(
            {
                "archive": "fixture",
                "run_id": "r1",
                "frame_id": frame_id,
                "object_id": rock["rock_id"],
                "height_m": rock["height_m"] - 0.01,
                "height_max_m": rock["height_m"] + 0.01,
                "width_m": rock["width_m"] * 1.1,
                "range_m": rock["range_m"],
                "size_class": rock["size_class"],
            }
        )
    return rows


def _relation_rows(frame_id: str) -> list[dict]:
    base = {"archive": "fixture", "run_id": "r1", "frame_id": frame_id}
    return [
        {**base, "subject_id": 1, "relation": "left_of", "object_id": 2, "distance_m": 1.0},
        {**base, "subject_id": 1, "relation": "in_front_of", "object_id": 2, "distance_m": 1.0},
        {**base, "subject_id": 2, "relation": "left_of", "object_id": 1, "distance_m": 1.0},
        {**base, "subject_id": 1, "relation": "adjacent", "object_id": 2, "distance_m": 1.0},
    ]


@pytest.fixture
def rundir(tmp_path: Path) -> Path:
    """A run of three frames: f0 perfect, f1 with a depth error, f2 failed; f3 has no truth."""
    truth_dir = tmp_path / "archive" / "truth"
    truth_dir.mkdir(parents=True)
    run = tmp_path / "run"
    run.mkdir()
    frame_ids = ["f0", "f1", "f2", "f3"]
    scenes = [_scene(i) for i in range(4)]
    rocks = []
    for fid, scene in zip(frame_ids[:3], scenes, strict=False):
        np.savez(
            truth_dir / f"{fid}.npz",
            **{k: scene[k] for k in ("disparity", "range", "height", "labels", "occluded")},
        )
        rocks += _rocks(fid)
    pq.write_table(pa.Table.from_pylist(rocks), truth_dir / "rocks.parquet")

    disparity = np.stack([s["disparity"] for s in scenes])
    disparity[1, : H // 2, : W // 2] += 1.5  # a quarter of frame f1 off by 1.5 px
    disparity[2] = np.nan
    stack = {k: np.stack([s[k] for s in scenes]) for k in ("left", "right", "labels")}
    ds = xr.Dataset(
        {
            "left": (("frame", "y", "x"), stack["left"]),
            "right": (("frame", "y", "x"), stack["right"]),
            "labels": (("frame", "y", "x"), stack["labels"]),
            "disparity": (("frame", "y", "x"), disparity),
        },
        coords={"frame": np.array(frame_ids, dtype=object)},
    )
    ds.to_zarr(run / "products.zarr", zarr_format=3, consolidated=False)
    frames = pa.Table.from_pylist(
        [
            {"frame_id": "f0", "status": "done", "error": None, "depth_seconds": 0.1},
            {"frame_id": "f1", "status": "done", "error": None, "depth_seconds": 0.3},
            {"frame_id": "f2", "status": "failed", "error": "boom", "depth_seconds": None},
            {"frame_id": "f3", "status": "done", "error": None, "depth_seconds": 0.1},
        ]
    )
    pq.write_table(frames, run / "frames.parquet")
    for name, rows in (("descriptors", _descriptor_rows), ("relations", _relation_rows)):
        (run / f"{name}.parquet").mkdir()
        table = pa.Table.from_pylist(rows("f0") + rows("f1") + rows("f3"))
        pq.write_table(table, run / f"{name}.parquet" / "part-0.parquet")
    meta = {
        "run_id": "r1",
        "archive": "fixture",
        "catalog": {
            "source": "fixture.toml",
            "path": str(tmp_path / "archive" / "catalog.toml"),
            "sha256": "0" * 64,
            "truth_dir": str(truth_dir),
        },
        "camera": {"focal_px": 430.0, "baseline_m": 0.1, "reference": "right"},
        "stages": {"depth": {"version": "1", "params": {"max_disparity": 15}}},
    }
    (run / "run.json").write_text(json.dumps(meta))
    return run


def _value(table: pa.Table, *, frame_id, product, method, metric) -> float:
    hits = [
        r["value"]
        for r in table.to_pylist()
        if (r["frame_id"], r["product"], r["method"], r["metric"])
        == (frame_id, product, method, metric)
    ]
    assert len(hits) == 1, (frame_id, product, method, metric, hits)
    return hits[0]


#: (product, metric) of the proportions whose aggregate carries a 95 % interval
_PROPORTIONS = (
    ("segmentation", "precision"),
    ("segmentation", "recall"),
    ("descriptors", "class_accuracy"),
    ("descriptors", "near_class_accuracy"),
    ("relations", "agreement"),
)
#: ... and those of descriptors with ``size_class_borderline`` (describe >= 11)
_DECIDED = (
    ("descriptors", "decided_class_accuracy"),
    ("descriptors", "near_decided_class_accuracy"),
)


def _interval_counts(aggregate: dict, product: str, method: str, metric: str):
    """(successes, trials) of a proportion, from the counts in the same aggregate rows."""

    def get(name):
        return aggregate[(product, method, name)]

    if metric == "precision":
        return get("tp"), get("tp") + get("fp")
    if metric == "recall":
        return get("tp"), get("tp") + get("fn")
    if metric == "agreement":
        return get("n_agree"), get("n_checked")
    n = get(metric.replace("class_accuracy", "n_rocks"))
    right = get(metric) * n
    assert right == pytest.approx(round(right), abs=1e-9)  # a count of rocks
    return round(right), n


def _assert_intervals_match_counts(table: pa.Table) -> int:
    """Every aggregate proportion's _low/_high is the Wilson interval of its counts; per-frame
    rows carry none. Returns how many intervals were checked."""
    rows = table.to_pylist()
    assert not [
        r for r in rows if r["frame_id"] != AGGREGATE and r["metric"].endswith(("_low", "_high"))
    ]
    aggregate = {
        (r["product"], r["method"], r["metric"]): r["value"]
        for r in rows
        if r["frame_id"] == AGGREGATE
    }
    proportions = _PROPORTIONS
    if any(m == "decided_n_rocks" for _, _, m in aggregate):
        proportions += _DECIDED
    checked = 0
    for product, method, metric in list(aggregate):
        if (product, metric) not in proportions:
            continue
        counts = _interval_counts(aggregate, product, method, metric)
        low = aggregate[(product, method, f"{metric}_low")]
        high = aggregate[(product, method, f"{metric}_high")]
        assert (low, high) == pytest.approx(wilson_interval(*counts), nan_ok=True)
        if counts[1] > 0:
            assert low <= aggregate[(product, method, metric)] <= high
        checked += 1
    intervals = {m for _, _, m in aggregate if m.endswith(("_low", "_high"))}
    assert len(intervals) == len({f"{m}_{s}" for _, m in proportions for s in ("low", "high")})
    return checked


def test_evaluate_run_scores_fixture(rundir: Path):
    table = evaluate_run(rundir)
    assert table.schema == EVALUATION_SCHEMA
    written = pq.read_table(rundir / "evaluation.parquet")
    # NaN-aware: an empty breakdown block (no border rocks within 2 m) scores NaN
    pd.testing.assert_frame_equal(written.to_pandas(), table.to_pandas())
    assert set(table.column("frame_id").to_pylist()) == {"f0", "f1", AGGREGATE}

    def v(frame_id, product, method, metric):
        return _value(table, frame_id=frame_id, product=product, method=method, metric=metric)

    assert v("f0", "depth", "arroyo", "bad1") == 0.0
    # a quarter of the frame off by 1.5 px, scored on the non-occluded columns only
    n_noc = H * (W - D)
    assert v("f1", "depth", "arroyo", "bad1") == pytest.approx((H // 2) * (W // 2) / n_noc)
    assert v("f1", "depth", "arroyo", "bad2") == 0.0
    assert v(AGGREGATE, "depth", "arroyo", "bad1") == pytest.approx(
        (H // 2) * (W // 2) / (2 * n_noc)
    )
    assert v(AGGREGATE, "depth", "arroyo", "n_frames") == 2
    assert v(AGGREGATE, "depth", "arroyo", "seconds_per_frame") == pytest.approx(0.2)
    # SGBM on an exactly shifted texture is good but not perfect (borders, rock edges)
    assert v(AGGREGATE, "depth", "opencv-sgbm", "bad2") < 0.3
    assert v(AGGREGATE, "depth", "opencv-sgbm", "n_frames") == 2

    assert v(AGGREGATE, "segmentation", "arroyo", "f1") == 1.0
    assert v(AGGREGATE, "segmentation", "arroyo", "mean_iou") == 1.0
    assert v(AGGREGATE, "segmentation", "otsu", "f1") == 1.0  # dark rocks on light ground

    assert v(AGGREGATE, "descriptors", "arroyo", "n_rocks") == 4
    assert v(AGGREGATE, "descriptors", "arroyo", "height_abs_err_median_m") == pytest.approx(0.01)
    assert v(AGGREGATE, "descriptors", "arroyo", "width_rel_err_median") == pytest.approx(0.1)
    assert v(AGGREGATE, "descriptors", "arroyo", "range_rel_err_p90") == 0.0
    assert v(AGGREGATE, "descriptors", "arroyo", "class_accuracy") == 1.0
    assert v(AGGREGATE, "descriptors", "arroyo", "near_n_rocks") == 2  # rock 1 at 1.6 m
    # breakdown by the truth's touches_border: rock 1 (near) is seen whole
    assert v(AGGREGATE, "descriptors", "arroyo", "near_interior_n_rocks") == 2
    assert v(AGGREGATE, "descriptors", "arroyo", "near_border_n_rocks") == 0

    # per frame: left_of 1->2 ok, in_front_of ok, left_of 2->1 wrong, adjacent unchecked;
    assert v("f0", "relations", "arroyo", "agreement") == pytest.approx(2 / 3)
    assert v(AGGREGATE, "relations", "arroyo", "n_checked") == 6
    assert v(AGGREGATE, "relations", "arroyo", "n_unchecked") == 2

    text = format_evaluation(table)
    assert "fixture: 2 frames scored" in text
    assert "opencv-sgbm" in text and "otsu" in text and "bad-2" in text


def test_evaluate_aggregates_carry_wilson_intervals(rundir: Path):
    """The pooled proportions come with their 95 % interval, computed from the pooled counts."""
    # f1 reads rock 1 (1.6 m, near) as an obstacle: 3 of 4 rocks classed right, 1 of 2 near
    part = rundir / "descriptors.parquet" / "part-0.parquet"
    rows = pq.read_table(part).to_pylist()
    for row in rows:
        if (row["frame_id"], row["object_id"]) == ("f1", 1):
            row["size_class"] = "obstacle"
    pq.write_table(pa.Table.from_pylist(rows), part)
    table = evaluate_run(rundir)

    def v(product, metric, method="arroyo"):
        return _value(table, frame_id=AGGREGATE, product=product, method=method, metric=metric)

    # the counts, known from the fixture: 2 frames of 2 rocks, all matched; 6 edges checked,
    # of which 4 agree (left_of 2 -> 1 is wrong in each frame)
    assert v("descriptors", "class_accuracy") == 0.75
    expected = {
        ("segmentation", "precision", "arroyo"): (4, 4),
        ("segmentation", "recall", "arroyo"): (4, 4),
        ("segmentation", "precision", "otsu"): (4, 4),
        ("segmentation", "recall", "otsu"): (4, 4),
        ("descriptors", "class_accuracy", "arroyo"): (3, 4),
        ("descriptors", "near_class_accuracy", "arroyo"): (1, 2),
        ("relations", "agreement", "arroyo"): (4, 6),
    }
    for (product, metric, method), counts in expected.items():
        low, high = v(product, f"{metric}_low", method), v(product, f"{metric}_high", method)
        assert (low, high) == wilson_interval(*counts), (product, metric, method)
    # the breakdown blocks and depth carry no interval
    metrics = set(table.column("metric").to_pylist())
    assert {m for m in metrics if m.endswith("_low")} == {
        "precision_low",
        "recall_low",
        "class_accuracy_low",
        "near_class_accuracy_low",
        "agreement_low",
    }
    assert _assert_intervals_match_counts(table) == 7

    # the table prints arroyo's interval next to its figure; the baselines' stay bare
    def pct(value):
        return f"{100 * value:.1f}"

    text = format_evaluation(table, width=120)
    low, high = wilson_interval(4, 6)
    assert f"{pct(4 / 6)} ({pct(low)}-{pct(high)})" in text
    low, high = wilson_interval(4, 4)
    assert f"1.000 ({low:.3f}-1.000)" in text
    assert "95 % Wilson score interval" in text
    (precision,) = [line for line in text.splitlines() if "precision" in line]
    cells = [cell.strip() for cell in precision.split("│")]
    assert cells[-3:] == [f"1.000 ({low:.3f}-1.000)", "1.000", ""]  # arroyo, otsu


def test_evaluate_intervals_leave_every_other_metric_unchanged(rundir: Path, monkeypatch):
    """The interval rows are added next to the metrics; every other row is as before."""
    import pipeline.evaluate

    def scores(table: pa.Table) -> pd.DataFrame:
        # SGBM's seconds are timed here, so they differ between two evaluations
        frame = table.to_pandas()
        return frame[frame["metric"] != "seconds_per_frame"].reset_index(drop=True)

    with_intervals = scores(evaluate_run(rundir))
    monkeypatch.setattr(pipeline.evaluate, "_with_intervals", lambda product, values: values)
    without = scores(evaluate_run(rundir))
    is_interval = with_intervals["metric"].str.endswith(("_low", "_high"))
    # NaN-aware and exact: same rows in the same order, values bit for bit
    pd.testing.assert_frame_equal(
        with_intervals[~is_interval].reset_index(drop=True), without, check_exact=True
    )
    assert is_interval.sum() == 2 * 7


def _set_descriptor(rundir: Path, changes: dict[tuple[str, int], dict]) -> None:
    """Rewrite the fixture's descriptors: ``changes[(frame_id, object_id)]`` into that row."""
    part = rundir / "descriptors.parquet" / "part-0.parquet"
    rows = pq.read_table(part).to_pylist()
    for row in rows:
        row.update(changes.get((row["frame_id"], row["object_id"]), {}))
    pq.write_table(pa.Table.from_pylist(rows), part)


def test_evaluate_class_accuracy_without_the_borderline_rocks(rundir: Path):
    """size_class_borderline: its share and the class accuracy over the other rocks."""
    # f1 reads rock 1 (1.6 m, near) as an obstacle, with a borderline size; every other
    # rock decided and right: 2 frames x 2 rocks, 2 of them near (rock 1 of f0 and f1)
    _set_descriptor(rundir, {("f1", 1): {"size_class": "obstacle"}})
    before = evaluate_run(rundir).to_pandas()
    changes = {
        (fid, rock): {"size_class_borderline": (fid, rock) == ("f1", 1)}
        for fid in ("f0", "f1", "f3")
        for rock in (1, 2)
    }
    _set_descriptor(rundir, changes)
    table = evaluate_run(rundir)

    def v(metric, frame_id=AGGREGATE):
        return _value(
            table, frame_id=frame_id, product="descriptors", method="arroyo", metric=metric
        )

    assert v("near_class_accuracy") == 1 / 2  # as before: 1 of the 2 near rocks right
    assert v("near_borderline_fraction") == 1 / 2
    assert v("near_decided_class_accuracy") == 1.0 and v("near_decided_n_rocks") == 1
    assert v("borderline_fraction") == 1 / 4
    assert v("decided_class_accuracy") == 1.0 and v("decided_n_rocks") == 3
    assert v("near_borderline_fraction", "f0") == 0.0
    assert v("near_borderline_fraction", "f1") == 1.0
    assert math.isnan(v("near_decided_class_accuracy", "f1"))  # no decided near rock
    for metric, counts in (
        ("decided_class_accuracy", (3, 3)),
        ("near_decided_class_accuracy", (1, 1)),
    ):
        assert (v(f"{metric}_low"), v(f"{metric}_high")) == wilson_interval(*counts)
    assert _assert_intervals_match_counts(table) == 9
    # every metric of before is unchanged (SGBM's seconds are timed here)
    after = table.to_pandas()
    after = after[after["metric"].isin(set(before["metric"]))].reset_index(drop=True)
    keep = before["metric"] != "seconds_per_frame"
    pd.testing.assert_frame_equal(
        after[keep].reset_index(drop=True), before[keep].reset_index(drop=True), check_exact=True
    )
    # the printed table shows the near figures under the near class accuracy
    text = format_evaluation(table, width=120)
    lines = text.splitlines()
    (row,) = [i for i, line in enumerate(lines) if "borderline class (%)" in line]
    assert "sample/obstacle accuracy" in lines[row - 1] and "50.0" in lines[row]
    low, _ = wilson_interval(1, 1)
    assert f"100.0 ({100 * low:.1f}-100.0)" in lines[row + 1]
    assert "borderline out" in lines[row + 1]


def test_evaluate_size_frequency_against_the_truth_rocks(rundir: Path):
    # the describe stage measured 2 m^2 of ground in each of f0 and f1; f3 has no truth
    frames = pq.read_table(rundir / "frames.parquet").to_pandas()
    frames["describe_seconds"] = [0.1, 0.1, None, 0.1]
    frames["describe_ground_area_m2"] = [2.0, 2.0, None, 2.0]
    pq.write_table(pa.Table.from_pandas(frames, preserve_index=False), rundir / "frames.parquet")
    meta = json.loads((rundir / "run.json").read_text())
    meta["stages"]["describe"] = {"version": "6", "params": {"sfd_max_range_m": 5.0}}
    (rundir / "run.json").write_text(json.dumps(meta))
    table = evaluate_run(rundir)

    def v(method, metric):
        return _value(
            table, frame_id=AGGREGATE, product="size-frequency", method=method, metric=metric
        )

    # the fixture's descriptors read every rock 10 % wide: 21 % more plan area
    truth_widths = [0.12, 0.3, 0.12, 0.3]
    expected = fit_size_frequency(truth_widths, ground_area_m2=4.0)
    assert v("truth", "k") == pytest.approx(expected.k)
    assert v("truth", "rock_area_fraction") == pytest.approx(
        sum(np.pi * w**2 / 4 for w in truth_widths) / 4.0
    )
    assert v("arroyo", "rock_area_fraction") == pytest.approx(
        1.21 * v("truth", "rock_area_fraction")
    )
    assert v("arroyo", "k") > v("truth", "k")
    assert v("arroyo", "n_rocks") == v("truth", "n_rocks") == 4
    assert "size-frequency (vs truth)" in format_evaluation(table)


def test_evaluate_size_frequency_needs_a_ground_area(rundir: Path):
    # the fixture's frames never ran describe: no ground area, no size-frequency rows
    assert "size-frequency" not in set(evaluate_run(rundir).column("product").to_pylist())


def test_evaluate_without_optional_products(rundir: Path):
    """Only ingest has run: baselines are still scored on every ingested frame with truth."""
    ds = xr.open_zarr(rundir / "products.zarr", consolidated=False)
    only_images = ds[["left", "right"]].load()
    ds.close()
    only_images.to_zarr(rundir / "images.zarr", zarr_format=3, consolidated=False)
    (rundir / "products.zarr").rename(rundir / "full.zarr")
    (rundir / "images.zarr").rename(rundir / "products.zarr")
    for name in ("descriptors", "relations"):
        (rundir / f"{name}.parquet" / "part-0.parquet").unlink()
        (rundir / f"{name}.parquet").rmdir()
    table = evaluate_run(rundir)
    methods = {(r["product"], r["method"]) for r in table.to_pylist()}
    assert methods == {("depth", "opencv-sgbm"), ("segmentation", "otsu")}


def test_missing_rundir_and_run_json(tmp_path: Path):
    with pytest.raises(RunDirError, match="does not exist"):
        evaluate_run(tmp_path / "nope")
    with pytest.raises(RunDirError, match="run.json is missing"):
        evaluate_run(tmp_path)
    with pytest.raises(TypeError, match="path"):
        evaluate_run(42)


def test_catalog_without_truth(rundir: Path):
    meta = json.loads((rundir / "run.json").read_text())
    meta["catalog"]["truth_dir"] = None
    (rundir / "run.json").write_text(json.dumps(meta))
    with pytest.raises(RunDirError, match="no ground truth"):
        evaluate_run(rundir)
    assert not (rundir / "evaluation.parquet").exists()


def test_sgbm_baseline_recovers_a_shift_in_right_geometry():
    scene = _scene(7)
    disparity = sgbm_disparity(scene["left"], scene["right"], min_disparity=0, max_disparity=15)
    inner = disparity[8:-8, 8 : W - 16]
    assert np.nanmedian(inner) == pytest.approx(D)
    assert np.isfinite(inner).mean() > 0.9


@pytest.mark.parametrize("dark_objects", [True, False])
def test_otsu_baseline_takes_the_minority_side(dark_objects):
    image = np.full((40, 40), 180 if dark_objects else 60, dtype=np.uint8)
    image[5:15, 5:15] = 40 if dark_objects else 220
    image[25:35, 20:30] = 40 if dark_objects else 220
    image[0, 39] = image[5, 5]  # a speck below the minimum area
    labels = otsu_labels(image, min_area_px=30)
    assert labels.max() == 2 and labels[0, 39] == 0
    assert set(np.unique(labels[5:15, 5:15])) == {1}


def test_evaluate_a_run_made_by_the_engine(tmp_path: Path):
    """The engine's real run directory layout (ingest only, fake stage package)."""
    import cv2

    from pipeline.runner import run

    root = tmp_path / "archive"
    (root / "images").mkdir(parents=True)
    (root / "truth").mkdir()
    lines = ["frame_id,left,right"]
    for k in range(2):
        scene = _scene(10 + k)
        for side in ("left", "right"):
            cv2.imwrite(str(root / "images" / f"g{k}_{side}.png"), scene[side])
        np.savez(
            root / "truth" / f"g{k}.npz",
            **{n: scene[n] for n in ("disparity", "range", "height", "labels", "occluded")},
        )
        lines.append(f"g{k},images/g{k}_left.png,images/g{k}_right.png")
    (root / "frames.csv").write_text("\n".join(lines) + "\n")
    catalog = root / "catalog.toml"
    catalog.write_text(
        '[archive]\nname = "engine"\ndescription = "fixture"\n\n'
        "[camera]\nfocal_px = 430.0\nbaseline_m = 0.1\n\n"
        '[frames]\nindex = "frames.csv"\n\n[truth]\ndir = "truth"\n'
    )
    out = tmp_path / "run"
    summary = run(catalog, out, stage_package="arroyo_fake_stages", scheduler="synchronous")
    assert summary.exit_code == 0
    table = evaluate_run(out)
    methods = {(r["product"], r["method"]) for r in table.to_pylist()}
    assert methods == {("depth", "opencv-sgbm"), ("segmentation", "otsu")}
    assert _value(
        table, frame_id=AGGREGATE, product="segmentation", method="otsu", metric="f1"
    ) == pytest.approx(1.0)
    assert "engine: 2 frames scored" in format_evaluation(table)


@pytest.mark.slow
def test_end_to_end_render_run_evaluate(tmp_path: Path):
    """A tiny built-in archive through the real stages, then scored against its truth."""
    pytest.importorskip("stages.depth", reason="the depth stage has not landed")
    synth = pytest.importorskip("pipeline.synth", reason="the renderer has not landed")
    from pipeline.runner import run

    archive = synth.synthesize_archive("lab", tmp_path / "lab", frames=2, seed=3, size=160)
    out = tmp_path / "run"
    summary = run(archive / "catalog.toml", out, scheduler="synchronous")
    assert summary.exit_code == 0
    table = evaluate_run(out)
    written = pq.read_table(out / "evaluation.parquet")
    pd.testing.assert_frame_equal(written.to_pandas(), table.to_pandas())  # NaN-aware
    rows = table.to_pylist()
    pairs = {(r["product"], r["method"]) for r in rows}
    assert {
        ("depth", "arroyo"),
        ("depth", "opencv-sgbm"),
        ("segmentation", "arroyo"),
        ("segmentation", "otsu"),
        ("descriptors", "arroyo"),
    } <= pairs
    aggregate = {
        (r["product"], r["method"], r["metric"]): r["value"]
        for r in rows
        if r["frame_id"] == AGGREGATE
    }
    assert aggregate[("depth", "arroyo", "n_frames")] == 2
    for method in ("arroyo", "opencv-sgbm"):
        assert 0.0 <= aggregate[("depth", method, "bad2")] <= 1.0
        assert aggregate[("depth", method, "n_px")] > 0.5 * 2 * 160 * 160
    assert 0.0 <= aggregate[("segmentation", "arroyo", "f1")] <= 1.0
    # each pooled proportion's interval is the Wilson interval of the run's own counts
    assert _assert_intervals_match_counts(table) >= 4
    assert "lab" in format_evaluation(table)


def test_evaluate_refuses_a_run_in_progress(rundir: Path):
    """Regression: `arroyo evaluate` on a live run scored whichever frames were done and
    wrote evaluation.parquet into the run directory (`arroyo query` and `arroyo report`
    refuse a live run), scores the run's later frames never entered."""
    from pipeline.lock import RunLock

    meta = json.loads((rundir / "run.json").read_text())
    (rundir / "run.json").write_text(json.dumps({**meta, "status": "running"}))
    with RunLock(rundir), pytest.raises(RunDirError, match="still in progress"):
        evaluate_run(rundir)
    assert not (rundir / "evaluation.parquet").exists()
    assert evaluate_run(rundir).num_rows > 0  # a killed run (no lock holder) is scored


def test_evaluate_refuses_a_left_referenced_run(rundir: Path):
    """Regression: a run with `reference = "left"` was scored against the truth, which is
    in the right image's geometry: mojave's segmentation F1 printed 0.000 (Otsu's too) and
    its depth bad-2 5.6 % instead of 0.9 %, as if those were the run's scores."""
    meta = json.loads((rundir / "run.json").read_text())
    meta["camera"]["reference"] = "left"
    (rundir / "run.json").write_text(json.dumps(meta))
    with pytest.raises(RunDirError, match="the ground truth is in the right image's geometry"):
        evaluate_run(rundir)
    assert not (rundir / "evaluation.parquet").exists()


def test_evaluate_with_moved_products_root_says_so(rundir: Path, tmp_path: Path):
    """Regression: a run whose --products directory was moved or unmounted printed
    "nothing to score: no frame has both products and ground truth" and exited 0."""
    meta = json.loads((rundir / "run.json").read_text())
    (rundir / "run.json").write_text(json.dumps({**meta, "products": str(tmp_path / "gone")}))
    with pytest.raises(RunDirError, match="which does not exist \\(moved or unmounted\\?\\)"):
        evaluate_run(rundir)


def test_evaluate_of_a_read_only_run_directory_says_so_before_scoring(rundir, readonly_view):
    """Regression: on a read-only mount `arroyo evaluate` scored every frame, then ended in
    an EROFS traceback writing evaluation.parquet."""
    with pytest.raises(RunDirError, match="the run directory is read-only"):
        evaluate_run(readonly_view(rundir))


def test_depth_seconds_per_frame_is_robust_to_the_first_frames_compilation(rundir: Path):
    """Regression: the mean of the run's depth seconds carried numba's one-off compilation
    of a fresh machine's first frame (lab: 20.2 s, the others 0.08 s): 4 frames printed
    arroyo 5.1 s per frame against SGBM's 0.1 s. It is now the median."""
    import shutil

    truth = Path(json.loads((rundir / "run.json").read_text())["catalog"]["truth_dir"])
    shutil.copy(truth / "f0.npz", truth / "f3.npz")  # a third scored frame
    frames = pq.read_table(rundir / "frames.parquet").to_pylist()
    seconds = {"f0": 20.2, "f1": 0.3, "f3": 0.1}
    for row in frames:
        row["depth_seconds"] = seconds.get(row["frame_id"], row["depth_seconds"])
    pq.write_table(pa.Table.from_pylist(frames), rundir / "frames.parquet")
    table = evaluate_run(rundir)
    scored = _value(table, frame_id=AGGREGATE, product="depth", method="arroyo", metric="n_frames")
    assert scored == 3
    median = _value(
        table, frame_id=AGGREGATE, product="depth", method="arroyo", metric="seconds_per_frame"
    )
    assert median == pytest.approx(0.3)


def test_a_run_cannot_start_while_evaluate_scores(rundir: Path, monkeypatch):
    """Regression: a run started while `arroyo evaluate` scored removed evaluation.parquet,
    which evaluate then wrote back with the scores of the products the run replaced.
    Evaluate now holds the run directory's lock while it scores and writes."""
    import pipeline.evaluate
    from pipeline.errors import RunLockedError
    from pipeline.lock import RunLock

    real = pipeline.evaluate._score_run
    refused = []

    def score_while_a_run_starts(*args):
        try:
            with RunLock(rundir):
                pass
        except RunLockedError as exc:
            refused.append(str(exc))
        return real(*args)

    monkeypatch.setattr(pipeline.evaluate, "_score_run", score_while_a_run_starts)
    assert evaluate_run(rundir).num_rows > 0
    assert refused and "in use by arroyo pid" in refused[0]
    with RunLock(rundir):  # released afterwards
        pass


def test_regression_empty_truth_directory_did_not_name_the_layout_expected():
    # a user's [truth] dir without arroyo synth's files: 'nothing to score' and no hint
    text = format_evaluation(EVALUATION_SCHEMA.empty_table())
    assert text.startswith("nothing to score") and "<frame_id>.npz" in text
    assert "docs/synth.md" in text
