"""The stage graph: discovered from ``stages/``, ordered by the products stages exchange."""

from __future__ import annotations

import difflib
import graphlib
import importlib
import os
import pkgutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .errors import (
    DuplicateOutputError,
    GraphCycleError,
    GraphError,
    MissingProductError,
    ParamError,
)
from .stage import Product, Stage

__all__ = [
    "StageGraph",
    "build_graph",
    "discover_stages",
    "default_graph",
    "parse_set_overrides",
    "describe_graph",
    "resolve_stage_params",
    "stage_package_name",
]


@dataclass(frozen=True)
class StageGraph:
    """Stages in topological order, with the product each stage writes."""

    stages: tuple[Stage, ...]
    producer: Mapping[str, str]  # product name -> stage name

    def stage(self, name: str) -> Stage:
        for stage in self.stages:
            if stage.name == name:
                return stage
        known = ", ".join(s.name for s in self.stages)
        raise ParamError(f"unknown stage {name!r}; the stages are: {known}")

    def product(self, name: str) -> Product:
        owner = self.stage(self.producer[name])
        return next(p for p in owner.outputs if p.name == name)

    def upstream(self, stage: Stage) -> tuple[str, ...]:
        """Names of the stages whose products ``stage`` reads, in graph order."""
        wanted = {self.producer[p] for p in self.inputs_of(stage)}
        return tuple(s.name for s in self.stages if s.name in wanted)

    def inputs_of(self, stage: Stage) -> tuple[str, ...]:
        """Required inputs plus the optional inputs some stage of the graph writes."""
        optional = tuple(p for p in stage.optional_inputs if p in self.producer)
        return tuple(stage.inputs) + optional

    def downstream(self, names: Iterable[str]) -> set[str]:
        """The named stages and every stage that depends on them, transitively."""
        closed = set(names)
        for stage in self.stages:  # topological order: one pass suffices
            if any(up in closed for up in self.upstream(stage)):
                closed.add(stage.name)
        return closed

    @property
    def array_products(self) -> tuple[Product, ...]:
        return tuple(p for s in self.stages for p in s.outputs if p.kind == "array")

    @property
    def table_products(self) -> tuple[Product, ...]:
        return tuple(p for s in self.stages for p in s.outputs if p.kind == "table")


