"""Seconds per rendered stereo pair (with its ground truth), per archetype, on one core.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_synth.py [--size 500] [--pairs 3] [--stages]
Prints CPU seconds (process time) and wall seconds per pair; the first, compiling call is
excluded. ``--stages`` adds CPU seconds per pair of each stage of ``render_pair``: scene
building, the right view (ray casting, shading, shadows and the occlusion truth rays), the
left view (no truth rays), the same left view without lights (primary rays and texture
only: what shadow rays cost is the difference), and exposure plus the rock table.

Comparing two renderer versions: ``--dump DIR`` writes the pairs (seeds 0..pairs-1 of every
archetype) as ``.npz`` with whatever ``pipeline`` is on PYTHONPATH (e.g. a checkout of an
older commit), and ``--compare DIR_A DIR_B`` prints per archetype the mean absolute gray
difference of the right and left images, the share of pixels whose label differs, and how
well warping the right image by the true disparity reproduces the left in each (median and
mean absolute gray residual on visible pixels, as in tests/pipeline/synth).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from pipeline.synth import ARCHETYPES, render_pair
from pipeline.synth.archetypes import get_spec
from pipeline.synth.pair import _expose, _render, make_camera
from pipeline.synth.scene import make_scene
from pipeline.synth.truth import dense_labels, rock_table

_STAGES = ("scene", "right+truth", "left", "left unlit", "expose+table")


def _stage_times(archetype: str, variant: str | None, seed: int, size: int) -> list[float]:
    # mirrors render_pair step by step; the unlit left view is extra (diagnostic only)
    spec = get_spec(archetype, variant)
    camera = make_camera(spec, size)
    shape = (size, size)
    scene_seq, noise_seq = np.random.SeedSequence(seed).spawn(2)
    marks = [time.process_time()]
    scene = make_scene(spec, np.random.default_rng(scene_seq), camera=camera, shape=shape)
    marks.append(time.process_time())
    assert camera.height_m is not None
    right_c = np.array([0.0, 0.0, camera.height_m])
    left_c = right_c - [camera.baseline_m, 0.0, 0.0]
    rad_r, zcam, solid, _zup, _occ = _render(scene, camera, shape, right_c, left_c, True)
    marks.append(time.process_time())
    rad_l, *_ = _render(scene, camera, shape, left_c, right_c, False)
    marks.append(time.process_time())
    unlit = dataclasses.replace(scene, lights=scene.lights[:0])
    _render(unlit, camera, shape, left_c, right_c, False)
    marks.append(time.process_time())
    noise_rng = np.random.default_rng(noise_seq)
    _expose(rad_r, scene, spec, noise_rng)
    _expose(rad_l, scene, spec, noise_rng)
    labels, rock_index = dense_labels(solid, zcam)
    rock_table(
        labels, rock_index, zcam, scene.rocks, scene.perm, scene.ground, scene.ground_albedo
    )
    marks.append(time.process_time())
    return [b - a for a, b in zip(marks[:-1], marks[1:], strict=True)]


def _dump(out: Path, names: list[str], pairs: int, size: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        archetype, _, variant = name.partition("/")
        for seed in range(pairs):
            left, right, truth, _rows, _cam = render_pair(
                archetype, seed=seed, size=size, variant=variant or None
            )
            path = out / f"{name.replace('/', '_')}_{seed}.npz"
            np.savez_compressed(path, left=left, right=right, **truth)


def _warp_residual(left, right, disparity, occluded) -> np.ndarray:
    rows = []
    w = right.shape[1]
    for y in range(right.shape[0]):
        xs = np.flatnonzero(~occluded[y])
        xl = xs + disparity[y, xs]
        keep = (xl >= 2) & (xl <= w - 3)
        predicted = right[y, xs[keep]].astype(float)
        rows.append(np.abs(predicted - left[y, np.round(xl[keep]).astype(int)]))
    return np.concatenate(rows)


def _compare(dir_a: Path, dir_b: Path, names: list[str]) -> None:
    print(
        f"{'archetype':<14} {'|dR| gray':>9} {'|dL| gray':>9} {'labels %':>8}"
        f"  warp residual A (median/mean)  B (median/mean)"
    )
    for name in names:
        files = sorted(dir_a.glob(f"{name.replace('/', '_')}_*.npz"))
        d_right, d_left, d_labels, warp_a, warp_b = [], [], [], [], []
        for path in files:
            a, b = np.load(path), np.load(dir_b / path.name)
            d_right.append(np.abs(a["right"].astype(float) - b["right"]).mean())
            d_left.append(np.abs(a["left"].astype(float) - b["left"]).mean())
            d_labels.append((a["labels"] != b["labels"]).mean() * 100)
            for z, acc in ((a, warp_a), (b, warp_b)):
                acc.append(_warp_residual(z["left"], z["right"], z["disparity"], z["occluded"]))
        wa, wb = np.concatenate(warp_a), np.concatenate(warp_b)
        print(
            f"{name:<14} {np.mean(d_right):>9.3f} {np.mean(d_left):>9.3f}"
            f" {np.mean(d_labels):>8.4f}  {np.median(wa):>14.2f} / {wa.mean():.2f}"
            f"  {np.median(wb):>9.2f} / {wb.mean():.2f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--stages", action="store_true", help="also time each stage")
    parser.add_argument("--dump", type=Path, metavar="DIR", help="write the pairs, no timing")
    parser.add_argument(
        "--compare", type=Path, nargs=2, metavar=("DIR_A", "DIR_B"), help="compare two dumps"
    )
    args = parser.parse_args()
    names = [*ARCHETYPES, "mojave/viking"]
    if args.compare:
        _compare(*args.compare, names)
        return
    if args.dump:
        _dump(args.dump, names, args.pairs, args.size)
        return
    render_pair("lab", seed=0, size=64)  # compile / load the numba cache
    print(f"{'archetype':<14} {'cpu s/pair':>10} {'wall s/pair':>11}  rocks/frame")
    for name in names:
        archetype, _, variant = name.partition("/")
        cpu0, wall0 = time.process_time(), time.perf_counter()
        rocks = 0
        for seed in range(args.pairs):
            *_, table, _cam = render_pair(
                archetype, seed=seed, size=args.size, variant=variant or None
            )
            rocks += len(table)
        cpu = (time.process_time() - cpu0) / args.pairs
        wall = (time.perf_counter() - wall0) / args.pairs
        print(f"{name:<14} {cpu:>10.3f} {wall:>11.3f}  {rocks / args.pairs:.0f}")
    if not args.stages:
        return
    print(f"\nCPU s per pair by stage\n{'archetype':<14}" + "".join(f" {s:>12}" for s in _STAGES))
    for name in names:
        archetype, _, variant = name.partition("/")
        total = np.zeros(len(_STAGES))
        for seed in range(args.pairs):
            total += _stage_times(archetype, variant or None, seed, args.size)
        print(f"{name:<14}" + "".join(f" {t / args.pairs:>12.3f}" for t in total))


if __name__ == "__main__":
    main()
