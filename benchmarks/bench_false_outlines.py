"""What is wrong with each false object's outline: its parts on and off the truth rock under it.

Usage (from the repository root)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_false_outlines.py /tmp/val7/dunes_s5
    PYTHONPATH=. .venv/bin/python benchmarks/bench_false_outlines.py RUNDIR --set KEY=VALUE

Each run's frames are segmented again with the current code and the run's catalog settings
(plus ``--set``), as ``bench_segment.py --rundir`` does. Every false object (graded,
unmatched at IoU >= 0.5; :func:`bench_misses.classify_false_objects`) that lies on a truth
rock gets one line: its pixels, the rock's (visible pixels, median range), their IoU, and
the object split three ways -- on the rock, off it (a cast shadow, a blurred rim, a blotch
of ground) and the rock's pixels it misses (a face no threshold reached) -- each with its
mean gray, beside the median gray of a 4-pixel ring of ground around the rock. A second line
splits the object's gray levels in two (Otsu), the way the shadow rules R6
(:func:`stages._rock_parts.trim_attached_shadows`) see it: each class's mean gray, its share
of the object and how much of it lies on the rock. A lighter class mostly off the rock is a
cast shadow; a lighter class on the rock is a lit face (for a dark rock) -- gray levels and
the class's position alone do not tell the two apart.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from stages.segment import segment_image

__all__ = ["describe_false_object", "main"]

_RING_PX = 4


def _mean(values: np.ndarray) -> str:
    return f"{values.mean():5.0f}" if values.size else "    -"


def describe_false_object(
    pred: np.ndarray, true: np.ndarray, image: np.ndarray, obj_id: int
) -> dict | None:
    """The parts of false object ``obj_id`` against the truth rock under most of it.

    Parameters
    ----------
    pred, true : (M, N) ndarray of int
        Object and truth labels (0 background).
    image : (M, N) ndarray of uint8
        Reference gray image.
    obj_id : int
        The object's label in ``pred``.

    Returns
    -------
    dict or None
        ``rock``, ``iou``, pixel counts ``obj_px``, ``rock_px``, ``on``, ``off``, ``missed``,
        mean grays ``gray_on``, ``gray_off``, ``gray_missed`` (strings, '-' when empty),
        ``ground`` (ring median) and the Otsu split ``dark_gray``, ``light_gray``,
        ``light_share``, ``light_on_rock``; None when no rock lies under the object.
    """
    obj = pred == obj_id
    under = true[obj]
    if not (under > 0).any():
        return None
    ids, counts = np.unique(under[under > 0], return_counts=True)
    rock = true == ids[np.argmax(counts)]
    on, off, missed = obj & rock, obj & ~rock, rock & ~obj
    kernel = np.ones((2 * _RING_PX + 1,) * 2, np.uint8)
    ring = cv2.dilate((obj | rock).view(np.uint8), kernel).view(bool) & (true == 0) & (pred == 0)
    gray = image[obj]
    split, _ = cv2.threshold(gray.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    light = obj & (image > split)
    return {
        "rock": int(ids[np.argmax(counts)]),
        "iou": float(on.sum() / (obj | rock).sum()),
        "obj_px": int(obj.sum()),
        "rock_px": int(rock.sum()),
        "on": int(on.sum()),
        "off": int(off.sum()),
        "missed": int(missed.sum()),
        "gray_on": _mean(image[on]),
        "gray_off": _mean(image[off]),
        "gray_missed": _mean(image[missed]),
        "ground": float(np.median(image[ring])) if ring.any() else float("nan"),
        "dark_gray": _mean(image[obj & ~light]),
        "light_gray": _mean(image[light]),
        "light_share": float(light.sum() / obj.sum()),
        "light_on_rock": float((light & rock).sum() / max(int(light.sum()), 1)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundirs", nargs="+", help="finished run directories of built-in archives")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    # sibling modules: benchmarks/ is on sys.path when this script runs (not when a test
    # imports describe_false_object)
    from _overrides import keyword_overrides
    from _rundir import open_run
    from bench_misses import classify_false_objects

    overrides = keyword_overrides(args.set)
    for rundir in args.rundirs:
        run = open_run(rundir)
        params = run.segment_params()
        params.update(overrides)
        print(rundir)
        for frame in run.frames():
            image = frame.product(run.camera.reference)
            pred = segment_image(
                image,
                height=frame.product("height"),
                disparity=frame.product("disparity"),
                **params,
            ).labels
            true = frame.truth["labels"]
            for row in classify_false_objects(pred, true, image):
                parts = describe_false_object(pred, true, image, row["object"])
                if parts is None:
                    print(f"  {frame.frame_id} object {row['object']}: {row['class']}, on no rock")
                    continue
                rock = true == parts["rock"]
                distance = float(np.median(frame.truth["range"][rock]))
                print(
                    f"  {frame.frame_id} object {row['object']} ({row['class']}): "
                    f"{parts['obj_px']} px on rock {parts['rock']} ({parts['rock_px']} px, "
                    f"{distance:.2f} m), IoU {parts['iou']:.2f}\n"
                    f"    on rock {parts['on']:4d} px gray {parts['gray_on']}   "
                    f"off rock {parts['off']:4d} px gray {parts['gray_off']}   "
                    f"rock missed {parts['missed']:4d} px gray {parts['gray_missed']}   "
                    f"ground ring {parts['ground']:.0f}\n"
                    f"    Otsu: dark class gray {parts['dark_gray']}, light class gray "
                    f"{parts['light_gray']} ({100 * parts['light_share']:.0f} % of the object, "
                    f"{100 * parts['light_on_rock']:.0f} % of it on the rock)"
                )


if __name__ == "__main__":
    main()
