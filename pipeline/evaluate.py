"""``arroyo evaluate RUNDIR``: score a run's products against the archive's ground truth.

What is scored (see :mod:`pipeline.metrics` for the exact definitions):

* ``depth``: arroyo's ``disparity`` and, on the same frames, OpenCV StereoSGBM
  (``opencv-sgbm``) computed here from the run's own ``left``/``right`` images; scored on
  non-occluded truth pixels.
* ``segmentation``: arroyo's ``labels`` and a global Otsu threshold (``otsu``) on the
  reference image.
* ``descriptors`` and ``relations``: arroyo's tables, on the rocks matched by segmentation.
* ``size-frequency``: the archive's Golombek-Rapp fit (``k``, the observed rock area
  fraction, the rocks in the fit) from arroyo's descriptors and, as the baseline ``truth``,
  from the truth rock table of the same frames, over the same ground area (the frames'
  ``describe_ground_area_m2``) with the run's ``sfd_max_range_m`` and
  ``sfd_min_diameter_m``: every object counts, matched or not, as in the products a
  scientist reads.

Which frames: a frame is scored for a product when its truth exists and its row in
``frames.parquet`` says the stage that writes the product completed (a ``<stage>_status``
column if present, else a non-null ``<stage>_seconds``, else the frame ``status`` is done).
Baselines run on the frames where arroyo's product of the same kind was scored, so the
comparison is like for like; when the run has no such product yet, they run on every ingested
frame with truth.

Output: a tidy long table (one row per archive, frame, product, method and metric; frame
``'*'`` is the aggregate over the archive's frames, pooled over pixels/objects/rocks rather than
averaged over frames), written atomically to ``RUNDIR/evaluation.parquet``. The aggregates of
the proportions over counts (segmentation ``precision`` and ``recall``, descriptors
``class_accuracy`` and ``near_class_accuracy``, and ``decided_class_accuracy`` and
``near_decided_class_accuracy`` where the descriptors have ``size_class_borderline``,
relations ``agreement``) come with ``<metric>_low`` and ``<metric>_high``: the 95 % Wilson
score interval (:func:`metrics.wilson_interval`) of the pooled proportion.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from . import metrics
from ._baselines import otsu_labels, sgbm_disparity
from ._evaluation_display import evaluation_tables, format_evaluation
from .errors import RunDirError
from .lock import RunLock, lock_holder
from .store import (
    check_products_reachable,
    open_products_group,
    products_root,
    zarr_location,
)

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
_TRUTH_REFERENCE = "right"  # the geometry of truth/<frame_id>.npz (pipeline.synth)


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


def _check_not_running(rundir: Path, run: Mapping[str, Any]) -> None:
    """Refuse a run directory a live run writes: its scores would cover whichever frames
    were done, and its evaluation.parquet would outlive the run's later frames."""
    if run.get("status") != "running":
        return
    holder = lock_holder(rundir)
    if holder is None:
        return  # a killed run: its recorded frames are complete
    raise RunDirError(
        f"run {rundir} is still in progress (arroyo pid {holder.get('pid', '?')} on host "
        f"{holder.get('host', '?')} since {holder.get('since', '?')}); evaluate it when it "
        "has finished"
    )


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


def _open_products(rundir: Path, run: Mapping[str, Any]):
    import xarray as xr

    root = products_root(rundir, run)
    if run.get("products"):  # a moved products directory printed "nothing to score", exit 0
        check_products_reachable(rundir, root, doing="nothing was scored")
    group = open_products_group(root)
    if group is None:
        return None
    consolidated = group.metadata.consolidated_metadata is not None
    with warnings.catch_warnings():
        # zarr 3 flags consolidated metadata as outside the v3 spec; reading it is fine
        warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
        return xr.open_zarr(zarr_location(root), consolidated=consolidated)


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
    """SGBM's search range: the depth stage's, or (when automatic) the truth's plus a margin."""
    params = ((run.get("stages") or {}).get("depth") or {}).get("params") or {}
    lo = int(params.get("min_disparity") or 0)
    hi = int(params.get("max_disparity") or 0)
    if hi <= lo:  # 0 (or absent) means "derived by the depth stage": derive ours from truth
        finite = truth_disparity[np.isfinite(truth_disparity)]
        top = float(finite.max()) if finite.size else 64.0
        hi = max(int(math.ceil(top)) + _DISPARITY_MARGIN_PX, lo + 2)
    return lo, hi


