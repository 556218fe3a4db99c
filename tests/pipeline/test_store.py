"""pipeline.store: frame slabs written straight to chunk files equal zarr's own writes."""

from __future__ import annotations

import uuid
import warnings
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, ZstdCodec

import pipeline.store
from pipeline.stage import Product
from pipeline.store import (
    coerce_products_root,
    compressor_for,
    ensure_zarr,
    products_root,
    read_frame_array,
    read_product_file,
    remove_orphan_temp_files,
    write_frame_array,
    write_product_file,
    zarr_location,
)

_FRAMES = 4


def _chunk_files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != "zarr.json"
    }


def _slabs(dtype: str, shape: tuple[int, ...], fill: float | int | bool) -> list[np.ndarray]:
    """Noisy frames, one with a fill-only tile, one that is all fill (no chunk files)."""
    rng = np.random.default_rng(7)
    frames = []
    for k in range(_FRAMES):
        if np.dtype(dtype).kind == "f":
            data = rng.normal(5.0, 2.0, size=shape).astype(dtype)
            data[rng.random(shape) < 0.2] = np.nan
            data.flat[0] = -0.0
        elif np.dtype(dtype).kind == "b":
            data = rng.random(shape) < 0.3
        else:
            data = rng.integers(0, 50, size=shape).astype(dtype)
        if k == 1:
            data[: shape[0] // 2] = fill
        if k == 3:
            data[...] = fill
        frames.append(data)
    return frames


@pytest.mark.parametrize(
    ("dtype", "shape", "chunks", "compressor"),
    [
        ("float32", (40, 30), (20, 15), "blosc"),
        ("float32", (41, 29), (21, 15), "blosc"),  # edge chunks padded with the fill value
        ("float64", (4,), (4,), "blosc"),
        ("uint8", (40, 30), (20, 15), "zstd"),
        ("int32", (41, 30), (21, 30), "zstd"),
        ("int8", (16, 16), (16, 16), "zstd"),
        ("bool", (16, 16), (16, 16), "zstd"),
        ("float32", (20, 20), (10, 10), None),
    ],
)
def test_slab_writer_writes_the_same_chunk_files_as_zarr(
    tmp_path, dtype, shape, chunks, compressor
):
    fill = np.nan if np.dtype(dtype).kind == "f" else np.zeros((), dtype)[()]
    compressors = {
        "blosc": BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),
        "zstd": ZstdCodec(level=1),
        None: None,
    }[compressor]
    for name in ("ours", "zarr"):
        zarr.create_array(
            tmp_path / "products.zarr" / name,
            shape=(_FRAMES, *shape),
            chunks=(1, *chunks),
            dtype=dtype,
            fill_value=fill,
            compressors=compressors,
        )
    reference = zarr.open_array(tmp_path / "products.zarr" / "zarr", mode="r+")
    # every frame twice: the second pass replaces chunks (and removes the all-fill frame's)
    for _ in range(2):
        for k, data in enumerate(_slabs(dtype, shape, fill)):
            write_frame_array(tmp_path, "ours", k, data)
            reference[k] = data
    assert pipeline.store._slab_writer(tmp_path / "products.zarr" / "ours") is not None
    ours = _chunk_files(tmp_path / "products.zarr" / "ours")
    assert ours == _chunk_files(tmp_path / "products.zarr" / "zarr")
    assert not any(key.startswith(f"c/{_FRAMES - 1}/") for key in ours)
    for k, data in enumerate(_slabs(dtype, shape, fill)):
        np.testing.assert_array_equal(read_frame_array(tmp_path, "ours", k), data)


def test_an_all_fill_rerun_removes_the_chunks_an_earlier_attempt_wrote(tmp_path):
    zarr.create_array(
        tmp_path / "products.zarr" / "a", shape=(2, 8, 8), chunks=(1, 4, 4), dtype="int32"
    )
    write_frame_array(tmp_path, "a", 1, np.ones((8, 8), dtype="int32"))
    write_frame_array(tmp_path, "a", 1, np.zeros((8, 8), dtype="int32"))
    assert not list((tmp_path / "products.zarr" / "a").rglob("c/1/*/*"))
    assert read_frame_array(tmp_path, "a", 1).sum() == 0


def test_sharded_arrays_are_written_through_zarr(tmp_path):
    zarr.create_array(
        tmp_path / "products.zarr" / "s",
        shape=(2, 8, 8),
        chunks=(1, 4, 4),
        shards=(1, 8, 8),
        dtype="float32",
    )
    assert pipeline.store._slab_writer(tmp_path / "products.zarr" / "s") is None
    data = np.arange(64, dtype="float32").reshape(8, 8)
    write_frame_array(tmp_path, "s", 1, data)
    np.testing.assert_array_equal(read_frame_array(tmp_path, "s", 1), data)


def test_write_frame_array_rejects_a_frame_outside_the_array(tmp_path):
    zarr.create_array(tmp_path / "products.zarr" / "a", shape=(2, 4), chunks=(1, 4), dtype="u1")
    with pytest.raises(IndexError, match="frame index 2 outside"):
        write_frame_array(tmp_path, "a", 2, np.zeros(4, dtype="u1"))


