"""Product stores of a run directory: ``products.zarr`` and loose product files (the Parquet
tables are in :mod:`pipeline.tables`).

Layout under the products root (by default RUNDIR)::

    products.zarr/                 zarr v3 group; one array per array product, dims
                                   (frame, ...); chunks: one frame x tiles; coordinate `frame`
      <array>/c/<frame>/0/0        one shard per frame: the frame's tiles in one file
    quicklooks/<frame_id>/*.png    loose files of ``files`` products

A new store gets one shard per frame and array (:func:`frame_shard`: 13 files per frame
instead of 34), holding the same tiles (:func:`tile_chunks`) as inner chunks, so readers
still read single tiles; a store made before shards keeps one file per chunk (the arrays it
gains later too), and both are written and read. A shard holds one frame only, so it is
owned by the task that writes the frame, as a chunk is: it is written whole, never read back
or merged with another frame's bytes.

Every file is written to a temporary name in its final directory, then renamed, so a reader
never sees half a file (the driver flushes the filesystem before it records a frame). Zarr
arrays are created once by the driver; workers only write whole chunk-aligned (or
shard-aligned) frame slabs of existing arrays.

The array products and loose files (what workers write) may live elsewhere than the run
directory: a *products root* is either a local directory (a shared filesystem) or an fsspec
URL such as ``s3://bucket/prefix``; the run records it in ``run.json`` (``products``) and every
reader goes through :func:`products_root`. On an object store each shard, chunk or file is
one PUT, which is atomic, so no temporaries are involved. The journal, staged parts and published
tables stay in the run directory, which only the driver writes.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import functools
import hashlib
import itertools
import math
import os
import struct
import uuid
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import google_crc32c
import numcodecs
import numpy as np
import zarr
from zarr.codecs import BloscCodec, ZstdCodec
from zarr.core.metadata import ArrayV3Metadata

from .errors import RunDirError, StoreError
from .stage import Product

__all__ = [
    "ZARR_NAME",
    "TMP_MARK",
    "is_url",
    "coerce_products_root",
    "products_root",
    "zarr_location",
    "open_products_group",
    "check_products_reachable",
    "write_product_file",
    "remove_other_product_files",
    "read_product_file",
    "tile_chunks",
    "frame_shard",
    "compressor_for",
    "atomic_write_bytes",
    "ensure_zarr",
    "check_frame_list",
    "claim_products",
    "products_writer",
    "WRITER_ATTR",
    "write_frame_array",
    "read_frame_array",
    "frame_checksum",
    "remove_orphan_temp_files",
    "is_disk_full",
    "file_sha256",
    "sync_filesystem",
    "disk_full_error",
]

ZARR_NAME = "products.zarr"
TMP_MARK = ".tmp-"
_MAX_TILE = 256
_DISK_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EROFS}


def is_disk_full(exc: BaseException) -> bool:
    """True for the OSErrors that mean "no space / cannot write here", not a bad frame."""
    return isinstance(exc, OSError) and exc.errno in _DISK_FULL


def tile_chunks(shape: Sequence[int]) -> tuple[int, ...]:
    """Chunk shape of one frame: tiles of at most 256 px, equal-sized, so that 500 px
    frames split into 250 px tiles, which the 8x8 and 16x16 sector grids align with."""
    return tuple(math.ceil(n / math.ceil(n / _MAX_TILE)) if n else 1 for n in shape)


def compressor_for(dtype: np.dtype | str) -> BloscCodec | ZstdCodec:
    """The compressor of a new product array of this dtype.

    Float products (disparity, range, residual, height) carry noisy mantissas: zstd's
    default level squeezes a 250x250 float32 tile only ~1.3x and costs ~6 ms, blosc lz4 with
    byte shuffle reaches 1.2-1.6x in ~1 ms. Integer, uint8 and bool products compress as
    well with zstd level 1 as with the default level 3, at a quarter of the time (measured
    on mojave frames, ``numcodecs`` encode of each 250x250 tile).
    """
    if np.dtype(dtype).kind == "f":
        return BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")
    return ZstdCodec(level=1)


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def frame_checksum(data: np.ndarray) -> str:
    """sha256 of a frame slab's bytes (C order), recorded to verify the store later."""
    return hashlib.sha256(np.ascontiguousarray(data).data).hexdigest()  # no copy


