"""Figures of the run report as PNG bytes: per-archive rock plots (matplotlib, no pyplot
state, Agg canvas) and per-frame quicklooks (the quicklook stage's PNGs, or drawn from
``products.zarr`` with the same functions when the stage did not write them)."""

from __future__ import annotations

import io
import math
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, NullFormatter

from stages._sizefreq import SizeFrequencyFit, cumulative_fractional_area, model_cfa

from .store import read_product_file

__all__ = [
    "QUICKLOOKS",
    "quicklook_caption",
    "size_frequency_png",
    "histograms_png",
    "top_view_png",
    "compact_png",
    "frame_quicklooks",
]

#: the stage that writes each product a quicklook is drawn from
_PRODUCER = {
    "left": "ingest",
    "right": "ingest",
    "labels": "segment",
    "range": "depth",
    "residual": "depth",
}

#: quicklook file name -> caption, in display order
QUICKLOOKS = {
    "objects": "reference image, object outlines and ids",
    "range_contours": "contours of equal range",
    "residual": "left − right | left − pseudo-left",
}


def quicklook_caption(name: str, reference: str) -> str:
    """The caption of quicklook ``name``; the residual's names the ``reference`` camera's
    roles (right minus pseudo-right when it is ``'left'``)."""
    if name == "residual":
        from stages.quicklook import residual_labels

        return " | ".join(residual_labels(reference)).replace(" - ", " − ")
    return QUICKLOOKS[name]
_CLASS_COLORS = {"sample": "#1f77b4", "obstacle": "#d62728"}
_OTHER_COLOR = "#7f7f7f"
_REFERENCE_K = (0.05, 0.1, 0.2)
_DPI = 100
_COMPACT_ABOVE = 64_000


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=_DPI)
    return buffer.getvalue()


def _finite(values: Any) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    return a[np.isfinite(a)]


