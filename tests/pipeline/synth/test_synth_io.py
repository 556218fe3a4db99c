"""Archive layout, determinism and caching of ``synthesize_archive`` / ``ensure_archive``."""

from __future__ import annotations

import csv
import hashlib
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.synth import ensure_archive, frame_seed, render_pair, synthesize_archive
from pipeline.synth.io import COMPLETE_MARKER

SIZE = 64


def _digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "lab"
    return synthesize_archive("lab", out, frames=3, seed=4, size=SIZE)


def test_layout_round_trip(archive):
    catalog = tomllib.loads((archive / "catalog.toml").read_text())
    assert catalog["archive"]["name"] == "lab"
    assert catalog["camera"]["reference"] == "right"
    assert catalog["camera"]["baseline_m"] == pytest.approx(0.07)
    assert catalog["frames"]["index"] == "frames.csv"
    assert catalog["truth"]["dir"] == "truth"
    with open(archive / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["frame_id", "left", "right", "archetype", "seed"]
    assert [r["frame_id"] for r in rows] == ["lab_0000", "lab_0001", "lab_0002"]
    import cv2

    for row in rows:
        left = cv2.imread(str(archive / row["left"]), cv2.IMREAD_UNCHANGED)
        right = cv2.imread(str(archive / row["right"]), cv2.IMREAD_UNCHANGED)
        assert left.shape == right.shape == (SIZE, SIZE) and left.dtype == np.uint8
        with np.load(archive / "truth" / f"{row['frame_id']}.npz") as truth:
            assert set(truth.files) == {"disparity", "range", "height", "labels", "occluded"}
            assert truth["disparity"].dtype == np.float32
            assert truth["labels"].dtype == np.int32
            assert truth["occluded"].dtype == bool
        # the frame is exactly render_pair of the recorded seed
        again = render_pair("lab", seed=int(row["seed"]), size=SIZE)
        np.testing.assert_array_equal(again[1], right)
    rocks = pq.read_table(archive / "truth" / "rocks.parquet").to_pandas()
    for column in ("frame_id", "rock_id", "x_m", "y_m", "z_m", "width_m", "length_m",
                   "height_m", "range_m", "albedo", "polarity", "visible_px", "size_class",
                   "buried_fraction"):  # fmt: skip
        assert column in rocks.columns
    assert set(rocks["frame_id"]) <= {r["frame_id"] for r in rows}
    assert (archive / COMPLETE_MARKER).is_file()


def test_same_arguments_same_bytes(archive, tmp_path):
    again = synthesize_archive("lab", tmp_path / "again", frames=3, seed=4, size=SIZE)
    assert _digest(again) == _digest(archive)


def test_frame_independent_of_count(archive, tmp_path):
    two = synthesize_archive("lab", tmp_path / "two", frames=2, seed=4, size=SIZE)
    for name in ("images/lab_0001_right.png", "truth/lab_0001.npz"):
        assert (two / name).read_bytes() == (archive / name).read_bytes()
    assert frame_seed(4, 1) != frame_seed(4, 2) != frame_seed(5, 1)


def test_refuses_foreign_directory(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not an empty directory"):
        synthesize_archive("lab", tmp_path, frames=1, size=SIZE)
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_out_below_a_file_is_a_clear_error(tmp_path):
    """Regression: `arroyo synth --out FILE/x` ended in a FileExistsError traceback."""
    (tmp_path / "afile").write_text("mine")
    with pytest.raises(ValueError, match="cannot create .*afile"):
        synthesize_archive("lab", tmp_path / "afile" / "x", frames=1, size=SIZE)
    assert (tmp_path / "afile").read_text() == "mine"


def test_bad_frames_rejected(tmp_path):
    with pytest.raises(ValueError):
        synthesize_archive("lab", tmp_path / "x", frames=0, size=SIZE)
    with pytest.raises(TypeError):
        synthesize_archive("lab", tmp_path / "x", frames="3", size=SIZE)


def test_ensure_archive_renders_once(tmp_path, monkeypatch):
    monkeypatch.setenv("ARROYO_CACHE", str(tmp_path))
    catalog = ensure_archive("dunes", frames=1, seed=0, size=SIZE)
    assert catalog.name == "catalog.toml" and catalog.is_file()
    assert catalog.parent.parent.parent == tmp_path
    stamp = catalog.stat().st_mtime_ns
    assert ensure_archive("dunes", frames=1, seed=0, size=SIZE) == catalog
    assert catalog.stat().st_mtime_ns == stamp  # not rendered again
    leftovers = [p for p in catalog.parent.parent.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_ensure_archive_redoes_incomplete(tmp_path):
    catalog = ensure_archive("dunes", frames=1, seed=0, cache_dir=tmp_path, size=SIZE)
    (catalog.parent / COMPLETE_MARKER).unlink()  # as if killed before completion
    catalog2 = ensure_archive("dunes", frames=1, seed=0, cache_dir=tmp_path, size=SIZE)
    assert (catalog2.parent / COMPLETE_MARKER).is_file()


def test_shipped_catalogs_name_valid_archetypes():
    from pipeline.synth.archetypes import get_spec

    root = Path(__file__).resolve().parents[3] / "catalogs"
    names = {"lab", "mojave", "mojave_viking", "dunes", "lava"}
    for name in names:
        data = tomllib.loads((root / f"{name}.toml").read_text())
        assert data["archive"]["name"] == name
        synth = data["synth"]
        get_spec(synth["archetype"], synth.get("variant"))
        assert synth["frames"] >= 1 and synth["seed"] >= 0


def test_ensure_archive_keeps_the_archive_a_concurrent_caller_completed(tmp_path, monkeypatch):
    """Regression: two `arroyo run catalogs/lab.toml` started together on an empty cache
    both rendered; the later one removed the earlier one's complete archive to put its own
    in place, while the earlier run was reading its frames (they failed as missing)."""
    import pipeline.synth.io as synth_io

    render = synth_io._render_into
    in_use: list[Path] = []
    calls: list[Path] = []

    def render_while_another_finishes(directory, *args):
        calls.append(directory)
        if len(calls) == 1:  # the other caller renders and completes during our rendering
            other = ensure_archive("dunes", frames=1, seed=0, cache_dir=tmp_path, size=SIZE)
            (other.parent / "being-read").write_text("a run reads these frames")
            in_use.append(other)
        render(directory, *args)

    monkeypatch.setattr(synth_io, "_render_into", render_while_another_finishes)
    catalog = ensure_archive("dunes", frames=1, seed=0, cache_dir=tmp_path, size=SIZE)
    assert catalog == in_use[0]
    assert (catalog.parent / "being-read").is_file()  # the same directory, untouched
    leftovers = [p for p in catalog.parent.parent.iterdir() if p.name.startswith(".")]
    assert leftovers == []
