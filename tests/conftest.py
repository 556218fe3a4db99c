"""Shared fixtures: small on-disk archives of PNG stereo pairs with a catalog, and an S3
object store on loopback for products at an fsspec URL."""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import settings

# CI explores the same examples on every run (a red CI then always reproduces); developers
# keep hypothesis' random exploration and its example database.
settings.register_profile("ci", derandomize=True, database=None)
if os.environ.get("CI"):
    settings.load_profile("ci")


def write_archive(
    root: Path,
    *,
    frames: int = 4,
    shape: tuple[int, int] = (40, 48),
    name: str = "testarch",
    seed: int = 0,
    extra_toml: str = "",
) -> Path:
    """PNG pairs (right = left shifted by 3 px) + frames.csv + catalog.toml; returns the TOML."""
    rng = np.random.default_rng(seed)
    images = root / "images"
    images.mkdir(parents=True, exist_ok=True)
    lines = ["frame_id,left,right,site"]
    for k in range(frames):
        texture = rng.integers(0, 256, size=(shape[0], shape[1] + 3), dtype=np.uint8)
        left, right = texture[:, 3:], texture[:, :-3]
        cv2.imwrite(str(images / f"f{k:03d}_left.png"), np.ascontiguousarray(left))
        cv2.imwrite(str(images / f"f{k:03d}_right.png"), np.ascontiguousarray(right))
        lines.append(f"f{k:03d},images/f{k:03d}_left.png,images/f{k:03d}_right.png,site{k % 2}")
    (root / "frames.csv").write_text("\n".join(lines) + "\n")
    catalog = root / "catalog.toml"
    catalog.write_text(
        f'[archive]\nname = "{name}"\ndescription = "test archive"\n\n'
        "[camera]\nfocal_px = 100.0\nbaseline_m = 0.1\n\n"
        '[frames]\nindex = "frames.csv"\n' + extra_toml
    )
    return catalog


@pytest.fixture
def archive(tmp_path: Path) -> Path:
    return write_archive(tmp_path / "archive")


def _forget_s3_clients() -> None:
    """Close and drop the cached S3 filesystems.

    fsspec caches filesystem instances, and with them an S3 client bound to the endpoint of
    the moment (a later test's server listens on another port) and an aiohttp session that
    warns when garbage-collected open. zarr's instances are asynchronous, on zarr's loop.
    """
    import fsspec.asyn
    import s3fs
    import zarr.core.sync

    for fs in list(s3fs.S3FileSystem._cache.values()):
        client = getattr(fs, "_s3", None)
        if client is None:
            continue
        if fs.asynchronous:
            zarr.core.sync.sync(client.close())
        else:
            fsspec.asyn.sync(fs.loop, client.close)
    s3fs.S3FileSystem.clear_instance_cache()


@pytest.fixture
def s3_products(monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A new bucket on a moto S3 server on 127.0.0.1; yields ``s3://<bucket>/products``.

    The AWS variables point every S3 client at the server, also those of processes started
    afterwards (a test's dask workers inherit them), as a user's environment would.
    """
    import fsspec
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line per request
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    for name, value in {
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL": f"http://{host}:{port}",
    }.items():
        monkeypatch.setenv(name, value)
    _forget_s3_clients()
    bucket = f"arroyo-test-{uuid.uuid4().hex[:8]}"  # moto's buckets outlive its server
    try:
        fsspec.filesystem("s3").mkdir(bucket)
        yield f"s3://{bucket}/products"
    finally:
        _forget_s3_clients()
        server.stop()


@pytest.fixture
def readonly_view(tmp_path):
    """``view(path)``: a read-only bind mount of ``path`` (skips where mounting is not
    allowed); as root, permissions alone do not stop writes, a read-only mount does."""
    import subprocess

    mounts = []

    def view(path):
        target = tmp_path / f"ro-{len(mounts)}"
        target.mkdir()
        done = subprocess.run(
            ["mount", "--bind", "-o", "ro", str(path), str(target)], capture_output=True
        )
        if done.returncode != 0:
            pytest.skip(f"cannot make a read-only bind mount: {done.stderr.decode().strip()}")
        mounts.append(target)
        return target

    yield view
    for target in mounts:
        subprocess.run(["umount", "-l", str(target)], check=False)  # lazy: even if busy