def atomic_write_bytes(path: Path, data: bytes, *, durable: bool = True) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename.

    ``durable=True`` fsyncs the temporary first. Workers pass ``False`` for a frame's files:
    the driver flushes the filesystem (:func:`sync_filesystem`) before it records the frame
    complete, as for the frame's zarr chunks, so one flush per batch replaces one per file.
    """
    tmp = path.with_name(f".{path.name}{TMP_MARK}{uuid.uuid4().hex[:8]}")
    try:
        fh = open(tmp, "wb")
    except FileNotFoundError:  # a new directory: created only then, not checked per file
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(tmp, "wb")
    try:
        with fh:
            fh.write(data)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def remove_orphan_temp_files(rundir: Path) -> int:
    """Delete temporary files left by a killed run; returns how many."""
    removed = 0
    for pattern in (f"*{TMP_MARK}*", "*.partial"):  # ours, and zarr's chunk temporaries
        for path in Path(rundir).rglob(pattern):
            if path.is_file():
                path.unlink(missing_ok=True)
                removed += 1
    return removed


# -- where products live ------------------------------------------------------------------
def is_url(root: str | os.PathLike[str]) -> bool:
    """Whether a products root is an fsspec URL (``s3://...``) rather than a local path."""
    return "://" in str(root)


def coerce_products_root(root: str | os.PathLike[str]) -> str:
    """Validate a products root given by a user; return its canonical form.

    A local path is made absolute (workers may run elsewhere in the tree); a URL must name
    a protocol fsspec knows and whose implementation is installed (``s3://`` needs
    ``s3fs``). Raises ValueError otherwise.
    """
    if not isinstance(root, str | os.PathLike):
        raise TypeError(
            f"the products root must be a path or URL string, got {type(root).__name__}"
        )
    text = str(root)
    if not text.strip():
        raise ValueError("the products root is empty; give a directory or a URL like s3://b/p")
    if not is_url(text):
        return str(Path(text).expanduser().resolve())
    import fsspec

    protocol = text.split("://", 1)[0]
    try:
        fsspec.get_filesystem_class(protocol)
    except ValueError:
        raise ValueError(
            f"unknown storage protocol {protocol!r} in products URL {text!r}; expected one "
            f"fsspec knows (s3, gcs, abfs, file...), see fsspec.available_protocols()"
        ) from None
    except ImportError as exc:
        raise ValueError(
            f"products URL {text!r} needs the {protocol!r} filesystem, which is not "
            f"installed ({exc}); install it (for s3: pip install s3fs) and rerun"
        ) from None
    return text.rstrip("/")


def products_root(rundir: str | os.PathLike[str], meta: Mapping[str, Any] | None = None) -> str:
    """Where a run's array products and files live: ``run.json``'s ``products`` (``meta``),
    else the run directory itself."""
    recorded = (meta or {}).get("products")
    return str(recorded) if recorded else str(rundir)


def zarr_location(root: str | os.PathLike[str]) -> str:
    """``products.zarr`` under a products root, as zarr and xarray accept it."""
    text = str(root)
    return f"{text.rstrip('/')}/{ZARR_NAME}" if is_url(text) else str(Path(text) / ZARR_NAME)


def _remote(url: str) -> tuple[Any, str]:
    import fsspec.core

    fs, path = fsspec.core.url_to_fs(url)
    return fs, path


def check_products_reachable(
    rundir: str | os.PathLike[str], root: str, *, doing: str, hint: str = ""
) -> None:
    """Raise when a run's products root recorded outside its run directory is not there.

    Parameters
    ----------
    rundir : path
        The run directory, for the message.
    root : str
        The recorded products root (a directory or an fsspec URL).
    doing : str
        What the caller did not do, for the message ("nothing was checked or reset").
    hint : str, optional
        A last sentence for a missing local root.

    Raises
    ------
    RunDirError
        A local root that does not exist (moved, unmounted), a URL without the store.
    StoreError
        A URL that cannot be reached (credentials, network, bucket).
    """
    if not is_url(root):
        if not Path(root).is_dir():
            raise RunDirError(
                f"the products of {rundir} are recorded at {root}, which does not exist "
                f"(moved or unmounted?); {doing}. Mount or move them back there" + hint
            )
        return
    try:
        fs, path = _remote(zarr_location(root))
        found = fs.exists(f"{path}/zarr.json")
    except Exception as exc:  # noqa: BLE001 - credentials, network, missing bucket
        raise StoreError(
            f"cannot reach the products of {rundir} at {root}: {type(exc).__name__}: {exc}; "
            f"{doing}. Check the URL, credentials and network"
        ) from None
    if not found:
        raise RunDirError(
            f"the products of {rundir} are recorded at {root}, but {ZARR_NAME} is not there; "
            f"{doing}. Check the URL (a moved bucket or prefix?)"
        )


def open_products_group(root: str | os.PathLike[str]) -> zarr.Group | None:
    """The run's product group, read-only; None when the run wrote no array yet."""
    location = zarr_location(root)
    if is_url(location):
        fs, path = _remote(location)
        if not fs.exists(f"{path}/zarr.json"):
            return None
    elif not Path(location, "zarr.json").is_file():
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)
        try:
            return zarr.open_group(location, mode="r")
        except ValueError as exc:
            raise RunDirError(
                f"the product store {location} cannot be opened: its zarr.json is damaged "
                f"({exc}); remove that zarr.json and rerun the run's catalog into its directory"
            ) from None


