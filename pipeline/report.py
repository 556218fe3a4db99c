"""``arroyo report RUNDIR``: one self-contained ``report.html`` for a run.

Sections
--------
Summary
    Archive, run id and status, frames done / failed / pending (failed frames with their
    error), stage versions and parameters with the time per stage (from ``frames.parquet``
    ``<stage>_seconds``), and the evaluation table when ``arroyo evaluate`` ran.
Rocks (per archive)
    Sample and obstacle counts, the size-frequency plot (cumulative fractional area with the
    fitted Golombek-Rapp model, :mod:`stages._sizefreq`; ground area = sum of the frames'
    ``describe_ground_area_m2``), histograms of rock heights and ranges, and a top view of
    the rock positions on the ground plane.
Frames
    Per frame (the first ``max_frames`` in catalog order, filterable by id and status): the
    reference image with object outlines and ids, contours of equal range, left minus
    pseudo-left, the scene graph (objects by size class, ``adjacent`` and ``occludes``
    edges, the counts of every relation) and the frame's rock table. The quicklook stage's
    PNGs are embedded when present, otherwise drawn from ``products.zarr`` with the same
    functions; the scene graph is always drawn from ``products.zarr``.

The page needs no network: CSS and JS are inline and images are base64 PNG data URIs. The
report reads what queries read (:mod:`pipeline.query`): completed, published frames only.
"""

from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from . import _report_figures as figs
from ._report_html import Raw, esc, fmt, html_table, key_values, page, png_img, stat_cards
from .errors import ParamError
from .query import RunInfo, _missing_directory, load_runs, open_runs
from .store import open_products_group, products_root

__all__ = ["REPORT_NAME", "build_report", "render_report"]

REPORT_NAME = "report.html"
_ROCK_COLUMNS = (
    ("object_id", "id", False),
    ("size_class", "class", False),
    ("range_m", "range m", True),
    ("x_m", "x m", True),
    ("y_m", "y m", True),
    ("width_m", "width m", True),
    ("height_m", "height m", True),
    ("area_px", "area px", True),
    ("polarity", "polarity", False),
    ("depth_valid_fraction", "depth valid", True),
)
_FRAME_COUNTS = (("describe_n_samples", "samples"), ("describe_n_obstacles", "obstacles"))
_FLAGS = ("touches_border", "occluded", "depth_unreliable")


def _coerce_max_frames(max_frames: Any) -> int:
    if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 0:
        raise ValueError(
            f"max_frames must be an int >= 0 (--max-frames), got {max_frames!r}; pass 0 for "
            "a report without frame images"
        )
    return max_frames


def _target(rundir: Path, output: str | os.PathLike[str] | None) -> Path:
    if output is None:
        return rundir / REPORT_NAME
    if str(output) == "-":  # wrote a file named '-' into the working directory
        raise ParamError(
            "--output -: the report is a file (HTML with embedded images), not stdout; pass "
            "a file name such as report.html, or a directory"
        )
    target = Path(output)
    if target.is_dir():
        return target / REPORT_NAME
    if not target.parent.is_dir():
        # `-o /etc/passwd/r.html` said "directory /etc/passwd does not exist"
        raise ParamError(f"--output {target}: {_missing_directory(target.parent)}")
    return target


def build_report(
    rundir: str | os.PathLike[str],
    output: str | os.PathLike[str] | None = None,
    *,
    max_frames: int = 50,
    allow_running: bool = False,
) -> Path:
    """Write the run's self-contained HTML report.

    Parameters
    ----------
    rundir : path
        Run directory.
    output : path, optional
        File to write (or a directory to write ``report.html`` into); default
        ``RUNDIR/report.html``. Written atomically.
    max_frames : int
        Frames shown with images, >= 0 (the rest are listed in the summary only).
    allow_running : bool
        Report on a run still in progress (its published frames so far).

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    RunDirError
        Missing run directory, or a run in progress without ``allow_running``.
    """
    from .store import atomic_write_bytes

    max_frames = _coerce_max_frames(max_frames)
    path = Path(rundir)
    run = load_runs([path], allow_running=allow_running)[0]
    target = _target(path, output)
    if not os.access(target.parent, os.W_OK):  # checked before the minutes of rendering
        raise ParamError(
            f"cannot write {target}: {target.parent} is not writable (a read-only archive?); "
            "pass --output FILE somewhere writable"
        )
    text = render_report(run, max_frames=max_frames)
    try:
        atomic_write_bytes(target, text.encode("utf-8"))
    except OSError as exc:  # was a traceback (exit 1)
        raise ParamError(f"cannot write {target}: {exc.strerror or exc}") from None
    return target


