"""``arroyo evaluate RUNDIR``: score a run's products against the archive's ground truth.

What is scored (see :mod:`pipeline.metrics` for the exact definitions):

* ``depth``: arroyo's ``disparity`` and, on the same frames, OpenCV StereoSGBM
  (``opencv-sgbm``) computed here from the run's own ``left``/``right`` images; scored on
  non-occluded truth pixels.
* ``segmentation``: arroyo's ``labels`` and a global Otsu threshold (``otsu``) on the
  reference image.
* ``descriptors`` and ``relations``: arroyo's tables, on the rocks matched by segmentation.

Which frames: a frame is scored for a product when its truth exists and its row in
``frames.parquet`` says the stage that writes the product completed (a ``<stage>_status``
column if present, else a non-null ``<stage>_seconds``, else the frame ``status`` is done).
Baselines run on the frames where arroyo's product of the same kind was scored, so the
comparison is like for like; when the run has no such product yet, they run on every ingested
frame with truth.

Output: a tidy long table (one row per archive, frame, product, method and metric; frame
``'*'`` is the aggregate over the archive's frames, pooled over pixels/objects/rocks rather than
averaged over frames), written atomically to ``RUNDIR/evaluation.parquet``.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from . import metrics
from ._baselines import otsu_labels, sgbm_disparity
from .errors import RunDirError

__all__ = [
    "EVALUATION_SCHEMA",
    "AGGREGATE",
    "evaluate_run",
    "evaluation_tables",
    "format_evaluation",
]

#: ``frame_id`` of the aggregate rows.
AGGREGATE = "*"

EVALUATION_SCHEMA = pa.schema(
    [
        ("run_id", pa.string()),
        ("archive", pa.string()),
        ("frame_id", pa.string()),
        ("product", pa.string()),
        ("method", pa.string()),
        ("metric", pa.string()),
        ("value", pa.float64()),
    ]
)

_DISPARITY_MARGIN_PX = 8
_METHOD_ORDER = ("arroyo", "opencv-sgbm", "otsu")


# ------------------------------------------------------------------------------ run reading
def _coerce_rundir(rundir: str | os.PathLike[str]) -> Path:
    if not isinstance(rundir, str | os.PathLike):
        raise TypeError(f"rundir must be a path (str or Path), got {type(rundir).__name__}")
    path = Path(rundir)
    if not path.is_dir():
        raise RunDirError(
            f"run directory {str(path)!r} does not exist; give the --out directory of an "
            "`arroyo run`"
        )
    if not (path / "run.json").is_file():
        raise RunDirError(
            f"{str(path)!r} is not an arroyo run directory: run.json is missing; give the "
            "--out directory of an `arroyo run`"
        )
    return path


def _load_run_json(rundir: Path) -> dict[str, Any]:
    try:
        run = json.loads((rundir / "run.json").read_text())
    except (OSError, ValueError) as exc:
        raise RunDirError(f"cannot read {rundir / 'run.json'}: {exc}") from exc
    if not isinstance(run, dict):
        raise RunDirError(
            f"{rundir / 'run.json'} must hold a JSON object, got {type(run).__name__}"
        )
    return run


def _truth_dir(run: Mapping[str, Any], rundir: Path) -> Path:
    catalog = run.get("catalog") or {}
    truth = catalog.get("truth_dir") if isinstance(catalog, Mapping) else None
    source = catalog.get("source") or catalog.get("path") if isinstance(catalog, Mapping) else None
    if not truth:
        raise RunDirError(
            f"the catalog of run {str(rundir)!r} ({source}) has no ground truth ([truth] dir "
            "in the catalog); `arroyo evaluate` needs an archive with truth, such as the "
            "built-in archives made by `arroyo synth`"
        )
    path = Path(truth)
    if not path.is_dir():
        raise RunDirError(
            f"the truth directory {str(path)!r} of run {str(rundir)!r} does not exist; "
            "re-render the archive (arroyo synth) or fix [truth] dir in the catalog"
        )
    return path


def _read_frames(rundir: Path) -> dict[str, dict[str, Any]]:
    path = rundir / "frames.parquet"
    if not path.exists():
        raise RunDirError(
            f"{str(path)!r} is missing: the run in {str(rundir)!r} has not recorded any frame yet"
        )
    rows = pq.read_table(path).to_pylist()
    return {str(r["frame_id"]): r for r in rows}


def _stage_done(row: Mapping[str, Any], stage: str) -> bool:
    """Whether ``stage`` completed for this frame, by the most specific record available."""
    if f"{stage}_status" in row:
        return row[f"{stage}_status"] == "done"
    if f"{stage}_seconds" in row:  # the engine records a stage's seconds once it completed
        seconds = row[f"{stage}_seconds"]
        return seconds is not None and not (isinstance(seconds, float) and math.isnan(seconds))
    return row.get("status") == "done"


def _open_products(rundir: Path):
    import xarray as xr

    path = rundir / "products.zarr"
    if not path.exists():
        return None
    consolidated = False
    meta = path / "zarr.json"
    if meta.is_file():
        try:
            consolidated = bool(json.loads(meta.read_text()).get("consolidated_metadata"))
        except ValueError:
            consolidated = False
    with warnings.catch_warnings():
        # zarr 3 flags consolidated metadata as outside the v3 spec; reading it is fine
        warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
        return xr.open_zarr(path, consolidated=consolidated)


def _read_table(path: Path) -> pa.Table | None:
    if not path.exists():
        return None
    dataset = pads.dataset(path, format="parquet", partitioning="hive")
    table = dataset.to_table()
    return table if table.num_rows else None


def _rows_by_frame(table: pa.Table | None) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    if table is None:
        return out
    for row in table.to_pylist():
        out.setdefault(str(row["frame_id"]), []).append(row)
    return out


def _depth_range(run: Mapping[str, Any], truth_disparity: np.ndarray) -> tuple[int, int]:
    params = ((run.get("stages") or {}).get("depth") or {}).get("params") or {}
    lo = int(params.get("min_disparity", 0) or 0)
    hi = params.get("max_disparity")
    if hi is None:
        finite = truth_disparity[np.isfinite(truth_disparity)]
        top = float(finite.max()) if finite.size else 64.0
        hi = int(math.ceil(top)) + _DISPARITY_MARGIN_PX
    return lo, max(int(hi), lo + 1)


# ------------------------------------------------------------------------------- scoring
class _Collector:
    """Per-frame rows plus what the aggregates pool."""

    def __init__(self, run_id: str, archive: str) -> None:
        self.run_id, self.archive = run_id, archive
        self.rows: list[dict[str, Any]] = []
        self.frames: dict[tuple[str, str], list[dict[str, float]]] = {}
        self.seconds: dict[tuple[str, str], list[float]] = {}

    def add(self, frame_id: str, product: str, method: str, values: Mapping[str, float]) -> None:
        self.frames.setdefault((product, method), []).append(dict(values))
        self.extend(frame_id, product, method, values)

    def extend(self, frame_id: str, product: str, method: str, values: Mapping[str, float]):
        for metric, value in values.items():
            self.rows.append(
                {
                    "run_id": self.run_id,
                    "archive": self.archive,
                    "frame_id": frame_id,
                    "product": product,
                    "method": method,
                    "metric": metric,
                    "value": float(value),
                }
            )


def _pair_columns(
    matches: metrics.ObjectMatches,
    descriptors: list[dict[str, Any]],
    rocks: Mapping[int, dict[str, Any]],
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    by_object = {int(r["object_id"]): r for r in descriptors}
    pred_rows, true_rows = [], []
    for p, t in zip(matches.pred_ids.tolist(), matches.true_ids.tolist(), strict=True):
        if p in by_object and t in rocks:
            pred_rows.append(by_object[p])
            true_rows.append(rocks[t])
    return pred_rows, true_rows


def _columns(rows: list[dict[str, Any]], names: Iterable[str]) -> dict[str, np.ndarray]:
    out = {}
    for name in names:
        values = [r.get(name) for r in rows]
        if name == "size_class":
            out[name] = np.asarray([str(v) for v in values], dtype=str)
        else:
            out[name] = np.asarray([np.nan if v is None else v for v in values], dtype=float)
    return out


_PRED_COLUMNS = ("height_max_m", "height_m", "width_m", "range_m", "size_class")
_TRUE_COLUMNS = ("height_m", "width_m", "range_m", "size_class")


def _edges(
    relations: list[dict[str, Any]],
    matches: metrics.ObjectMatches,
    rocks: Mapping[int, dict[str, Any]],
    occlusions: set[tuple[int, int]],
) -> dict[str, list[Any]]:
    to_true = dict(zip(matches.pred_ids.tolist(), matches.true_ids.tolist(), strict=True))
    edges: dict[str, list[Any]] = {k: [] for k in ("relation", "sx", "sy", "ox", "oy", "occ")}
    for r in relations:
        s, o = to_true.get(int(r["subject_id"])), to_true.get(int(r["object_id"]))
        if s is None or o is None or s not in rocks or o not in rocks:
            continue
        edges["relation"].append(str(r["relation"]))
        edges["sx"].append(float(rocks[s]["x_m"]))
        edges["sy"].append(float(rocks[s]["y_m"]))
        edges["ox"].append(float(rocks[o]["x_m"]))
        edges["oy"].append(float(rocks[o]["y_m"]))
        edges["occ"].append((s, o) in occlusions)
    return edges


def _relation_scores(edges: Mapping[str, list[Any]]) -> dict[str, float]:
    return metrics.relation_agreement(
        np.asarray(edges["relation"], dtype=str),
        {"x_m": np.asarray(edges["sx"], float), "y_m": np.asarray(edges["sy"], float)},
        {"x_m": np.asarray(edges["ox"], float), "y_m": np.asarray(edges["oy"], float)},
        occludes_truth=np.asarray(edges["occ"], dtype=bool),
    )


def evaluate_run(rundir: str | os.PathLike[str]) -> pa.Table:
    """Score a run's products against the ground truth of its archive.

    Parameters
    ----------
    rundir : str or Path
        The ``--out`` directory of an ``arroyo run`` whose catalog has a ``[truth]`` dir.

    Returns
    -------
    evaluation : pyarrow.Table
        Columns ``run_id, archive, frame_id, product, method, metric, value``
        (:data:`EVALUATION_SCHEMA`); ``frame_id == '*'`` rows are the archive aggregates.
        The same table is written to ``RUNDIR/evaluation.parquet``.

    Raises
    ------
    RunDirError
        The directory is not a run, its records are missing, or its catalog has no truth.
    """
    path = _coerce_rundir(rundir)
    run = _load_run_json(path)
    truth_dir = _truth_dir(run, path)
    frames = _read_frames(path)
    products = _open_products(path)
    run_id, archive = str(run.get("run_id", "")), str(run.get("archive", ""))
    reference = str((run.get("camera") or {}).get("reference", "right"))
    rocks_path = truth_dir / "rocks.parquet"
    truth_rocks = _rows_by_frame(pq.read_table(rocks_path) if rocks_path.exists() else None)
    descriptors = _rows_by_frame(_read_table(path / "descriptors.parquet"))
    relations = _rows_by_frame(_read_table(path / "relations.parquet"))
    variables = set(products.data_vars) if products is not None else set()
    stored = set(map(str, products["frame"].values)) if products is not None else set()

    out = _Collector(run_id, archive)
    pooled_pairs: tuple[list[dict[str, Any]], list[dict[str, Any]]] = ([], [])
    pooled_edges: dict[str, list[Any]] = {}
    for frame_id in sorted(frames):
        row = frames[frame_id]
        truth_file = truth_dir / f"{frame_id}.npz"
        if frame_id not in stored or not truth_file.is_file():
            continue
        with np.load(truth_file) as npz:
            truth = {k: npz[k] for k in npz.files}
        frame = products.sel(frame=frame_id)
        has_images = {"left", "right"} <= variables and _stage_done(row, "ingest")

        depth_done = "disparity" in variables and _stage_done(row, "depth")
        if depth_done or ("disparity" not in variables and has_images):
            valid = ~truth["occluded"].astype(bool)
            if depth_done:
                pred = np.asarray(frame["disparity"].values, dtype=np.float32)
                out.add(
                    frame_id,
                    "depth",
                    "arroyo",
                    metrics.disparity_errors(pred, truth["disparity"], valid_truth=valid),
                )
                seconds = row.get("depth_seconds")
                if seconds is not None:
                    out.seconds.setdefault(("depth", "arroyo"), []).append(float(seconds))
            if has_images:
                lo, hi = _depth_range(run, truth["disparity"])
                start = time.perf_counter()
                sgbm = sgbm_disparity(
                    np.asarray(frame["left"].values),
                    np.asarray(frame["right"].values),
                    min_disparity=lo,
                    max_disparity=hi,
                    reference=reference,
                )
                out.seconds.setdefault(("depth", "opencv-sgbm"), []).append(
                    time.perf_counter() - start
                )
                out.add(
                    frame_id,
                    "depth",
                    "opencv-sgbm",
                    metrics.disparity_errors(sgbm, truth["disparity"], valid_truth=valid),
                )

        labels_done = "labels" in variables and _stage_done(row, "segment")
        truth_labels = truth["labels"].astype(np.int32, copy=False)
        if labels_done or ("labels" not in variables and has_images):
            if has_images:
                image = np.asarray(frame[reference].values)
                out.add(
                    frame_id,
                    "segmentation",
                    "otsu",
                    metrics.segmentation_scores(otsu_labels(image), truth_labels),
                )
            if labels_done:
                pred_labels = np.asarray(frame["labels"].values).astype(np.int32, copy=False)
                matches = metrics.match_objects(pred_labels, truth_labels)
                out.add(frame_id, "segmentation", "arroyo", matches.scores())
                if _stage_done(row, "describe") and frame_id in descriptors:
                    rocks = {int(r["rock_id"]): r for r in truth_rocks.get(frame_id, [])}
                    p_rows, t_rows = _pair_columns(matches, descriptors[frame_id], rocks)
                    out.extend(
                        frame_id,
                        "descriptors",
                        "arroyo",
                        metrics.descriptor_errors(
                            _columns(p_rows, _PRED_COLUMNS), _columns(t_rows, _TRUE_COLUMNS)
                        ),
                    )
                    pooled_pairs[0].extend(p_rows)
                    pooled_pairs[1].extend(t_rows)
                    if frame_id in relations:
                        occl = metrics.true_occlusions(truth_labels, truth["range"])
                        edges = _edges(relations[frame_id], matches, rocks, occl)
                        out.extend(frame_id, "relations", "arroyo", _relation_scores(edges))
                        for k, v in edges.items():
                            pooled_edges.setdefault(k, []).extend(v)

    _add_aggregates(out, pooled_pairs, pooled_edges)
    table = pa.Table.from_pylist(out.rows, schema=EVALUATION_SCHEMA)
    _write_atomic(table, path / "evaluation.parquet")
    return table


def _add_aggregates(
    out: _Collector,
    pooled_pairs: tuple[list[dict[str, Any]], list[dict[str, Any]]],
    pooled_edges: Mapping[str, list[Any]],
) -> None:
    pool = {
        "depth": metrics.pool_disparity_errors,
        "segmentation": metrics.pool_segmentation_scores,
    }
    for (product, method), per_frame in out.frames.items():
        values = pool[product](per_frame)
        values["n_frames"] = float(len(per_frame))
        seconds = out.seconds.get((product, method))
        if seconds:
            values["seconds_per_frame"] = float(np.mean(seconds))
        out.extend(AGGREGATE, product, method, values)
    if pooled_pairs[0] or pooled_pairs[1]:
        out.extend(
            AGGREGATE,
            "descriptors",
            "arroyo",
            metrics.descriptor_errors(
                _columns(pooled_pairs[0], _PRED_COLUMNS), _columns(pooled_pairs[1], _TRUE_COLUMNS)
            ),
        )
    if pooled_edges:
        out.extend(AGGREGATE, "relations", "arroyo", _relation_scores(pooled_edges))


def _write_atomic(table: pa.Table, target: Path) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".evaluation-", suffix=".parquet.tmp", dir=target.parent)
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


# ------------------------------------------------------------------------------- display
#: (product, metric, label, kind): what the terminal table shows, in order.
_DISPLAY: tuple[tuple[str, str, str, str], ...] = (
    ("depth", "bad1", "bad-1 (% px off > 1 px)", "pct"),
    ("depth", "bad2", "bad-2 (% px off > 2 px)", "pct"),
    ("depth", "epe", "end-point error (px)", "f3"),
    ("depth", "density", "density (% valid)", "pct"),
    ("depth", "seconds_per_frame", "seconds per frame", "f3"),
    ("segmentation", "precision", "precision (IoU >= 0.5)", "f3"),
    ("segmentation", "recall", "recall", "f3"),
    ("segmentation", "f1", "F1", "f3"),
    ("segmentation", "mean_iou", "mean IoU of matches", "f3"),
    ("segmentation", "fp", "false positives", "int"),
    ("descriptors", "n_rocks", "matched rocks", "int"),
    ("descriptors", "height_abs_err_median_m", "|height err| median (cm)", "cm"),
    ("descriptors", "height_abs_err_p90_m", "|height err| p90 (cm)", "cm"),
    ("descriptors", "width_rel_err_median", "width err median (%)", "pct"),
    ("descriptors", "width_rel_err_p90", "width err p90 (%)", "pct"),
    ("descriptors", "range_rel_err_median", "range err median (%)", "pct"),
    ("descriptors", "range_rel_err_p90", "range err p90 (%)", "pct"),
    ("descriptors", "class_accuracy", "sample/obstacle accuracy (%)", "pct"),
    ("descriptors", "near_n_rocks", "rocks within 2 m", "int"),
    ("descriptors", "near_height_abs_err_median_m", "  |height err| median (cm)", "cm"),
    ("descriptors", "near_width_rel_err_median", "  width err median (%)", "pct"),
    ("descriptors", "near_range_rel_err_median", "  range err median (%)", "pct"),
    ("descriptors", "near_class_accuracy", "  sample/obstacle accuracy (%)", "pct"),
    ("relations", "agreement", "edges agreeing with truth (%)", "pct"),
    ("relations", "n_checked", "edges checked", "int"),
)


def _format_value(value: float | None, kind: str) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    if kind == "pct":
        return f"{100 * value:.1f}"
    if kind == "cm":
        return f"{100 * value:.2f}"
    if kind == "int":
        return f"{value:.0f}"
    return f"{value:.3f}"


def evaluation_tables(table: pa.Table) -> list[Any]:
    """Rich tables of the aggregate rows, one per archive, methods side by side.

    Parameters
    ----------
    table : pyarrow.Table
        The result of :func:`evaluate_run` (or ``evaluation.parquet`` read back).

    Returns
    -------
    tables : list of rich.table.Table
        One per archive: rows = metrics, columns = arroyo and the baseline of each product
        (named in the product column).
    """
    from rich.table import Table

    if not isinstance(table, pa.Table):
        raise TypeError(f"table must be a pyarrow.Table, got {type(table).__name__}")
    missing = set(EVALUATION_SCHEMA.names) - set(table.column_names)
    if missing:
        raise ValueError(f"table lacks evaluation columns {sorted(missing)}; pass evaluate_run's")
    values: dict[str, dict[tuple[str, str, str], float]] = {}
    frames: dict[str, int] = {}
    for r in table.to_pylist():
        if r["frame_id"] != AGGREGATE:
            continue
        values.setdefault(r["archive"], {})[(r["product"], r["method"], r["metric"])] = r["value"]
        if r["metric"] == "n_frames":
            frames[r["archive"]] = max(frames.get(r["archive"], 0), int(r["value"]))
    tables = []
    for archive in sorted(values):
        vals = values[archive]
        t = Table(title=f"{archive}: {frames.get(archive, 0)} frames scored")
        t.add_column("product")
        t.add_column("metric")
        t.add_column("arroyo", justify="right")
        t.add_column("baseline", justify="right")
        for product in dict.fromkeys(p for p, _, _, _ in _DISPLAY):
            methods = sorted({m for p, m, _ in vals if p == product}, key=_method_rank)
            baselines = [m for m in methods if m != "arroyo"]
            first = True
            for product_, metric, label, kind in _DISPLAY:
                if product_ != product:
                    continue
                ours = vals.get((product, "arroyo", metric))
                theirs = [vals.get((product, m, metric)) for m in baselines]
                if ours is None and all(v is None for v in theirs):
                    continue
                name = product + (f" (vs {', '.join(baselines)})" if baselines else "")
                t.add_row(
                    name if first else "",
                    label,
                    _format_value(ours, kind),
                    " / ".join(_format_value(v, kind) for v in theirs) or "",
                )
                first = False
        tables.append(t)
    return tables


def _method_rank(method: str) -> tuple[int, str]:
    rank = _METHOD_ORDER.index(method) if method in _METHOD_ORDER else len(_METHOD_ORDER)
    return rank, method


def format_evaluation(table: pa.Table, *, width: int = 100) -> str:
    """The evaluation as plain text: the tables of :func:`evaluation_tables`, rendered.

    Parameters
    ----------
    table : pyarrow.Table
        The result of :func:`evaluate_run`.
    width : int
        Console width in characters.

    Returns
    -------
    text : str
        The tables, or a line saying that nothing could be scored.
    """
    import io

    from rich.console import Console

    tables = evaluation_tables(table)
    if not tables:
        return "nothing to score: no frame has both products and ground truth\n"
    buffer = io.StringIO()
    console = Console(file=buffer, width=width, force_terminal=False, color_system=None)
    for t in tables:
        console.print(t)
    return buffer.getvalue()
