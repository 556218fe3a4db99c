"""What a run must do: validate the catalog and params, key every (frame, stage) result.

A (frame, stage) result has a cache key: the stage's name, version and effective params, the
frame's camera, the keys of the stages it reads from, and (for ``ingest``) the sha256 of the
two input files. A run redoes exactly the results whose key has no completion record.

A parameter declared with ``omit_default_from_key`` (added to a stage later, its default
reproducing the stage's earlier output) is left out of the key while at its default, so
adding it does not make every existing run recompute everything (:meth:`Stage.key_params`).
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .catalog import Catalog, FrameRecord, load_catalog
from .errors import CatalogError, ParamError
from .graph import (
    StageGraph,
    build_graph,
    discover_stages,
    parse_set_overrides,
    resolve_stage_params,
    stage_package_name,
)
from .state import RunState
from .store import file_sha256

__all__ = [
    "RunPlan",
    "RunRequest",
    "plan_run",
    "frame_keys",
    "format_plan",
    "format_duplicates",
    "validate_request",
    "default_rundir",
]


@dataclass(frozen=True)
class RunRequest:
    """A validated request: the catalog, stage graph, effective params and selected frames."""

    catalog: Catalog
    graph: StageGraph
    params: dict[str, dict[str, Any]]
    frames: list[FrameRecord]
    stage_package: str


@dataclass
class RunPlan:
    """What a run will do, and why."""

    catalog: Catalog
    graph: StageGraph
    params: dict[str, dict[str, Any]]
    rundir: Path
    frames: list[FrameRecord]  # selected frames, catalog order
    indices: dict[str, int]  # frame_id -> position in the catalog (zarr index)
    keys: dict[str, dict[str, str]]  # frame_id -> stage -> key
    todo: dict[str, list[str]]  # frame_id -> stages to run, graph order
    reasons: dict[str, dict[str, str]]  # frame_id -> stage -> new|changed|failed
    image_shape: tuple[int, int] | None
    input_hashes: dict[str, tuple[str, str]]
    stage_package: str = "stages"
    products: str = ""  # products root (directory or fsspec URL); empty: the run directory

    @property
    def duplicates(self) -> dict[str, str]:
        """Selected frames whose two files have the same contents as an earlier selected
        frame's: frame id -> that earlier frame's id. A pair listed twice under two ids ran
        twice and its rocks counted twice in every query and fit, without a word."""
        first: dict[tuple[str, str], str] = {}
        out: dict[str, str] = {}
        for frame in self.frames:
            pair = self.input_hashes.get(frame.frame_id)
            if pair is None or not all(_HEX64.fullmatch(h) for h in pair):
                continue  # a missing or unreadable file: ingest fails the frame anyway
            if pair in first:
                out[frame.frame_id] = first[pair]
            else:
                first[pair] = frame.frame_id
        return out

    @property
    def products_root(self) -> str:
        """Where workers write array products and files."""
        return self.products or str(self.rundir)

    def counts(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        for stage in self.graph.stages:
            row = {"new": 0, "changed": 0, "failed": 0, "done": 0}
            for frame in self.frames:
                reason = self.reasons[frame.frame_id].get(stage.name)
                row[reason or "done"] += 1
            out[stage.name] = row
        return out


# -- keys and plan ------------------------------------------------------------------------
def _digest(payload: Any) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def frame_keys(
    graph: StageGraph,
    params: Mapping[str, Mapping[str, Any]],
    frame: FrameRecord,
    input_hash: tuple[str, str],
    image_shape: tuple[int, int] | None,
) -> dict[str, str]:
    """Cache key of every stage for one frame."""
    keys: dict[str, str] = {}
    for stage in graph.stages:
        payload: dict[str, Any] = {
            "stage": stage.name,
            "version": stage.version,
            "params": stage.key_params(params[stage.name]),
            "upstream": {u: keys[u] for u in graph.upstream(stage)},
        }
        if not stage.inputs and not stage.optional_inputs:
            payload["files"] = list(input_hash)
            payload["shape"] = list(image_shape) if image_shape else None
        else:
            payload["camera"] = frame.camera.to_dict()
        keys[stage.name] = _digest(payload)
    return keys


def _hash_inputs(
    frames: Sequence[FrameRecord], state: RunState | None, *, remember: bool
) -> dict[str, tuple[str, str]]:
    """sha256 of both files of each frame, reusing earlier hashes of unchanged files."""
    fresh: list[tuple[str, int, int, str]] = []
    out = {}

    def one(path: Path) -> str:
        try:
            st = path.stat()
            if not path.is_file():
                return "not-a-file"
            cached = state.input_hash(str(path), st.st_size, st.st_mtime_ns) if state else None
            if cached:
                return cached
            sha = file_sha256(path)
        except OSError as exc:
            return f"unreadable:{exc.errno}"
        fresh.append((str(path), st.st_size, st.st_mtime_ns, sha))
        return sha

    for frame in frames:
        out[frame.frame_id] = (one(frame.left), one(frame.right))
    if remember and state is not None and fresh:
        state.remember_input_hashes(fresh)
    return out


_HEX64 = re.compile(r"[0-9a-f]{64}")

_SHAPE_VOTES = 9
"""Right images whose sizes vote for the archive's frame shape (the most common wins)."""


