"""Footprint extents across and along the line of sight against the truth rock's extents.

The describe stage's ``width_m`` is the largest dimension of a rock's footprint: its ground
points (pixels projected with a disparity surface fitted per object) projected on 60
directions. This benchmark splits that measurement by axis on the truth labels of finished
``arroyo run`` directories: the spread of the footprint along the ground x axis (across the
view) and y axis (along the view), one pixel added as in
:func:`stages._footprint.footprint_dimensions`, against the truth's ``extent_x_m`` and
``extent_y_m``. Rocks within ``--near`` m, seen whole; the whole truth region (no fringe
trimming, no outlier rule). Disparity per pixel from the truth or the run (``--depth``),
either raw or on the describe stage's fitted disparity
(:func:`stages._footprint.footprint_disparity`). Prints per archive the median signed and absolute
relative error of each axis.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_footprint_axes.py --depth truth \\
        runs/eval/lab runs/eval/mojave runs/eval/lava
"""

from __future__ import annotations

import argparse

import numpy as np
from _rundir import open_run  # sibling module (benchmarks/ is on sys.path)

from stages._footprint import footprint_disparity
from stages._ground import frame_ground, pixel_points


def _axis_errors(rundir: str, depth: str, near: float) -> tuple[str, dict[str, list[float]]]:
    run = open_run(rundir)
    camera = run.camera
    out: dict[str, list[float]] = {}
    for frame in run.frames():
        labels = frame.truth["labels"]
        disparity = frame.truth["disparity"] if depth == "truth" else frame.product("disparity")
        ground = frame_ground(camera, frame.product("ground_plane"))
        if ground is None:
            continue
        for rock in frame.rocks:
            if rock["touches_border"] or rock["range_m"] > near:
                continue
            rows, cols = np.nonzero(labels == rock["rock_id"])
            d = disparity[rows, cols].astype(np.float64)
            d[~(d > 0)] = np.nan
            if np.count_nonzero(np.isfinite(d)) < 10:
                continue
            pixel_m = float(np.nanmedian(camera.k_m_px / d)) / camera.focal_px
            surfaces = {
                "raw": d,
                "fitted": footprint_disparity(rows, cols, d),
            }
            for name, surface in surfaces.items():
                p = ground.to_ground(
                    pixel_points(rows, cols, surface, camera=camera, shape=labels.shape)
                )
                p = p[np.isfinite(p).all(axis=1)]
                for axis, truth in ((0, rock["extent_x_m"]), (1, rock["extent_y_m"])):
                    key = f"{name}_{'xy'[axis]}"
                    spread = float(np.ptp(p[:, axis]))
                    out.setdefault(key, []).append((spread + pixel_m) / truth - 1)
                    out.setdefault(f"{key}_no_px", []).append(spread / truth - 1)
            out.setdefault("size_px", []).append(rock["extent_x_m"] / pixel_m)
    return run.archive, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundirs", nargs="+", help="finished arroyo run directories")
    parser.add_argument("--depth", choices=("truth", "run"), default="truth")
    parser.add_argument("--near", type=float, default=2.0)
    parser.add_argument(
        "--by-size",
        action="store_true",
        help="also the across-view extent by the rock's size in pixels, with and without "
        "the one pixel footprint_dimensions adds",
    )
    args = parser.parse_args()
    pooled: dict[str, dict[str, list[float]]] = {}
    for rundir in args.rundirs:
        archive, errors = _axis_errors(rundir, args.depth, args.near)
        for key, values in errors.items():
            pooled.setdefault(archive, {}).setdefault(key, []).extend(values)
    keys = ("raw_x", "raw_y", "fitted_x", "fitted_y")
    print(f"depth from {args.depth}: median signed (median |.|) relative error of the extent")
    print(f"{'archive':8} {'rocks':>5} " + " ".join(f"{k:>16}" for k in keys))
    for archive, errors in sorted(pooled.items()):
        cells = []
        for key in keys:
            e = np.asarray(errors.get(key, []))
            cells.append(f"{np.median(e):+.3f} ({np.median(np.abs(e)):.3f})" if e.size else "-")
        n = len(errors.get("raw_x", []))
        print(f"{archive:8} {n:5d} " + " ".join(f"{c:>16}" for c in cells))
    if args.by_size:
        _by_size(pooled)


def _by_size(pooled: dict[str, dict[str, list[float]]]) -> None:
    """Median signed error of the across-view extent per size bin (truth extent_x in px)."""
    edges = (0, 12, 18, 25, 40, 10_000)
    keys = ("raw_x", "raw_x_no_px", "fitted_x", "fitted_x_no_px")
    print(f"{'archive':8} {'size px':>9} {'rocks':>5} " + " ".join(f"{k:>14}" for k in keys))
    for archive, errors in sorted(pooled.items()):
        size = np.asarray(errors["size_px"])
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            sel = (size > lo) & (size <= hi)
            if not sel.any():
                continue
            cells = [f"{np.median(np.asarray(errors[k])[sel]):+14.3f}" for k in keys]
            print(
                f"{archive:8} {f'{lo}-{hi}' if hi < 10_000 else f'>{lo}':>9} "
                f"{int(sel.sum()):5d} " + " ".join(cells)
            )


if __name__ == "__main__":
    main()
