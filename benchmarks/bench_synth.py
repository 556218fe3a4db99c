"""Seconds per rendered stereo pair (with its ground truth), per archetype, on one core.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_synth.py [--size 500] [--pairs 3] [--stages]
Prints CPU seconds (process time) and wall seconds per pair; the first, compiling call is
excluded. ``--stages`` adds CPU seconds per pair of each stage of ``render_pair``: scene
building, the right view (ray casting, shading, shadows and the occlusion truth rays), the
left view (no truth rays), the same left view without lights (primary rays and texture
only: what shadow rays cost is the difference), and exposure plus the rock table.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--stages", action="store_true", help="also time each stage")
    args = parser.parse_args()
    render_pair("lab", seed=0, size=64)  # compile / load the numba cache
    names = [*ARCHETYPES, "mojave/viking"]
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
