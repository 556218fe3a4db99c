"""Why near rocks get the wrong size class: each of the describe stage's inputs made perfect.

For finished run directories (``--rundir``) every frame is segmented again with the current
code (the run's depth products, its catalog's segment settings, as ``bench_describe.py
--labels segment``) and described six ways, on the rocks within ``--near`` m (truth range)
that the segmented labels match (IoU >= 0.5, ``pipeline.metrics.match_objects``):

* ``pipeline``: the segmented labels on the run's disparity, range and height;
* ``masks``: the truth's labels on the run's depth products;
* ``depth``: the segmented labels on the truth's disparity, range and height;
* ``heights``: the segmented labels and the run's disparity and range, the truth's heights
  (which pixels the footprint keeps, :func:`stages._footprint.ground_fringe_keep`, and the
  class height read the height map);
* ``both``: the truth's labels and depth (the describe stage's own limit);
* ``surface``: the visible surface itself, the truth's labels and disparity placed pixel by
  pixel on the ground (no fringe rule, no fitted disparity) and measured with
  :func:`stages._footprint.footprint_dimensions`, classed with the 98th percentile of the
  truth's heights: what any footprint of the visible pixels can see.

Each rock the pipeline classes wrong gets one cause (:func:`attribute`): ``mask`` (the
truth's labels alone fix it), ``depth`` (the truth's depth alone fixes it; ``depth
(heights)`` when the truth's heights alone do), ``mask or depth`` (either alone does),
``mask+depth`` (only both together), ``describe`` (wrong on perfect inputs while the visible
surface is right: the stage's fringe rule and fitted footprint disparity) and ``visible
surface`` (wrong on the visible surface itself: the rock's hidden back, or the border cuts
it; ``border-cut`` prefixes rocks cut by the image border). The table gives the rocks each
input classes right (the same rocks), then the causes with the direction of the error
(``large``: a sample read as an obstacle).

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_class_causes.py --rundir runs/eval/lab \
        runs/eval/mojave runs/eval/lava [--near 2] [--rocks]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from pipeline.camera import Camera
from pipeline.metrics import match_objects
from stages._descriptors import classify_size
from stages._footprint import footprint_dimensions
from stages._ground import GroundFrame, frame_ground, pixel_points
from stages.describe import describe_frame
from stages.segment import segment_image

__all__ = ["COMBOS", "attribute", "visible_surface_largest"]

COMBOS: tuple[str, ...] = ("pipeline", "masks", "depth", "heights", "both", "surface")
"""The ways each rock is described, see the module docstring."""


def attribute(ok: dict[str, bool], *, border: bool = False) -> str:
    """The cause of a wrong class: which perfect input fixes it.

    Parameters
    ----------
    ok : dict of str to bool
        Class right with each of :data:`COMBOS` (a missing entry counts as wrong).
    border : bool
        The rock is cut by the image border (prefixes ``'border-cut: '``).

    Returns
    -------
    str
        ``'right'`` when the pipeline is right, else one of ``'mask'``, ``'depth'``,
        ``'depth (heights)'``, ``'mask or depth'``, ``'mask+depth'``, ``'describe'``,
        ``'visible surface'``.
    """
    get = {name: bool(ok.get(name, False)) for name in COMBOS}
    if get["pipeline"]:
        return "right"
    if get["masks"] and get["depth"]:
        cause = "mask or depth"
    elif get["masks"]:
        cause = "mask"
    elif get["depth"]:
        cause = "depth (heights)" if get["heights"] else "depth"
    elif get["both"]:
        cause = "mask+depth"
    elif get["surface"]:
        cause = "describe"
    else:
        cause = "visible surface"
    return f"border-cut: {cause}" if border else cause


def visible_surface_largest(
    rows: np.ndarray,
    cols: np.ndarray,
    disparity: np.ndarray,
    *,
    camera: Camera,
    ground: GroundFrame,
    shape: tuple[int, int],
) -> float:
    """Largest horizontal dimension of a rock's visible pixels placed one by one on the ground.

    Parameters
    ----------
    rows, cols : (K,) ndarray of int
        The rock's pixels.
    disparity : (K,) ndarray of float
        Their (true) disparity, px; NaN or <= 0 where unknown (left out).
    camera : Camera
    ground : GroundFrame
    shape : (int, int)
        Image shape.

    Returns
    -------
    float
        Metres, the larger of :func:`stages._footprint.footprint_dimensions`' width and
        length; NaN with fewer than two valid pixels.
    """
    d = np.asarray(disparity, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    if np.count_nonzero(ok) < 2:
        return float("nan")
    points = ground.to_ground(
        pixel_points(np.asarray(rows)[ok], np.asarray(cols)[ok], d[ok], camera=camera, shape=shape)
    )
    pixel_m = float(np.median(camera.k_m_px / d[ok])) / camera.focal_px
    width, length = footprint_dimensions(points[:, 0], points[:, 1], pixel_m=pixel_m)
    return float(np.nanmax([width, length]))


def _classes(desc: dict) -> dict[int, str]:
    return dict(zip(desc["object_id"].tolist(), desc["size_class"].tolist(), strict=True))


def _run_rows(rundir: str, near: float) -> list[dict]:
    """One row per near rock the segmented labels match: its class with each combo."""
    # sibling module: benchmarks/ is on sys.path when this script runs (not when a test
    # imports attribute)
    from _rundir import open_run

    run = open_run(rundir)
    camera = run.camera
    params = run.segment_params()
    name = rundir.rstrip("/").split("/")[-1]
    out = []
    for frame in run.frames():
        image = frame.product(camera.reference)
        disp, rng, hgt = (frame.product(k) for k in ("disparity", "range", "height"))
        plane = frame.product("ground_plane")
        truth = frame.truth
        true_labels = truth["labels"]
        labels = segment_image(image, height=hgt, disparity=disp, **params).labels

        def describe(lab, d, r, h, image=image, plane=plane):
            desc, _, _ = describe_frame(lab, image, d, r, h, camera=camera, ground_plane=plane)
            return _classes(desc)

        t_disp, t_rng, t_hgt = truth["disparity"], truth["range"], truth["height"]
        pred = {
            "pipeline": describe(labels, disp, rng, hgt),
            "depth": describe(labels, t_disp, t_rng, t_hgt),
            "heights": describe(labels, disp, rng, t_hgt),
        }
        by_truth = {
            "masks": describe(true_labels, disp, rng, hgt),
            "both": describe(true_labels, t_disp, t_rng, t_hgt),
        }
        ground = frame_ground(camera, plane)
        rocks = {int(r["rock_id"]): r for r in frame.rocks}
        matches = match_objects(labels, true_labels)
        for obj, rock_id in zip(matches.pred_ids.tolist(), matches.true_ids.tolist(), strict=True):
            rock = rocks.get(rock_id)
            if rock is None or not rock["range_m"] <= near:
                continue
            want = rock["size_class"]
            ok = {key: pred[key].get(obj) == want for key in pred}
            ok.update({key: by_truth[key].get(rock_id) == want for key in by_truth})
            rr, cc = np.nonzero(true_labels == rock_id)
            largest = visible_surface_largest(
                rr, cc, t_disp[rr, cc], camera=camera, ground=ground, shape=true_labels.shape
            )
            h = t_hgt[rr, cc]
            h98 = float(np.percentile(h[np.isfinite(h)], 98)) if np.isfinite(h).any() else np.nan
            ok["surface"] = (
                classify_size(largest, h98, sample_max_m=0.10, rover_clearance_m=0.10) == want
            )
            border = bool(rock["touches_border"])
            out.append(
                {
                    "run": name,
                    "frame": frame.frame_id,
                    "object": obj,
                    "rock": rock_id,
                    "truth": want,
                    "width": float(rock["width_m"]),
                    "ok": ok,
                    "cause": attribute(ok, border=border),
                    "read": "large" if want == "sample" else "small",
                }
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rundir", nargs="+", required=True, help="finished run directories")
    parser.add_argument("--near", type=float, default=2.0, help="truth range limit, metres")
    parser.add_argument("--rocks", action="store_true", help="list every wrongly classed rock")
    args = parser.parse_args()
    rows: list[dict] = []
    print(f"{'run':12} {'near':>5} " + " ".join(f"{c:>8}" for c in COMBOS))
    for rundir in args.rundir:
        part = _run_rows(rundir, args.near)
        rows.extend(part)
        label = part[0]["run"] if part else rundir
        print(
            f"{label:12} {len(part):5d} "
            + " ".join(f"{sum(r['ok'][c] for r in part):8d}" for c in COMBOS)
        )
    print(
        f"{'pooled':12} {len(rows):5d} "
        + " ".join(f"{sum(r['ok'][c] for r in rows):8d}" for c in COMBOS)
    )
    wrong = [r for r in rows if r["cause"] != "right"]
    causes = Counter((r["cause"], r["read"]) for r in wrong)
    print(f"\n{len(wrong)} wrongly classed near rocks; cause (read large / small):")
    for cause in sorted({c for c, _ in causes}):
        large, small = causes[cause, "large"], causes[cause, "small"]
        print(f"  {cause:34} {large + small:3d}  ({large} / {small})")
    close = sum(abs(r["width"] - 0.10) <= 0.0025 for r in wrong)
    print(f"  of them with the truth's width within 2.5 mm of 0.10 m: {close}")
    if args.rocks:
        for r in wrong:
            print(
                f"{r['run']:12} {r['frame']:12} object {r['object']:3d} rock {r['rock']:3d} "
                f"{r['truth']:8} width {r['width']:.3f} read {r['read']:5} {r['cause']}"
            )


if __name__ == "__main__":
    main()
