"""Figures of the run report as PNG bytes: per-archive rock plots (matplotlib, no pyplot
state, Agg canvas), per-frame quicklooks (the quicklook stage's PNGs, or drawn from
``products.zarr`` with the same functions when the stage did not write them) and the
frame's scene graph (OpenCV, over the reference image from ``products.zarr``)."""

from __future__ import annotations

import io
import math
from collections.abc import Collection, Mapping, Sequence
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
    "GRAPH_CLASS_COLORS",
    "GRAPH_EDGE_COLORS",
    "GRAPH_DRAWN",
    "scene_graph_image",
    "relation_counts",
    "scene_graph_caption",
    "frame_scene_graph",
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


# -- scene graph -----------------------------------------------------------------------------
#: size class -> (B, G, R) of the scene graph's discs (bright on the dimmed gray image; the
#: hues of the per-archive plots' sample blue and obstacle red)
GRAPH_CLASS_COLORS: dict[str, tuple[int, int, int]] = {
    "sample": (255, 190, 70),  # sky blue
    "obstacle": (40, 110, 255),  # orange
}
_GRAPH_OTHER_BGR = (235, 80, 235)  # magenta: any other size class (None, NaN, '')
#: drawn relation -> (B, G, R) of its stroke: a white line, a yellow arrow
GRAPH_EDGE_COLORS: dict[str, tuple[int, int, int]] = {
    "adjacent": (235, 235, 235),
    "occludes": (0, 235, 255),
}
_GRAPH_COLOR_NAMES = {"sample": "blue", "obstacle": "orange"}
#: the relations :func:`scene_graph_image` draws; the ordering ones (left_of, right_of,
#: in_front_of, behind: ~230 rows each per lava frame) would cover the image
GRAPH_DRAWN = tuple(GRAPH_EDGE_COLORS)
_NODE_COLUMNS = ("object_id", "centroid_x", "centroid_y", "size_class")
_EDGE_COLUMNS = ("subject_id", "relation", "object_id")


def _graph_columns(name: str, table: Any, required: Sequence[str]) -> dict[str, np.ndarray]:
    """The ``required`` columns of a mapping (or pyarrow.Table) as 1-D arrays of one length."""
    if hasattr(table, "column_names") and hasattr(table, "to_pydict"):  # pyarrow.Table
        table = table.select([c for c in required if c in table.column_names]).to_pydict()
    if not isinstance(table, Mapping):
        raise TypeError(
            f"{name} must be a mapping of column name to (K,) array (a dict, or a "
            f"pyarrow.Table), got {type(table).__name__}; pass e.g. "
            f"{{'{required[0]}': [...], ...}}"
        )
    missing = [c for c in required if c not in table]
    if missing:
        raise ValueError(
            f"{name} lacks the column(s) {missing}: expected {list(required)}, got "
            f"{sorted(map(str, table))}; pass the {name} table's columns"
        )
    out = {c: np.asarray(table[c], dtype=object) for c in required}
    shapes = {c: a.shape for c, a in out.items()}
    if any(len(s) != 1 for s in shapes.values()) or len({s[0] for s in shapes.values()}) > 1:
        raise ValueError(
            f"{name}'s columns must be 1-D and of one length, got shapes {shapes}; pass one "
            "value per row in every column"
        )
    return out


def _as_ids(name: str, values: np.ndarray) -> np.ndarray:
    try:
        ids = values.astype(np.float64)
    except (TypeError, ValueError):
        ids = np.full(values.shape, np.nan)
    if not (np.isfinite(ids).all() and (ids == np.round(ids)).all()):
        raise ValueError(
            f"{name} must hold integer object ids, got {values[:5].tolist()!r}...; pass the "
            "ids of the labels image"
        )
    return ids.astype(np.int64)


