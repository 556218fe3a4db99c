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
