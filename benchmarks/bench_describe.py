"""Descriptor and relation accuracy of the describe stage on TRUE inputs.

Renders pairs with ``pipeline.synth.pair.render_pair``, feeds the truth labels, disparity,
range and height to :func:`stages.describe.describe_frame` (so only the describe stage's own
errors are measured, not segmentation or matching), and scores against the truth rocks with
``pipeline.metrics`` (rocks within ``--near`` m of the camera for the descriptor targets).

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_describe.py --frames 4 --size 500
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pipeline.camera import Camera
from pipeline.metrics import descriptor_errors, relation_agreement, true_occlusions
from pipeline.synth.pair import render_pair
from stages.describe import describe_frame


def _frame(archetype: str, seed: int, size: int) -> dict:
    left, right, truth, rocks, cam = render_pair(archetype, seed=seed, size=size)
    camera = Camera(**cam)
    start = time.perf_counter()
    desc, rel, figures = describe_frame(
        truth["labels"],
        right,
        truth["disparity"],
        truth["range"],
        truth["height"],
        camera=camera,
    )
    seconds = time.perf_counter() - start
    by_id = {r["rock_id"]: r for r in rocks}
    ids = desc["object_id"].tolist()
    truth_cols = {
        name: np.array([by_id[i][name] for i in ids])
        for name in ("height_m", "width_m", "range_m", "size_class", "x_m", "y_m", "extent_x_m")
    }
    occ = true_occlusions(truth["labels"], truth["range"])
    subj = [by_id[i] for i in rel["subject_id"].tolist()]
    obj = [by_id[i] for i in rel["object_id"].tolist()]
    occludes_truth = np.array(
        [(s["rock_id"], o["rock_id"]) in occ for s, o in zip(subj, obj, strict=True)],
        dtype=bool,
    )
    return {
        "desc": desc,
        "truth": truth_cols,
        "relation": rel["relation"],
        "subject": {k: np.array([s[k] for s in subj]) for k in ("x_m", "y_m")},
        "object": {k: np.array([o[k] for o in obj]) for k in ("x_m", "y_m")},
        "occludes_truth": occludes_truth,
        "seconds": seconds,
        "k": figures["sfd_k"],
    }


def _cat(frames: list[dict], key: str, sub: str | None = None) -> dict:
    parts = [f[key] for f in frames]
    names = parts[0].keys()
    return {n: np.concatenate([p[n] for p in parts]) for n in names}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archetypes", default="lab,mojave,lava,dunes")
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--near", type=float, default=2.0)
    args = parser.parse_args()
    print(
        f"{'archetype':9} {'rocks':>5} {'near':>5} {'|dh|max':>8} {'|dh|top':>8} "
        f"{'dw/w':>6} {'dw/wx':>6} {'dr/r':>6} {'class':>6} {'rel':>6} {'occl':>6} {'ms':>6}"
    )
    for archetype in args.archetypes.split(","):
        frames = [_frame(archetype, seed, args.size) for seed in range(args.frames)]
        desc = _cat(frames, "desc")
        truth = _cat(frames, "truth")
        err = descriptor_errors(desc, truth, near_range_m=args.near)
        near = truth["range_m"] <= args.near
        wx = np.nanmedian(np.abs(desc["width_m"][near] / truth["extent_x_m"][near] - 1))
        rel = relation_agreement(
            np.concatenate([f["relation"] for f in frames]),
            _cat(frames, "subject"),
            _cat(frames, "object"),
            occludes_truth=np.concatenate([f["occludes_truth"] for f in frames]),
        )
        ms = 1000 * np.mean([f["seconds"] for f in frames])
        print(
            f"{archetype:9} {desc['object_id'].size:5d} {int(near.sum()):5d} "
            f"{err['near_height_abs_err_median_m']:8.4f} "
            f"{err['near_study_height_abs_err_median_m']:8.4f} "
            f"{err['near_width_rel_err_median']:6.3f} {wx:6.3f} "
            f"{err['near_range_rel_err_median']:6.4f} {err['near_class_accuracy']:6.3f} "
            f"{rel['agreement']:6.3f} {rel.get('agreement_occludes', float('nan')):6.3f} "
            f"{ms:6.1f}"
        )


if __name__ == "__main__":
    main()