def build_graph(stages: Iterable[Stage]) -> StageGraph:
    """Order stages by the products they read and write.

    Raises
    ------
    GraphError
        Two stages share a name.
    DuplicateOutputError
        Two stages write the same product.
    MissingProductError
        A stage reads a product no stage writes.
    GraphCycleError
        The stages depend on each other in a cycle (the message lists it).
    """
    by_name: dict[str, Stage] = {}
    for stage in stages:
        if not isinstance(stage, Stage):
            raise TypeError(f"expected a pipeline.stage.Stage, got {type(stage).__name__}")
        if stage.name in by_name:
            raise GraphError(f"two stages are named {stage.name!r}; stage names must be unique")
        by_name[stage.name] = stage
    producer: dict[str, str] = {}
    for stage in by_name.values():
        for name in stage.output_names:
            if name in producer:
                raise DuplicateOutputError(
                    f"product {name!r} is written by both stage {producer[name]!r} and stage "
                    f"{stage.name!r}; each product must have exactly one producer"
                )
            producer[name] = stage.name
    sorter: graphlib.TopologicalSorter[str] = graphlib.TopologicalSorter()
    for stage in by_name.values():
        deps = []
        for name in stage.inputs:
            if name not in producer:
                close = difflib.get_close_matches(name, producer, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise MissingProductError(
                    f"stage {stage.name!r} reads product {name!r}, which no stage writes"
                    f"{hint}; known products: {', '.join(sorted(producer)) or 'none'}"
                )
            deps.append(producer[name])
        deps += [producer[n] for n in stage.optional_inputs if n in producer]
        sorter.add(stage.name, *deps)
    try:
        order = tuple(sorter.static_order())
    except graphlib.CycleError as exc:
        cycle = " -> ".join(exc.args[1])
        raise GraphCycleError(f"the stages form a cycle: {cycle}") from None
    return StageGraph(stages=tuple(by_name[n] for n in order), producer=producer)


def stage_package_name(package: str | None = None) -> str:
    """The stage package: the argument, else ``$ARROYO_STAGE_PACKAGE``, else ``stages``."""
    return package or os.environ.get("ARROYO_STAGE_PACKAGE") or "stages"


def discover_stages(package: str | None = None) -> list[Stage]:
    """Every ``STAGE`` declared by a public module of the stage package."""
    package = stage_package_name(package)
    try:
        pkg = importlib.import_module(package)
    except ModuleNotFoundError as exc:
        if exc.name is None or not (package == exc.name or package.startswith(exc.name + ".")):
            raise  # the package exists; something it imports does not
        raise GraphError(
            f"stage package {package!r} cannot be imported ({exc}); put its parent "
            "directory on PYTHONPATH or install it, or pass another --stage-package"
        ) from None
    if not hasattr(pkg, "__path__"):
        raise GraphError(
            f"stage package {package!r} is a module ({pkg.__file__}), not a package: make it a "
            "directory with __init__.py and one module per stage declaring STAGE = Stage(...)"
        )
    found = []
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        try:
            module = importlib.import_module(f"{package}.{info.name}")
        except (ValueError, TypeError) as exc:  # a bad declaration: say which module
            raise GraphError(f"stage module {package}.{info.name}: {exc}") from exc
        stage = getattr(module, "STAGE", None)
        if isinstance(stage, Stage):
            found.append(stage)
    if not found:
        raise GraphError(
            f"stage package {package!r} ({', '.join(pkg.__path__)}) declares no stage: each "
            "stage is a public module (name not starting with '_') with a module-level "
            "STAGE = pipeline.stage.Stage(...)"
        )
    return found


def default_graph() -> StageGraph:
    """The graph of every stage shipped in ``stages/``."""
    return build_graph(discover_stages())


def parse_set_overrides(graph: StageGraph, items: Iterable[str]) -> dict[str, dict[str, Any]]:
    """Parse ``--set stage.param=value`` items into validated per-stage overrides."""
    parsed: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        stage_name, dot, param_name = key.strip().partition(".")
        if not sep or not dot or not stage_name or not param_name:
            raise ParamError(
                f"--set expects STAGE.PARAM=VALUE (for example depth.max_disparity=96), "
                f"got {item!r}"
            )
        param = graph.stage(stage_name).param(param_name)
        parsed.setdefault(stage_name, {})[param_name] = param.parse(text.strip())
    return parsed


def resolve_stage_params(
    graph: StageGraph, *layers: Mapping[str, Mapping[str, Any]]
) -> dict[str, dict[str, Any]]:
    """Effective params per stage: defaults, then each override layer in turn."""
    merged: dict[str, dict[str, Any]] = {s.name: {} for s in graph.stages}
    for layer in layers:
        for stage_name, values in layer.items():
            stage = graph.stage(stage_name)
            if not isinstance(values, Mapping):
                raise ParamError(
                    f"params for stage {stage_name!r} must be a table of name = value, "
                    f"got {values!r}"
                )
            for name in values:
                stage.param(name)
            merged[stage.name].update(values)
    return {s.name: s.resolve_params(merged[s.name]) for s in graph.stages}


def describe_graph(
    graph: StageGraph | None = None, *, fmt: str = "text", stage_package: str | None = None
) -> str:
    """The graph in order with each stage's inputs, outputs and params.

    Parameters
    ----------
    graph : StageGraph, optional
        Default: the graph of ``stage_package``.
    fmt : {'text', 'dot'}
    stage_package : str, optional
        Package to discover stages in when ``graph`` is not given (see
        :func:`stage_package_name`).
    """
    graph = graph or build_graph(discover_stages(stage_package))
    if fmt == "dot":
        return _dot(graph)
    if fmt != "text":
        raise ValueError(f"fmt must be 'text' or 'dot', got {fmt!r}")
    out = []
    for i, stage in enumerate(graph.stages, 1):
        out.append(f"{i}. {stage.name} (version {stage.version}): {stage.doc}".rstrip(": "))
        out.append(f"   reads:  {', '.join(graph.inputs_of(stage)) or '(frame files)'}")
        out.append(f"   writes: {', '.join(stage.output_names)}")
        for p in stage.params:
            extra = f" one of {list(p.choices)}" if p.choices else ""
            out.append(f"   - {p.name} = {p.default!r} ({p.type.__name__}{extra}) {p.doc}")
    return "\n".join(out) + "\n"


def _dot_str(text: str) -> str:
    """A DOT quoted string: a str param default may hold quotes or backslashes."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _dot(graph: StageGraph) -> str:
    """Stages as boxes, the products one reads from another as edges, and the products no
    stage reads (the run's results: tables, quicklooks...) as ellipses."""
    lines = ["digraph arroyo {", "  rankdir=LR;", "  node [shape=box];"]
    read = {p for stage in graph.stages for p in graph.inputs_of(stage)}
    for stage in graph.stages:
        label = "\n".join(
            [f"{stage.name} v{stage.version}", *(f"{p.name}={p.default!r}" for p in stage.params)]
        )
        lines.append(f"  {_dot_str(stage.name)} [label={_dot_str(label)}];")
        for product in graph.inputs_of(stage):
            lines.append(
                f"  {_dot_str(graph.producer[product])} -> {_dot_str(stage.name)} "
                f"[label={_dot_str(product)}];"
            )
        for output in stage.outputs:
            if output.name not in read:
                node = _dot_str(f"product:{output.name}")
                lines.append(
                    f"  {node} [label={_dot_str(f'{output.name} ({output.kind})')}, "
                    "shape=ellipse];"
                )
                lines.append(f"  {_dot_str(stage.name)} -> {node};")
    lines.append("}")
    return "\n".join(lines) + "\n"
