"""Cache keys (pipeline/plan.py): which changes make a (frame, stage) result recompute."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
import zarr

from conftest import write_archive
from pipeline.camera import Camera
from pipeline.catalog import FrameRecord
from pipeline.errors import CatalogError, ParamError
from pipeline.graph import build_graph, discover_stages, resolve_stage_params
from pipeline.plan import format_plan, frame_keys
from pipeline.runner import run
from pipeline.stage import Param, Stage

OLD = "arroyo_ingest_v1_stages"  # ingest declared without sample_bits
NEW = "arroyo_ingest_stages"  # the real ingest of today
FRAME = FrameRecord(
    frame_id="f000",
    left=Path("l.png"),
    right=Path("r.png"),
    camera=Camera(focal_px=100.0, baseline_m=0.1),
    metadata={},
    overrides={},
)


def _keys(stages: list[Stage], overrides: dict | None = None) -> dict[str, str]:
    graph = build_graph(stages)
    params = resolve_stage_params(graph, overrides or {})
    return frame_keys(graph, params, FRAME, ("a" * 64, "b" * 64), (40, 48))


def _without_sample_bits(stage: Stage) -> Stage:
    if stage.name != "ingest":
        return stage
    params = tuple(p for p in stage.params if p.name != "sample_bits")
    return dataclasses.replace(stage, params=params, check_params=None)


def test_ingest_sample_bits_at_its_default_keeps_every_stage_key() -> None:
    """Every shipped stage's key is the one it had before ingest.sample_bits existed while
    sample_bits is at its default (16); 12 changes ingest's key and so every stage's."""
    current = discover_stages()
    before = _keys([_without_sample_bits(s) for s in current])
    assert _keys(current) == before
    assert _keys(current, {"ingest": {"sample_bits": 16}}) == before
    twelve = _keys(current, {"ingest": {"sample_bits": 12}})
    assert set(twelve) == set(before) and all(twelve[s] != before[s] for s in before)


def test_omit_default_from_key_only_omits_the_default() -> None:
    stage = next(s for s in discover_stages(NEW) if s.name == "blend")
    added = Param("gain", float, 1.0, "a parameter added later", omit_default_from_key=True)
    later = dataclasses.replace(stage, params=(*stage.params, added))
    assert later.key_params({"weight": 0.5, "gain": 1.0}) == {"weight": 0.5}
    assert later.key_params({"weight": 0.5, "gain": 2.0}) == {"weight": 0.5, "gain": 2.0}
    plain = dataclasses.replace(added, omit_default_from_key=False)
    kept = dataclasses.replace(stage, params=(*stage.params, plain))
    assert kept.key_params({"weight": 0.5, "gain": 1.0}) == {"weight": 0.5, "gain": 1.0}


def test_regression_adding_ingest_sample_bits_recomputed_existing_runs(tmp_path: Path) -> None:
    """A parameter added to a stage enters every key of that stage and of every stage after
    it: a run directory made before ingest.sample_bits existed would have recomputed every
    frame and stage. At its default the parameter is left out of the key."""
    catalog = write_archive(tmp_path / "archive", frames=2)
    out = tmp_path / "run"
    assert run(catalog, out, scheduler="synchronous", stage_package=OLD).exit_code == 0
    for overrides in ([], ["ingest.sample_bits=16"]):
        plan = run(catalog, out, overrides=overrides, dry_run=True, stage_package=NEW)
        assert plan.todo == {"f000": [], "f001": []}, overrides
    plan = run(
        catalog, out, overrides=["ingest.sample_bits=12"], dry_run=True, stage_package=NEW
    )
    stages = [s.name for s in plan.graph.stages]
    assert plan.reasons == {f: dict.fromkeys(stages, "changed") for f in ("f000", "f001")}


def _twelve_bit_archive(root: Path, extra_toml: str = "") -> Path:
    """The conftest archive with every image rewritten as 12-bit samples in 16-bit PNGs."""
    catalog = write_archive(root, frames=2, extra_toml=extra_toml)
    for path in sorted((root / "images").glob("*.png")):
        gray = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.uint16)
        assert cv2.imwrite(str(path), gray * 16 + gray // 16)
    return catalog


def test_catalog_params_sample_bits_reads_12bit_archives_at_full_range(tmp_path: Path) -> None:
    params = "\n[params]\ningest = { sample_bits = 12 }\n"
    catalog = _twelve_bit_archive(tmp_path / "archive", params)
    out = tmp_path / "run"
    assert run(catalog, out, scheduler="synchronous", stage_package=NEW).exit_code == 0
    left = np.asarray(zarr.open_array(out / "products.zarr" / "left", mode="r")[0])
    expected = cv2.imread(str(tmp_path / "archive" / "images" / "f000_left.png"), -1) >> 4
    np.testing.assert_array_equal(left, expected)
    assert left.max() == 255
    notes = pq.read_table(out / "frames.parquet").column("notes").to_pylist()
    assert all("12 significant bits" in note for note in notes), notes


def test_default_notes_of_a_12bit_archive_name_the_setting(tmp_path: Path) -> None:
    catalog = _twelve_bit_archive(tmp_path / "archive")
    out = tmp_path / "run"
    assert run(catalog, out, scheduler="synchronous", stage_package=NEW).exit_code == 0
    assert int(np.asarray(zarr.open_array(out / "products.zarr" / "left", mode="r")).max()) <= 15
    notes = pq.read_table(out / "frames.parquet").column("notes").to_pylist()
    assert all("set ingest.sample_bits = 12" in note for note in notes), notes


@pytest.mark.parametrize(
    ("toml", "overrides", "fragments"),
    [
        ("ingest = { sample_bits = 17 }", [], ["catalog.toml: [params]", "from 8 to 16, got 17"]),
        ("ingest = { sample_bits = '12' }", [], ["[params]", "expects int, got str '12'"]),
        ("", ["ingest.sample_bits=twelve"], ["--set", "expects int, got 'twelve'"]),
        ("", ["ingest.sample_bits=4"], ["--set", "got 4; set it to the camera's bit depth"]),
    ],
)
def test_bad_sample_bits_stop_the_run_before_any_work(
    tmp_path: Path, toml: str, overrides: list[str], fragments: list[str]
) -> None:
    catalog = write_archive(tmp_path / "archive", frames=1, extra_toml=f"\n[params]\n{toml}\n")
    with pytest.raises(ParamError) as info:
        run(catalog, tmp_path / "run", overrides=overrides, dry_run=True, stage_package=NEW)
    for fragment in fragments:
        assert fragment in str(info.value), str(info.value)
    assert not (tmp_path / "run").exists()


def test_regression_metadata_column_named_like_a_stage_figure_was_lost(tmp_path: Path) -> None:
    # frames.parquet kept the engine's `ingest_seconds` and dropped the user's column
    catalog = write_archive(tmp_path / "archive", frames=1)
    index = tmp_path / "archive" / "frames.csv"
    index.write_text(index.read_text().replace(",site", ",ingest_seconds"))
    with pytest.raises(CatalogError, match="'ingest_seconds'.*'ingest_...'.*my_ingest_seconds"):
        run(catalog, tmp_path / "run", dry_run=True, stage_package=NEW)
    assert not (tmp_path / "run").exists()
    index.write_text(index.read_text().replace(",ingest_seconds", ",ingestseconds"))
    assert run(catalog, tmp_path / "run", dry_run=True, stage_package=NEW).frames


def test_regression_a_pair_listed_twice_ran_twice_without_a_word(tmp_path: Path) -> None:
    # a user's index listed one pair under two frame ids: both ran and every query and
    # size-frequency fit counted its rocks twice
    catalog = write_archive(tmp_path / "archive", frames=3)
    index = tmp_path / "archive" / "frames.csv"
    header, *rows = index.read_text().splitlines()
    rows[2] = rows[0].replace("f000,", "f002,", 1)
    index.write_text("\n".join([header, *rows]) + "\n")
    plan = run(catalog, tmp_path / "run", dry_run=True, stage_package=NEW)
    assert plan.duplicates == {"f002": "f000"}
    assert "same images as an earlier frame: f002 = f000" in format_plan(plan)
    summary = run(catalog, tmp_path / "run", scheduler="synchronous", stage_package=NEW)
    assert summary.duplicates == {"f002": "f000"}
    (tmp_path / "archive" / "images" / "f000_left.png").unlink()  # unreadable: not a pair
    assert run(catalog, tmp_path / "run", dry_run=True, stage_package=NEW).duplicates == {}
