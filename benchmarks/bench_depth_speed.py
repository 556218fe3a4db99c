"""Depth matching speed, single-threaded: arroyo's methods against OpenCV StereoSGBM.

Target (issue 5): the default method matches a 500 x 500 pair over 64 disparities at
>= 5 pairs/s per core (<= 200 ms). numba and OpenCV are pinned to one thread, every method
runs on the same pairs in the same process, and the median of the repeats is reported.
Times are CPU seconds of this process (``time.process_time``), so other jobs sharing the
machine inflate them less than wall-clock time would (cache sharing still does).

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_speed.py [--repeats 5] [--size 500]
        [--archetypes mojave,lava,lab,dunes] [--methods adaptive,sgm] [--set name=value ...]

``x sgbm`` is each method's time over OpenCV StereoSGBM's on the same pair in the same run.
``--set`` passes depth-stage settings (for example ``windows=9,15x41,31x63,63x255``, the lab
catalog's) to every method. ``adaptive``'s larger windows search each row's band the
depth stage derives from the rendered camera's pose (``depth.floor_margin``,
``depth.ceiling_ratio``, clipped to 0..63); ``--set floor_margin=1 ceiling_ratio=0`` searches
all 64 disparities in every row, as before depth stage version 4.

``--rundir DIR [DIR ...]`` times the whole depth stage instead (``stages.depth.run_depth``:
matching, filters, ground fit, range, height, residual) on the frames of finished runs, with
each run's recorded depth parameters and camera: CPU ms per frame, mean and median over
the run's frames after one warm-up frame::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_depth_speed.py \
        --rundir runs/eval/mojave runs/eval/lava runs/eval/lab runs/eval/dunes
"""

from __future__ import annotations

import os

os.environ["NUMBA_NUM_THREADS"] = "1"  # before numba is imported

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from _overrides import matching_settings  # noqa: E402  (benchmarks/ is on sys.path)

from pipeline._baselines import sgbm_disparity  # noqa: E402
from pipeline.camera import Camera  # noqa: E402
from pipeline.synth import render_pair  # noqa: E402
from stages._stereo import match_disparity  # noqa: E402
from stages.depth import resolve_row_band, resolve_row_gradient  # noqa: E402

D_MAX = 63  # 64 disparities, 0..63


def _median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up: numba compilation / caches
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)


def _stage_per_run(rundirs: list[str]) -> None:
    from _rundir import open_run  # benchmarks/ is on sys.path

    from pipeline.stage import FrameContext
    from stages import depth

    print("whole depth stage (run_depth), 1 thread, CPU ms per frame after one warm-up frame")
    print(f"{'run':<28}{'method':<10}{'frames':>7}{'mean':>8}{'median':>8}")
    for rundir in rundirs:
        run = open_run(rundir)
        params = {**depth.STAGE.defaults(), **run.run["stages"]["depth"]["params"]}
        frame_ids = [str(v) for v in run.products["frame"].values]
        lefts = np.asarray(run.products["left"].values)
        rights = np.asarray(run.products["right"].values)
        times = []
        for i in [0, *range(len(frame_ids))]:  # the first call compiles / loads numba caches
            context = FrameContext(frame_id=frame_ids[i], archive=run.archive, camera=run.camera)
            inputs = {"left": lefts[i], "right": rights[i]}
            t0 = time.process_time()
            depth.run_depth(inputs, frame=context, params=params)
            times.append(time.process_time() - t0)
        times = times[1:]
        print(
            f"{str(rundir)[-28:]:<28}{params['method']:<10}{len(times):>7}"
            f"{statistics.mean(times) * 1e3:8.1f}{statistics.median(times) * 1e3:8.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--archetypes", default="mojave,lava,lab,dunes")
    parser.add_argument("--methods", default="adaptive,sgm")
    parser.add_argument("--set", nargs="*", default=[], help="match_disparity keyword=value")
    parser.add_argument(
        "--rundir", nargs="+", help="time the whole depth stage on these finished runs instead"
    )
    args = parser.parse_args()
    if args.rundir:
        _stage_per_run(args.rundir)
        return
    settings, band_params = matching_settings(args.set)
    cv2.setNumThreads(1)
    methods = args.methods.split(",")
    print(
        f"{args.size}x{args.size}, disparities 0..{D_MAX}, 1 thread, median of {args.repeats}"
        + (f", settings {settings}" if settings else "")
    )
    print(f"{'archetype':<10}{'method':<10}{'ms/pair':>9}{'pairs/s':>9}{'x sgbm':>8}")
    for archetype in args.archetypes.split(","):
        left, right, _, _, cam = render_pair(archetype, seed=0, size=args.size)
        camera = Camera(**{k: cam[k] for k in ("focal_px", "baseline_m", "height_m", "pitch_deg")})
        sgbm = _median_seconds(
            lambda lft=left, rgt=right: sgbm_disparity(
                lft, rgt, min_disparity=0, max_disparity=D_MAX
            ),
            args.repeats,
        )
        for method in methods:
            stage_params = {**band_params, "method": method}
            band = resolve_row_band(camera, right.shape, stage_params)
            gradient = resolve_row_gradient(camera, right.shape, stage_params)
            secs = _median_seconds(
                lambda m=method, lft=left, rgt=right, b=band, g=gradient: match_disparity(
                    rgt, lft, min_disparity=0, max_disparity=D_MAX, method=m,
                    row_min_disparity=b[0], row_max_disparity=b[1], row_gradient=g, **settings,
                ),
                args.repeats,
            )  # fmt: skip
            print(f"{archetype:<10}{method:<10}{secs * 1e3:9.1f}{1 / secs:9.2f}{secs / sgbm:8.2f}")
        print(f"{archetype:<10}{'sgbm':<10}{sgbm * 1e3:9.1f}{1 / sgbm:9.2f}{1.0:8.2f}")


if __name__ == "__main__":
    main()
