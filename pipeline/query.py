"""``arroyo query``: SQL (DuckDB, in-process) over the Parquet products of one or more runs.

Views
-----
Every run directory given contributes its rows to four views, so several runs (for example
one per archive) query as one table set:

``descriptors``
    One row per rock per frame (columns in ``docs/design.md``).
``relations``
    One row per scene-graph edge.
``frames``
    One row per catalog frame: ``status`` ('done'|'failed'|'pending'), ``error``,
    ``failed_stage``, ``<stage>_seconds``, ``<stage>_<figure>`` and the catalog's metadata
    columns.
``evaluation``
    Scores against ground truth, when ``arroyo evaluate`` ran (tidy: product, method, metric,
    value; ``frame_id = '*'`` is the archive aggregate).

Each view has an ``archive`` column (the catalog's archive name) and a ``run`` column: the
name of the run directory as given (``runs/lab`` -> ``lab``; the whole path as given when
two directories share a name). ``run_id`` stays the id of the run that computed the row (a
resumed run directory may hold rows of several run ids). Columns that exist in some runs
only (per-archive catalog metadata, new figures) are NULL in the others. A view that no
given run has files for (``evaluation`` before ``arroyo evaluate``) is an empty view with
the documented columns, so a query over it returns no rows rather than an error.

A table product of a run's own stages (``arroyo run --stage-package``) is a view of the
same name, built the same way from each run that published it.

What a query sees
-----------------
``descriptors`` and ``relations`` are read from the published generation of each run
(``RUNDIR/<product>.parquet``, a symlink swapped atomically when a run ends; files
hive-partitioned by ``archive=<name>/`` so a filter on ``archive`` prunes whole files, and
compacted into few large files). They therefore hold completed frames only. The files are
listed once when the views are created: a run publishing meanwhile does not change what an
open connection reads. A run still in progress (``run.json`` status ``running`` and a live
holder of ``RUNDIR/.arroyo.lock``) is refused unless ``allow_running=True``, which reads
what the last finished run published plus the current ``frames.parquet``.

Only one read-only statement (``SELECT``, ``WITH ... SELECT``, ``DESCRIBE``, ``SHOW``,
``EXPLAIN``, ``SUMMARIZE``) is accepted by :func:`query_runs`; it may read local files of
the user's own (``read_csv('picked.csv')``) but loads no DuckDB extension (no URL); use
:func:`open_runs` for a full DuckDB connection in a notebook.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path
from typing import IO, Any

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

from .errors import ParamError, RunDirError
from .lock import lock_holder
from .store import (
    atomic_write_bytes,
    check_products_reachable,
    open_products_group,
    products_root,
    zarr_location,
)
from .tables import FRAMES_NAME, published_path

__all__ = [
    "VIEWS",
    "FORMATS",
    "RunInfo",
    "load_runs",
    "open_runs",
    "query_runs",
    "query_df",
    "frame_dataset",
    "format_text_table",
    "query_command",
]

VIEWS = ("descriptors", "relations", "frames", "evaluation")
FORMATS = ("table", "csv", "parquet", "json")
EVALUATION_NAME = "evaluation.parquet"
_TABLE_ROWS_SHOWN = 500
_JSON_BATCH_ROWS = 10_000
_SUFFIX_FORMATS = {".csv": "csv", ".json": "json", ".parquet": "parquet", ".pq": "parquet"}
_FORMAT_SUFFIXES = {"csv": ".csv", "json": ".json", "parquet": ".parquet"}
_READ_ONLY = {"SELECT", "EXPLAIN"}
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_READ_ONLY_PRAGMAS = ("describe", "show", "summarize", "pragma show", "pragma table_info")


@dataclass(frozen=True)
class RunInfo:
    """A run directory resolved for querying.

    Attributes
    ----------
    path : Path
        The run directory.
    run : str
        The value of the views' ``run`` column.
    run_id, archive, status : str
        From ``run.json``.
    files : dict of str to list of Path
        View name -> Parquet files it reads (possibly empty).
    meta : dict
        The whole ``run.json``.
    """

    path: Path
    run: str
    run_id: str
    archive: str
    status: str
    files: dict[str, list[Path]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


# -- run directories ----------------------------------------------------------------------
def _coerce_rundirs(rundirs: Any) -> list[Path]:
    if isinstance(rundirs, str | os.PathLike):
        rundirs = [rundirs]
    if not isinstance(rundirs, Iterable):
        raise TypeError(
            f"rundirs must be a path or a sequence of paths, got {type(rundirs).__name__}"
        )
    paths = []
    for item in rundirs:
        if not isinstance(item, str | os.PathLike):
            raise TypeError(f"each run directory must be a str or Path, got {item!r}")
        paths.append(Path(item))
    if not paths:
        raise ParamError("no run directory given; pass at least one RUNDIR")
    seen: dict[Path, Path] = {}
    for path in paths:
        key = path.resolve()
        if key in seen:
            raise ParamError(
                f"run directory {path} is given twice (also as {seen[key]}); its rows would "
                "be counted twice. Pass each RUNDIR once"
            )
        seen[key] = path
    return paths


def _load_run_json(rundir: Path) -> dict[str, Any]:
    if not rundir.exists():
        raise RunDirError(
            f"run directory {rundir} does not exist; check the path or run "
            "`arroyo run CATALOG --out DIR` first"
        )
    if not rundir.is_dir():
        raise RunDirError(f"{rundir} is a file, not a run directory")
    path = rundir / "run.json"
    if not path.is_file():
        raise RunDirError(
            f"{rundir} is not an arroyo run directory (no run.json); pass the --out directory "
            "of `arroyo run`"
        )
    try:
        meta = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RunDirError(
            f"cannot read {path}: {exc}; `arroyo run` writes it anew: remove the file and "
            "rerun the catalog into this directory (with the same --products, if any)"
        ) from None
    if not isinstance(meta, dict):
        raise RunDirError(f"{path} does not hold a JSON object; it is not an arroyo run.json")
    return meta


def _check_not_running(rundir: Path, meta: Mapping[str, Any]) -> None:
    # A run holds the lock only while it runs; checking run.json first keeps us from
    # touching the lock of finished runs at all.
    if meta.get("status") != "running":
        return
    holder = lock_holder(rundir)
    if holder is None:
        return  # a killed run: what it published is complete, the rest is not visible
    raise RunDirError(
        f"run {rundir} is still in progress (arroyo pid {holder.get('pid', '?')} on host "
        f"{holder.get('host', '?')} since {holder.get('since', '?')}); wait until it "
        "finishes, or pass --allow-running (Python: allow_running=True) to read the frames "
        "it has published so far"
    )


def _published_files(rundir: Path, product: str) -> list[Path]:
    link = published_path(rundir, product)
    if not link.exists() and not link.is_symlink():
        return []
    # resolve the symlink once: a later swap by a new run must not change what we read
    target = link.resolve()
    if target.is_file():
        return [target]
    files = []
    if target.is_dir():
        files = sorted(target.glob("archive=*/*.parquet")) or sorted(target.rglob("*.parquet"))
    if not files:
        # a publication holds at least one (typed, maybe empty) file: with its files deleted
        # the view was silently empty
        raise RunDirError(
            f"{link} of run {rundir} points to {target}, which holds no Parquet file (deleted "
            f"or lost?), so the {product} view would be silently empty; the next `arroyo run "
            f"CATALOG --out {rundir}` publishes it again (`arroyo status --verify {rundir}` "
            "lists what else is damaged)"
        )
    return files


def _other_tables(rundir: Path) -> list[str]:
    """Table products of the run's own stages (``--stage-package``) besides the built-in
    ones: every published ``<name>.parquet`` link whose name is an SQL identifier."""
    found = []
    for link in sorted(rundir.glob("*.parquet")):
        name = link.name.removesuffix(".parquet")
        if link.is_symlink() and name not in VIEWS and _IDENTIFIER.fullmatch(name):
            found.append(name)
    return found


def _written_by_current_stage(files: Sequence[Path], meta: Mapping[str, Any]) -> bool:
    """A table left by a stage the run directory's last run no longer has (another
    ``--stage-package``) is stale: its rows are not of the current products."""
    if not files:
        return False
    try:
        metadata = pq.read_schema(files[0]).metadata or {}
    except (OSError, pa.ArrowInvalid):
        return True  # unreadable: _branch_sql names the file
    stage = metadata.get(b"arroyo.stage", b"").decode()
    return not stage or stage in (meta.get("stages") or {})


def _check_frames_table(rundir: Path, files: Mapping[str, Sequence[Path]]) -> None:
    """A run with published rows but no ``frames.parquet`` lost it (the file is written when
    a run starts): its ``frames`` view was silently empty while ``descriptors`` had rows."""
    if files["frames"] or not (files["descriptors"] or files["relations"]):
        return
    raise RunDirError(
        f"{rundir} has published descriptors and relations but no {FRAMES_NAME} (deleted or "
        "lost?), so the frames view would be silently empty; rerun the catalog into it "
        f"(`arroyo run CATALOG --out {rundir}`): it writes {FRAMES_NAME} again and recomputes "
        "only results that are not current"
    )


def _view_names(runs: Sequence[RunInfo]) -> list[str]:
    extra = sorted({name for r in runs for name in r.files} - set(VIEWS))
    return [*VIEWS, *extra]


def _run_labels(paths: Sequence[Path]) -> list[str]:
    names = [p.resolve().name or str(p) for p in paths]
    return [
        name if names.count(name) == 1 else str(path)
        for name, path in zip(names, paths, strict=True)
    ]


def load_runs(rundirs: Any, *, allow_running: bool = False) -> list[RunInfo]:
    """Resolve run directories: metadata and the Parquet files each view reads.

    Parameters
    ----------
    rundirs : path or sequence of paths
        Run directories (``arroyo run --out``).
    allow_running : bool
        Accept a run still in progress (reads what it has published so far).

    Raises
    ------
    RunDirError
        A directory is missing, not a run directory, or (without ``allow_running``) still
        being written by a live run.
    ParamError
        No directory, or the same directory twice.
    """
    paths = _coerce_rundirs(rundirs)
    runs = []
    for path, label in zip(paths, _run_labels(paths), strict=True):
        meta = _load_run_json(path)
        if not allow_running:
            _check_not_running(path, meta)
        files = {
            "descriptors": _published_files(path, "descriptors"),
            "relations": _published_files(path, "relations"),
            "frames": [path / FRAMES_NAME] if (path / FRAMES_NAME).is_file() else [],
            "evaluation": [path / EVALUATION_NAME] if (path / EVALUATION_NAME).is_file() else [],
        }
        _check_frames_table(path, files)
        for product in _other_tables(path):
            published = _published_files(path, product)
            if _written_by_current_stage(published, meta):
                files[product] = published
        runs.append(
            RunInfo(
                path=path,
                run=label,
                run_id=str(meta.get("run_id", "")),
                archive=str(meta.get("archive", "")),
                status=str(meta.get("status", "")),
                files=files,
                meta=meta,
            )
        )
    return runs


# -- views --------------------------------------------------------------------------------
def _sql_str(value: str | os.PathLike[str]) -> str:
    return "'" + str(value).replace("'", "''") + "'"


def _empty_schema(view: str) -> pa.Schema:
    ids = [("archive", pa.string()), ("run", pa.string()), ("run_id", pa.string())]
    if view in ("descriptors", "relations"):
        from stages.describe import DESCRIPTOR_SCHEMA, RELATION_SCHEMA

        body = DESCRIPTOR_SCHEMA if view == "descriptors" else RELATION_SCHEMA
        return pa.schema([*ids, ("frame_id", pa.string()), *body])
    if view == "frames":
        return pa.schema(
            [
                *ids,
                ("frame_id", pa.string()),
                ("index", pa.int64()),
                ("status", pa.string()),
                ("failed_stage", pa.string()),
                ("error", pa.string()),
            ]
        )
    if view != "evaluation":  # a table of the run's own stages that published no files
        return pa.schema([*ids, ("frame_id", pa.string())])
    return pa.schema(
        [
            *ids,
            ("frame_id", pa.string()),
            ("product", pa.string()),
            ("method", pa.string()),
            ("metric", pa.string()),
            ("value", pa.float64()),
        ]
    )


def _branch_sql(view: str, run: RunInfo) -> str | None:
    files = run.files.get(view, [])
    if not files:
        return None
    names: set[str] = set()
    for path in files:
        try:
            names |= set(pq.read_schema(path).names)
        except (OSError, pa.ArrowInvalid) as exc:
            raise RunDirError(
                f"cannot read {path} of run {run.path}: {exc}; `arroyo status --verify "
                f"{run.path}` checks the store and the next run repairs it"
            ) from None
    partitioned = any(p.parent.name.startswith("archive=") for p in files)
    if partitioned:
        names.add("archive")  # from the hive directory name, not a column in the files
    hive = "true" if partitioned else "false"
    source = (
        f"read_parquet([{', '.join(_sql_str(p) for p in files)}], "
        f"hive_partitioning={hive}, union_by_name=true)"
    )
    first = []
    if "archive" in names:
        first.append("archive")
    else:
        first.append(f"{_sql_str(run.archive)} AS archive")
    first.append(f"{_sql_str(run.run)} AS run")
    first.append("run_id" if "run_id" in names else f"{_sql_str(run.run_id)} AS run_id")
    drop = [c for c in ("archive", "run", "run_id") if c in names]
    star = f"* EXCLUDE ({', '.join(drop)})" if drop else "*"
    return f"SELECT {', '.join(first)}, {star} FROM {source}"


def _create_views(con: duckdb.DuckDBPyConnection, runs: Sequence[RunInfo]) -> None:
    for view in _view_names(runs):
        branches = [b for b in (_branch_sql(view, r) for r in runs) if b is not None]
        if branches:
            body = "\nUNION ALL BY NAME\n".join(f"({b})" for b in branches)
            con.execute(f"CREATE VIEW {view} AS {body}")
        else:
            empty = _empty_schema(view).empty_table()
            con.register(f"_empty_{view}", empty)
            con.execute(f"CREATE VIEW {view} AS SELECT * FROM _empty_{view}")


def open_runs(rundirs: Any, *, allow_running: bool = False) -> duckdb.DuckDBPyConnection:
    """A DuckDB connection with the views over these runs (for notebooks).

    Parameters
    ----------
    rundirs : path or sequence of paths
        One or more run directories.
    allow_running : bool
        Accept runs still in progress (see the module docstring).

    Returns
    -------
    duckdb.DuckDBPyConnection
        In-memory connection with views ``descriptors``, ``relations``, ``frames`` and
        ``evaluation``. ``con.sql(SQL)`` gives a relation: ``.to_arrow_table()``,
        ``.df()`` (pandas), ``.fetchall()``.

    Examples
    --------
    >>> con = open_runs(["runs/lab", "runs/mojave"])  # doctest: +SKIP
    >>> con.sql("SELECT archive, count(*) FROM descriptors GROUP BY ALL").df()  # doctest: +SKIP
    """
    runs = load_runs(rundirs, allow_running=allow_running)
    con = duckdb.connect(":memory:")
    try:
        _create_views(con, runs)
    except BaseException:
        con.close()
        raise
    return con


def _offline(con: duckdb.DuckDBPyConnection) -> None:
    """No extension is downloaded or loaded behind the user's back: a URL in a query made
    DuckDB try to fetch httpfs from the network (a hang offline). Local files stay readable,
    so a scientist can join a table of their own (``read_csv('picked.csv')``); writes are
    refused by :func:`_check_read_only`. Locked, so no statement can lift it."""
    con.execute("SET autoinstall_known_extensions = false")
    con.execute("SET autoload_known_extensions = false")
    con.execute("SET lock_configuration = true")


def _check_read_only(con: duckdb.DuckDBPyConnection, sql: str) -> None:
    if not isinstance(sql, str):
        raise TypeError(f"sql must be a str, got {type(sql).__name__}")
    if not sql.strip():
        raise ParamError('empty SQL; pass a query such as "SELECT count(*) FROM descriptors"')
    try:
        statements = con.extract_statements(sql)
    except duckdb.Error as exc:
        raise ParamError(f"invalid SQL: {exc}") from None
    if len(statements) != 1:
        raise ParamError(
            f"pass exactly one SQL statement, got {len(statements)}; run them one at a time"
        )
    kind = statements[0].type.name
    text = sql.strip().lower()
    if kind not in _READ_ONLY and not text.startswith(_READ_ONLY_PRAGMAS):
        raise ParamError(
            f"only read-only queries (SELECT, WITH ... SELECT, DESCRIBE, SUMMARIZE, EXPLAIN) "
            f"are allowed, got a statement of type {kind}; arroyo query never changes a run. Use "
            "--format/--output to save results"
        )


def query_runs(rundirs: Any, sql: str, *, allow_running: bool = False) -> pa.Table:
    """Run one read-only SQL statement over the views of these runs.

    Parameters
    ----------
    rundirs : path or sequence of paths
        One or more run directories.
    sql : str
        One DuckDB SELECT (or DESCRIBE/SUMMARIZE/EXPLAIN) over ``descriptors``,
        ``relations``, ``frames``, ``evaluation``.
    allow_running : bool
        Accept runs still in progress.

    Returns
    -------
    pyarrow.Table

    Raises
    ------
    ParamError
        Invalid SQL, an unknown table or column, or a statement that is not read-only.
    RunDirError
        A missing or in-progress run directory.
    """
    runs = load_runs(rundirs, allow_running=allow_running)
    con = duckdb.connect(":memory:")
    try:
        _create_views(con, runs)
        _offline(con)
        _check_read_only(con, sql)
        try:
            relation = con.sql(sql)
            if relation is None:
                return pa.table({})
            return relation.to_arrow_table()
        except duckdb.IOException as exc:
            raise RunDirError(f"cannot read the run's Parquet files: {exc}") from None
        except duckdb.Error as exc:
            needed = re.search(r"requires the extension (\w+)", str(exc))
            if needed:  # DuckDB's advice (INSTALL, LOAD, SET) is refused here
                raise ParamError(
                    f"the query needs DuckDB's {needed.group(1)} extension (a URL, or a format "
                    "DuckDB does not read by itself), and arroyo query loads none; copy the "
                    "file to a local path, or use pipeline.query.open_runs(RUNDIRS) in Python, "
                    "a full DuckDB connection"
                ) from None
            raise ParamError(
                f"query failed: {exc}\nviews: {', '.join(_view_names(runs))} (DESCRIBE "
                "descriptors lists the columns)"
            ) from None
    finally:
        con.close()


def query_df(rundirs: Any, sql: str, *, allow_running: bool = False) -> Any:
    """:func:`query_runs` as a pandas DataFrame."""
    return query_runs(rundirs, sql, allow_running=allow_running).to_pandas()


# -- one frame's maps ---------------------------------------------------------------------
def frame_dataset(rundir: str | os.PathLike[str], frame_id: str) -> Any:
    """The array products of one frame (images, disparity, range, height, residual, labels,
    sector grids) as an in-memory ``xarray.Dataset``.

    Parameters
    ----------
    rundir : path
        Run directory.
    frame_id : str
        A frame of the run's catalog.

    Returns
    -------
    xarray.Dataset
        Variables with dims (y, x) or (sector_y, sector_x)...; attrs ``archive``,
        ``run_id``, ``frame_id``, ``status`` ('done'|'failed'|'pending') and ``error``.
        Maps of a frame that is not done hold fill values (NaN, 0) or, for a frame that
        failed or is pending on a rerun, an earlier run's results: check ``status``.
    """
    import xarray as xr

    path = Path(rundir)
    meta = _load_run_json(path)
    if not isinstance(frame_id, str):
        raise TypeError(f"frame_id must be a str, got {type(frame_id).__name__}")
    store = zarr_location(products_root(path, meta))
    if meta.get("products"):  # "wrote no array products yet" of a moved products directory
        check_products_reachable(path, products_root(path, meta), doing="no frame was read")
    if open_products_group(products_root(path, meta)) is None:
        raise RunDirError(f"{store} does not exist; the run wrote no array products yet")
    data = xr.open_zarr(store)
    frames = [str(f) for f in data["frame"].values]
    if frame_id not in frames:
        raise ParamError(
            f"frame {frame_id!r} is not in run {path} ({len(frames)} frames, e.g. "
            f'{frames[:3]}); `arroyo query {path} "SELECT frame_id FROM frames"` lists them'
        )
    one = data.sel(frame=frame_id).load()
    data.close()
    status, error = "pending", None
    if (path / FRAMES_NAME).is_file():
        rows = pq.read_table(path / FRAMES_NAME, columns=["frame_id", "status", "error"])
        for row in rows.to_pylist():
            if row["frame_id"] == frame_id:
                status, error = row["status"], row["error"]
    one.attrs.update(
        archive=str(meta.get("archive", "")),
        run_id=str(meta.get("run_id", "")),
        frame_id=frame_id,
        status=status,
        error=error or "",
    )
    return one


# -- output -------------------------------------------------------------------------------
def _format_cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value).lower()
        if value == 0 or 1e-3 <= abs(value) < 1e7:
            text = f"{value:.4f}".rstrip("0").rstrip(".")
            return text if text not in ("", "-0") else "0"
        return f"{value:.4g}"
    return str(value)


def _is_numeric(type_: pa.DataType) -> bool:
    return pa.types.is_integer(type_) or pa.types.is_floating(type_) or pa.types.is_decimal(type_)


def format_text_table(table: pa.Table, *, max_rows: int | None = None) -> str:
    """A plain-text table (numbers right-aligned) for pipes, files and logs.

    Parameters
    ----------
    table : pyarrow.Table
    max_rows : int, optional
        Show at most this many rows and say how many were left out.
    """
    shown = table if max_rows is None else table.slice(0, max_rows)
    names = table.column_names
    cells = [[_format_cell(v) for v in shown.column(n).to_pylist()] for n in names]
    numeric = [_is_numeric(table.schema.field(n).type) for n in names]
    widths = [max([len(n), *map(len, col)]) for n, col in zip(names, cells, strict=True)]

    def line(values: Sequence[str]) -> str:
        parts = [
            v.rjust(w) if num else v.ljust(w)
            for v, w, num in zip(values, widths, numeric, strict=True)
        ]
        return "  ".join(parts).rstrip()

    out = [line(names), "  ".join("-" * w for w in widths)]
    out += [line(row) for row in zip(*cells, strict=True)] if names else []
    footer = f"({table.num_rows} row{'s' if table.num_rows != 1 else ''}"
    if shown.num_rows < table.num_rows:
        footer += f", first {shown.num_rows} shown; use --format csv for all"
    out.append(footer + ")")
    return "\n".join(out) + "\n"


def _rich_table(table: pa.Table, *, max_rows: int) -> Any:
    from rich.table import Table

    shown = table.slice(0, max_rows)
    caption = f"{table.num_rows} row{'s' if table.num_rows != 1 else ''}"
    if shown.num_rows < table.num_rows:
        caption += f", first {shown.num_rows} shown; use --format csv for all"
    out = Table(caption=caption, header_style="bold")
    for name in table.column_names:
        numeric = _is_numeric(table.schema.field(name).type)
        out.add_column(name, justify="right" if numeric else "left")
    columns = [[_format_cell(v) for v in shown.column(n).to_pylist()] for n in table.column_names]
    for row in zip(*columns, strict=True):
        out.add_row(*row)
    return out


def _narrowest_rich_width(table: pa.Table, *, max_rows: int) -> int:
    """Terminal columns the rich table needs with every cell wrapped at its spaces: rich
    cuts a word that does not fit to '…', losing the value."""
    shown = table.slice(0, max_rows)
    total = 1  # the left border
    for name in table.column_names:
        cells = shown.column(name).to_pylist()
        words = [name, *(w for v in cells for w in _format_cell(v).split())]
        total += max(len(w) for w in words) + 3  # padding both sides, the right border
    return total


def _json_value(value: Any) -> Any:
    if isinstance(value, Decimal):
        # sum() of an integer column is a HUGEINT, a decimal of scale 0: 61902, not 61902.0,
        # and exact beyond 2**53
        exponent = value.as_tuple().exponent
        value = int(value) if isinstance(exponent, int) and exponent >= 0 else float(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_value(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_value(v) for v in value]
    return value


def _encode_json(table: pa.Table) -> bytes:
    """``json.dumps(rows, indent=1)``, built batch by batch: the whole table as Python rows
    took ~10 times the output's size in memory (5.4 GB for 524,000 rows of descriptors)."""
    chunks: list[bytes] = []
    for batch in table.to_batches(max_chunksize=_JSON_BATCH_ROWS):
        rows = [
            json.dumps(_json_value(row), indent=1, default=str, allow_nan=False)
            for row in batch.to_pylist()
        ]
        if rows:  # each row one level deeper, as in the list json.dumps would indent
            chunks.append((" " + ",\n".join(rows).replace("\n", "\n ")).encode())
    if not chunks:
        return b"[]\n"
    return b"[\n" + b",\n".join(chunks) + b"\n]\n"


