"""Fake ingest: reads two PNGs with OpenCV; fails clearly for unreadable files."""

from __future__ import annotations

import time

import cv2
import numpy as np

from pipeline.errors import FrameError
from pipeline.stage import Param, Product, Stage, StageResult


def _read(path):
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise FrameError(f"cannot decode {path}")
    return image


def run(inputs, *, frame, params):
    if params["sleep"]:
        time.sleep(params["sleep"])
    left, right = _read(frame.left_path), _read(frame.right_path)
    if left.shape != right.shape or (frame.image_shape and left.shape != frame.image_shape):
        raise FrameError(f"{frame.left_path}: shape {left.shape} does not match")
    return StageResult(
        arrays={"left": left, "right": right}, figures={"mean": float(np.mean(left))}
    )


STAGE = Stage(
    name="ingest",
    version="1",
    inputs=(),
    outputs=(Product("left", dtype="uint8"), Product("right", dtype="uint8")),
    params=(Param("sleep", float, 0.0, "seconds to sleep (for kill tests)", minimum=0.0),),
    run=run,
)
