"""Provenance of a run: who made the products, from what, with which code and settings."""

from __future__ import annotations

import importlib.metadata
import platform
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

__all__ = ["new_run_id", "environment", "git_commit", "now_iso", "TRACKED_PACKAGES"]

TRACKED_PACKAGES = (
    "arroyo",
    "dask",
    "distributed",
    "numpy",
    "opencv-python-headless",
    "zarr",
    "xarray",
    "pyarrow",
    "numba",
    "scipy",
    "duckdb",
    "matplotlib",
    "rich",
)


def new_run_id() -> str:
    """Sortable, unique: UTC time plus 6 random hex digits."""
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + uuid.uuid4().hex[:6]


def now_iso() -> str:
    """Local time as ISO 8601 with its UTC offset (``2026-12-01T23:00:00+0000``)."""
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def git_commit() -> str | None:
    """The commit of the arroyo source tree when it is a git checkout (editable install)."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    dirty = subprocess.run(
        ["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
        capture_output=True,
        text=True,
        timeout=5,
        check=False,
    ).stdout.strip()
    return out.stdout.strip() + ("-dirty" if dirty else "")


def environment() -> dict[str, Any]:
    """Python, platform, host and versions of the packages that shape the products."""
    versions: dict[str, str | None] = {}
    for name in TRACKED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "host": socket.gethostname(),
        "packages": versions,
        "git_commit": git_commit(),
    }