def write_product_file(root: str | os.PathLike[str], rel: str, content: bytes) -> None:
    """Write a loose product file (a quicklook) under a products root.

    Locally through a temporary and a rename, flushed later by the driver's
    :func:`sync_filesystem`; on an object store as one PUT, atomic by itself.
    """
    if is_url(root):
        fs, path = _remote(f"{str(root).rstrip('/')}/{rel}")
        fs.pipe_file(path, content)
    else:
        atomic_write_bytes(Path(root) / rel, content, durable=False)


def remove_other_product_files(
    root: str | os.PathLike[str], folder: str, keep: Iterable[str]
) -> None:
    """Remove the files under ``folder`` (relative to a products root) not in ``keep``.

    A files product's frame folder holds what its stage wrote for the frame's current
    result only: the quicklooks of a frame that ``quicklook.every`` now skips were an
    earlier run's drawing of earlier labels, and the report showed them as current.
    """
    kept = {str(k) for k in keep}
    if is_url(root):
        fs, base = _remote(f"{str(root).rstrip('/')}/{folder}")
        if not fs.exists(base):
            return
        prefix = base.rstrip("/") + "/"
        for path in fs.find(base):
            if f"{folder}/{path[len(prefix):]}" not in kept:
                fs.rm_file(path)
        return
    directory = Path(root) / folder
    if not directory.is_dir():
        return
    for path in directory.rglob("*"):
        if path.is_file() and path.relative_to(root).as_posix() not in kept:
            path.unlink()
    for path in sorted(directory.rglob("*"), reverse=True) + [directory]:
        if path.is_dir() and not any(path.iterdir()):
            path.rmdir()  # deepest first: an emptied folder goes too


def read_product_file(root: str | os.PathLike[str], rel: str) -> bytes | None:
    """A loose product file's bytes, or None when it does not exist."""
    if is_url(root):
        fs, path = _remote(f"{str(root).rstrip('/')}/{rel}")
        try:
            return bytes(fs.cat_file(path))
        except FileNotFoundError:
            return None
    local = Path(root) / rel
    return local.read_bytes() if local.is_file() else None


# -- zarr ---------------------------------------------------------------------------------
def _zarr_path(rundir: str | os.PathLike[str]) -> Path:
    return Path(rundir) / ZARR_NAME


WRITER_ATTR = "arroyo_owner"
"""Attribute of ``products.zarr``: the token of the run directory whose runs write it."""


def products_writer(root: str | os.PathLike[str]) -> str | None:
    """The token of the run directory that claimed the products at ``root`` (None: none)."""
    group = open_products_group(root)
    if group is None:
        return None
    writer = group.attrs.get(WRITER_ATTR)
    return str(writer) if writer else None


def claim_products(root: str | os.PathLike[str], owner: str) -> None:
    """Record ``owner``, a run directory's token, in the products at ``root``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)
        zarr.open_group(zarr_location(root), mode="a").attrs[WRITER_ATTR] = owner


def check_frame_list(root: str | os.PathLike[str], frame_ids: Sequence[str]) -> None:
    """Raise RunDirError when the products at ``root`` hold another frame list than the
    catalog's ``frame_ids`` (which may only extend it at the end); reads, never writes."""
    group = open_products_group(root)
    if group is None or "frame" not in group:
        return
    old = [str(v) for v in np.asarray(_array(group, "frame")[:]).ravel()]
    _check_frame_list(zarr_location(root), old, list(frame_ids))


