"""Issue 9: every kind of bad frame fails alone, with a message naming the file and cause."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
import zarr

from conftest import write_archive
from pipeline.runner import run

STAGES = "arroyo_ingest_stages"
SHAPE = (40, 48)


def _png(shape=SHAPE, dtype=np.uint8, channels=None, value=None) -> bytes:
    rng = np.random.default_rng(1)
    full = shape + ((channels,) if channels else ())
    info = np.iinfo(dtype)
    image = (
        rng.integers(0, info.max, size=full, dtype=dtype)
        if value is None
        else np.full(full, value, dtype)
    )
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def _encoded(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def _texture() -> np.ndarray:
    return np.random.default_rng(2).integers(0, 256, size=SHAPE, dtype=np.uint8)


def _float_tiff_with_nan() -> bytes:
    image = np.random.default_rng(3).random(SHAPE, dtype=np.float32)
    image[5, 5] = np.nan
    return _encoded(".tiff", image)


# case -> (how to damage frame f001's left image, expected status, words in the message)
FAILING = {
    "zero bytes": (lambda p: p.write_bytes(b""), ["empty"]),
    "truncated png": (lambda p: p.write_bytes(_png()[:200]), ["truncated"]),
    "truncated tiff": (
        lambda p: _write_as(p, ".tiff", _encoded(".tiff", _texture())[:300]),
        ["truncated"],
    ),
    "truncated jpeg": (
        lambda p: _write_as(p, ".jpg", _encoded(".jpg", _texture())[:300]),
        ["truncated"],
    ),
    "random bytes": (lambda p: p.write_bytes(os.urandom(5000)), ["unrecognised content"]),
    "unsupported gif": (lambda p: p.write_bytes(b"GIF89a" + bytes(100)), ["GIF"]),
    "directory": (lambda p: (p.unlink(), p.mkdir()), ["directory"]),
    "missing": (lambda p: p.unlink(), ["missing file"]),
    "float nan": (lambda p: _write_as(p, ".tiff", _float_tiff_with_nan()), ["NaN"]),
    "size mismatch": (lambda p: p.write_bytes(_png(shape=(40, 40))), ["40x40"]),
    "much larger": (lambda p: p.write_bytes(_png(shape=(2000, 2400))), ["2000x2400"]),
}

SUCCEEDING = {
    "colour": (lambda p: p.write_bytes(_png(channels=3)), "gray"),
    "16-bit": (lambda p: p.write_bytes(_png(dtype=np.uint16)), "16-bit"),
    "constant": (lambda p: p.write_bytes(_png(value=128)), None),
    "saturated": (lambda p: p.write_bytes(_png(value=255)), None),
}


def _write_as(path: Path, ext: str, data: bytes) -> None:
    """Replace the image by a file of another format, updating the index to point at it."""
    target = path.with_suffix(ext)
    target.write_bytes(data)
    path.unlink()
    index = path.parent.parent / "frames.csv"
    index.write_text(index.read_text().replace(path.name, target.name))


def _run(tmp_path: Path, damage) -> tuple[dict, Path]:
    catalog = write_archive(tmp_path / "archive", frames=3, shape=SHAPE)
    damage(tmp_path / "archive" / "images" / "f001_left.png")
    out = tmp_path / "run"
    summary = run(catalog, out, scheduler="synchronous", stage_package=STAGES)
    frames = {r["frame_id"]: r for r in pq.read_table(out / "frames.parquet").to_pylist()}
    return {"summary": summary, "frames": frames}, out


@pytest.mark.parametrize("case", sorted(FAILING))
def test_bad_frame_fails_alone_with_a_clear_message(tmp_path, case):
    damage, words = FAILING[case]
    result, out = _run(tmp_path, damage)
    frames = result["frames"]
    assert result["summary"].exit_code == 1
    assert frames["f000"]["status"] == "done" and frames["f002"]["status"] == "done"
    bad = frames["f001"]
    assert bad["status"] == "failed" and bad["failed_stage"] == "ingest"
    assert "f001_left" in bad["error"], bad["error"]
    for word in words:
        assert word.lower() in bad["error"].lower(), bad["error"]
    # nothing partial: no rows and no written slab for the failed frame
    rows = ds.dataset(out / "tallies.parquet").to_table()
    assert "f001" not in set(rows["frame_id"].to_pylist())
    left = zarr.open_array(out / "products.zarr" / "left", mode="r")
    assert not np.asarray(left[1]).any()


@pytest.mark.parametrize("case", sorted(SUCCEEDING))
def test_unusual_but_valid_frames_complete(tmp_path, case):
    damage, note = SUCCEEDING[case]
    result, _out = _run(tmp_path, damage)
    frame = result["frames"]["f001"]
    assert frame["status"] == "done", frame["error"]
    if note:
        assert note in (frame["notes"] or ""), frame["notes"]


def test_left_and_right_of_different_size_name_both_files(tmp_path):
    def damage(path: Path) -> None:
        path.write_bytes(_png(shape=(40, 44)))

    result, _out = _run(tmp_path, damage)
    error = result["frames"]["f001"]["error"]
    assert "f001_left" in error and "f001_right" in error


def test_an_odd_first_frame_does_not_set_the_archive_shape(tmp_path):
    """Bug: the archive's frame shape came from the first readable right image alone, so a
    1x1 first frame failed every good frame as 'wrong size'; the most common size wins."""
    catalog = write_archive(tmp_path / "archive", frames=4, shape=SHAPE)
    for side in ("left", "right"):
        (tmp_path / "archive" / "images" / f"f000_{side}.png").write_bytes(_png(shape=(1, 1)))
    out = tmp_path / "run"
    summary = run(catalog, out, scheduler="synchronous", stage_package=STAGES)
    frames = {r["frame_id"]: r for r in pq.read_table(out / "frames.parquet").to_pylist()}
    assert summary.exit_code == 1
    assert [frames[f]["status"] for f in ("f001", "f002", "f003")] == ["done"] * 3
    assert frames["f000"]["status"] == "failed"
    assert "1x1" in frames["f000"]["error"] and "f000_left" in frames["f000"]["error"]