def _encode(table: pa.Table, fmt: str) -> bytes:
    if fmt == "csv":
        import pyarrow.csv as pacsv

        sink = pa.BufferOutputStream()
        pacsv.write_csv(table, sink)
        return sink.getvalue().to_pybytes()
    if fmt == "json":
        return _encode_json(table)
    if fmt == "parquet":
        sink = pa.BufferOutputStream()
        pq.write_table(table, sink, compression="zstd")
        return sink.getvalue().to_pybytes()
    return format_text_table(table).encode()


def _encode_checked(table: pa.Table, fmt: str) -> bytes:
    """:func:`_encode`, with a column pyarrow cannot write in ``fmt`` (an INTERVAL in CSV or
    Parquet, a list in CSV) named in a ParamError; it was a traceback (exit 1)."""
    try:
        return _encode(table, fmt)
    except (pa.ArrowNotImplementedError, pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        failing = []
        for name in table.column_names:
            try:
                _encode(table.select([name]).slice(0, 1), fmt)
            except (pa.ArrowNotImplementedError, pa.ArrowInvalid, pa.ArrowTypeError):
                failing.append(name)
        if not failing:
            raise ParamError(f"--format {fmt} cannot hold the query's result: {exc}") from None
        described = ", ".join(f"{n!r} ({table.schema.field(n).type})" for n in failing)
        first = failing[0]
        raise ParamError(
            f"--format {fmt} cannot hold column{'s' if len(failing) > 1 else ''} "
            f"{described}; convert it in the query, e.g. "
            f'CAST("{first}" AS VARCHAR) AS "{first}", or use --format json, which takes '
            "every type"
        ) from None


def _coerce_format(fmt: Any, output: str | os.PathLike[str] | None) -> str:
    """The format given, else the one ``output``'s suffix names, else ``table``; a suffix
    naming another format is refused (``-o x.parquet`` wrote a text table into x.parquet)."""
    if fmt is not None and fmt not in FORMATS:
        raise ParamError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    implied = _SUFFIX_FORMATS.get(Path(output).suffix.lower()) if output is not None else None
    if fmt is None:
        return implied or "table"
    if implied is not None and implied != fmt:
        raise ParamError(
            f"--output {output} names a {implied} file but --format is {fmt}; pass "
            f"--format {implied}, or an output name ending in "
            f"{_FORMAT_SUFFIXES.get(fmt, '.txt')}"
        )
    return str(fmt)


def _missing_directory(directory: Path) -> str:
    """Why ``directory`` cannot hold a file: its nearest existing ancestor is a file, or it
    does not exist (``--output /etc/passwd/x`` said /etc/passwd "does not exist")."""
    for ancestor in (directory, *directory.parents):
        if ancestor.is_dir():
            break
        if ancestor.exists() or ancestor.is_symlink():
            what = "a file, not a directory" if ancestor.is_file() else "not a directory"
            return f"{ancestor} is {what}; pass a file name inside a directory"
    return f"directory {directory} does not exist"


def _check_unique_columns(table: pa.Table) -> None:
    """Raise ParamError when two result columns share a name: the text table failed with a
    traceback, JSON kept one of them and Parquet wrote a file pyarrow cannot read back."""
    names = table.column_names
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        listed = ", ".join(repr(n) for n in twice)
        first = twice[0]
        raise ParamError(
            f"the query's result has more than one column named {listed}; give each a name "
            f"of its own with AS, e.g. SELECT a.{first} AS a_{first}, b.{first} AS b_{first}"
        )


def _quietly(test: Callable[[], bool]) -> bool:
    """A path test that is False, not an OSError, for a string no path can be: a whole SQL
    query is longer than a file name may be (ENAMETOOLONG crashed the README's query)."""
    try:
        return test()
    except (OSError, ValueError):
        return False


def _check_argument_order(
    rundirs: Sequence[str | os.PathLike[str]] | str | os.PathLike[str], sql: Any
) -> None:
    """``arroyo query "SQL" RUNDIR`` said "run directory SELECT ... does not exist"."""
    given = [rundirs] if isinstance(rundirs, str | os.PathLike) else list(rundirs)
    if (
        isinstance(sql, str)
        and _quietly(lambda: (Path(sql) / "run.json").is_file())
        and any(" " in str(r) and not _quietly(Path(r).exists) for r in given)
    ):
        raise ParamError(
            f"the SQL comes last, after the run directories, got the run directory {sql} "
            f'last; pass arroyo query RUNDIR... "SQL"'
        )


def _check_output(
    target: Path, rundirs: Sequence[str | os.PathLike[str]] | str | os.PathLike[str]
) -> None:
    """Raise ParamError, before the query runs, for an output no file can be written to or
    one inside a queried run directory (``-o RUNDIR/frames.parquet`` replaced the run's own
    frames table: "arroyo query never changes a run")."""
    if target.is_dir():
        raise ParamError(f"--output {target} is a directory; pass a file name")
    if not target.parent.is_dir():
        raise ParamError(f"--output {target}: {_missing_directory(target.parent)}")
    if not os.access(target.parent, os.W_OK):
        raise ParamError(
            f"--output {target}: directory {target.parent} is not writable (read-only?)"
        )
    where = target.resolve()
    for rundir in _coerce_rundirs(rundirs):
        if where.is_relative_to(rundir.resolve()):
            raise ParamError(
                f"--output {target} is inside the queried run directory {rundir}, which "
                "arroyo query never changes (it could replace the run's own files); write "
                "the result outside it"
            )


def query_command(
    rundirs: Sequence[str | os.PathLike[str]],
    sql: str,
    *,
    fmt: str | None = None,
    output: str | os.PathLike[str] | None = None,
    allow_running: bool = False,
    stdout: IO[str] | None = None,
) -> int:
    """``arroyo query``: run the query, then print or write the result.

    Parameters
    ----------
    rundirs : sequence of paths
    sql : str
    fmt : {'table', 'csv', 'parquet', 'json'}, optional
        ``table``: a rich table on a terminal (plain text when it is wider than the
        terminal), plain text otherwise. ``parquet`` needs ``output`` unless stdout is
        redirected. Default: the format ``output``'s suffix names (``.csv``, ``.json``,
        ``.parquet``), else ``table``; a suffix naming another format is refused.
    output : path, optional
        File to write (atomically), outside the queried run directories; default (or
        ``'-'``) stdout.
    allow_running : bool
        Accept runs still in progress.
    stdout : text stream, optional
        Where to print (default ``sys.stdout``).

    Returns
    -------
    int
        0. Errors raise ParamError / RunDirError (exit code 2 in the CLI) before anything
        is written.
    """
    _check_argument_order(rundirs, sql)
    if output is not None and str(output) == "-":  # wrote a file named '-'
        output = None
    fmt = _coerce_format(fmt, output)
    stream = stdout if stdout is not None else sys.stdout
    tty = bool(getattr(stream, "isatty", lambda: False)())
    if fmt == "parquet" and output is None and tty:
        raise ParamError(
            "--format parquet writes binary data; pass --output FILE.parquet or redirect "
            "stdout to a file"
        )
    if output is not None:
        _check_output(Path(output), rundirs)
    table = query_runs(rundirs, sql, allow_running=allow_running)
    _check_unique_columns(table)
    if output is not None:
        data = _encode_checked(table, fmt)
        try:
            atomic_write_bytes(Path(output), data)
        except OSError as exc:  # was a traceback (exit 1)
            raise ParamError(f"--output {output}: cannot write: {exc.strerror or exc}") from None
        return 0
    if fmt == "table" and tty:
        from rich.console import Console

        console = Console(file=stream)
        if _narrowest_rich_width(table, max_rows=_TABLE_ROWS_SHOWN) <= console.width:
            console.print(_rich_table(table, max_rows=_TABLE_ROWS_SHOWN))
            return 0
        # too wide: rich cut every cell to '…' (36 columns of `SELECT * FROM descriptors`)
        stream.write(format_text_table(table, max_rows=_TABLE_ROWS_SHOWN))
        stream.write(
            f"(wider than the terminal's {console.width} columns: pipe it to `less -S`, or "
            "select fewer columns)\n"
        )
    elif fmt == "table":
        stream.write(format_text_table(table, max_rows=_TABLE_ROWS_SHOWN))
    elif fmt == "parquet":
        data = _encode_checked(table, fmt)
        stream.flush()
        buffer = getattr(stream, "buffer", None)
        if buffer is None:
            raise ParamError("stdout takes no binary data here; pass --output FILE.parquet")
        buffer.write(data)
        buffer.flush()
    else:
        stream.write(_encode_checked(table, fmt).decode())
    stream.flush()
    return 0