def scene_graph_image(
    image: np.ndarray,
    nodes: Mapping[str, Any],
    edges: Mapping[str, Any],
    *,
    dim: float = 0.5,
    radius_px: int | None = None,
    label_ids: bool = True,
) -> np.ndarray:
    """The frame's scene graph over its dimmed reference image.

    Objects are filled discs at their centroids, coloured by size class
    (:data:`GRAPH_CLASS_COLORS`; magenta for any other class), with their id beside them.
    Of the edges only :data:`GRAPH_DRAWN` are drawn, between centroids: ``adjacent`` as a
    white line (one per pair, stored in both directions), ``occludes`` as a yellow arrow from
    the occluder to the occluded object, its head at the occluded disc's rim. Lines and
    arrows have a black outline so they read on light and dark ground alike. Edges naming
    an id without a node or with a non-finite centroid, and self-edges, are not drawn.

    Parameters
    ----------
    image : (M, N) ndarray
        Gray reference image (uint8; other dtypes are clipped to 0..255).
    nodes : mapping of str to (K,) array, or pyarrow.Table
        Columns ``object_id`` (int), ``centroid_x``, ``centroid_y`` (float, pixels: column
        and row; NaN: not drawn) and ``size_class`` (``'sample'`` | ``'obstacle'`` | other)
        of the descriptors table; other columns are ignored. Ids must be unique.
    edges : mapping of str to (E,) array, or pyarrow.Table
        Columns ``subject_id``, ``relation``, ``object_id`` of the relations table.
    dim : float
        Share of the image's brightness taken away, in [0, 1] (1: black background).
    radius_px : int, optional
        Disc radius, >= 1 pixels; default ``max(3, min(M, N) // 125)`` (4 for 500 x 500).
    label_ids : bool
        Write each object's id beside its disc.

    Returns
    -------
    (M, N, 3) ndarray of uint8
        BGR image (OpenCV's channel order, as the quicklooks).

    Raises
    ------
    TypeError
        ``nodes`` or ``edges`` is not a mapping of columns.
    ValueError
        A 2-D image was not given, a column is missing or of another length, ids are not
        integers or repeat, or a setting is out of range.
    """
    import cv2

    from stages.quicklook import _coerce_image, _text

    if isinstance(dim, bool) or not isinstance(dim, int | float) or not 0 <= dim <= 1:
        raise ValueError(f"dim must be a number in [0, 1], got {dim!r}; 0.5 halves brightness")
    if radius_px is not None and (
        isinstance(radius_px, bool) or not isinstance(radius_px, int) or radius_px < 1
    ):
        raise ValueError(f"radius_px must be an int >= 1 or None (automatic), got {radius_px!r}")
    gray = _coerce_image("image", image)
    node_cols = _graph_columns("nodes", nodes, _NODE_COLUMNS)
    edge_cols = _graph_columns("edges", edges, _EDGE_COLUMNS)
    ids = _as_ids("nodes['object_id']", node_cols["object_id"])
    if np.unique(ids).size != ids.size:
        raise ValueError(
            f"nodes['object_id'] must be unique, got {ids.size} rows for "
            f"{np.unique(ids).size} ids; pass one frame's descriptors"
        )
    try:
        cx = node_cols["centroid_x"].astype(np.float64)
        cy = node_cols["centroid_y"].astype(np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            "nodes['centroid_x'] and nodes['centroid_y'] must be numbers (pixels; NaN for "
            f"none), got {node_cols['centroid_x'][:3].tolist()!r} and "
            f"{node_cols['centroid_y'][:3].tolist()!r}"
        ) from None
    subj = _as_ids("edges['subject_id']", edge_cols["subject_id"])
    obj = _as_ids("edges['object_id']", edge_cols["object_id"])
    relation = edge_cols["relation"]

    h, w = gray.shape
    radius = radius_px if radius_px is not None else max(3, min(h, w) // 125)
    out = cv2.cvtColor(cv2.convertScaleAbs(gray, alpha=1.0 - float(dim)), cv2.COLOR_GRAY2BGR)
    placed = np.isfinite(cx) & np.isfinite(cy)
    # beyond any image: drawing clips, and int() of a huge float must not overflow OpenCV
    px = np.clip(np.where(placed, cx, 0.0), -(w + 1), 2 * w + 1).round().astype(np.int64)
    py = np.clip(np.where(placed, cy, 0.0), -(h + 1), 2 * h + 1).round().astype(np.int64)
    where = {int(i): k for k, i in enumerate(ids) if placed[k]}

    pairs: set[tuple[int, int]] = set()
    arrows: set[tuple[int, int]] = set()
    for s, r, o in zip(subj.tolist(), relation.tolist(), obj.tolist(), strict=True):
        a, b = where.get(s), where.get(o)
        if a is None or b is None or a == b:
            continue
        if r == "adjacent":
            pairs.add((min(a, b), max(a, b)))
        elif r == "occludes":
            arrows.add((a, b))

    def point(k: int) -> tuple[int, int]:
        return int(px[k]), int(py[k])

    head_px = max(6.0, 2.0 * radius)
    shafts: list[tuple[tuple[int, int], tuple[int, int], float]] = []
    for a, b in sorted(arrows):
        start = np.array(point(a), np.float64)
        vector = np.array(point(b), np.float64) - start
        length = float(np.hypot(*vector))
        if length < 1:
            continue
        # the head ends at the occluded disc's rim, where it stays visible
        end = start + vector * max(length - radius - 1, 0.5 * length) / length
        tip = min(0.5, head_px / max(float(np.hypot(*(end - start))), 1.0))
        shafts.append(((int(px[a]), int(py[a])), (round(end[0]), round(end[1])), tip))
    # black outlines under the discs, the coloured strokes over them: rocks in contact have
    # centroids ~10 px apart, and a line drawn only between the discs would not show
    for a, b in sorted(pairs):
        cv2.line(out, point(a), point(b), (0, 0, 0), 4, cv2.LINE_AA)
    for p0, p1, tip in shafts:
        cv2.arrowedLine(out, p0, p1, (0, 0, 0), 4, cv2.LINE_AA, tipLength=tip)
    classes = node_cols["size_class"]
    for k in np.flatnonzero(placed).tolist():
        color = GRAPH_CLASS_COLORS.get(str(classes[k]), _GRAPH_OTHER_BGR)
        cv2.circle(out, point(k), radius, color, -1, cv2.LINE_AA)
        cv2.circle(out, point(k), radius, (0, 0, 0), 1, cv2.LINE_AA)
    for a, b in sorted(pairs):
        cv2.line(out, point(a), point(b), GRAPH_EDGE_COLORS["adjacent"], 2, cv2.LINE_AA)
    for p0, p1, tip in shafts:
        cv2.arrowedLine(out, p0, p1, GRAPH_EDGE_COLORS["occludes"], 2, cv2.LINE_AA, tipLength=tip)
    if label_ids:
        scale = 0.35 if min(h, w) < 300 else 0.45  # as stages.quicklook._text draws
        for k in np.flatnonzero(placed).tolist():
            x, y = point(k)
            text = str(int(ids[k]))
            (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
            # upper right of the disc, kept inside the image (ids at the border stay whole)
            org = (min(x + radius + 1, w - tw - 1), max(y - radius + 1, th + 2))
            _text(out, text, org, (255, 255, 255))
    return out


def relation_counts(relations: Sequence[Any]) -> dict[str, int]:
    """Edge rows per relation: the six of :data:`stages._relations.RELATIONS` in their order
    (0 when absent), then any other names found, in order of first appearance.

    Parameters
    ----------
    relations : (E,) sequence of str
        The ``relation`` column of one frame's edges.
    """
    from stages._relations import RELATIONS

    counts = dict.fromkeys(RELATIONS, 0)
    for name in relations:
        counts[str(name)] = counts.get(str(name), 0) + 1
    return counts


def scene_graph_caption(counts: Mapping[str, int], *, unclassified: bool = False) -> str:
    """The scene-graph figure's caption: legend, what is left out, and the frame's relation
    counts (``counts``: :func:`relation_counts`); ``unclassified`` adds the magenta disc."""
    colors = ", ".join(f"{_GRAPH_COLOR_NAMES[c]} = {c}" for c in GRAPH_CLASS_COLORS)
    if unclassified:
        colors += ", magenta = no size class"
    hidden = ", ".join(name for name in counts if name not in GRAPH_DRAWN)
    text = (
        f"Scene graph: objects at their centroids ({colors}); white line = adjacent, "
        "yellow arrow = occludes (from the nearer object). "
        f"Not drawn: {hidden}."
    )
    if not any(counts.values()):
        return f"{text} This frame has no relations."
    listed = []
    for name, n in counts.items():
        item = f"{name} {n}"
        if name == "adjacent" and n:
            pairs = n // 2  # stored in both directions
            item += f" ({pairs} pair{'s' if pairs != 1 else ''})"
        listed.append(item)
    return f"{text} Edge rows in this frame: {', '.join(listed)}."


def frame_scene_graph(
    index: int,
    *,
    products: Any,
    nodes: Mapping[str, Any],
    edges: Mapping[str, Any],
    reference: str = "right",
    done_stages: Collection[str] | None = None,
) -> bytes | None:
    """The frame's scene graph as PNG bytes (:func:`scene_graph_image` over the
    ``reference`` image of ``products``, the run's ``zarr.Group``), compacted as the
    quicklooks are; None without products, objects, or a current ingest and describe
    (``done_stages``, as for :func:`frame_quicklooks`)."""
    from stages.quicklook import encode_png

    if products is None or reference not in products or index < 0:
        return None
    if done_stages is not None and not {"ingest", "describe"} <= set(done_stages):
        return None
    columns = _graph_columns("nodes", nodes, _NODE_COLUMNS)
    if columns["object_id"].size == 0:
        return None
    image = np.asarray(products[reference][index])
    return compact_png(encode_png(scene_graph_image(image, nodes, edges)))