# -- data ------------------------------------------------------------------------------------
def _tables(run: RunInfo) -> dict[str, pa.Table]:
    con = open_runs([run.path], allow_running=True)  # load_runs already checked
    try:
        return {
            "frames": con.sql("SELECT * FROM frames ORDER BY index").to_arrow_table(),
            "descriptors": con.sql(
                "SELECT * FROM descriptors ORDER BY frame_id, object_id"
            ).to_arrow_table(),
            "relations": con.sql("SELECT * FROM relations").to_arrow_table(),
            "evaluation": con.sql("SELECT * FROM evaluation").to_arrow_table(),
        }
    finally:
        con.close()


def _column(table: pa.Table, name: str, dtype: Any = np.float64) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan if dtype is np.float64 else None, dtype=dtype)
    values = table[name].to_pylist()
    if dtype is np.float64:
        return np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    return np.array(values, dtype=object)


def _stage_params(meta: Mapping[str, Any], stage: str) -> dict[str, Any]:
    return dict((meta.get("stages") or {}).get(stage, {}).get("params") or {})


# -- sections --------------------------------------------------------------------------------
def _summary(run: RunInfo, frames: pa.Table, desc: pa.Table, evaluation: pa.Table) -> str:
    meta = run.meta
    status = _column(frames, "status", object)
    n_done, n_failed = int(np.sum(status == "done")), int(np.sum(status == "failed"))
    n_pending = frames.num_rows - n_done - n_failed
    classes = _column(desc, "size_class", object)
    parts = ['<section id="summary"><h2>Summary</h2>']
    parts.append(
        stat_cards(
            [
                ("frames", frames.num_rows, ""),
                ("done", n_done, "ok"),
                ("failed", n_failed, "bad" if n_failed else ""),
                ("pending", n_pending, "warn" if n_pending else ""),
                ("rocks", desc.num_rows, ""),
                ("samples", int(np.sum(classes == "sample")), ""),
                ("obstacles", int(np.sum(classes == "obstacle")), ""),
            ]
        )
    )
    camera = meta.get("camera") or {}
    shape = meta.get("image_shape")
    parts.append(
        key_values(
            [
                ("archive", run.archive),
                ("run id", run.run_id),
                ("status", meta.get("status")),
                ("started", meta.get("started")),
                ("finished", meta.get("finished")),
                ("seconds", meta.get("seconds")),
                ("scheduler", meta.get("scheduler")),
                ("catalog", (meta.get("catalog") or {}).get("source")),
                ("image shape", " x ".join(map(str, shape)) if shape else None),
                (
                    "camera",
                    ", ".join(f"{k} {v}" for k, v in camera.items() if v is not None) or None,
                ),
            ]
        )
    )
    parts.append(_stages_table(meta, frames))
    if n_failed:
        rows = [
            (
                r["frame_id"],
                r.get("failed_stage"),
                Raw(f'<span class="error">{esc(r["error"])}</span>'),
            )
            for r in frames.to_pylist()
            if r.get("status") == "failed"
        ]
        parts.append(f"<h3>Failed frames ({n_failed})</h3>")
        parts.append(f'<div class="scroll">{html_table(("frame", "stage", "error"), rows)}</div>')
    parts.append(_evaluation_table(evaluation))
    parts.append("</section>")
    return "".join(parts)


