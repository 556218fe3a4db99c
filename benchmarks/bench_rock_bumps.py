"""How much of a rock's disparity bump the depth stage keeps, by polarity and miss class.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_rock_bumps.py runs/eval/lava \
        runs/eval/mojave runs/eval/lab [--near 3]

For every truth rock of at least 30 visible pixels within ``--near`` m (truth range) of a
finished run, the *bump* is the median disparity over the rock's exact truth mask minus
the median over its ring of ground (3 to 7 px from the rock, other rocks left out), as
``bench_untouched_depth.py`` measures it: ``truth`` on the truth's disparity, ``run`` on
the run's. A segmentation rule that tells a rock from the ground by its heights can only
use the ``run`` bump. Rows group the rocks by polarity (``darker`` / ``lighter`` than the
ground, the truth rock table's) and by what the current segmentation makes of them
(:func:`bench_misses.classify_misses` on the run's frames segmented again with the catalog's
settings: ``matched``, ``untouched``, ``partial``, ...). Columns: ``rocks``; the median
``truth`` and ``run`` bumps (px); ``kept``, the median of run / truth over rocks whose truth
bump is at least 0.1 px; ``<half``, the share of those that keep less than half of it;
first for the median over the mask, then for its top (the 90th percentile over the mask
minus the ring's median: the part of the rock a height rule or a rock's height reads).

Written after lava_0005 rock 10 (279 px, 2 m, a dark rock of uniform gray): its truth bump
is 0.46 px, the run's 0.02 px. Windows of 5 to 9 px inside it keep a median bias of -0.2
to -0.37 px: the rock's edge against the brighter, textured ground dominates the
correlation of every window that reaches it.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from stages.segment import segment_image

__all__ = ["kept_shares", "main", "top_bump"]

_MIN_TRUE_PX = 30
_MIN_TRUTH_BUMP = 0.1  # px: smaller bumps make the kept share meaningless


def kept_shares(truth: np.ndarray, run: np.ndarray) -> np.ndarray:
    """run / truth bump of the rocks whose both bumps are finite and whose truth bump is at
    least 0.1 px (a smaller one makes the share meaningless)."""
    finite = np.isfinite(truth) & np.isfinite(run)
    big = finite & (np.where(finite, truth, 0.0) >= _MIN_TRUTH_BUMP)
    return run[big] / truth[big]


def _columns(truth: np.ndarray, run: np.ndarray) -> str:
    """Median truth and run bumps, median kept share and the share keeping under half."""
    finite = np.isfinite(truth) & np.isfinite(run)
    if not finite.any():
        return "     -      -      -      -"
    kept = kept_shares(truth, run)
    kept_median = f"{np.median(kept):6.2f}" if kept.size else "     -"
    below_half = f"{np.mean(kept < 0.5):6.2f}" if kept.size else "     -"
    return (
        f"{np.median(truth[finite]):6.3f} {np.median(run[finite]):6.3f} {kept_median} {below_half}"
    )


def _summary(rows: list[tuple[float, float, float, float]]) -> str:
    values = np.array(rows, dtype=float).reshape(-1, 4)
    return (
        f"{len(rows):6d} {_columns(values[:, 0], values[:, 1])} | "
        f"{_columns(values[:, 2], values[:, 3])}"
    )


def top_bump(values: np.ndarray, mask: np.ndarray, ring: np.ndarray) -> float:
    """90th percentile over ``mask`` minus the median over ``ring`` (finite pixels)."""
    inside = values[mask]
    inside = inside[np.isfinite(inside)]
    around = values[ring]
    around = around[np.isfinite(around)]
    if inside.size < max(5, 0.3 * mask.sum()) or around.size < 5:
        return float("nan")
    return float(np.percentile(inside, 90) - np.median(around))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundirs", nargs="+", help="finished run directories of built-in archives")
    parser.add_argument("--near", type=float, default=3.0, help="truth range limit, m")
    args = parser.parse_args()
    # sibling modules: benchmarks/ is on sys.path when this script runs (not when a test
    # imports its functions)
    from _rundir import open_run
    from bench_misses import classify_misses
    from bench_untouched_depth import _bump, _ring

    print(
        "archive   polarity  class         rocks  median: truth    run   kept  <half"
        " | top: truth    run   kept  <half"
    )
    for rundir in args.rundirs:
        run = open_run(rundir)
        params = run.segment_params()
        groups: dict[tuple[str, str], list[tuple[float, float, float, float]]] = defaultdict(list)
        for frame in run.frames():
            image = frame.product(run.camera.reference)
            disparity = frame.product("disparity")
            labels = segment_image(
                image, height=frame.product("height"), disparity=disparity, **params
            ).labels
            true = frame.truth["labels"]
            polarity = {int(rock["rock_id"]): str(rock["polarity"]) for rock in frame.rocks}
            ground = true == 0
            for row in classify_misses(labels, true, image, frame.truth["range"]):
                if row["px"] < _MIN_TRUE_PX or row["range_m"] > args.near:
                    continue
                mask = true == row["rock"]
                ring = _ring(mask, ground)
                truth_disparity = frame.truth["disparity"]
                bumps = (
                    _bump(truth_disparity, mask, ring),
                    _bump(disparity, mask, ring),
                    top_bump(truth_disparity, mask, ring),
                    top_bump(disparity, mask, ring),
                )
                side = polarity.get(row["rock"], "?")
                groups[(side, row["class"])].append(bumps)
                groups[(side, "all")].append(bumps)
        for side, kind in sorted(groups):
            print(f"{run.archive:9s} {side:9s} {kind:12s} {_summary(groups[(side, kind)])}")


if __name__ == "__main__":
    main()
