"""Depth stage on rocks: disparity scores and rock heights per archetype, with SGBM beside.

Runs the depth stage (``stages.depth.STAGE.run``, the shipped catalogs' depth settings per
archetype unless ``--set`` overrides them) on frames rendered by ``pipeline.synth.render_pair``
and prints, pooled over the frames:

* ``bad2``, ``epe``, ``density``: ``pipeline.metrics`` conventions (non-occluded pixels);
  the same for OpenCV StereoSGBM on the same range (``sgbm`` rows);
* ``rock_dh``: median |height - true height| (cm) over the visible rock pixels with a valid
  height; ``rock_top``: median over rocks (>= 30 visible px) of |95th percentile of the
  rock's heights - true 95th percentile| (cm), i.e. how well a rock's top stands out;
* ``ground_sd``: robust spread (1.4826 MAD, cm) of the height on ground pixels;
* ``ms``: wall milliseconds of the stage per frame (machine shared: indicative only;
  ``bench_depth_speed.py`` measures CPU time).

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_heights.py [--frames 3] \
        [--archetypes lab,mojave,lava,dunes] [--set name=value ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pipeline._baselines import sgbm_disparity
from pipeline.camera import Camera
from pipeline.graph import default_graph, parse_set_overrides
from pipeline.metrics import disparity_errors, pool_disparity_errors
from pipeline.stage import FrameContext
from pipeline.synth import render_pair
from stages import depth as depth_stage

#: The shipped catalogs' depth settings (catalogs/*.toml).
CATALOG_PARAMS: dict[str, dict[str, object]] = {
    "lab": {"windows": "9,15x41,31x63,63x255"},
    "dunes": {"method": "sgm"},
}


def _rock_errors(height: np.ndarray, truth: dict) -> tuple[list[float], list[float]]:
    labels, visible = truth["labels"], ~truth["occluded"]
    pixel_err: list[float] = []
    top_err: list[float] = []
    for rock in range(1, int(labels.max()) + 1):
        mask = (labels == rock) & visible
        if mask.sum() < 30:
            continue
        h, t = height[mask], truth["height"][mask]
        ok = np.isfinite(h)
        pixel_err.extend(np.abs(h[ok] - t[ok]).tolist())
        if ok.sum() >= 5:
            top_err.append(abs(float(np.percentile(h[ok], 95) - np.percentile(t, 95))))
    return pixel_err, top_err


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--archetypes", default="lab,mojave,lava,dunes")
    parser.add_argument("--no-sgbm", action="store_true")
    parser.add_argument("--set", nargs="*", default=[], help="depth stage param=value")
    args = parser.parse_args()
    # the engine's own --set parsing: typed and validated against the depth stage
    overrides = parse_set_overrides(default_graph(), [f"depth.{i}" for i in args.set]).get(
        "depth", {}
    )
    print(
        f"{'archetype':<10}{'method':<10}{'bad2':>8}{'epe':>7}{'density':>9}{'rock_dh':>9}"
        f"{'rock_top':>9}{'ground_sd':>10}{'ms':>7}"
    )
    for archetype in args.archetypes.split(","):
        params = {**depth_stage.STAGE.defaults(), **CATALOG_PARAMS.get(archetype, {})}
        params.update(overrides)
        rows, sgbm_rows, pixel_err, top_err, ground = [], [], [], [], []
        seconds = 0.0
        for seed in range(args.frames):
            left, right, truth, _, cam = render_pair(archetype, seed=seed, size=args.size)
            camera = Camera(**cam)
            frame = FrameContext(frame_id=f"{seed}", archive=archetype, camera=camera)
            t0 = time.perf_counter()
            result = depth_stage.STAGE.run(
                {"left": left, "right": right}, frame=frame, params=params
            )
            seconds += time.perf_counter() - t0
            keep = ~truth["occluded"]
            rows.append(
                disparity_errors(result.arrays["disparity"], truth["disparity"], valid_truth=keep)
            )
            height = result.arrays["height"]
            p, t = _rock_errors(height, truth)
            pixel_err += p
            top_err += t
            flat = (truth["labels"] == 0) & keep & np.isfinite(height)
            g = height[flat] - truth["height"][flat]
            ground.append(1.4826 * np.median(np.abs(g - np.median(g))) if g.size else np.nan)
            if not args.no_sgbm:
                lo = int(result.figures["min_disparity"])
                hi = int(result.figures["max_disparity"])
                s = sgbm_disparity(left, right, min_disparity=lo, max_disparity=hi)
                sgbm_rows.append(disparity_errors(s, truth["disparity"], valid_truth=keep))
        r = pool_disparity_errors(rows)
        print(
            f"{archetype:<10}{str(params['method']):<10}{r['bad2']:8.4f}{r['epe']:7.3f}"
            f"{r['density']:9.3f}{100 * np.median(pixel_err):9.2f}{100 * np.median(top_err):9.2f}"
            f"{100 * np.nanmean(ground):10.2f}{1e3 * seconds / args.frames:7.0f}"
        )
        if sgbm_rows:
            s = pool_disparity_errors(sgbm_rows)
            print(f"{archetype:<10}{'sgbm':<10}{s['bad2']:8.4f}{s['epe']:7.3f}{s['density']:9.3f}")


if __name__ == "__main__":
    main()
