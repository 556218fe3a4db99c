"""A finished ``arroyo run`` directory of an archive with truth, read frame by frame.

The benchmarks that measure a run's products again against the truth
(``bench_describe.py --rundir``, ``bench_segment.py --rundir``, ``bench_footprint_axes.py``)
read the same files:
``run.json`` (archive, camera, the catalog's truth directory), the truth rock table
``TRUTH_DIR/rocks.parquet``, the products in ``products.zarr`` and one
``TRUTH_DIR/FRAME_ID.npz`` of truth arrays per frame (written by ``pipeline.synth``).
Nothing is written: a run directory can be read while another process reads it too.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.camera import Camera
from pipeline.errors import RunDirError

__all__ = ["FinishedRun", "RunFrame", "open_run"]


@dataclass(frozen=True)
class RunFrame:
    """One frame of a finished run: its products and its truth.

    Attributes
    ----------
    frame_id : str
    products : xarray.Dataset
        The run's products at this frame (read when :meth:`product` asks for one).
    truth : dict of str to ndarray
        Every array of the frame's truth ``.npz``: ``labels`` (M, N) int32 (0 = ground,
        k = rock k), ``disparity``, ``range``, ``height`` (M, N) float32, ...
    rocks : list of dict
        The rows of the truth rock table of this frame, in table order.
    """

    frame_id: str
    products: Any
    truth: dict[str, np.ndarray]
    rocks: list[dict[str, Any]]

    def product(self, name: str) -> np.ndarray:
        """The frame's product ``name`` (e.g. ``'disparity'``, the reference image) in memory."""
        return np.asarray(self.products[name].values)


@dataclass(frozen=True)
class FinishedRun:
    """What a finished run directory says about its archive, and its frames.

    Attributes
    ----------
    path : Path
        The run directory.
    run : dict
        ``run.json`` as parsed.
    archive : str
        The archive's name (``run.json``).
    camera : Camera
        The camera the run used.
    truth_dir : Path
        The catalog's truth directory.
    rocks : list of dict
        Every row of ``rocks.parquet`` (all frames).
    products : xarray.Dataset
        ``products.zarr``, opened lazily.
    """

    path: Path
    run: dict[str, Any]
    archive: str
    camera: Camera
    truth_dir: Path
    rocks: list[dict[str, Any]]
    products: Any

    def segment_params(self) -> dict[str, Any]:
        """:func:`stages.segment.segment_image` keywords to segment this run again: the
        current code's defaults with the catalog's current ``[params.segment]`` (not the
        run's recorded ones, so a rule change is measured on old depth products)."""
        import tomllib

        from stages import segment as segment_stage

        catalog = tomllib.loads(Path(self.run["catalog"]["source"]).read_text())
        params = dict(segment_stage.STAGE.defaults())
        params.update(catalog.get("params", {}).get("segment", {}))
        params.pop("tile_px", None)  # the stage's own tiling, not a segment_image keyword
        return params

    def frames(self) -> Iterator[RunFrame]:
        """The run's frames in the order of ``products.zarr``, each with its truth loaded."""
        for frame_id in map(str, self.products["frame"].values):
            with np.load(self.truth_dir / f"{frame_id}.npz") as npz:
                truth = {name: npz[name] for name in npz.files}
            truth["labels"] = truth["labels"].astype(np.int32)
            yield RunFrame(
                frame_id=frame_id,
                products=self.products.sel(frame=frame_id),
                truth=truth,
                rocks=[rock for rock in self.rocks if rock["frame_id"] == frame_id],
            )


def open_run(rundir: str | Path) -> FinishedRun:
    """Open a finished run directory of an archive with truth, as ``arroyo evaluate`` does.

    Parameters
    ----------
    rundir : str or Path
        The ``--out`` directory of an ``arroyo run`` whose catalog names a truth directory.

    Raises
    ------
    RunDirError
        When the directory is not a run, its catalog has no truth, or it holds no products
        (the message says which and what to give instead).
    """
    import pyarrow.parquet as pq

    # arroyo evaluate's own readers: the same checks and messages, products wherever
    # the run wrote them
    from pipeline.evaluate import _coerce_rundir, _load_run_json, _open_products, _truth_dir

    path = _coerce_rundir(rundir)
    run = _load_run_json(path)
    truth_dir = _truth_dir(run, path)
    products = _open_products(path, run)
    if products is None:
        raise RunDirError(
            f"run {str(path)!r} has no products yet; give a run that has finished a frame"
        )
    return FinishedRun(
        path=path,
        run=run,
        archive=run["archive"],
        camera=Camera(**run["camera"]),
        truth_dir=truth_dir,
        rocks=pq.read_table(truth_dir / "rocks.parquet").to_pylist(),
        products=products,
    )