# ------------------------------------------------------------------------------- scoring
class _Collector:
    """Per-frame rows plus what the aggregates pool."""

    def __init__(self, run_id: str, archive: str) -> None:
        self.run_id, self.archive = run_id, archive
        self.rows: list[dict[str, Any]] = []
        self.frames: dict[tuple[str, str], list[dict[str, float]]] = {}
        self.seconds: dict[tuple[str, str], list[float]] = {}
        self.pooled_pairs: tuple[list[dict[str, Any]], list[dict[str, Any]]] = ([], [])
        self.pooled_edges: dict[str, list[Any]] = {}

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


#: ``size_class_borderline`` gives the decided-class figures of :func:`metrics.descriptor_errors`
#: (NaN, so none, for descriptors of describe < 11, without it)
_PRED_COLUMNS = (
    "height_max_m",
    "height_m",
    "width_m",
    "range_m",
    "size_class",
    "size_class_borderline",
)
#: ``touches_border`` gives the border / interior breakdown of :func:`metrics.descriptor_errors`
#: (NaN, so no breakdown, for rock tables without it)
_TRUE_COLUMNS = ("height_m", "width_m", "range_m", "size_class", "touches_border")


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
        The directory is not a run, its records are missing, its catalog has no truth, or
        a live run is writing it.
    RunLockedError
        A run took the directory between that check and the scoring; a run started while
        this scores is refused (it would remove evaluation.parquet, which this then wrote).
    """
    path = _coerce_rundir(rundir)
    run = _load_run_json(path)
    _check_not_running(path, run)
    if not os.access(path, os.W_OK):  # scored, then an EROFS traceback when saving
        raise RunDirError(
            f"cannot write {path / 'evaluation.parquet'}: the run directory is read-only; "
            "evaluate a writable copy of it (cp -r)"
        )
    truth_dir = _truth_dir(run, path)
    reference = str((run.get("camera") or {}).get("reference", "right"))
    if reference != _TRUTH_REFERENCE:
        # every map was compared pixel by pixel with a view 'd' columns away: segmentation
        # F1 0.000 and inflated depth errors, printed as if they were the run's scores
        raise RunDirError(
            f"run {str(path)!r} used the {reference} image as reference, but the ground truth "
            f"is in the {_TRUTH_REFERENCE} image's geometry (docs/synth.md), so its maps "
            f"cannot be scored against it; run the catalog with reference = "
            f'"{_TRUTH_REFERENCE}" (the default) into another --out to evaluate'
        )
    # held while scoring: a run started meanwhile removed evaluation.parquet, which this
    # then wrote back with the scores of the products that run replaced
    with RunLock(path):
        table = _score_run(path, run, truth_dir, reference)
        _write_atomic(table, path / "evaluation.parquet")
    return table


def _score_run(
    path: Path, run: Mapping[str, Any], truth_dir: Path, reference: str
) -> pa.Table:
    """Every scored frame's rows and the archive aggregates (see :func:`evaluate_run`)."""
    frames = _read_frames(path)
    products = _open_products(path, run)
    rocks_path = truth_dir / "rocks.parquet"
    ctx = _RunData(
        run=run,
        reference=reference,
        variables=set(products.data_vars) if products is not None else set(),
        truth_rocks=_rows_by_frame(pq.read_table(rocks_path) if rocks_path.exists() else None),
        descriptors=_rows_by_frame(_read_table(path / "descriptors.parquet")),
        relations=_rows_by_frame(_read_table(path / "relations.parquet")),
    )
    stored = set(map(str, products["frame"].values)) if products is not None else set()
    out = _Collector(str(run.get("run_id", "")), str(run.get("archive", "")))
    described: list[str] = []
    for frame_id in sorted(frames):
        truth_file = truth_dir / f"{frame_id}.npz"
        if frame_id not in stored or not truth_file.is_file():
            continue
        with np.load(truth_file) as npz:
            truth = {k: npz[k] for k in npz.files}
        frame = products.sel(frame=frame_id)
        _score_depth(ctx, out, frame_id, frames[frame_id], frame, truth)
        _score_objects(ctx, out, frame_id, frames[frame_id], frame, truth)
        if _stage_done(frames[frame_id], "describe"):
            described.append(frame_id)

    _add_aggregates(out)
    _score_size_frequency(ctx, out, [frames[f] for f in described])
    return pa.Table.from_pylist(out.rows, schema=EVALUATION_SCHEMA)


