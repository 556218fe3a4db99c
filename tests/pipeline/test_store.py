"""pipeline.store: frame slabs written straight to chunk files equal zarr's own writes."""

from __future__ import annotations

import itertools
import tempfile
import uuid
import warnings
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import zarr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
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


@pytest.mark.parametrize("sharded", [False, True], ids=["chunk-files", "frame-shards"])
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
    tmp_path, dtype, shape, chunks, compressor, sharded
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
            shards=_frame_shard(shape, chunks) if sharded else None,
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


@pytest.mark.parametrize(
    ("shards", "location"),
    [((2, 8, 8), "end"), ((1, 8, 8), "start")],
    ids=["shard-of-two-frames", "index-first"],
)
def test_shards_the_slab_writer_does_not_know_are_written_through_zarr(
    tmp_path, shards, location
):
    # a shard shared by two frames would need a read-modify-write: zarr does it
    zarr.create_array(
        tmp_path / "products.zarr" / "s",
        shape=(2, 8, 8),
        chunks=(1, 4, 4),
        shards={"shape": shards, "index_location": location},
        dtype="float32",
    )
    assert pipeline.store._slab_writer(tmp_path / "products.zarr" / "s") is None
    data = np.arange(64, dtype="float32").reshape(8, 8)
    write_frame_array(tmp_path, "s", 1, data)
    np.testing.assert_array_equal(read_frame_array(tmp_path, "s", 1), data)


