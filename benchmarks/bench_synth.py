"""Seconds per rendered stereo pair (with its ground truth), per archetype, on one core.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_synth.py [--size 500] [--pairs 3]
Prints CPU seconds (process time) and wall seconds per pair; the first, compiling call is
excluded.
"""

from __future__ import annotations

import argparse
import time

from pipeline.synth import ARCHETYPES, render_pair


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    render_pair("lab", seed=0, size=64)  # compile / load the numba cache
    print(f"{'archetype':<14} {'cpu s/pair':>10} {'wall s/pair':>11}  rocks/frame")
    for name in [*ARCHETYPES, "mojave/viking"]:
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


if __name__ == "__main__":
    main()