def size_frequency_png(
    diameters_m: np.ndarray,
    *,
    ground_area_m2: float,
    fit: SizeFrequencyFit | None,
    title: str,
) -> bytes:
    """Cumulative fractional area against rock diameter with the fitted Golombek-Rapp model.

    Parameters
    ----------
    diameters_m : (K,) ndarray of float
        Rock diameters, metres (NaN ignored).
    ground_area_m2 : float
        Ground area the rocks were counted on, m^2 (> 0, else only a note is drawn).
    fit : SizeFrequencyFit, optional
        Fitted model; drawn when its ``k`` is finite.
    title : str
    """
    fig = Figure(figsize=(5.2, 3.8))
    fig.subplots_adjust(left=0.15, right=0.97, bottom=0.13, top=0.92)
    ax = fig.add_subplot()
    d = _finite(diameters_m)
    if not (math.isfinite(ground_area_m2) and ground_area_m2 > 0) or d.size == 0:
        ax.text(0.5, 0.5, "no rocks with a known ground area", ha="center", va="center")
        ax.set_axis_off()
        ax.set_title(title, fontsize=10)
        return _png(fig)
    diam, cfa = cumulative_fractional_area(d, ground_area_m2=ground_area_m2)
    grid = np.linspace(0, max(float(diam.max()) * 1.15, 0.05), 200)
    for k in _REFERENCE_K:
        ax.plot(grid, model_cfa(grid, k), color="0.8", lw=0.8, zorder=1)
        ax.annotate(
            f"k={k:g}",
            (grid[-1], float(model_cfa(grid[-1:], k)[0])),
            fontsize=7,
            color="0.55",
            ha="right",
            va="bottom",
        )
    ax.plot(diam, cfa, "o", ms=4, color="#1f77b4", label=f"observed ({d.size} rocks)", zorder=3)
    if fit is not None and math.isfinite(fit.k):
        ax.plot(
            grid,
            model_cfa(grid, fit.k),
            color="#d62728",
            lw=1.8,
            label=f"fit k = {fit.k:.3f}, q = {fit.q:.2f} /m",
            zorder=2,
        )
    ax.set_yscale("log")
    # plain tick labels: mathtext (10^-2) costs a parser run per report
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    low = min(float(cfa.min()), 1e-3)
    ax.set_ylim(low / 2, 1.0)
    ax.set_xlim(0, grid[-1])
    ax.set_xlabel("rock diameter D (m)")
    ax.set_ylabel("cumulative fractional area F(D)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="major", color="0.92")
    ax.legend(fontsize=8, loc="upper right")
    return _png(fig)


def histograms_png(height_m: np.ndarray, range_m: np.ndarray, size_class: np.ndarray) -> bytes:
    """Histograms of rock heights and ranges, stacked by size class.

    Parameters
    ----------
    height_m, range_m : (K,) ndarray of float
        Metres, NaN ignored.
    size_class : (K,) ndarray of str
        'sample' | 'obstacle' (others drawn gray).
    """
    fig = Figure(figsize=(6.4, 3.0))
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.17, top=0.95, wspace=0.3)
    classes = np.asarray(size_class, dtype=object)
    for i, (values, label) in enumerate(
        ((height_m, "height above ground (m)"), (range_m, "range (m)"))
    ):
        ax = fig.add_subplot(1, 2, i + 1)
        v = np.asarray(values, dtype=np.float64)
        finite = np.isfinite(v)
        if not finite.any():
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
        else:
            bins = np.histogram_bin_edges(
                v[finite], bins=min(30, max(5, int(finite.sum() ** 0.5) * 2))
            )
            groups, colors, names = [], [], []
            for name in ("sample", "obstacle"):
                groups.append(v[finite & (classes == name)])
                colors.append(_CLASS_COLORS[name])
                names.append(name)
            other = finite & ~np.isin(classes, ("sample", "obstacle"))
            if other.any():
                groups.append(v[other])
                colors.append(_OTHER_COLOR)
                names.append("unclassified")
            ax.hist(groups, bins=list(bins), stacked=True, color=colors, label=names)
            ax.legend(fontsize=7)
        ax.set_xlabel(label)
        ax.set_ylabel("rocks")
        ax.grid(True, axis="y", color="0.92")
    return _png(fig)