@dataclass
class _RunData:
    """What every frame's scoring needs from the run, read once."""

    run: Mapping[str, Any]
    reference: str
    variables: set[str]
    truth_rocks: dict[str, list[dict[str, Any]]]
    descriptors: dict[str, list[dict[str, Any]]]
    relations: dict[str, list[dict[str, Any]]]


def _has_images(ctx: _RunData, row: Mapping[str, Any]) -> bool:
    return {"left", "right"} <= ctx.variables and _stage_done(row, "ingest")


def _score_depth(ctx: _RunData, out: _Collector, frame_id: str, row, frame, truth) -> None:
    done = "disparity" in ctx.variables and _stage_done(row, "depth")
    has_images = _has_images(ctx, row)
    if not (done or ("disparity" not in ctx.variables and has_images)):
        return  # arroyo's depth exists but not for this frame: no baseline either
    valid = ~truth["occluded"].astype(bool)
    if done:
        pred = np.asarray(frame["disparity"].values, dtype=np.float32)
        scores = metrics.disparity_errors(pred, truth["disparity"], valid_truth=valid)
        out.add(frame_id, "depth", "arroyo", scores)
        seconds = row.get("depth_seconds")
        if seconds is not None:
            out.seconds.setdefault(("depth", "arroyo"), []).append(float(seconds))
    if has_images:
        lo, hi = _depth_range(ctx.run, truth["disparity"])
        left, right = np.asarray(frame["left"].values), np.asarray(frame["right"].values)
        start = time.perf_counter()
        sgbm = sgbm_disparity(
            left, right, min_disparity=lo, max_disparity=hi, reference=ctx.reference
        )
        out.seconds.setdefault(("depth", "opencv-sgbm"), []).append(time.perf_counter() - start)
        scores = metrics.disparity_errors(sgbm, truth["disparity"], valid_truth=valid)
        out.add(frame_id, "depth", "opencv-sgbm", scores)


def _score_objects(ctx: _RunData, out: _Collector, frame_id: str, row, frame, truth) -> None:
    done = "labels" in ctx.variables and _stage_done(row, "segment")
    has_images = _has_images(ctx, row)
    if not (done or ("labels" not in ctx.variables and has_images)):
        return
    truth_labels = truth["labels"].astype(np.int32, copy=False)
    if has_images:
        baseline = otsu_labels(np.asarray(frame[ctx.reference].values))
        out.add(
            frame_id, "segmentation", "otsu", metrics.segmentation_scores(baseline, truth_labels)
        )
    if not done:
        return
    pred_labels = np.asarray(frame["labels"].values).astype(np.int32, copy=False)
    matches = metrics.match_objects(pred_labels, truth_labels)
    out.add(frame_id, "segmentation", "arroyo", matches.scores())
    if not _stage_done(row, "describe") or frame_id not in ctx.descriptors:
        return
    rocks = {int(r["rock_id"]): r for r in ctx.truth_rocks.get(frame_id, [])}
    p_rows, t_rows = _pair_columns(matches, ctx.descriptors[frame_id], rocks)
    errors = metrics.descriptor_errors(
        _columns(p_rows, _PRED_COLUMNS), _columns(t_rows, _TRUE_COLUMNS)
    )
    out.extend(frame_id, "descriptors", "arroyo", errors)
    out.pooled_pairs[0].extend(p_rows)
    out.pooled_pairs[1].extend(t_rows)
    if frame_id in ctx.relations:
        occlusions = metrics.true_occlusions(truth_labels, truth["range"])
        edges = _edges(ctx.relations[frame_id], matches, rocks, occlusions)
        out.extend(frame_id, "relations", "arroyo", _relation_scores(edges))
        for k, v in edges.items():
            out.pooled_edges.setdefault(k, []).extend(v)


