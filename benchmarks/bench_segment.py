"""Segmentation benchmark: speed per 500x500 frame and object F1 per archetype.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py              # speed + scores
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --frames 4 --archetypes lab lava
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --depth stage   # depth stage input
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --depth stage --scores-only \
        --set depth.subpixel=parabola min_area_px=20  # depth param, segment_image keyword
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --speed-only
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --stage-speed  # + describe
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --stage-speed --archetypes lava \
        --set band_sigmas=2.5 blob_sigmas=4  # the lava catalog's segment settings
    PYTHONPATH=. .venv/bin/python benchmarks/bench_segment.py --rundir runs/eval/lava \
        --truth-depth  # a run's frames with the truth's depth: the depth stage made perfect

``--stage-speed`` prints the CPU time per frame of the segment and describe stages (the
engine's entry points, depth stage products as input) for ``--frames`` seeds of each
archetype, best of ``min(--repeats, 3)``.

Speed: milliseconds per frame of :func:`stages.segment.segment_image` on one core (OpenCV
single-threaded), best and median of ``--repeats`` runs, for both methods (the best is the
cost of the code; the median includes whatever else the machine is doing).

Scores: object precision / recall / F1 at IoU >= 0.5 over truth rocks of at least 30 visible
pixels (``pipeline.metrics``, the scorer of ``arroyo evaluate``), pooled over the frames of
each archetype rendered by ``pipeline.synth.render_pair``, for the faithful method, the depth
method and the global Otsu baseline. ``--depth truth`` feeds the true height and disparity
(plus ``--depth-noise`` px of Gaussian disparity noise) to isolate the segmentation from the
depth stage; ``--depth stage`` runs ``stages.depth`` first.

``--set`` takes ``segment_image`` keywords as ``KEY=VALUE`` (scores and ``--rundir``) and,
with ``--depth stage``, depth stage parameters as ``depth.PARAM=VALUE``, parsed and checked
like ``arroyo run --set`` (an unknown one is an error that lists the stage's parameters;
``benchmarks/_overrides.py``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import cv2
import numpy as np

# sibling modules: benchmarks/ is on sys.path when one of its scripts runs
from _overrides import depth_products, keyword_overrides, stage_overrides
from _rundir import open_run

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.metrics import pool_segmentation_scores, segmentation_scores
from stages.segment import segment_image

ARCHETYPES = ("lab", "mojave", "lava", "dunes")


def _handmade_frame(size: int = 500, seed: int = 0) -> np.ndarray:
    """A 500x500 gradient-lit ground with dark and light disks, when no renderer exists."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    image = 120 + 50 * xx / size + rng.normal(0, 6, (size, size))
    for _ in range(25):
        cy, cx, r = rng.integers(0, size), rng.integers(0, size), rng.integers(5, 30)
        image[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.choice([40, 230])
    return np.clip(image, 0, 255).astype(np.uint8)


def _render(archetype: str, seed: int, size: int):
    from pipeline.synth import render_pair

    left, right, truth, _, camera = render_pair(archetype, seed=seed, size=size)
    return left, right, truth, Camera(**camera)


def _time_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Best and median wall time in ms; the best is the one-core cost on a busy machine."""
    fn()  # warm-up (imports, caches)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.min(times)), 1e3 * float(np.median(times))


def speed(repeats: int, size: int) -> None:
    cv2.setNumThreads(1)
    try:
        _, right, truth, _ = _render("mojave", 0, size)
        height, disparity = truth["height"], truth["disparity"]
        source = "pipeline.synth mojave seed 0"
    except ImportError:
        right = _handmade_frame(size)
        height = np.zeros(right.shape, np.float32)
        disparity = np.full(right.shape, 20.0, np.float32)
        source = "hand-made frame (pipeline.synth not available)"
    print(f"speed on a {size}x{size} frame ({source}), one core, best / median of {repeats}:")
    for method in ("sector-histogram", "sector-histogram+depth"):
        for sectors in (16, 8):
            best, median = _time_ms(
                lambda m=method, s=sectors: segment_image(
                    right, method=m, sectors=s, height=height, disparity=disparity
                ),
                repeats,
            )
            print(f"  {method:24s} {sectors:2d}x{sectors:<2d} {best:7.1f} / {median:7.1f} ms/frame")


def stage_speed(
    archetypes,
    frames: int,
    size: int,
    repeats: int,
    stages=("segment", "describe"),
    profile: int = 0,
    segment_overrides: dict | None = None,
) -> None:
    """CPU ms per frame of the segment and describe stages as the engine runs them.

    Each frame is rendered, run through the depth stage once, then ``segment`` (on the depth
    products) and ``describe`` (on segment's labels) are timed with ``time.process_time``
    (CPU time of this process: other agents on the machine do not count, library threads
    do), best of ``repeats``, OpenCV single-threaded. ``profile`` > 0 also runs each stage
    once more per frame under cProfile and prints its ``profile`` costliest functions (own
    time), over all frames: where a stage's time goes. ``segment_overrides`` (``--set``)
    replace segment stage defaults, e.g. a catalog's ``[params.segment]``.
    """
    import cProfile
    import pstats

    from pipeline.stage import FrameContext
    from stages import describe as describe_stage
    from stages import segment as segment_stage

    cv2.setNumThreads(1)
    chosen = {"segment": segment_stage.STAGE, "describe": describe_stage.STAGE}
    params = {name: dict(stage.defaults()) for name, stage in chosen.items()}
    params["segment"].update(segment_overrides or {})
    profilers = {name: cProfile.Profile() for name in stages}
    print(f"stage CPU time per {size}x{size} frame (process_time, best of {repeats}):")
    print(f"{'archetype':9s} {'seed':>4s} " + " ".join(f"{name:>10s}" for name in stages))
    for archetype in archetypes:
        per_stage: dict[str, list[float]] = {name: [] for name in stages}
        for seed in range(frames):
            left, right, _, camera = _render(archetype, seed, size)
            frame = FrameContext(frame_id="bench", archive="bench", camera=camera)
            inputs = {"left": left, "right": right}
            inputs.update(depth_products(left, right, camera=camera))
            inputs.update(
                segment_stage.STAGE.run(inputs, frame=frame, params=params["segment"]).arrays
            )
            for name in stages:
                stage = chosen[name]
                best = float("inf")
                for _ in range(repeats):
                    start = time.process_time()
                    stage.run(inputs, frame=frame, params=params[name])
                    best = min(best, time.process_time() - start)
                per_stage[name].append(1e3 * best)
                if profile:
                    profilers[name].runcall(stage.run, inputs, frame=frame, params=params[name])
            row = " ".join(f"{per_stage[name][-1]:8.1f}ms" for name in stages)
            print(f"{archetype:9s} {seed:4d} {row}")
        mean = " ".join(f"{np.mean(per_stage[name]):8.1f}ms" for name in stages)
        print(f"{archetype:9s} mean {mean}")
    for name in stages if profile else ():
        print(f"\n{name}: the {profile} functions with the most own time, all frames")
        pstats.Stats(profilers[name]).sort_stats("tottime").print_stats(profile)


def _depth_inputs(
    kind: str, left, right, truth, camera, noise_px: float, rng, depth_params: dict
):
    if kind == "truth":
        disparity = truth["disparity"].astype(np.float32)
        height = truth["height"].astype(np.float32)
        if noise_px > 0:
            # perturb height consistently with a disparity error: dh ~ dZ ~ Z * dd / d
            error = rng.normal(0, noise_px, disparity.shape).astype(np.float32)
            with np.errstate(invalid="ignore", divide="ignore"):
                range_m = camera.k_m_px / disparity if camera is not None else 2.0
                height = height + (range_m * error / disparity).astype(np.float32) * 0.5
            disparity = disparity + error
        return height, disparity
    products = depth_products(left, right, camera=camera, params=depth_params)
    return products["height"], products["disparity"]


def scores(
    archetypes,
    frames: int,
    size: int,
    depth: str,
    noise_px: float,
    overrides: dict,
    depth_params: dict | None = None,
) -> None:
    """Object scores per archetype; ``overrides`` go to ``segment_image``, ``depth_params``
    (``--depth stage``) to the depth stage."""
    from pipeline._baselines import otsu_labels

    rng = np.random.default_rng(0)
    depth_params = depth_params or {}
    header = f"{'archetype':9s} {'method':24s} {'prec':>6s} {'recall':>6s} {'F1':>6s} {'mIoU':>6s}"
    settings = "".join(f", depth.{key}={value}" for key, value in depth_params.items())
    print(f"object scores at IoU >= 0.5, {frames} frames each, depth input: {depth}{settings}")
    print(header)
    for archetype in archetypes:
        per_method: dict[str, list] = {"sector-histogram": [], "sector-histogram+depth": []}
        per_method["otsu"] = []
        for seed in range(frames):
            left, right, truth, camera = _render(archetype, seed, size)
            true_labels = truth["labels"]
            height, disparity = _depth_inputs(
                depth, left, right, truth, camera, noise_px, rng, depth_params
            )
            for method in ("sector-histogram", "sector-histogram+depth"):
                labels = segment_image(
                    right, method=method, height=height, disparity=disparity, **overrides
                ).labels
                per_method[method].append(segmentation_scores(labels, true_labels))
            per_method["otsu"].append(segmentation_scores(otsu_labels(right), true_labels))
        for method, results in per_method.items():
            pooled = pool_segmentation_scores(results)
            print(
                f"{archetype:9s} {method:24s} {pooled['precision']:6.3f} {pooled['recall']:6.3f} "
                f"{pooled['f1']:6.3f} {pooled['mean_iou']:6.3f}"
                f"   (tp {pooled['tp']:.0f} fp {pooled['fp']:.0f} fn {pooled['fn']:.0f})"
            )


def rundir_scores(
    rundirs: list[str], overrides: dict, verbose: bool = False, *, truth_depth: bool = False
) -> None:
    """Segment a finished run's frames again (its depth products) and score like evaluate.

    Reads the reference image, height and disparity of every frame of ``products.zarr``,
    runs :func:`stages.segment.segment_image` with the catalog's segment params plus
    ``overrides`` (the current code, not the run's), and pools the object scores against
    the archive's truth labels, as ``arroyo evaluate`` does. ``truth_depth`` feeds the
    truth's height and disparity instead of the run's: the segmentation's own limit when
    the depth stage is made perfect (the rules keep the thresholds tuned for the run's
    noisy heights).
    """
    for rundir in rundirs:
        run = open_run(rundir)
        params = run.segment_params()
        params.update(overrides)
        results = []
        depth_source = "truth depth" if truth_depth else ""
        for frame in run.frames():
            depth = frame.truth if truth_depth else frame
            labels = segment_image(
                frame.product(run.camera.reference),
                height=_depth_product(depth, "height"),
                disparity=_depth_product(depth, "disparity"),
                **params,
            ).labels
            results.append(segmentation_scores(labels, frame.truth["labels"]))
            if verbose:
                r = results[-1]
                print(f"  {frame.frame_id}: tp {r['tp']:.0f} fp {r['fp']:.0f} fn {r['fn']:.0f}")
        pooled = pool_segmentation_scores(results)
        print(
            f"{run.archive:9s} {params['method']:24s} {pooled['precision']:6.3f} "
            f"{pooled['recall']:6.3f} {pooled['f1']:6.3f} {pooled['mean_iou']:6.3f}"
            f"   (tp {pooled['tp']:.0f} fp {pooled['fp']:.0f} fn {pooled['fn']:.0f})  {rundir}"
            f"{'  ' + depth_source if depth_source else ''}"
        )


def _depth_product(source, name: str) -> np.ndarray:
    """A depth product of a run frame (``RunFrame.product``) or of its truth (a dict)."""
    return source[name] if isinstance(source, dict) else source.product(name)




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archetypes", nargs="+", default=list(ARCHETYPES))
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--depth", choices=("truth", "stage"), default="truth")
    parser.add_argument("--depth-noise", type=float, default=0.0, help="px, truth depth only")
    parser.add_argument("--speed-only", action="store_true")
    parser.add_argument("--scores-only", action="store_true")
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE|depth.PARAM=VALUE",
        help="segment_image keywords (KEY=VALUE) and, with --depth stage, depth stage "
        "parameters (depth.PARAM=VALUE, checked like arroyo run --set)",
    )
    parser.add_argument(
        "--stage-speed",
        action="store_true",
        help="only: CPU ms per frame of the segment and describe stages (depth stage input)",
    )
    parser.add_argument(
        "--rundir",
        nargs="+",
        help="only: segment finished run directories again (their depth products) and score",
    )
    parser.add_argument("--verbose", action="store_true", help="--rundir: per-frame counts")
    parser.add_argument(
        "--truth-depth",
        action="store_true",
        help="--rundir: segment with the truth's height and disparity instead of the run's",
    )
    parser.add_argument(
        "--profile", type=int, default=0, metavar="N", help="--stage-speed: top N functions"
    )
    args = parser.parse_args()
    # a dotted key names a stage parameter, a bare key a segment_image keyword
    staged = [item for item in args.set if "." in item.partition("=")[0]]
    overrides = keyword_overrides([item for item in args.set if item not in staged])
    if args.rundir:
        mode = "--rundir (the run's depth products)"
    elif args.stage_speed:
        mode = "--stage-speed (the stages' defaults, segment keywords from --set)"
    elif args.speed_only:
        mode = "--speed-only"
    else:
        mode = f"--depth {args.depth}"
    runs = ("depth",) if mode == "--depth stage" else ()
    try:
        depth_params = stage_overrides(
            staged, runs=runs, mode=mode, other="segment_image keywords as KEY=VALUE"
        ).get("depth", {})
        _run(args, overrides, depth_params)
    except ParamError as error:
        parser.error(str(error))


def _run(args: argparse.Namespace, overrides: dict, depth_params: dict) -> None:
    if args.rundir:
        rundir_scores(args.rundir, overrides, args.verbose, truth_depth=args.truth_depth)
        return
    if args.stage_speed:
        stage_speed(
            args.archetypes,
            args.frames,
            args.size,
            min(args.repeats, 3),
            profile=args.profile,
            segment_overrides=overrides,
        )
        return
    if not args.scores_only:
        speed(args.repeats, args.size)
    if not args.speed_only:
        scores(
            args.archetypes,
            args.frames,
            args.size,
            args.depth,
            args.depth_noise,
            overrides,
            depth_params,
        )


if __name__ == "__main__":
    main()
