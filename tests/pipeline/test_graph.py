"""Graph construction: order from product names, and its named errors."""

from __future__ import annotations

import re

import pyarrow as pa
import pytest

from pipeline.errors import (
    DuplicateOutputError,
    GraphCycleError,
    GraphError,
    MissingProductError,
    ParamError,
)
from pipeline.graph import build_graph, describe_graph, discover_stages, parse_set_overrides
from pipeline.stage import Param, Product, Stage, StageResult


def _stage(name, inputs, outputs, optional=()):
    return Stage(
        name=name,
        version="1",
        inputs=tuple(inputs),
        outputs=tuple(Product(o, dtype="float32") for o in outputs),
        params=(Param("k", int, 1, "a knob", minimum=0),),
        run=lambda inputs, *, frame, params: StageResult(),
        optional_inputs=tuple(optional),
    )


def test_order_follows_products_not_declaration_order():
    graph = build_graph(
        [_stage("c", ["b"], ["c"]), _stage("a", [], ["a"]), _stage("b", ["a"], ["b"])]
    )
    assert [s.name for s in graph.stages] == ["a", "b", "c"]
    assert graph.downstream(["b"]) == {"b", "c"}
    assert graph.upstream(graph.stage("c")) == ("b",)


def test_optional_inputs_order_only_when_present():
    graph = build_graph([_stage("b", [], ["b"], optional=["a", "zzz"]), _stage("a", [], ["a"])])
    assert [s.name for s in graph.stages] == ["a", "b"]
    assert graph.inputs_of(graph.stage("b")) == ("a",)


def test_cycle_is_a_named_error():
    with pytest.raises(GraphCycleError, match="cycle"):
        build_graph([_stage("a", ["y"], ["x"]), _stage("b", ["x"], ["y"])])


def test_duplicate_output_names_both_stages():
    with pytest.raises(DuplicateOutputError, match="'a'.*'b'"):
        build_graph([_stage("a", [], ["x"]), _stage("b", [], ["x"])])


def test_missing_product_is_named():
    with pytest.raises(MissingProductError, match="reads product 'ghost'"):
        build_graph([_stage("a", ["ghost"], ["x"])])


def test_set_overrides_are_parsed_and_validated():
    graph = build_graph([_stage("a", [], ["x"])])
    assert parse_set_overrides(graph, ["a.k=4"]) == {"a": {"k": 4}}
    with pytest.raises(ParamError, match="STAGE.PARAM=VALUE"):
        parse_set_overrides(graph, ["k=4"])
    with pytest.raises(ParamError, match=">= 0"):
        parse_set_overrides(graph, ["a.k=-1"])


def test_shipped_graph_is_ordered_and_describable():
    graph = build_graph(discover_stages())
    names = [s.name for s in graph.stages]
    assert names[0] == "ingest"
    text = describe_graph(graph)
    assert "1. ingest" in text
    dot = describe_graph(graph, fmt="dot")
    assert dot.startswith("digraph arroyo")
    with pytest.raises(ValueError, match="'text' or 'dot'"):
        describe_graph(graph, fmt="svg")


def test_stage_check_params_turns_a_bad_combination_into_a_param_error():
    """Bug: a value each Param accepts but the stage rejects (depth.windows='abc') passed
    planning and failed every frame (exit 1); a stage's check_params now stops the run."""

    def odd_k(params):
        if params["k"] % 2 == 0:
            raise ValueError(f"k must be odd, got {params['k']}")

    stage = Stage(
        name="a",
        version="1",
        inputs=(),
        outputs=(Product("x", dtype="float32"),),
        params=(Param("k", int, 1, "a knob", minimum=0),),
        run=lambda inputs, *, frame, params: StageResult(),
        check_params=odd_k,
    )
    assert stage.resolve_params({"k": 3}) == {"k": 3}
    with pytest.raises(ParamError, match="stage 'a': k must be odd, got 4"):
        stage.resolve_params({"k": 4})


def test_regression_misspelt_input_without_suggestion():
    # the message listed every product but did not point at the near miss
    from pipeline.graph import build_graph, discover_stages
    from pipeline.stage import Product, Stage, StageResult

    typo = Stage(
        "areas", "1", ("blnd",), (Product("mask", dtype="uint8"),), (), lambda i, **k: StageResult()
    )
    with pytest.raises(MissingProductError, match="did you mean 'blend'"):
        build_graph([*discover_stages("arroyo_fake_stages"), typo])


def test_regression_bad_declaration_in_a_stage_module_unnamed(tmp_path, monkeypatch):
    # a Param with a bad default raised at import with no word of which module declared it
    package = tmp_path / "arroyo_bad_param_stages"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "broken.py").write_text(
        "from pipeline.stage import Param\nP = Param('k', int, 0, minimum=1)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    from pipeline.graph import discover_stages

    with pytest.raises(GraphError, match="stage module arroyo_bad_param_stages.broken: .*>= 1"):
        discover_stages("arroyo_bad_param_stages")


def test_regression_dot_broken_by_quotes_and_missing_results():
    # a str param default with a double quote ended the DOT label early (invalid file), and
    # products no stage reads (descriptors, relations, quicklooks) did not appear at all
    a = Stage(
        "a", "1", (), (Product("x", dtype="uint8"),),
        (Param("fmt", str, 'say "hi" \\ bye'),), lambda i, **k: StageResult(),
    )
    b = Stage(
        "b", "1", ("x",), (Product("t", kind="table", schema=pa.schema([("v", pa.int32())])),),
        (), lambda i, **k: StageResult(),
    )
    dot = describe_graph(build_graph([a, b]), fmt="dot")
    for line in dot.splitlines():  # every quote opened is closed on its line
        assert len(re.findall(r'(?<!\\)"', line.replace("\\\\", ""))) % 2 == 0, line
    assert '\\"hi\\"' in dot
    assert '"b" -> "product:t"' in dot and '"a" -> "b" [label="x"]' in dot