def _check_frame_list(path: str, old: list[str], new: list[str]) -> None:
    if len(old) <= len(new) and old == new[: len(old)]:
        return
    if len(old) > len(new) and old[: len(new)] == new:
        what = (
            f"{len(old)} frames: the catalog's {len(new)}, then {old[len(new)]!r}..., which "
            "the catalog no longer lists"
        )
    else:
        k = next(i for i, (a, b) in enumerate(zip(old, new, strict=False)) if a != b)
        what = (
            f"{len(old)} frames whose frame {k} is {old[k]!r} where the catalog has "
            f"{new[k]!r}"
        )
    # a user who dropped a bad pair from the index was only told to start over elsewhere
    raise RunDirError(
        f"{path} holds {what}: not the catalog's frame list (a different archive, or frames "
        "removed, renamed or reordered?). A run directory's frames may only be extended at "
        "the end of the index. To leave frames out, keep them in the index and choose the "
        "others with --frames PATTERN (a failed frame may also stay: it fails alone); to "
        "drop them for good, use a new --out directory for this catalog"
    )


def ensure_zarr(
    root: str | os.PathLike[str],
    frame_ids: Sequence[str],
    arrays: Mapping[str, tuple[Product, tuple[int, ...], Mapping[str, Any]]],
) -> set[str]:
    """Create or extend ``products.zarr`` for these frames and arrays.

    New arrays get chunks of one frame x :func:`tile_chunks` tiles, stored as one shard per
    frame (:func:`frame_shard`), unless the store already holds unsharded product arrays
    (made before shards): then they get one file per chunk like the others.

    Parameters
    ----------
    root : path or str
        The products root: the run directory, another directory, or an fsspec URL.
    frame_ids : sequence of str
        All frames of the catalog, in order (the ``frame`` coordinate).
    arrays : mapping
        Product name to (product, per-frame shape, attrs).

    Returns
    -------
    recreated : set of str
        Arrays that existed with another per-frame shape (a parameter changed it) and were
        recreated empty; their stage must be redone for every frame.
    """
    path = zarr_location(root)
    try:
        group = zarr.open_group(path, mode="a")
    except ValueError as exc:  # damaged group metadata: a bare JSON message before
        raise RunDirError(
            f"the product store {path} cannot be opened: its zarr.json is damaged ({exc}); "
            "remove that zarr.json and rerun (arroyo writes it anew and `arroyo status "
            "--verify` checks the arrays), or use a new --out"
        ) from None
    n = len(frame_ids)
    ids = np.array(list(frame_ids), dtype=str)
    if "frame" in group:
        coord = _array(group, "frame")
        old = [str(v) for v in np.asarray(coord[:]).ravel()]
        _check_frame_list(path, old, list(frame_ids))
        if len(old) < n:
            coord.resize((n,))
            coord[:] = ids
    else:
        coord = group.create_array(
            "frame", shape=(n,), dtype=str, chunks=(max(n, 1),), dimension_names=("frame",)
        )
        coord[:] = ids
    recreated: set[str] = set()
    sharded = _store_is_sharded(group)
    for name, (product, frame_shape, attrs) in arrays.items():
        full = (n, *frame_shape)
        if name in group:
            existing = _array(group, name)
            if tuple(existing.shape[1:]) != tuple(frame_shape):
                del group[name]
                recreated.add(name)
            else:
                if existing.shape[0] < n:
                    existing.resize(full)
                existing.attrs.update(dict(attrs))
                continue
        chunks = (1, *tile_chunks(frame_shape))
        group.create_array(
            name,
            shape=full,
            dtype=product.dtype,
            chunks=chunks,
            shards=frame_shard(frame_shape) if sharded else None,
            fill_value=product.resolved_fill(),
            compressors=compressor_for(product.dtype or "float32"),
            dimension_names=product.dims,
            attributes=dict(attrs),
        )
    with warnings.catch_warnings():
        # Consolidated metadata is what lets `xarray.open_zarr(path)` open the store without
        # arguments; zarr warns that v3 has not standardised it yet.
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)
        zarr.consolidate_metadata(path)
    return recreated


def frame_shard(shape: Sequence[int]) -> tuple[int, ...]:
    """Shard shape of a new product array: one whole frame, (1, *shape) rounded up to whole
    :func:`tile_chunks` tiles (a shard holds whole inner chunks; those past the frame's
    edge are padded with the fill value, as unsharded edge chunks are)."""
    tiles = tile_chunks(shape)
    return (1, *(math.ceil(n / c) * c if n else c for n, c in zip(shape, tiles, strict=True)))


def _store_is_sharded(group: zarr.Group) -> bool:
    """Whether new arrays of this store get one shard per frame: yes in a new store, and in
    a store whose product arrays are sharded; a store made before shards keeps one file per
    chunk for the arrays added to it or recreated, so that a run directory has one layout."""
    for name, node in group.arrays():
        if name != "frame":
            codecs = getattr(node.metadata, "codecs", ())  # a zarr v2 array has none
            return any(c.to_dict()["name"] == "sharding_indexed" for c in codecs)
    return True


