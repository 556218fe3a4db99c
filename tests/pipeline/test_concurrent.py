"""Readers during a run: queries see completed frames only; a live run is refused by default."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pytest
import zarr

from conftest import write_archive
from pipeline.errors import RunDirError
from pipeline.lock import lock_holder
from pipeline.query import query_runs
from pipeline.runner import run

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent

_CHILD = """
import sys
sys.path[:0] = [{here!r}, {root!r}]
from pipeline.runner import run
run({catalog!r}, {out!r}, stage_package="arroyo_fake_stages", scheduler="synchronous",
    overrides=["ingest.sleep=0.3"])
"""


@pytest.mark.slow
def test_query_during_a_run_sees_only_completed_frames(tmp_path):
    catalog = write_archive(tmp_path / "archive", frames=8)
    out = tmp_path / "run"
    run(catalog, out, stage_package="arroyo_fake_stages", scheduler="synchronous", frames="f00[01]")
    script = _CHILD.format(here=str(HERE), root=str(ROOT), catalog=str(catalog), out=str(out))
    child = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 30
        while lock_holder(out) is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lock_holder(out) is not None, "the child run never took the lock"
        time.sleep(1.0)  # some frames of the second run are finished by now, not published
        with pytest.raises(RunDirError, match="in progress"):
            query_runs([out], "SELECT count(*) AS n FROM frames")
        done = query_runs(
            [out],
            "SELECT frame_id FROM frames WHERE status = 'done' ORDER BY 1",
            allow_running=True,
        )["frame_id"].to_pylist()
        # what the journal calls done is really on disk
        left = zarr.open_array(out / "products.zarr" / "left", mode="r")
        for frame_id in done:
            assert np.asarray(left[int(frame_id[1:])]).any(), frame_id
        # the published table is the last complete generation: the first run's two frames
        published = ds.dataset(out / "tallies.parquet", partitioning="hive").to_table()
        assert sorted(set(published["frame_id"].to_pylist())) == ["f000", "f001"]
    finally:
        child.wait(timeout=60)
    assert child.returncode == 0
    published = ds.dataset(out / "tallies.parquet", partitioning="hive").to_table()
    assert len(set(published["frame_id"].to_pylist())) == 8
