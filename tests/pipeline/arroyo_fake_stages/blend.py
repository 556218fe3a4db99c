"""Fake processing stage: weighted blend of left and right."""

from __future__ import annotations

import numpy as np

from pipeline.stage import Param, Product, Stage, StageResult


def run(inputs, *, frame, params):
    mixed = inputs["left"].astype(np.float32) * params["weight"] + inputs["right"].astype(
        np.float32
    ) * (1 - params["weight"])
    return StageResult(
        arrays={"blend": mixed.astype(np.float32)}, figures={"max": float(mixed.max())}
    )


STAGE = Stage(
    name="blend",
    version="1",
    inputs=("left", "right"),
    outputs=(Product("blend", dtype="float32", attrs={"units": "gray"}),),
    params=(Param("weight", float, 0.5, "weight of left", minimum=0.0, maximum=1.0),),
    run=run,
)