def _score_size_frequency(ctx: _RunData, out: _Collector, rows: list[Mapping[str, Any]]) -> None:
    """The archive's size-frequency fit from arroyo's rocks and from the truth's, same ground."""
    from stages._sizefreq import size_frequency_from_table

    areas = np.array([row.get("describe_ground_area_m2") for row in rows], dtype=np.float64)
    area = float(np.nansum(areas))
    if not area > 0:
        return  # no frame measured its ground: there is no fraction to compare
    params = ((ctx.run.get("stages") or {}).get("describe") or {}).get("params") or {}
    frame_ids = [str(row["frame_id"]) for row in rows]
    for method, by_frame in (("arroyo", ctx.descriptors), ("truth", ctx.truth_rocks)):
        if method == "truth" and not by_frame:
            continue  # no truth rock table: nothing to compare with
        rocks = [rock for frame_id in frame_ids for rock in by_frame.get(frame_id, [])]
        table = {
            name: np.array([rock[name] for rock in rocks], dtype=np.float64)
            for name in ("width_m", "range_m")
        }
        fit = size_frequency_from_table(
            table,
            ground_area_m2=area,
            max_range_m=float(params.get("sfd_max_range_m", math.inf)),
            d_min_m=float(params.get("sfd_min_diameter_m", 0.0)),
        )
        values = {"k": fit.k, "rock_area_fraction": fit.rock_area_fraction}
        out.extend(AGGREGATE, "size-frequency", method, {**values, "n_rocks": fit.n_rocks})


#: Confidence of the ``<metric>_low`` / ``<metric>_high`` aggregate rows.
_INTERVAL_CONFIDENCE = 0.95


def _successes(rate: float, trials: float) -> float:
    """The count behind ``rate = successes / trials`` (exact: ``trials`` is far below 2**52)."""
    return float(round(rate * trials)) if trials > 0 else 0.0


def _proportion_counts(product: str, values: Mapping[str, float]) -> dict[str, tuple[float, float]]:
    """(successes, trials) of each pooled proportion of ``product`` that gets an interval."""
    if product == "segmentation":
        tp, fp, fn = values["tp"], values["fp"], values["fn"]
        return {"precision": (tp, tp + fp), "recall": (tp, tp + fn)}
    if product == "descriptors":
        return {
            f"{prefix}{share}class_accuracy": (
                _successes(values[f"{prefix}{share}class_accuracy"], values[f"{prefix}{n}"]),
                values[f"{prefix}{n}"],
            )
            for prefix in ("", "near_")
            for share, n in (("", "n_rocks"), ("decided_", "decided_n_rocks"))
            if f"{prefix}{n}" in values  # decided_*: descriptors with size_class_borderline
        }
    if product == "relations":
        return {"agreement": (values["n_agree"], values["n_checked"])}
    return {}


def _with_intervals(product: str, values: Mapping[str, float]) -> dict[str, float]:
    """``values`` with ``<metric>_low`` and ``<metric>_high`` right after each proportion."""
    counts = _proportion_counts(product, values)
    out: dict[str, float] = {}
    for metric, value in values.items():
        out[metric] = value
        if metric in counts:
            low, high = metrics.wilson_interval(*counts[metric], confidence=_INTERVAL_CONFIDENCE)
            out[f"{metric}_low"], out[f"{metric}_high"] = low, high
    return out


def _add_aggregates(out: _Collector) -> None:
    pool = {
        "depth": metrics.pool_disparity_errors,
        "segmentation": metrics.pool_segmentation_scores,
    }
    for (product, method), per_frame in out.frames.items():
        values = pool[product](per_frame)
        values["n_frames"] = float(len(per_frame))
        seconds = out.seconds.get((product, method))
        if seconds:
            # the median: a fresh machine's first frame carries numba's compilation (lab:
            # 20.2 s, the others 0.08 s), and the mean of 4 frames printed 5.1 s against
            # SGBM's 0.1 s
            values["seconds_per_frame"] = float(np.median(seconds))
        out.extend(AGGREGATE, product, method, _with_intervals(product, values))
    pooled_pairs, pooled_edges = out.pooled_pairs, out.pooled_edges
    if pooled_pairs[0] or pooled_pairs[1]:
        errors = metrics.descriptor_errors(
            _columns(pooled_pairs[0], _PRED_COLUMNS), _columns(pooled_pairs[1], _TRUE_COLUMNS)
        )
        out.extend(AGGREGATE, "descriptors", "arroyo", _with_intervals("descriptors", errors))
    if pooled_edges:
        relations = _relation_scores(pooled_edges)
        out.extend(AGGREGATE, "relations", "arroyo", _with_intervals("relations", relations))


def _write_atomic(table: pa.Table, target: Path) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".evaluation-", suffix=".parquet.tmp", dir=target.parent)
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
