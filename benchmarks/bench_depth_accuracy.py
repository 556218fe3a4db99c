"""Depth accuracy on the built-in archetypes: arroyo's matcher against OpenCV StereoSGBM.

Renders a few frames per archetype with ``pipeline.synth.render_pair``, matches them with
``stages._stereo.match_disparity`` (the depth stage's math, search range as the stage derives
it from the camera) and with the evaluate module's StereoSGBM baseline on the same range,
and prints bad-1 / bad-2 / EPE / density pooled over the frames (non-occluded truth pixels,
``pipeline.metrics`` conventions). The ``adaptive`` method's larger windows search each row's
band the stage derives from the camera pose (``depth.floor_margin``, ``depth.ceiling_ratio``;
``--set floor_margin=1 ceiling_ratio=0`` searches the whole range, as before depth stage
version 4).

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_accuracy.py [--frames 3] \
        [--archetypes lab,mojave,lava,dunes] [--methods adaptive,sgm] [--set name=value ...]
"""

from __future__ import annotations

import argparse
import time

from _overrides import matching_settings  # sibling module (benchmarks/ is on sys.path)

from pipeline._baselines import sgbm_disparity
from pipeline.camera import Camera
from pipeline.metrics import disparity_errors, pool_disparity_errors
from pipeline.synth import render_pair
from stages._stereo import match_disparity
from stages.depth import resolve_row_band, resolve_row_gradient
from stages.geometry import derive_max_disparity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--archetypes", default="lab,mojave,lava,dunes")
    parser.add_argument("--methods", default="adaptive,sgm")
    parser.add_argument("--set", nargs="*", default=[], help="match_disparity keyword=value")
    args = parser.parse_args()
    settings, band_params = matching_settings(args.set)
    methods = args.methods.split(",")
    print(
        f"{'archetype':<10}{'method':<12}{'bad1':>8}{'bad2':>8}{'epe':>8}{'density':>9}"
        f"{'s/frame':>9}"
    )
    for archetype in args.archetypes.split(","):
        per: dict[str, list] = {m: [] for m in [*methods, "sgbm"]}
        secs: dict[str, float] = {m: 0.0 for m in per}
        for seed in range(args.frames):
            left, right, truth, _, cam = render_pair(archetype, seed=seed, size=args.size)
            camera = Camera(
                **{k: cam[k] for k in ("focal_px", "baseline_m", "height_m", "pitch_deg")}
            )
            hi = derive_max_disparity(camera, shape=right.shape)
            keep = ~truth["occluded"]
            for method in methods:
                t0 = time.perf_counter()
                stage_params = {**band_params, "method": method}
                band = resolve_row_band(camera, right.shape, stage_params)
                gradient = resolve_row_gradient(camera, right.shape, stage_params)
                m = match_disparity(
                    right, left, min_disparity=0, max_disparity=hi, method=method,
                    row_min_disparity=band[0], row_max_disparity=band[1],
                    row_gradient=gradient, **settings,
                )  # fmt: skip
                secs[method] += time.perf_counter() - t0
                per[method].append(
                    disparity_errors(m.disparity, truth["disparity"], valid_truth=keep)
                )
            t0 = time.perf_counter()
            s = sgbm_disparity(left, right, min_disparity=0, max_disparity=hi)
            secs["sgbm"] += time.perf_counter() - t0
            per["sgbm"].append(disparity_errors(s, truth["disparity"], valid_truth=keep))
        for method, rows in per.items():
            r = pool_disparity_errors(rows)
            print(
                f"{archetype:<10}{method:<12}{r['bad1']:8.4f}{r['bad2']:8.4f}{r['epe']:8.3f}"
                f"{r['density']:9.3f}{secs[method] / args.frames:9.3f}"
            )


if __name__ == "__main__":
    main()