def _stages_table(meta: Mapping[str, Any], frames: pa.Table) -> str:
    stages = meta.get("stages") or {}
    rows = []
    for name, info in stages.items():
        seconds = [v for v in _column(frames, f"{name}_seconds") if math.isfinite(v)]
        params = json.dumps((info or {}).get("params") or {}, sort_keys=True)
        rows.append(
            (
                name,
                (info or {}).get("version"),
                Raw(f"<code>{esc(params)}</code>"),
                len(seconds),
                statistics.fmean(seconds) if seconds else None,
                statistics.median(seconds) if seconds else None,
                sum(seconds) if seconds else None,
            )
        )
    table = html_table(
        ("stage", "version", "parameters", "frames timed", "mean s", "median s", "total s"),
        rows,
        numeric=(False, False, False, True, True, True, True),
    )
    return f"<h3>Stages and time per stage</h3>{table}"


def _evaluation_table(evaluation: pa.Table) -> str:
    if evaluation.num_rows == 0:
        return (
            '<h3>Evaluation</h3><p class="note">No evaluation: run '
            "<code>arroyo evaluate RUNDIR</code> on an archive with ground truth.</p>"
        )
    rows = [r for r in evaluation.to_pylist() if r.get("frame_id") == "*"]
    methods = sorted({r["method"] for r in rows}, key=lambda m: (m != "arroyo", m))
    cells: dict[tuple[str, str], dict[str, float]] = {}
    for r in rows:
        cells.setdefault((r["product"], r["metric"]), {})[r["method"]] = r["value"]
    body = [
        (product, metric, *(values.get(m) for m in methods))
        for (product, metric), values in cells.items()
    ]
    table = html_table(
        ("product", "metric", *methods),
        body,
        numeric=(False, False, *([True] * len(methods))),
    )
    return (
        "<h3>Evaluation against ground truth</h3>"
        '<p class="note">Aggregates over the archive (pooled over pixels, objects and rocks); '
        "per-frame scores are in <code>evaluation.parquet</code>.</p>"
        f'<div class="scroll">{table}</div>'
    )


def _rocks(run: RunInfo, frames: pa.Table, desc: pa.Table) -> str:
    from stages._sizefreq import size_frequency_from_table

    parts = ['<section id="rocks"><h2>Rocks</h2>']
    if desc.num_rows == 0:
        parts.append('<p class="note">No rocks were described in this run.</p></section>')
        return "".join(parts)
    params = _stage_params(run.meta, "describe")
    max_range = float(params.get("sfd_max_range_m", math.inf))
    d_min = float(params.get("sfd_min_diameter_m", 0.0))
    archives = sorted({a for a in _column(desc, "archive", object) if a is not None})
    for archive in archives:
        sub = desc.filter(pa.compute.equal(desc["archive"], archive))
        fr = frames.filter(pa.compute.equal(frames["archive"], archive))
        done = fr.filter(pa.compute.equal(fr["status"], "done")) if fr.num_rows else fr
        areas = _column(done, "describe_ground_area_m2")
        area = float(np.nansum(areas)) if np.isfinite(areas).any() else math.nan
        fit = None
        if math.isfinite(area) and area > 0:
            fit = size_frequency_from_table(
                sub, ground_area_m2=area, max_range_m=max_range, d_min_m=d_min
            )
        rng = _column(sub, "range_m")
        with np.errstate(invalid="ignore"):
            near = rng <= max_range if math.isfinite(max_range) else np.isfinite(rng)
        classes = _column(sub, "size_class", object)
        parts.append(f"<h3>Archive {esc(archive)}</h3>")
        parts.append(
            stat_cards(
                [
                    ("rocks", sub.num_rows, ""),
                    ("samples", int(np.sum(classes == "sample")), ""),
                    ("obstacles", int(np.sum(classes == "obstacle")), ""),
                    ("frames with rocks", len(set(sub["frame_id"].to_pylist())), ""),
                    ("ground area m²", area, ""),
                    ("rock area fraction", fit.rock_area_fraction if fit else None, ""),
                    ("fitted k", fit.k if fit else None, ""),
                ]
            )
        )
        if fit is not None:
            parts.append(
                f'<p class="note">Golombek-Rapp fit on {fit.n_rocks} rocks: k = {fmt(fit.k)}, '
                f"q(k) = {fmt(fit.q)} /m, rms of log F = {fmt(fit.rms_log)}.</p>"
            )
        within = f" (range ≤ {max_range:g} m)" if math.isfinite(max_range) else ""
        sfd = figs.size_frequency_png(
            _column(sub, "width_m")[near],
            ground_area_m2=area,
            fit=fit,
            title=f"{archive}: size-frequency{within}",
        )
        hist = figs.histograms_png(_column(sub, "height_m"), rng, classes)
        top = figs.top_view_png(
            _column(sub, "x_m"), _column(sub, "y_m"), _column(sub, "width_m"), classes
        )
        parts.append('<div class="grid">')
        for png, caption in (
            (
                sfd,
                "Cumulative fractional area of rocks at least D wide, with the fitted "
                "model F(D) = k exp(-q(k) D) (gray: k = 0.05, 0.1, 0.2)",
            ),
            (
                top,
                "Rock positions on the ground plane, camera at the origin; marker size "
                "follows rock width",
            ),
            (hist, "Rock heights above the ground plane and ranges, by size class"),
        ):
            parts.append(
                f"<figure>{png_img(png, caption)}<figcaption>{esc(caption)}</figcaption></figure>"
            )
        parts.append("</div>")
    parts.append("</section>")
    return "".join(parts)


