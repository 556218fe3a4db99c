"""What importing the stage package costs: every run's driver and worker process pays it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_stage_package_imports_without_dask_array():
    # regression: segment imported dask.array (and with it xarray and pandas, ~0.4 s of a
    # ~1.5 s import) at module level, though only frames larger than tile_px use it
    code = (
        "import sys; from pipeline.worker import _stages; _stages('stages'); "
        "print(sorted(m for m in ('dask.array', 'xarray', 'pandas') if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "[]"
