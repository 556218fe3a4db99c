"""Fake table stage: one row per bright blob row band, plus a sector grid."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from pipeline.stage import Param, Product, Stage, StageResult

SCHEMA = pa.schema([pa.field("object_id", pa.int32()), pa.field("value", pa.float64())])


def run(inputs, *, frame, params):
    blend = inputs["blend"]
    n = params["rows"]
    bands = np.array_split(blend, n, axis=0)
    values = [float(b.mean()) for b in bands]
    grid = np.zeros((params["grid"], params["grid"]), np.float32) + values[0]
    return StageResult(
        arrays={"grid": grid},
        tables={"tallies": {"object_id": np.arange(1, n + 1, dtype=np.int32), "value": values}},
        figures={"rows": n},
        files=(
            {f"quicklooks/{frame.frame_id}/note.txt": f"{values[0]:.3f}".encode()}
            if params["note"]
            else {}
        ),
    )


STAGE = Stage(
    name="tally",
    version="1",
    inputs=("blend",),
    outputs=(
        Product("tallies", kind="table", schema=SCHEMA),
        Product("quicklooks", kind="files"),
        Product(
            "grid",
            dtype="float32",
            dims=("frame", "gy", "gx"),
            shape=lambda image_shape, params: (params["grid"], params["grid"]),
        ),
    ),
    params=(
        Param("rows", int, 3, "rows per frame", minimum=0),
        Param("grid", int, 4, "grid side", minimum=1),
        Param("note", bool, True, "write quicklooks/<frame_id>/note.txt"),
    ),
    run=run,
)
