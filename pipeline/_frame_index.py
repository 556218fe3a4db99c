"""The frame index of a survey catalog: a CSV of stereo pairs, validated row by row.

Columns ``frame_id,left,right`` are required (image paths relative to the CSV's directory, or
absolute; a leading ``~`` is the home directory). A column named like a numeric camera field
overrides it per frame (an empty cell keeps the catalog's value); any other column is
metadata, typed per column: int when every non-empty cell is an integer, float when every
non-empty cell is a number, str otherwise (so each column stores cleanly in Parquet); an
empty cell is ``None``. A metadata column may not take a name of ``frames.parquet``'s own
columns (:data:`RESERVED_COLUMNS`; the engine's ``<stage>_...`` figures are checked by
:func:`pipeline.plan.validate_request`, which knows the stages): a user's ``notes`` or
``status`` column was dropped without a word, and an ``archive`` or ``run_id`` column
replaced the real ones in ``arroyo query``.
Every problem raises CatalogError naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import CatalogError

__all__ = [
    "IndexRow",
    "read_index",
    "read_bytes",
    "decode_utf8",
    "as_float",
    "OVERRIDABLE",
    "RESERVED_COLUMNS",
]

OVERRIDABLE: tuple[str, ...] = ("focal_px", "baseline_m", "height_m", "pitch_deg", "cx", "cy")
"""Camera fields an index column of the same name overrides per frame."""

RESERVED_COLUMNS: tuple[str, ...] = (
    "index", "status", "failed_stage", "error", "notes", "archive", "run", "run_id",
)  # fmt: skip
"""Columns of ``frames.parquet`` (and of ``arroyo query``'s views) a metadata column may not
be named."""

_FRAME_ID_RE = re.compile(r"[A-Za-z0-9_.-]+")
_FRAME_ID_MAX = 200
_REQUIRED_COLUMNS = ("frame_id", "left", "right")
_INT_RE = re.compile(r"[+-]?[0-9]+")
_FLOAT_RE = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


@dataclass(frozen=True)
class IndexRow:
    """One validated row: where it is, the pair's absolute paths, overrides and metadata."""

    line: int
    frame_id: str
    left: Path
    right: Path
    overrides: dict[str, float]
    metadata: dict[str, Any]


def read_bytes(path: Path, what: str, fix: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise CatalogError(f"{what} {path} does not exist; {fix}") from None
    except IsADirectoryError:
        raise CatalogError(f"{what} {path} is a directory, expected a file; {fix}") from None
    except PermissionError:
        raise CatalogError(
            f"{what} {path} is not readable (permission denied); check its permissions"
        ) from None
    except (OSError, ValueError) as exc:
        raise CatalogError(f"{what} {path} cannot be read: {exc}; {fix}") from None


def decode_utf8(raw: bytes, path: Path, what: str) -> str:
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise CatalogError(
            f"{path}: line {line}: {what} is not valid UTF-8 text (byte {exc.start}); "
            "save it as UTF-8 text"
        ) from None


def as_float(value: Any) -> float | None:
    """``value`` as a finite float, or None when it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def read_index(path: Path) -> list[IndexRow]:
    """Read and validate the frame index CSV at ``path`` (absolute); at least one row."""
    rows = _csv_rows(path)
    header_line, header = rows[0]
    _check_header(path, header_line, header)
    if len(rows) == 1:
        raise CatalogError(f"{path}: the frame index has no frames; add one row per stereo pair")
    columns = {name: i for i, name in enumerate(header)}
    metadata_types = _metadata_types(header, rows[1:])
    seen: dict[str, int] = {}
    records = []
    for line, cells in rows[1:]:
        if len(cells) != len(header):
            raise CatalogError(
                f"{path}: line {line}: expected {len(header)} cells like the header, got "
                f"{len(cells)}; quote cells that contain commas"
            )
        for name in _REQUIRED_COLUMNS:
            if not cells[columns[name]]:
                raise CatalogError(f"{path}: line {line}: empty cell in column {name!r}; fill it")
        frame_id = _frame_id(path, line, cells[columns["frame_id"]])
        if frame_id in seen:
            raise CatalogError(
                f"{path}: line {line}: duplicate frame_id {frame_id!r} (first on line "
                f"{seen[frame_id]}); frame ids must be unique"
            )
        seen[frame_id] = line
        paths = {}
        for side in ("left", "right"):
            cell = cells[columns[side]]
            if "\x00" in cell:
                raise CatalogError(f"{path}: line {line}: column {side!r} is not a valid path")
            # `~/data/x.png` was taken as relative to the CSV: '.../index/~/data/x.png'
            paths[side] = Path(os.path.abspath(path.parent / os.path.expanduser(cell)))
        metadata = {
            name: None if not cells[columns[name]] else kind(cells[columns[name]])
            for name, kind in metadata_types.items()
        }
        overrides = {
            name: _override(path, line, name, cells[columns[name]])
            for name in OVERRIDABLE
            if name in columns and cells[columns[name]]
        }
        records.append(IndexRow(line, frame_id, paths["left"], paths["right"], overrides, metadata))
    return records


def _csv_rows(path: Path) -> list[tuple[int, list[str]]]:
    """Non-blank rows as (line number, stripped cells); at least one."""
    fix = "check [frames] index in the catalog (relative to the catalog's directory)"
    text = decode_utf8(read_bytes(path, "frame index", fix), path, "the frame index")
    rows: list[tuple[int, list[str]]] = []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        for row in reader:
            if any(cell.strip() for cell in row):
                rows.append((reader.line_num, [cell.strip() for cell in row]))
    except csv.Error as exc:
        raise CatalogError(
            f"{path}: line {reader.line_num}: invalid CSV ({exc}); fix the quoting"
        ) from None
    if not rows:
        raise CatalogError(
            f"{path}: the frame index is empty; it needs a header frame_id,left,right and "
            "one row per stereo pair"
        )
    return rows


def _check_header(path: Path, line: int, header: list[str]) -> None:
    missing = [name for name in _REQUIRED_COLUMNS if name not in header]
    if missing:
        # a spreadsheet's export with semicolons or tabs read as one column
        other = next((sep for sep in (";", "\t", "|") if len(header) == 1 and sep in header[0]), "")
        hint = (
            f"; the cells are separated by {other!r}: save the index with commas "
            "(CSV, comma-separated)"
            if other
            else ""
        )
        raise CatalogError(
            f"{path}: line {line}: the frame index lacks the column(s) {', '.join(missing)}; "
            f"its header must contain frame_id,left,right, got {','.join(header)!r}{hint}"
        )
    for i, name in enumerate(header):
        if not name:
            raise CatalogError(f"{path}: line {line}: header cell {i + 1} is empty; name it")
        if header.index(name) != i:
            raise CatalogError(f"{path}: line {line}: column {name!r} appears twice; rename one")
        if name in RESERVED_COLUMNS:
            raise CatalogError(
                f"{path}: line {line}: column {name!r} is a name frames.parquet uses for its "
                f"own column (reserved: {', '.join(RESERVED_COLUMNS)}), so this metadata "
                f"would be lost or would replace the engine's; rename it, e.g. to "
                f"'my_{name}'"
            )


def _metadata_types(header: list[str], rows: list[tuple[int, list[str]]]) -> dict[str, type]:
    """Per metadata column: int, float or str, whichever fits every non-empty cell."""
    types: dict[str, type] = {}
    for i, name in enumerate(header):
        if name in _REQUIRED_COLUMNS or name in OVERRIDABLE:
            continue
        cells = [cells[i] for _, cells in rows if i < len(cells) and cells[i]]
        if all(_INT_RE.fullmatch(c) for c in cells):
            types[name] = int
        elif all(_FLOAT_RE.fullmatch(c) or _INT_RE.fullmatch(c) for c in cells):
            types[name] = float
        else:
            types[name] = str
    return types


def _frame_id(path: Path, line: int, frame_id: str) -> str:
    if (
        not _FRAME_ID_RE.fullmatch(frame_id)
        or set(frame_id) == {"."}
        or len(frame_id) > _FRAME_ID_MAX
    ):
        raise CatalogError(
            f"{path}: line {line}: frame_id {frame_id!r} must be 1-{_FRAME_ID_MAX} of "
            "A-Z a-z 0-9 _ . - (not only dots) so it is safe in file names; rename it"
        )
    return frame_id


def _override(path: Path, line: int, name: str, cell: str) -> float:
    number = as_float(float(cell)) if _FLOAT_RE.fullmatch(cell) else None
    if number is None:
        problem = "a finite number"
    elif name == "pitch_deg" and not 0 <= number < 90:
        problem = "a number in [0, 90) degrees"
    elif name in ("focal_px", "baseline_m", "height_m") and number <= 0:
        problem = "a number > 0"
    else:
        return number
    raise CatalogError(
        f"{path}: line {line}: column {name!r} overrides the camera's {name} for this frame "
        f"and must be {problem}, got {cell!r}; fix the cell, or leave it empty to keep the "
        "catalog's value"
    )