def _array(group: zarr.Group, name: str) -> zarr.Array:
    node = group[name]
    if not isinstance(node, zarr.Array):
        raise RunDirError(f"{name!r} in the product store is a group, expected an array")
    return node


def _open_array(path: Path, mode: str) -> zarr.Array:
    """Open a product array, reusing the handle while its metadata file is unchanged.

    Opening reads and parses ``zarr.json``; a worker writes several arrays per frame, so the
    handles are cached, keyed by the metadata file's identity (a recreated array, after a
    parameter changed its shape, has a new file and gets a new handle).
    """
    meta = os.stat(path / "zarr.json")
    return _cached_array(str(path), mode, meta.st_ino, meta.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _cached_array(path: str, mode: str, _ino: int, _mtime_ns: int) -> zarr.Array:
    return zarr.open_array(path, mode=mode)


def _slab_writer(path: Path) -> _SlabWriter | None:
    meta = os.stat(path / "zarr.json")
    return _cached_writer(str(path), meta.st_ino, meta.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _cached_writer(path: str, ino: int, mtime_ns: int) -> _SlabWriter | None:
    try:
        return _SlabWriter(path, _cached_array(path, "r+", ino, mtime_ns))
    except _Unsupported:
        return None


@functools.lru_cache(maxsize=64)
def _remote_writer(url: str, token: str) -> _SlabWriter | None:
    """The slab writer of a sharded array at a URL, None for other arrays (zarr writes
    them): zarr reads a shard back before it writes one (a GET per shard, and a damaged
    shard stops its own rewrite), which a frame's shard, written whole, does not need."""
    try:
        writer = _SlabWriter(url, _remote_array(url, token), remote=True)
    except _Unsupported:
        return None
    return writer if writer.inner is not None else None


# a chunk of a frame slab: its window in the slab (None for a chunk of a shard that lies
# wholly outside the array), its chunk coordinates after the frame's (of the shard, or local
# to the shard for an inner chunk), whether it is an edge chunk that zarr pads with the fill
_Tile = tuple[tuple[slice, ...] | None, tuple[int, ...], bool]
# a shard of a frame slab: its key's coordinates after the frame's and its inner chunks in
# the order zarr stores them (Morton order)
_Shard = tuple[tuple[int, ...], list[_Tile]]

_NO_CHUNK = 2**64 - 1  # a shard index entry (offset, nbytes) of an inner chunk not stored


@functools.lru_cache(maxsize=16)
def _morton_order(grid: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """The inner chunks of a shard of ``grid`` chunks in the order zarr stores them: the
    compressed Morton (Z) order of Neuroglancer, as ``zarr.core.indexing.decode_morton``
    (kept here, not imported: that module is zarr's internals; a test compares the two).
    Codes are decoded from 0 up and those outside ``grid`` skipped."""
    bits = tuple((n - 1).bit_length() for n in grid)
    total = math.prod(grid)
    order: list[tuple[int, ...]] = []
    code = 0
    while len(order) < total:
        out = [0] * len(grid)
        used = 0
        for bit in range(max(bits, default=0)):
            for dim, width in enumerate(bits):
                if bit < width:
                    out[dim] |= ((code >> used) & 1) << bit
                    used += 1
        if all(c < n for c, n in zip(out, grid, strict=True)):
            order.append(tuple(out))
        code += 1
    return tuple(order)


class _Unsupported(Exception):
    """The array uses a layout or codec the slab writer does not encode itself."""


class _SlabWriter:
    """Writes a frame's chunks or shards of one array straight to their files, in the
    calling thread.

    ``array[index] = data`` sends each chunk through zarr's asyncio loop and two thread
    hops (encode, write); for the ~30 small chunks of a frame that machinery cost more than
    the encoding (~2 ms per array, measured). This writer produces the same files zarr
    would, byte for byte (``tests/pipeline/test_store.py`` compares them): the ``bytes``
    codec (C order, the declared endianness), then the array's blosc or zstd compressor
    through the same ``numcodecs`` classes zarr uses; a chunk equal to the fill value is
    left out (zarr's ``write_empty_chunks=False``); each file goes to a
    ``<chunk>.<uuid>.partial`` temporary and is renamed over the chunk, as zarr's local
    store does.

    Two layouts are known. Unsharded (stores made before shards, and arrays added to them):
    one file per chunk, a fill-only chunk's file removed. Sharded (``sharding_indexed``,
    index at the end, coded ``bytes`` little-endian + ``crc32c`` as zarr's default): the
    inner chunks' encoded bytes concatenated in Morton order, then the index, one
    (offset, nbytes) uint64 pair per inner chunk, ``(2**64-1, 2**64-1)`` for a fill-only
    chunk that is left out, then the index's crc32c; a shard whose inner chunks are all fill
    is removed. A shard is written whole, never read back, so a shard must lie within one
    frame (shards of shape (1, ...)). Arrays with any other layout (index first, other
    index codecs, transposes, other compressors) raise ``_Unsupported`` and are written
    through zarr.
    """

    def __init__(self, root: str, array: zarr.Array, *, remote: bool = False) -> None:
        meta = array.metadata
        if not isinstance(meta, ArrayV3Metadata) or meta.storage_transformers:
            raise _Unsupported("not a plain zarr v3 array")
        if array.config.write_empty_chunks:
            raise _Unsupported("write_empty_chunks")
        outer = tuple(getattr(meta.chunk_grid, "chunk_shape", ()))
        if len(outer) != array.ndim or not outer or outer[0] != 1:
            raise _Unsupported("chunks (or shards) are not one frame each")
        codecs: list[dict[str, Any]] = [dict(c.to_dict()) for c in meta.codecs]
        self.inner: tuple[int, ...] | None = None  # inner chunk shape of a sharded array
        if len(codecs) == 1 and codecs[0]["name"] == "sharding_indexed":
            conf = codecs[0].get("configuration", {})
            index_codecs = [dict(c) for c in conf.get("index_codecs", ())]
            if conf.get("index_location", "end") != "end" or index_codecs != [
                {"name": "bytes", "configuration": {"endian": "little"}},
                {"name": "crc32c"},
            ]:
                raise _Unsupported(f"shard index {conf}")
            self.inner = tuple(conf["chunk_shape"])[1:]
            codecs = [dict(c) for c in conf["codecs"]]
        if not codecs or codecs[0]["name"] != "bytes" or len(codecs) > 2:
            raise _Unsupported(f"codecs {codecs}")
        endian = codecs[0].get("configuration", {}).get("endian") or "little"
        self.dtype = array.dtype.newbyteorder("<" if endian == "little" else ">")
        self.compress = _numcodec(codecs[1]) if len(codecs) == 2 else None
        if remote:  # an object store: one PUT (or DELETE) per file, atomic by itself
            fs, self.root = _remote(root)
            self._put: Callable[[str, bytes | Sequence[bytes]], None] = functools.partial(
                _put_object, fs.pipe_file
            )
            self._delete: Callable[[str], None] = functools.partial(_forget, fs.rm_file)
        else:
            self.root = root
            self._put = _replace_file
            self._delete = functools.partial(_forget, os.unlink)
        self.chunks = outer[1:]  # the file grid: chunks, or shards
        self.key = meta.chunk_key_encoding.encode_chunk_key
        self.fill = np.asarray(meta.fill_value, dtype=array.dtype)
        self._grid: dict[tuple[int, ...], list[_Tile]] = {}
        self._shards: dict[tuple[int, ...], list[_Shard]] = {}
        self._fill_nan = self.fill.dtype.kind in "fc" and bool(np.isnan(self.fill))
        self._fill_item = self.fill.item()

    def write(self, index: int, data: np.ndarray) -> None:
        if self.inner is not None:
            self._write_shards(index, data)
            return
        for window, tail, edge in self._tiles(data.shape):
            path = f"{self.root}/{self.key((index, *tail))}"
            encoded = self._encode(data, window, self.chunks, edge)
            if encoded is None:
                self._delete(path)  # an earlier attempt's chunk must not survive
                continue
            self._put(path, encoded)

    def _write_shards(self, index: int, data: np.ndarray) -> None:
        assert self.inner is not None
        for tail, tiles in self._shard_grid(data.shape):
            path = f"{self.root}/{self.key((index, *tail))}"
            table = np.full((*self._per_shard, 2), _NO_CHUNK, dtype="<u8")
            parts: list[bytes] = []
            offset = 0
            for window, local, edge in tiles:
                encoded = self._encode(data, window, self.inner, edge)
                if encoded is None:
                    continue
                table[local] = (offset, len(encoded))
                parts.append(encoded)
                offset += len(encoded)
            if not parts:  # zarr removes a shard with no stored chunk
                self._delete(path)
                continue
            raw = table.tobytes()
            parts += (raw, struct.pack("<I", google_crc32c.value(raw)))
            self._put(path, parts)

    def _encode(
        self,
        data: np.ndarray,
        window: tuple[slice, ...] | None,
        chunks: tuple[int, ...],
        edge: bool,
    ) -> bytes | None:
        """The encoded bytes of one chunk, None for a chunk that is all fill (not stored)."""
        if window is None:
            return None
        block = data[window]
        if edge:  # an edge chunk: zarr pads it with the fill value
            padded = np.full(chunks, self.fill, dtype=data.dtype)
            padded[tuple(slice(0, n) for n in block.shape)] = block
            block = padded
        if self._is_fill(block):
            return None
        raw = np.ascontiguousarray(block, dtype=self.dtype)
        return raw.tobytes() if self.compress is None else self.compress.encode(raw)

    def _tiles(self, shape: tuple[int, ...]) -> list[_Tile]:
        """(slab window, chunk or shard coordinates after the frame's, whether padded) of
        each file; computed once per slab shape, not per frame."""
        tiles = self._grid.get(shape)
        if tiles is None:
            tiles = []
            chunks = self.chunks
            grid = [range(0, n, c) for n, c in zip(shape, chunks, strict=True)]
            for starts in itertools.product(*grid):
                window = tuple(
                    slice(s, min(s + c, n)) for s, c, n in zip(starts, chunks, shape, strict=True)
                )
                edge = any(w.stop - w.start != c for w, c in zip(window, chunks, strict=True))
                tail = tuple(s // c for s, c in zip(starts, chunks, strict=True))
                tiles.append((window, tail, edge))
            self._grid[shape] = tiles
        return tiles

    @property
    def _per_shard(self) -> tuple[int, ...]:
        assert self.inner is not None
        return tuple(s // c for s, c in zip(self.chunks, self.inner, strict=True))

    def _shard_grid(self, shape: tuple[int, ...]) -> list[_Shard]:
        """Each shard of a slab of this shape with its inner chunks in Morton order (zarr's
        order within a shard); computed once per slab shape."""
        shards = self._shards.get(shape)
        if shards is None:
            assert self.inner is not None
            shards = []
            per_shard = self._per_shard
            for shard_window, tail, _ in self._tiles(shape):
                tiles: list[_Tile] = []
                for local in _morton_order((1, *per_shard)):
                    local = local[1:]  # the frame axis: one inner chunk per shard
                    starts = [
                        w.start + i * c
                        for w, i, c in zip(shard_window or (), local, self.inner, strict=True)
                    ]
                    if any(s >= n for s, n in zip(starts, shape, strict=True)):
                        tiles.append((None, local, False))  # wholly outside: fill only
                        continue
                    window = tuple(
                        slice(s, min(s + c, n))
                        for s, c, n in zip(starts, self.inner, shape, strict=True)
                    )
                    edge = any(
                        w.stop - w.start != c for w, c in zip(window, self.inner, strict=True)
                    )
                    tiles.append((window, local, edge))
                shards.append((tail, tiles))
            self._shards[shape] = shards
        return shards

    def _is_fill(self, block: np.ndarray) -> bool:
        # the same test as zarr's Buffer.all_equal: bit patterns for a zero float fill (so
        # that -0.0 is stored), NaN equal to a NaN fill
        fill = self.fill
        first = block[(0,) * block.ndim]
        # most chunks hold data: settled by their first element (scalar compares, cheaper
        # than np.array_equal)
        if (first == first) if self._fill_nan else (first != self._fill_item):
            return False
        if fill.dtype.kind == "f" and fill == 0.0:
            void = f"V{block.dtype.itemsize}"
            return np.array_equal(block.view(void), np.full(block.shape, fill).view(void))
        if fill.dtype.kind in "fc" and np.isnan(fill):
            return bool(np.isnan(block).all())
        return bool((block == fill).all())


def _numcodec(config: Mapping[str, Any]) -> Any:
    name, conf = config["name"], dict(config.get("configuration", {}))
    if name == "zstd":
        return numcodecs.Zstd(level=conf["level"], checksum=conf.get("checksum", False))
    if name == "blosc":
        shuffle = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}[conf["shuffle"]]
        return numcodecs.Blosc(
            cname=conf["cname"],
            clevel=conf["clevel"],
            shuffle=shuffle,
            blocksize=conf["blocksize"],
            typesize=conf["typesize"],
        )
    raise _Unsupported(f"compressor {name!r}")


def _put_object(
    pipe: Callable[[str, bytes], Any], path: str, data: bytes | Sequence[bytes]
) -> None:
    pipe(path, data if isinstance(data, bytes) else b"".join(data))


def _forget(remove: Callable[[str], Any], path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        remove(path)


_TMP_PREFIX = uuid.uuid4().hex[:16]  # per process (with the pid: forks share it)
_tmp_serial = itertools.count()


def _replace_file(path: str, data: bytes | Sequence[bytes]) -> None:
    # zarr's temporary name is <chunk>.<uuid hex>.partial: the same shape, so that
    # remove_orphan_temp_files finds both, without reading urandom for each file; a
    # shard comes in parts, written one after the other rather than joined (a copy)
    tmp = f"{path}.{_TMP_PREFIX}{os.getpid():x}{next(_tmp_serial):08x}.partial"
    try:
        fh = open(tmp, "wb")
    except FileNotFoundError:  # the frame's first chunk in this directory
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fh = open(tmp, "wb")
    try:
        with fh:
            if isinstance(data, bytes):
                fh.write(data)
            else:
                fh.writelines(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_frame_array(
    root: str | os.PathLike[str], name: str, index: int, data: np.ndarray, *, token: str = ""
) -> str:
    """Write one frame's slab of an array product; return its checksum.

    Local shard or chunk files reach the disk when the driver calls :func:`sync_filesystem`
    before it records the frame as complete (one flush per batch instead of one per file);
    on an object store each shard is encoded here and PUT whole, each chunk of an
    unsharded array is PUT by zarr. ``token`` (the run id) keys the cached handles of
    remote arrays, whose metadata cannot be checked for changes as cheaply as a local file's.
    """
    writer: _SlabWriter | None = None
    if is_url(root):
        url = f"{zarr_location(root)}/{name}"
        array = _remote_array(url, token)
        writer = _remote_writer(url, token)
    else:
        # plain strings: three pathlib objects per array and frame cost more than the stat
        path = os.path.join(root, ZARR_NAME, name)
        meta = os.stat(os.path.join(path, "zarr.json"))  # one stat keys both cached handles
        array = _cached_array(path, "r+", meta.st_ino, meta.st_mtime_ns)
        writer = _cached_writer(path, meta.st_ino, meta.st_mtime_ns)
    if tuple(array.shape[1:]) != data.shape or array.dtype != data.dtype:
        raise ValueError(
            f"product {name!r} expects per-frame shape {tuple(array.shape[1:])} and dtype "
            f"{array.dtype}, the stage returned {data.shape} {data.dtype}"
        )
    if not 0 <= index < array.shape[0]:
        raise IndexError(f"frame index {index} outside product {name!r} of {array.shape[0]}")
    if writer is not None:
        writer.write(index, data)
    else:
        array[index] = data
    return frame_checksum(data)


def read_frame_array(
    root: str | os.PathLike[str], name: str, index: int, *, token: str = ""
) -> np.ndarray:
    """Frame ``index`` of array product ``name`` under the products root (a directory or
    an fsspec URL); ``token`` keys the cache of remote array handles."""
    if is_url(root):
        array = _remote_array(f"{zarr_location(root)}/{name}", token)
    else:
        array = _open_array(_zarr_path(root) / name, "r")
    return np.asarray(array[index])


@functools.lru_cache(maxsize=64)
def _remote_array(url: str, _token: str) -> zarr.Array:
    return zarr.open_array(url, mode="r+")


def sync_filesystem(path: Path) -> None:
    """Flush every dirty page of the filesystem holding ``path`` (Linux ``syncfs``).

    Called by the driver before it commits completion records, so products written by the
    workers are on disk before they are recorded (power-loss safety). Falls back to
    ``os.sync`` where ``syncfs`` is not available.
    """
    libc = _libc()
    if libc is not None:
        fd = os.open(path, os.O_RDONLY)
        try:
            if libc.syncfs(fd) == 0:
                return
        finally:
            os.close(fd)
    os.sync()


@functools.lru_cache(maxsize=1)
def _libc() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.syncfs  # noqa: B018 - probe: AttributeError where the call does not exist
    except (OSError, AttributeError):
        return None
    return libc


def disk_full_error(exc: OSError, what: Path | str) -> StoreError:
    """The StoreError (exit 4) for a write of ``what`` that failed with ``exc``."""
    return StoreError(
        f"cannot write {what}: {os.strerror(exc.errno or 0)} (errno {exc.errno}); free space "
        "(or fix permissions) and rerun the same command: finished frames are kept"
    )
