"""Terminal tables of an evaluation (``arroyo evaluate``): arroyo beside each baseline."""

from __future__ import annotations

import math
from typing import Any

import pyarrow as pa

__all__ = ["evaluation_tables", "format_evaluation"]

_AGGREGATE = "*"
_COLUMNS = ("run_id", "archive", "frame_id", "product", "method", "metric", "value")
_METHOD_ORDER = ("arroyo", "opencv-sgbm", "otsu", "truth")

#: (product, metric, label, kind): what the terminal table shows, in order.
_DISPLAY: tuple[tuple[str, str, str, str], ...] = (
    ("depth", "bad1", "bad-1 (% px off > 1 px)", "pct"),
    ("depth", "bad2", "bad-2 (% px off > 2 px)", "pct"),
    ("depth", "epe", "end-point error (px)", "f3"),
    ("depth", "density", "density (% valid)", "pct"),
    ("depth", "seconds_per_frame", "seconds per frame (median)", "f3"),
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
    ("descriptors", "near_borderline_fraction", "  borderline class (%)", "pct"),
    ("descriptors", "near_decided_class_accuracy", "  accuracy, borderline out (%)", "pct"),
    ("relations", "agreement", "edges agreeing with truth (%)", "pct"),
    ("relations", "n_checked", "edges checked", "int"),
    ("size-frequency", "k", "Golombek-Rapp k", "f3"),
    ("size-frequency", "rock_area_fraction", "rock area fraction (%)", "pct"),
    ("size-frequency", "n_rocks", "rocks in the fit", "int"),
)


def _format_interval(value: float | None, low: float | None, high: float | None, kind: str) -> str:
    """``value (low-high)``, or the value alone when the interval is missing or undefined."""
    text = _format_value(value, kind)
    bounds = (value, low, high)
    if any(v is None or not math.isfinite(v) for v in bounds):
        return text
    return f"{text} ({_format_value(low, kind)}-{_format_value(high, kind)})"


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
        (named in the product column). Where the table has ``<metric>_low`` and
        ``<metric>_high``, arroyo's figure is followed by its 95 % interval in brackets.
    """
    from rich.table import Table

    if not isinstance(table, pa.Table):
        raise TypeError(f"table must be a pyarrow.Table, got {type(table).__name__}")
    missing = set(_COLUMNS) - set(table.column_names)
    if missing:
        raise ValueError(f"table lacks evaluation columns {sorted(missing)}; pass evaluate_run's")
    values: dict[str, dict[tuple[str, str, str], float]] = {}
    frames: dict[str, int] = {}
    for r in table.to_pylist():
        if r["frame_id"] != _AGGREGATE:
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
        if any(metric.endswith("_high") for _, _, metric in vals):
            t.caption = "(low-high): 95 % Wilson score interval of arroyo's pooled proportion"
        for product in dict.fromkeys(p for p, _, _, _ in _DISPLAY):
            methods = sorted({m for p, m, _ in vals if p == product}, key=_method_rank)
            baselines = [m for m in methods if m != "arroyo"]
            first = True
            for product_, metric, label, kind in _DISPLAY:
                if product_ != product:
                    continue
                ours = vals.get((product, "arroyo", metric))
                low = vals.get((product, "arroyo", f"{metric}_low"))
                high = vals.get((product, "arroyo", f"{metric}_high"))
                theirs = [vals.get((product, m, metric)) for m in baselines]
                if ours is None and all(v is None for v in theirs):
                    continue
                name = product + (f" (vs {', '.join(baselines)})" if baselines else "")
                t.add_row(
                    name if first else "",
                    label,
                    _format_interval(ours, low, high, kind),
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
        # a user's own truth in another layout was read as none, with nothing said about
        # the layout expected
        return (
            "nothing to score: no frame has both products and ground truth (a file "
            "<[truth] dir>/<frame_id>.npz per frame, as `arroyo synth` writes them: "
            "docs/synth.md)\n"
        )
    buffer = io.StringIO()
    console = Console(file=buffer, width=width, force_terminal=False, color_system=None)
    for t in tables:
        console.print(t)
    return buffer.getvalue()