def _open_products(run: RunInfo) -> Any:
    return open_products_group(products_root(run.path, run.meta))


def _rock_table(rows: Sequence[Mapping[str, Any]]) -> str:
    if not rows:
        return '<p class="note">No rocks in this frame.</p>'
    headers = [label for _c, label, _n in _ROCK_COLUMNS] + ["flags"]
    numeric = [n for _c, _l, n in _ROCK_COLUMNS] + [False]
    body = []
    for r in rows:
        flags = ", ".join(f.replace("_", " ") for f in _FLAGS if r.get(f))
        body.append([r.get(c) for c, _l, _n in _ROCK_COLUMNS] + [flags])
    return f'<div class="scroll">{html_table(headers, body, numeric=numeric)}</div>'


def _graph_columns(rows: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, list]:
    return {name: [r.get(name) for r in rows] for name in names}


def _frames(
    run: RunInfo, frames: pa.Table, desc: pa.Table, relations: pa.Table, max_frames: int
) -> str:
    rows = frames.to_pylist()
    by_frame: dict[str, list[dict[str, Any]]] = {}
    for r in desc.to_pylist():
        by_frame.setdefault(r["frame_id"], []).append(r)
    # the shown frames' edges, for the scene graphs (a survey's table has many more)
    columns = ["frame_id", "subject_id", "relation", "object_id"]
    edges_of: dict[str, list[dict[str, Any]]] = {}
    if relations.num_rows and set(columns) <= set(relations.column_names):
        shown_ids = pa.array([str(r["frame_id"]) for r in rows[:max_frames]], pa.string())
        keep = pa.compute.is_in(relations["frame_id"], value_set=shown_ids)
        for r in relations.select(columns).filter(keep).to_pylist():
            edges_of.setdefault(r["frame_id"], []).append(r)
    products = _open_products(run)
    frame_index = {}
    if products is not None and "frame" in products:
        frame_index = {str(f): i for i, f in enumerate(products["frame"][:])}
    step = float(_stage_params(run.meta, "quicklook").get("range_step_m", 0.25))
    reference = str((run.meta.get("camera") or {}).get("reference", "right"))
    stages = list(run.meta.get("stages") or {})
    shown = rows[:max_frames]
    parts = ['<section id="frames"><h2>Frames</h2>']
    if len(rows) > len(shown):
        parts.append(
            f'<p class="note">Showing the first {len(shown)} of {len(rows)} frames; the '
            "summary lists every failed frame, and <code>arroyo query</code> reaches all.</p>"
        )
    parts.append(
        '<div class="toolbar"><input id="frame-search" type="search" '
        'placeholder="filter by frame id" aria-label="filter by frame id">'
        '<select id="frame-status" aria-label="status"><option value="all">all</option>'
        '<option value="done">done</option><option value="failed">failed</option>'
        '<option value="pending">pending</option></select>'
        '<span id="frame-count" class="note"></span></div>'
    )
    for i, row in enumerate(shown):
        fid, status = str(row["frame_id"]), str(row.get("status") or "pending")
        rocks = by_frame.get(fid, [])
        summary = (
            f'<summary><strong class="mono">{esc(fid)}</strong>'
            f'<span class="badge {esc(status)}">{esc(status)}</span>'
            f'<span class="note">{len(rocks)} rocks</span>'
        )
        for key, label in (
            ("describe_n_samples", "samples"),
            ("describe_n_obstacles", "obstacles"),
        ):
            if row.get(key) is not None:
                summary += f'<span class="note">{fmt(row[key])} {label}</span>'
        summary += "</summary>"
        body = []
        if row.get("error"):
            body.append(
                f'<p class="error">failed in {esc(row.get("failed_stage"))}: '
                f"{esc(row['error'])}</p>"
            )
        if row.get("notes"):
            body.append(f'<p class="note">notes: {esc(row["notes"])}</p>')
        # a failed or pending frame's quicklook files and slabs may be an earlier run's
        done = {s for s in stages if row.get(f"{s}_seconds") is not None}
        images = figs.frame_quicklooks(
            products_root(run.path, run.meta),
            fid,
            frame_index.get(fid, -1),
            products=products if fid in frame_index else None,
            range_step_m=step,
            reference=reference,
            done_stages=done,
        )
        edges = edges_of.get(fid, [])
        graph = figs.frame_scene_graph(
            frame_index.get(fid, -1),
            products=products if fid in frame_index else None,
            nodes=_graph_columns(rocks, ("object_id", "centroid_x", "centroid_y", "size_class")),
            edges=_graph_columns(edges, ("subject_id", "relation", "object_id")),
            reference=reference,
            done_stages=done,
        )
        if images or graph is not None:
            body.append('<div class="quicklooks">')
            for name in figs.QUICKLOOKS:
                caption = figs.quicklook_caption(name, reference)
                if name in images:
                    wide = ' class="wide"' if name == "residual" else ""
                    body.append(
                        f"<figure{wide}>{png_img(images[name], f'{fid}: {caption}')}"
                        f"<figcaption>{esc(caption)}</figcaption></figure>"
                    )
            if graph is not None:
                caption = figs.scene_graph_caption(
                    figs.relation_counts([e["relation"] for e in edges]),
                    unclassified=any(
                        r.get("size_class") not in figs.GRAPH_CLASS_COLORS for r in rocks
                    ),
                )
                body.append(
                    f'<figure class="scene-graph">{png_img(graph, f"{fid}: scene graph")}'
                    f"<figcaption>{esc(caption)}</figcaption></figure>"
                )
            body.append("</div>")
        else:
            body.append('<p class="note">No images for this frame.</p>')
        if graph is None and "describe" in done and not rocks:
            body.append('<p class="note">Scene graph: no objects, so no relations.</p>')
        body.append(f"<h3>Rocks ({len(rocks)})</h3>{_rock_table(rocks)}")
        is_open = " open" if i == 0 else ""
        parts.append(
            f'<details class="frame" data-id="{esc(fid)}" data-status="{esc(status)}"'
            f'{is_open}>{summary}<div class="frame-body">{"".join(body)}</div></details>'
        )
    if not rows:
        parts.append('<p class="note">This run has no frames yet.</p>')
    parts.append("</section>")
    return "".join(parts)


def render_report(run: RunInfo, *, max_frames: int = 50) -> str:
    """The report's HTML text for a resolved run (see :func:`build_report`)."""
    tables = _tables(run)
    frames, desc = tables["frames"], tables["descriptors"]
    sections = []
    if run.meta.get("status") == "running":
        sections.append(
            '<div class="banner">This run was still in progress when the report was written: '
            "rock tables and plots show the frames published by the last finished run.</div>"
        )
    sections.append(_summary(run, frames, desc, tables["evaluation"]))
    sections.append(_rocks(run, frames, desc))
    sections.append(_frames(run, frames, desc, tables["relations"], max_frames))
    subtitle = esc(
        f"archive {run.archive} · run {run.run_id} · {run.meta.get('status', '?')} · "
        f"{run.path.resolve()}"
    )
    return page(
        f"arroyo report — {run.archive}",
        subtitle,
        {"summary": "Summary", "rocks": "Rocks", "frames": "Frames"},
        sections,
    )
