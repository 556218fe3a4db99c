"""Declarations a user's stage package writes are checked when they are made."""

from __future__ import annotations

import pytest

from pipeline.errors import ParamError
from pipeline.stage import Param, Product, Stage, StageResult


def _run(inputs, *, frame, params):
    return StageResult()


def _stage(**changes):
    spec = dict(
        name="areas",
        version="1",
        inputs=("labels",),
        outputs=(Product("mask", dtype="uint8"),),
        params=(Param("k", int, 1),),
        run=_run,
    )
    spec.update(changes)
    return Stage(**spec)


def test_a_valid_declaration_is_accepted():
    assert _stage().output_names == ("mask",)


@pytest.mark.parametrize(
    ("changes", "error", "expected"),
    [
        ({"inputs": "labels"}, TypeError, "inputs must be a tuple of str"),
        ({"outputs": Product("mask", dtype="uint8")}, TypeError, "outputs must be a tuple"),
        ({"version": 2}, TypeError, "version must be a str"),
        ({"run": None}, TypeError, "run must be callable"),
        ({"name": "my.areas"}, ValueError, "must be an identifier"),
        ({"params": (Param("k", int, 1), Param("k", int, 2))}, ValueError, "params name 'k'"),
        (
            {"outputs": (Product("m", dtype="uint8"), Product("m", dtype="uint8"))},
            ValueError,
            "outputs name 'm' more than once",
        ),
    ],
)
def test_regression_bad_stage_declaration_accepted(changes, error, expected):
    # a str inputs read as one product per letter ('l'), a dotted name made `--set` unusable,
    # a repeated param or output was silently shadowed, a non-callable run failed every frame
    with pytest.raises(error, match=expected):
        _stage(**changes)


def test_regression_bad_product_declaration_accepted():
    # a product name became a path under products.zarr ('../x' escaped it) and an unknown
    # dtype failed only when the run created the store
    with pytest.raises(ValueError, match="must be an identifier"):
        Product("../evil", dtype="uint8")
    with pytest.raises(ValueError, match="not a NumPy dtype"):
        Product("mask", dtype="uint9")


def test_regression_param_minimum_above_maximum_blamed_the_default():
    # it said "default must be >= 10, got 5" rather than that the bounds are swapped
    with pytest.raises(ParamError, match="minimum 10 is above maximum 1"):
        Param("k", int, 5, minimum=10, maximum=1)


@pytest.mark.parametrize(
    ("dims", "shape", "expected"),
    [
        (("frame", "g"), lambda s, p: 1 / 0, "raised ZeroDivisionError"),
        (("frame", "g"), lambda s, p: "4", r"per-frame shape \('4',\) does not fit"),
        (("frame", "y", "x"), lambda s, p: (4,), r"\(4,\) does not fit dims"),
    ],
)
def test_regression_bad_product_shape_crashed_the_run(dims, shape, expected):
    # a shape callable that raised, or disagreed with dims, ended the run in a traceback
    # (ZeroDivisionError, KeyError: 'dims') while the store was being created
    product = Product("grid", dtype="float32", dims=dims, shape=shape)
    with pytest.raises(ValueError, match=expected):
        product.frame_shape((8, 8), {})


def test_frame_shape_of_images_and_grids():
    assert Product("m", dtype="uint8").frame_shape((8, 6), {}) == (8, 6)
    grid = Product("g", dtype="uint8", dims=("frame", "a", "b"), shape=lambda s, p: (p["n"], 2))
    assert grid.frame_shape((8, 6), {"n": 3}) == (3, 2)