def _probe_shape(catalog: Catalog) -> tuple[int, int] | None:
    """The archive's frame shape: the catalog's, else the most common size among the first
    readable right images (ties: the earliest). One odd first frame (a thumbnail, a 1x1
    placeholder) used to set the shape alone and fail every good frame as the wrong size.
    Sizes come from the image headers (:func:`stages._imageio.read_header`), not decoding."""
    if catalog.shape:
        return catalog.shape
    from stages._imageio import read_header

    sizes: list[tuple[int, int]] = []
    for frame in catalog.frames[:50]:
        try:
            header = read_header(Path(frame.right).read_bytes())
        except (OSError, ValueError):  # unreadable or not an image: the next one
            continue
        sizes.append((int(header.height), int(header.width)))
        if len(sizes) == _SHAPE_VOTES:
            break
    if not sizes:
        return None
    votes = Counter(sizes)
    return max(sizes, key=votes.__getitem__)  # max keeps the first of equals


def default_rundir(catalog: Catalog) -> Path:
    """``runs/<archive name>``: the run directory when ``--out`` is not given."""
    return Path("runs") / catalog.name


def validate_request(
    catalog_path: str | os.PathLike[str],
    overrides: Iterable[str],
    frames: str | None,
    stage_package: str | None,
) -> RunRequest:
    """Catalog, graph, effective params and selected frames; raises before any work."""
    catalog = load_catalog(catalog_path)
    package = stage_package_name(stage_package)
    graph = build_graph(discover_stages(package))
    _check_metadata_names(catalog, graph)
    try:  # the catalog's own [params] first, so that its errors name the catalog
        resolve_stage_params(graph, catalog.params)
    except ParamError as exc:
        raise ParamError(
            f"{catalog.source}: [params]: {exc}; fix the catalog's [params] table"
        ) from None
    overrides = list(overrides)
    try:
        params = resolve_stage_params(
            graph, catalog.params, parse_set_overrides(graph, overrides)
        )
    except ParamError as exc:  # the catalog alone was valid: the --set values are not
        message = str(exc)
        raise ParamError(
            message if message.startswith("--set") else f"--set {' '.join(overrides)}: {message}"
        ) from None
    selected = [f for f in catalog.frames if frames is None or fnmatch.fnmatch(f.frame_id, frames)]
    if not selected:
        raise ParamError(
            f"--frames {frames!r} matches none of the {len(catalog.frames)} frames of "
            f"{catalog.source}; frame ids look like {catalog.frames[0].frame_id!r}"
        )
    return RunRequest(catalog, graph, params, selected, package)