def top_view_png(
    x_m: np.ndarray, y_m: np.ndarray, width_m: np.ndarray, size_class: np.ndarray
) -> bytes:
    """Rock positions on the ground plane seen from above (camera at the origin).

    Parameters
    ----------
    x_m, y_m : (K,) ndarray of float
        Ground frame: x right, y forward, metres (NaN: not placed).
    width_m : (K,) ndarray of float
        Marker size scales with the rock's width.
    size_class : (K,) ndarray of str
    """
    fig = Figure(figsize=(5.0, 4.2))
    fig.subplots_adjust(left=0.14, right=0.97, bottom=0.12, top=0.92)
    ax = fig.add_subplot()
    x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    w = np.asarray(width_m, np.float64)
    classes = np.asarray(size_class, dtype=object)
    placed = np.isfinite(x) & np.isfinite(y)
    size = np.where(np.isfinite(w), np.clip(w, 0.01, None), 0.05)
    size = 8 + 400 * size / max(float(np.nanmax(size[placed])) if placed.any() else 1.0, 1e-6)
    for name in ("sample", "obstacle"):
        sel = placed & (classes == name)
        if sel.any():
            ax.scatter(
                x[sel],
                y[sel],
                s=size[sel],
                c=_CLASS_COLORS[name],
                alpha=0.55,
                edgecolors="none",
                label=f"{name} ({int(sel.sum())})",
            )
    other = placed & ~np.isin(classes, ("sample", "obstacle"))
    if other.any():
        ax.scatter(
            x[other],
            y[other],
            s=size[other],
            c=_OTHER_COLOR,
            alpha=0.55,
            edgecolors="none",
            label=f"unclassified ({int(other.sum())})",
        )
    ax.plot([0], [0], marker="^", color="k", ms=9, ls="none", label="camera")
    ax.set_xlabel("x, right (m)")
    ax.set_ylabel("y, forward (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, color="0.92")
    ax.legend(fontsize=8, loc="upper left")
    n_missing = int((~placed).sum())
    title = "rock positions, top view"
    if n_missing:
        title += f" ({n_missing} without depth not shown)"
    ax.set_title(title, fontsize=10)
    return _png(fig)


def compact_png(data: bytes, *, max_bytes: int = _COMPACT_ABOVE) -> bytes:
    """PNG bytes re-encoded with a 256-colour palette when larger than ``max_bytes``.

    Quicklooks are gray images with a few coloured overlays: a palette keeps them legible at
    about a tenth of the size (a 500 x 500 frame: ~330 KB -> ~30 KB), which is what keeps a
    report of 50 frames a few MB. The original is returned when that does not shrink it.
    """
    if len(data) <= max_bytes:
        return data
    from PIL import Image

    image = Image.open(io.BytesIO(data)).convert("RGB")
    palette = image.quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    buffer = io.BytesIO()
    palette.save(buffer, format="PNG", compress_level=9)
    smaller = buffer.getvalue()
    return smaller if len(smaller) < len(data) else data


def frame_quicklooks(
    root: str,
    frame_id: str,
    index: int,
    *,
    products: Any,
    range_step_m: float,
    reference: str = "right",
    done_stages: Collection[str] | None = None,
) -> dict[str, bytes]:
    """The frame's three quicklook PNGs: the stage's files under the products ``root`` (a
    directory or URL) when present, else drawn from the products (``products``: the run's
    ``zarr.Group`` or None) over the ``reference`` image; missing inputs skip a figure.

    ``done_stages`` (the stages current for the frame, from ``frames.parquet``) limits both
    to current results: a failed or pending frame's files and slabs may be an earlier
    run's. Without the segment stage the objects figure is the bare reference image.

    Returns
    -------
    dict of str to bytes
        Keys of :data:`QUICKLOOKS` that could be made.
    """
    from stages.quicklook import (
        encode_png,
        objects_image,
        range_contours_image,
        residual_image,
    )

    out: dict[str, bytes] = {}
    cache: dict[str, np.ndarray | None] = {}

    def current(name: str) -> bool:
        return done_stages is None or _PRODUCER.get(name, "") in done_stages

    def array(name: str) -> np.ndarray | None:
        if name not in cache:
            cache[name] = None
            if products is not None and name in products and current(name):
                cache[name] = np.asarray(products[name][index])
            elif name == "labels" and products is not None and current(reference):
                # no current labels: the bare reference image, not an earlier run's outlines
                image = array(reference)
                cache[name] = None if image is None else np.zeros(image.shape, np.int32)
        return cache[name]

    draw = {
        "objects": ((reference, "labels"), lambda a: objects_image(a[reference], a["labels"])),
        "range_contours": (
            (reference, "range"),
            lambda a: range_contours_image(a[reference], a["range"], step_m=range_step_m),
        ),
        "residual": (
            ("left", "right", "residual"),
            lambda a: residual_image(a["left"], a["right"], a["residual"], reference=reference),
        ),
    }
    for name, (inputs, render) in draw.items():
        stored = None
        if done_stages is None or "quicklook" in done_stages:
            stored = read_product_file(root, f"quicklooks/{frame_id}/{name}.png")
        if stored is not None:
            out[name] = compact_png(stored)
            continue
        arrays: Mapping[str, np.ndarray | None] = {n: array(n) for n in inputs}
        if any(v is None for v in arrays.values()):
            continue
        last = arrays[inputs[-1]]
        if name != "objects" and last is not None and not np.isfinite(last).any():
            continue  # depth never ran for this frame: nothing to draw over the image
        out[name] = compact_png(encode_png(render(arrays)))
    return out