def _frame_shard(shape: tuple[int, ...], chunks: tuple[int, ...]) -> tuple[int, ...]:
    """One frame per shard, rounded up to whole chunks (as ensure_zarr's frame_shard)."""
    return (1, *(-(-n // c) * c for n, c in zip(shape, chunks, strict=True)))


_DTYPES = ["float32", "float64", "uint8", "uint16", "int8", "int32", "bool"]  # the products'


@st.composite
def _frames(draw: st.DrawFn) -> tuple[np.ndarray, tuple[int, ...], np.ndarray]:
    """Two frames of a random product dtype and shape (not a multiple of the chunk), chunks,
    and a fill value; some chunks of the frames all fill, sometimes a whole frame."""
    dtype = np.dtype(draw(st.sampled_from(_DTYPES)))
    shape = tuple(draw(st.lists(st.integers(1, 40), min_size=1, max_size=2)))
    chunks = tuple(draw(st.integers(1, n)) for n in shape)
    fill = np.asarray(np.nan if dtype.kind == "f" else 0, dtype=dtype)
    if dtype.kind == "f" and draw(st.booleans()):
        fill = np.zeros((), dtype)  # a 0.0 fill: -0.0 is data, stored
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if dtype.kind == "f":
        data = rng.normal(0.0, 3.0, size=(2, *shape)).astype(dtype)
        data[rng.random(data.shape) < 0.1] = -0.0
        data[rng.random(data.shape) < 0.1] = np.nan
    elif dtype.kind == "b":
        data = rng.random((2, *shape)) < 0.5
    else:
        info = np.iinfo(dtype)
        data = rng.integers(info.min, info.max, size=(2, *shape), endpoint=True, dtype=dtype)
    blank = draw(st.sampled_from(["none", "some chunks", "frame"]))
    for starts in itertools.product(*(range(0, n, c) for n, c in zip(shape, chunks, strict=True))):
        if blank == "frame" or (blank == "some chunks" and rng.random() < 0.5):
            window = tuple(slice(s, s + c) for s, c in zip(starts, chunks, strict=True))
            data[(1, *window)] = fill
    return data, chunks, fill


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames=_frames())
def test_frame_shards_round_trip_as_zarr_writes_and_reads_them(frames):
    """Property: a one-frame shard the slab writer writes is byte for byte zarr's shard of
    the same frame (Morton order, fill-only inner chunks left out, crc32c index; a shard of
    all fill removed), and zarr and xarray read it back: the whole frame and single tiles."""
    xarray = pytest.importorskip("xarray")
    data, chunks, fill = frames
    shape = data.shape[1:]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        group = zarr.open_group(root / "products.zarr", mode="w")
        for name in ("ours", "zarr"):
            group.create_array(
                name,
                shape=data.shape,
                chunks=(1, *chunks),
                shards=_frame_shard(shape, chunks),
                dtype=data.dtype,
                fill_value=fill,
                compressors=compressor_for(data.dtype),
                dimension_names=("frame", *(f"d{i}" for i in range(len(shape)))),
            )
        assert pipeline.store._slab_writer(root / "products.zarr" / "ours") is not None
        reference = zarr.open_array(root / "products.zarr" / "zarr", mode="r+")
        for k in (0, 1, 0):  # frame 0 again: its shard replaced whole
            write_frame_array(root, "ours", k, data[k])
            reference[k] = data[k]
        assert _chunk_files(root / "products.zarr" / "ours") == _chunk_files(
            root / "products.zarr" / "zarr"
        )
        ours = zarr.open_array(root / "products.zarr" / "ours", mode="r")
        tile = tuple(slice(0, c) for c in chunks)
        for k in range(2):
            np.testing.assert_array_equal(ours[k], data[k])  # NaN == NaN; -0.0 == 0.0
            assert ours[k].tobytes() == data[k].tobytes()  # ... so compare the bits too
            np.testing.assert_array_equal(ours[(k, *tile)], data[(k, *tile)])
        with xarray.open_zarr(root / "products.zarr", consolidated=False) as ds:
            assert ds["ours"].encoding["chunks"] == (1, *chunks)  # dask reads tiles
            assert ds["ours"].values.tobytes() == data.tobytes()


def test_new_stores_get_one_shard_per_frame_and_old_stores_keep_chunk_files(tmp_path):
    """A new products.zarr holds one file per frame and array (frame-shaped shards of the
    same tiles); a store made before shards keeps one file per chunk when it is extended or
    gets a new array, and both read the same values."""
    products = {
        "left": (Product("left", dtype="uint8"), (300, 520), {}),
        "sector_low": (Product("sector_low", dtype="float32"), (8, 8), {}),
    }
    frames = {
        "left": np.arange(300 * 520, dtype=np.int64).reshape(300, 520).astype("uint8"),
        "sector_low": np.linspace(0, 1, 64, dtype="float32").reshape(8, 8),
    }
    new, old = tmp_path / "new", tmp_path / "old"
    ensure_zarr(new, ["a", "b"], products)
    with mock.patch.object(pipeline.store, "_store_is_sharded", return_value=False):
        ensure_zarr(old, ["a"], {"left": products["left"]})  # what the code before made
    ensure_zarr(old, ["a", "b"], products)  # a rerun extends it and adds an array
    tiles = {"left": 2 * 3, "sector_low": 1}  # 300x520 in tiles of 150x174
    for root in (new, old):
        for name, data in frames.items():
            for k in range(2):
                write_frame_array(root, name, k, data)
                np.testing.assert_array_equal(read_frame_array(root, name, k), data)
    group = zarr.open_group(new / "products.zarr", mode="r")
    assert group["left"].shards == pipeline.store.frame_shard((300, 520)) == (1, 300, 522)
    assert group["left"].chunks == (1, 150, 174)
    for name, n in tiles.items():
        for root, files in ((new, 1), (old, n)):
            frame = root / "products.zarr" / name / "c" / "1"
            assert len([p for p in frame.rglob("*") if p.is_file()]) == files
        assert zarr.open_group(old / "products.zarr", mode="r")[name].shards is None


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


def test_frame_shards_at_a_url_are_one_put_each_and_replace_a_damaged_shard():
    """Products at an fsspec URL: a frame's shard is encoded here and PUT whole, as
    locally. Regression: through zarr, writing a shard first reads the old one back (a GET
    per shard), so a damaged shard (crc32c mismatch) made every rerun of its frame fail."""
    import fsspec

    root = f"memory://arroyo-{uuid.uuid4().hex}"
    products = {"height": (Product("height", dtype="float32"), (30, 20), {})}
    ensure_zarr(root, ["a", "b"], products)
    data = _slabs("float32", (30, 20), np.nan)[0]
    fs = fsspec.filesystem("memory")
    shard = f"{root[len('memory://'):]}/products.zarr/height/c/1/0/0"
    write_frame_array(root, "height", 1, data)
    assert fs.find(f"{root}/products.zarr/height/c") == [f"/{shard}"]
    fs.pipe_file(shard, fs.cat_file(shard)[:-3] + b"bad")  # the index's crc32c
    with pytest.raises(ValueError, match="checksum"):
        read_frame_array(root, "height", 1)
    write_frame_array(root, "height", 1, data)
    assert read_frame_array(root, "height", 1).tobytes() == data.tobytes()
    write_frame_array(root, "height", 1, np.full((30, 20), np.nan, dtype="float32"))
    assert not fs.exists(shard)  # all fill: no shard, as zarr leaves none


@pytest.mark.parametrize(
    "grid", [(1,), (1, 1, 1), (1, 2, 2), (1, 3, 5), (1, 1, 7), (1, 4, 4), (1, 8, 3), (2, 3, 2)]
)
def test_shard_morton_order_is_zarrs(grid):
    """The shard writer keeps its own copy of zarr's inner-chunk order (zarr's is internal
    API); the bytes it writes match zarr's only while the two agree."""
    from pipeline.store import _morton_order

    indexing = pytest.importorskip("zarr.core.indexing")
    if not hasattr(indexing, "morton_order_iter"):
        pytest.skip("this zarr has no morton_order_iter to compare with")
    assert list(_morton_order(grid)) == [tuple(c) for c in indexing.morton_order_iter(grid)]
    assert sorted(_morton_order(grid)) == sorted(np.ndindex(*grid))