def _check_metadata_names(catalog: Catalog, graph: StageGraph) -> None:
    """Raise CatalogError when a metadata column of the index is named like a stage's
    ``<stage>_...`` column of ``frames.parquet``: the engine's value would win and the
    user's metadata be dropped without a word (fixed names: ``_frame_index``)."""
    for name in catalog.frames[0].metadata:
        for stage in graph.stages:
            if name.startswith(f"{stage.name}_"):
                raise CatalogError(
                    f"{catalog.index_path}: header: column {name!r} is named like the columns "
                    f"frames.parquet gives the {stage.name!r} stage's times and figures "
                    f"('{stage.name}_...'), so this metadata could be lost; rename it, e.g. "
                    f"to 'my_{name}'"
                )


def plan_run(
    request: RunRequest,
    out: str | os.PathLike[str] | None = None,
    *,
    state: RunState | None = None,
    products: str = "",
) -> RunPlan:
    """Work out what a validated request (:func:`validate_request`) must run.

    With ``state`` (the run's writable journal) newly computed input hashes are remembered;
    without it the run directory is only read. ``products`` is the canonical products root
    when it is not the run directory (see :func:`pipeline.store.coerce_products_root`).
    """
    catalog, graph, params, selected = (
        request.catalog,
        request.graph,
        request.params,
        request.frames,
    )
    rundir = Path(out) if out is not None else default_rundir(catalog)
    reader = state
    if reader is None and (rundir / "state.sqlite").exists():
        reader = RunState(rundir, readonly=True)
    try:
        done = reader.done_keys() if reader else {}
        failed = reader.failed() if reader else {}
        hashes = _hash_inputs(selected, reader, remember=state is not None)
    finally:
        if reader is not None and reader is not state:
            reader.close()
    image_shape = _probe_shape(catalog)
    keys: dict[str, dict[str, str]] = {}
    todo: dict[str, list[str]] = {}
    reasons: dict[str, dict[str, str]] = {}
    for frame in selected:
        fid = frame.frame_id
        keys[fid] = frame_keys(graph, params, frame, hashes[fid], image_shape)
        todo[fid], reasons[fid] = [], {}
        for stage in graph.stages:
            recorded = done.get((fid, stage.name))
            if recorded == keys[fid][stage.name]:
                continue
            todo[fid].append(stage.name)
            if fid in failed:
                reasons[fid][stage.name] = "failed"
            else:
                reasons[fid][stage.name] = "new" if recorded is None else "changed"
    return RunPlan(
        catalog=catalog,
        graph=graph,
        params=params,
        rundir=rundir,
        frames=selected,
        indices={f.frame_id: i for i, f in enumerate(catalog.frames)},
        keys=keys,
        todo=todo,
        reasons=reasons,
        image_shape=image_shape,
        input_hashes=hashes,
        stage_package=request.stage_package,
        products=products,
    )


def format_duplicates(duplicates: Mapping[str, str]) -> str:
    """One line naming frames whose images repeat an earlier frame's; empty when none."""
    if not duplicates:
        return ""
    pairs = [f"{fid} = {earlier}" for fid, earlier in list(duplicates.items())[:5]]
    more = f" and {len(duplicates) - 5} more" if len(duplicates) > 5 else ""
    return (
        f"same images as an earlier frame: {', '.join(pairs)}{more}; their rocks count twice "
        "in queries and fits: remove the repeated rows from the index (for a new --out), or "
        "leave those frames out of queries (WHERE frame_id NOT IN (...))\n"
    )


def format_plan(plan: RunPlan) -> str:
    """The dry-run table: per stage, how many frames are new, changed, failed or done."""
    lines = [
        f"catalog {plan.catalog.source} ({plan.catalog.name}), {len(plan.frames)} frames "
        f"selected, run directory {plan.rundir}"
        + (f", products at {plan.products}" if plan.products else ""),
        f"{'stage':<12}{'new':>8}{'changed':>9}{'failed':>8}{'done':>8}",
    ]
    for stage, row in plan.counts().items():
        lines.append(
            f"{stage:<12}{row['new']:>8}{row['changed']:>9}{row['failed']:>8}{row['done']:>8}"
        )
    work = sum(1 for f in plan.frames if plan.todo[f.frame_id])
    lines.append(
        f"{work} frame(s) would run; 'changed' = parameters, code version or inputs "
        "differ from the recorded result"
    )
    return "\n".join(lines) + "\n" + format_duplicates(plan.duplicates)