def test_products_use_fast_compressors_and_open_with_xarray(tmp_path):
    xarray = pytest.importorskip("xarray")
    products = {
        "disparity": (Product("disparity", dtype="float32"), (40, 30), {"units": "px"}),
        "labels": (Product("labels", dtype="int32"), (40, 30), {}),
    }
    ensure_zarr(tmp_path, ["a", "b"], products)
    disparity = _slabs("float32", (40, 30), np.nan)[:2]
    labels = _slabs("int32", (40, 30), 0)[:2]
    for k in range(2):
        write_frame_array(tmp_path, "disparity", k, disparity[k])
        write_frame_array(tmp_path, "labels", k, labels[k])
    store = zarr.open_group(tmp_path / "products.zarr", mode="r")
    assert isinstance(store["disparity"].compressors[0], BloscCodec)
    assert isinstance(store["labels"].compressors[0], ZstdCodec)
    assert compressor_for("float32").to_dict()["configuration"]["cname"] == "lz4"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)  # consolidated metadata
        ds = xarray.open_zarr(tmp_path / "products.zarr")
        np.testing.assert_array_equal(ds["disparity"].values, np.stack(disparity))
        np.testing.assert_array_equal(ds["labels"].values, np.stack(labels))
        assert list(ds["frame"].values) == ["a", "b"]


def test_orphan_partial_files_of_killed_writes_are_removed(tmp_path):
    zarr.create_array(tmp_path / "products.zarr" / "a", shape=(1, 4), chunks=(1, 4), dtype="u1")
    write_frame_array(tmp_path, "a", 0, np.ones(4, dtype="u1"))
    orphan = tmp_path / "products.zarr" / "a" / "c" / "0" / "0.0123abcd.partial"
    orphan.write_bytes(b"half a chunk")
    assert remove_orphan_temp_files(tmp_path) == 1
    assert not orphan.exists()


# -- products roots ---------------------------------------------------------------------------
def test_coerce_products_root_makes_local_paths_absolute_and_keeps_urls(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert coerce_products_root("shared/run1") == str(tmp_path / "shared" / "run1")
    assert coerce_products_root("memory://bucket/prefix/") == "memory://bucket/prefix"
    assert zarr_location("memory://b/p") == "memory://b/p/products.zarr"
    assert zarr_location(tmp_path) == str(tmp_path / "products.zarr")
    assert products_root(tmp_path, {"products": None}) == str(tmp_path)
    assert products_root(tmp_path, {"products": "s3://b/p"}) == "s3://b/p"


@pytest.mark.parametrize(
    ("root", "error", "message"),
    [
        ("nosuch://b/p", ValueError, "unknown storage protocol 'nosuch'"),
        ("   ", ValueError, "products root is empty"),
        (42, TypeError, "path or URL string, got int"),
    ],
)
def test_coerce_products_root_names_what_is_wrong(root, error, message):
    with pytest.raises(error, match=message):
        coerce_products_root(root)


@pytest.mark.parametrize("kind", ["local", "url"])
def test_product_files_round_trip_under_a_directory_or_an_fsspec_url(tmp_path, kind):
    root = str(tmp_path) if kind == "local" else f"memory://arroyo-{uuid.uuid4().hex}"
    assert read_product_file(root, "quicklooks/f1/objects.png") is None
    write_product_file(root, "quicklooks/f1/objects.png", b"\x89PNG data")
    assert read_product_file(root, "quicklooks/f1/objects.png") == b"\x89PNG data"
    write_product_file(root, "quicklooks/f1/objects.png", b"again")  # replaced whole
    assert read_product_file(root, "quicklooks/f1/objects.png") == b"again"


@pytest.mark.parametrize(("dtype", "fill"), [("int32", 0), ("float32", 0.0), ("float32", np.nan)])
def test_a_chunk_that_only_starts_with_the_fill_value_is_written_as_zarr_writes_it(
    tmp_path, dtype, fill
):
    # the fill test settles most chunks by their first element: a chunk whose first element
    # is the fill (or -0.0 for a 0.0 fill) must still go through the whole-chunk test
    for name in ("ours", "zarr"):
        zarr.create_array(
            tmp_path / "products.zarr" / name,
            shape=(1, 8, 8),
            chunks=(1, 4, 4),
            dtype=dtype,
            fill_value=fill,
            compressors=ZstdCodec(level=1),
        )
    data = np.full((8, 8), fill, dtype=dtype)
    data[0, 1] = 3  # chunk (0, 0): fill first, data after
    if np.dtype(dtype).kind == "f":
        data[4:, :4] = -0.0  # chunk (1, 0): a 0.0 fill stores -0.0 (bit patterns differ)
    write_frame_array(tmp_path, "ours", 0, data)
    zarr.open_array(tmp_path / "products.zarr" / "zarr", mode="r+")[0] = data
    ours = _chunk_files(tmp_path / "products.zarr" / "ours")
    assert "c/0/0/0" in ours
    assert ours == _chunk_files(tmp_path / "products.zarr" / "zarr")
    np.testing.assert_array_equal(read_frame_array(tmp_path, "ours", 0), data)


def test_damaged_group_metadata_says_how_to_recover(tmp_path):
    """Bug: a damaged products.zarr/zarr.json stopped `arroyo run` with the bare JSON error
    ('Expecting property name...'), naming no file."""
    from pipeline.errors import RunDirError

    products = {"labels": (Product("labels", dtype="int32"), (8, 8), {})}
    ensure_zarr(tmp_path, ["a"], products)
    meta = tmp_path / "products.zarr" / "zarr.json"
    meta.write_text("{garbage")
    with pytest.raises(RunDirError, match="products.zarr cannot be opened: its zarr.json is"):
        ensure_zarr(tmp_path, ["a"], products)
    with pytest.raises(RunDirError, match="rerun the run's catalog"):
        pipeline.store.open_products_group(tmp_path)  # evaluate, report
    meta.unlink()  # the advice: arroyo writes it anew, the arrays are kept
    assert ensure_zarr(tmp_path, ["a"], products) == set()
    assert "labels" in zarr.open_group(tmp_path / "products.zarr", mode="r")
