"""Survey catalogs: a TOML file describing one archive, and its CSV frame index.

A catalog names the archive, gives the stereo camera, points to a CSV index of stereo
pairs and may carry stage parameter overrides::

    [archive]
    name = "mojave"                 # [a-z0-9_-]+
    description = "Mojave desert rock field"

    [camera]
    focal_px = 430.0                # required, > 0
    baseline_m = 0.10               # required, > 0
    height_m = 1.0                  # optional, > 0
    pitch_deg = 38.0                # optional, in [0, 90)
    reference = "right"             # optional: "right" (default) or "left"
    # cx, cy optional: principal point in pixels (image centre when absent)

    [frames]
    index = "frames.csv"            # relative to the catalog file, or absolute
    shape = [480, 640]              # optional: [H, W] every frame must have

    [truth]                         # optional: ground truth of a synthetic archive
    dir = "truth"

    [params]                        # optional: stage -> {param -> value}
    depth = { max_disparity = 64 }

    [synth]                         # optional instead of [camera]/[frames]/[truth]
    archetype = "lab"               # rendered on first use by pipeline.synth.ensure_archive
    frames = 8
    seed = 1
    variant = "hard"                # optional

The index CSV has columns ``frame_id,left,right`` (image paths relative to the CSV's
directory, or absolute; a leading ``~`` is the home directory, as in ``index`` and ``dir``).
A column named like a numeric camera field (``focal_px``, ``baseline_m``, ``height_m``,
``pitch_deg``, ``cx``, ``cy``) overrides it for that frame
(an empty cell keeps the catalog's value); any other column is frame metadata. A metadata
column is typed as a whole so that it stores cleanly in Parquet: int when every non-empty
cell is an integer, float when every non-empty cell is a number, str otherwise; an empty
cell is ``None``. It may not be named like a column ``frames.parquet`` has itself
(``notes``, ``status``, ``archive``, ``run_id``..., ``<stage>_...``): rename such a column.

Every problem raises :class:`pipeline.errors.CatalogError` whose message names the file,
the field (with its line where it can be found), what was expected and how to fix it.
The catalog does not check that image files exist: a missing image fails only its frame
at ingest time, and the rest of the run goes on.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ._frame_index import OVERRIDABLE, as_float, decode_utf8, read_bytes, read_index
from .camera import Camera
from .errors import CatalogError

__all__ = ["FrameRecord", "Catalog", "load_catalog", "OVERRIDABLE_CAMERA_FIELDS"]

OVERRIDABLE_CAMERA_FIELDS: tuple[str, ...] = OVERRIDABLE
"""Camera fields an index column of the same name overrides per frame."""

_TABLE_KEYS: dict[str, tuple[str, ...]] = {
    "archive": ("name", "description"),
    "camera": (*OVERRIDABLE_CAMERA_FIELDS, "reference"),
    "frames": ("index", "shape"),
    "truth": ("dir",),
    "params": (),  # free-form: stage -> {param -> scalar}
    "synth": ("archetype", "frames", "seed", "variant"),
}
_NAME_RE = re.compile(r"[a-z0-9_-]+")


@dataclass(frozen=True)
class FrameRecord:
    """One stereo pair of the index.

    Attributes
    ----------
    frame_id : str
        Unique within the catalog, ``[A-Za-z0-9_.-]+`` (safe in file names).
    left, right : Path
        Absolute image paths (not checked for existence).
    camera : Camera
        The catalog camera with this frame's overrides applied.
    metadata : dict of str to {int, float, str, None}
        The index's other columns.
    overrides : dict of str to float
        Camera fields overridden for this frame.
    """

    frame_id: str
    left: Path
    right: Path
    camera: Camera
    metadata: dict[str, Any]
    overrides: dict[str, Any]


@dataclass(frozen=True)
class Catalog:
    """A validated survey catalog.

    Attributes
    ----------
    path : Path
        Absolute path of the TOML actually loaded (the rendered one for ``[synth]``).
    sha256 : str
        Hex digest of that TOML's bytes.
    name, description : str
        From ``[archive]``.
    camera : Camera
        From ``[camera]``.
    frames : tuple of FrameRecord
        In index order, at least one.
    params : dict of str to dict of str to {int, float, str, bool}
        ``[params]``: stage -> {param -> value}; not validated against the stages here.
    truth_dir : Path or None
        Absolute ``[truth] dir`` when present.
    shape : (int, int) or None
        ``[frames] shape = [H, W]`` when present.
    index_path : Path
        Absolute path of the frame index CSV.
    source : Path
        Absolute path of the catalog the user gave (differs from ``path`` for ``[synth]``).
    """

    path: Path
    sha256: str
    name: str
    description: str
    camera: Camera
    frames: tuple[FrameRecord, ...]
    params: dict[str, dict[str, Any]]
    truth_dir: Path | None
    shape: tuple[int, int] | None
    index_path: Path
    source: Path


def load_catalog(path: str | os.PathLike[str]) -> Catalog:
    """Read and validate a survey catalog and its frame index.

    Parameters
    ----------
    path : str or os.PathLike
        The catalog TOML file.

    Returns
    -------
    catalog : Catalog

    Raises
    ------
    CatalogError
        For any problem with the TOML, the index CSV or their values; the message names
        the file, the field and line where known, what was expected and how to fix it.
    """
    source = _coerce_path(path)
    doc = _TomlDoc.read(source)
    if "synth" in doc.data:
        return _load_synth(doc)
    return _load_plain(doc, source=source)


def _coerce_path(path: Any) -> Path:
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"catalog path must be a str or os.PathLike, got {type(path).__name__}")
    text = os.fspath(path)
    if isinstance(text, bytes) or "\x00" in text or not text:
        raise CatalogError(f"catalog path {text!r} is not a valid file path")
    return Path(os.path.abspath(text))


_SHIPPED = Path(__file__).resolve().parent.parent / "catalogs"  # in a checkout


class _TomlDoc:
    """The parsed TOML, its text (to locate keys' lines) and error helpers."""

    def __init__(self, path: Path, raw: bytes, text: str, data: dict[str, Any]) -> None:
        self.path = path
        self.sha256 = hashlib.sha256(raw).hexdigest()
        self.lines = text.splitlines()
        self.data = data

    @classmethod
    def read(cls, path: Path) -> _TomlDoc:
        fix = "give the path of a catalog TOML file"
        shipped = _SHIPPED / f"{path.stem}.toml"
        if not path.exists() and shipped.is_file():
            # `arroyo run lab`: the name of a built-in archive where a path is expected
            fix += f"; the built-in {path.stem} archive's catalog is {shipped}"
        raw = read_bytes(path, "catalog", fix)
        text = decode_utf8(raw, path, "the catalog")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            # Python < 3.14 only puts "(at line N, column M)" in the message.
            found = re.search(r"at line (\d+)", str(exc))
            lineno = getattr(exc, "lineno", None) or (found and int(found.group(1)))
            where = f"line {lineno}: " if lineno else ""
            raise CatalogError(
                f"{path}: {where}malformed TOML: {exc}; fix the syntax at that place"
            ) from None
        except (RecursionError, ValueError) as exc:
            raise CatalogError(f"{path}: malformed TOML ({exc}); fix the syntax") from None
        doc = cls(path, raw, text, data)
        doc.check_tables()
        return doc

    def line_of(self, table: str | None, key: str | None = None) -> int | None:
        """1-based line of ``[table]`` (key None) or of ``key =`` inside it, when found."""
        current: str | None = None
        header = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]")
        key_re = re.compile(rf"^\s*[\"']?{re.escape(key)}[\"']?\s*=") if key else None
        dotted = re.compile(rf"^\s*{re.escape(table or '')}\.{re.escape(key or '')}\s*=")
        for number, line in enumerate(self.lines, start=1):
            match = header.match(line)
            if match:
                current = match.group(1)
                if key is None and current == table:
                    return number
                continue
            if key_re is not None and current == table and key_re.match(line):
                return number
            if key is not None and table and current is None and dotted.match(line):
                return number
        return None

    def error(
        self, table: str | None, key: str | None, message: str, *, line: int | None = None
    ) -> CatalogError:
        """A CatalogError naming the file, the line of ``[table] key`` (or of the table
        itself when the key's line cannot be found) and the field."""
        if line is None and table is not None:
            line = (
                self.line_of(table, key)
                or (self.line_of(f"{table}.{key}") if key else None)
                or self.line_of(table)
            )
        where = f"line {line}: " if line else ""
        field = f"[{table}] {key}: " if key else f"[{table}]: " if table else ""
        return CatalogError(f"{self.path}: {where}{field}{message}")

    def check_tables(self) -> None:
        for name, value in self.data.items():
            if name not in _TABLE_KEYS:
                known = ", ".join(f"[{t}]" for t in _TABLE_KEYS)
                raise self.error(
                    None,
                    None,
                    f"unknown table or key {name!r}; a catalog has the tables {known}; "
                    "remove or rename it",
                    line=self.line_of(name) or self.line_of(None, name),
                )
            if not isinstance(value, dict):
                raise self.error(
                    name,
                    None,
                    f"expected a table, got {type(value).__name__}; write it as a [{name}] section",
                )
            allowed = _TABLE_KEYS[name]
            if name == "params":
                continue
            for key in value:
                if key not in allowed:
                    raise self.error(
                        name,
                        key,
                        f"unknown key; [{name}] accepts {', '.join(allowed)}; remove or rename it",
                    )

    def table(self, name: str, *, required: bool) -> dict[str, Any]:
        if name not in self.data:
            if required:
                raise self.error(None, None, f"missing required table [{name}]; add it")
            return {}
        return self.data[name]

    def get(self, table: str, key: str, kind: str, *, required: bool) -> Any:
        """A validated value of ``kind``: 'str', 'positive', 'number', 'int'."""
        values = self.data.get(table, {})
        if key not in values:
            if required:
                raise self.error(
                    table, None, f"missing required key {key!r}; add `{key} = ...` to [{table}]"
                )
            return None
        value = values[key]
        if kind == "str":
            if not isinstance(value, str):
                raise self.error(table, key, f"expected a string, got {value!r}")
            return value
        if kind == "int":
            if not isinstance(value, int) or isinstance(value, bool):
                raise self.error(table, key, f"expected an integer, got {value!r}")
            return value
        number = as_float(value)
        if number is None:
            raise self.error(table, key, f"expected a finite number, got {value!r}")
        if kind == "positive" and number <= 0:
            raise self.error(table, key, f"must be > 0, got {value!r}; set a positive value")
        return number


def _load_plain(doc: _TomlDoc, *, source: Path) -> Catalog:
    name, description, params = _archive_and_params(doc)
    doc.table("camera", required=True)
    camera = _camera(doc)
    doc.table("frames", required=True)
    index = doc.get("frames", "index", "str", required=True)
    if not index or "\x00" in index:
        raise doc.error("frames", "index", f"expected a CSV file path, got {index!r}")
    shape = _shape(doc)
    truth_dir = None
    if "truth" in doc.data:
        truth = doc.get("truth", "dir", "str", required=True)
        if not truth or "\x00" in truth:
            raise doc.error("truth", "dir", f"expected a directory path, got {truth!r}")
        truth_dir = Path(os.path.abspath(doc.path.parent / os.path.expanduser(truth)))
    index_path = Path(os.path.abspath(doc.path.parent / os.path.expanduser(index)))
    if not index_path.exists() and not index_path.is_symlink():
        # the index reader's own message named neither the catalog nor the line to fix
        raise doc.error(
            "frames",
            "index",
            f"the frame index {index_path} does not exist (a relative path is taken from the "
            f"catalog's directory {doc.path.parent}); fix the path",
        )
    frames = _frames(index_path, camera)
    return Catalog(
        path=doc.path,
        sha256=doc.sha256,
        name=name,
        description=description,
        camera=camera,
        frames=frames,
        params=params,
        truth_dir=truth_dir,
        shape=shape,
        index_path=index_path,
        source=source,
    )


def _archive_and_params(doc: _TomlDoc) -> tuple[str, str, dict[str, dict[str, Any]]]:
    doc.table("archive", required=True)
    name = doc.get("archive", "name", "str", required=True)
    if not _NAME_RE.fullmatch(name):
        raise doc.error(
            "archive",
            "name",
            f"must match [a-z0-9_-]+ (lower-case letters, digits, _ and -), "
            f"got {name!r}; rename the archive",
        )
    description = doc.get("archive", "description", "str", required=False) or ""
    params: dict[str, dict[str, Any]] = {}
    for stage, table in doc.table("params", required=False).items():
        if not isinstance(table, dict):
            raise doc.error(
                "params",
                stage,
                f"expected a table of parameters, got {table!r}; "
                f"write it as `{stage} = {{ name = value }}`",
            )
        for key, value in table.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise doc.error("params", stage, f"{stage}.{key} must be finite, got {value!r}")
            if not isinstance(value, bool | int | float | str):
                raise doc.error(
                    "params",
                    stage,
                    f"{stage}.{key} must be a number, string or boolean, got {value!r}",
                )
        params[stage] = dict(table)
    return name, description, params


def _camera(doc: _TomlDoc) -> Camera:
    values: dict[str, Any] = {}
    for key in OVERRIDABLE_CAMERA_FIELDS:
        kind = "number" if key in ("pitch_deg", "cx", "cy") else "positive"
        values[key] = doc.get("camera", key, kind, required=key in ("focal_px", "baseline_m"))
    pitch = values["pitch_deg"]
    if pitch is not None and not 0 <= pitch < 90:
        raise doc.error("camera", "pitch_deg", f"must be in [0, 90) degrees, got {pitch!r}")
    reference = doc.get("camera", "reference", "str", required=False) or "right"
    if reference not in ("right", "left"):
        raise doc.error("camera", "reference", f"must be 'right' or 'left', got {reference!r}")
    try:
        return Camera(reference=reference, **values)
    except (TypeError, ValueError) as exc:  # defensive: Camera's own checks
        raise doc.error("camera", None, str(exc)) from None


def _shape(doc: _TomlDoc) -> tuple[int, int] | None:
    shape = doc.data["frames"].get("shape")
    if shape is None:
        return None
    ok = (
        isinstance(shape, list)
        and len(shape) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in shape)
    )
    if not ok:
        raise doc.error("frames", "shape", f"expected [H, W], two positive integers, got {shape!r}")
    return (shape[0], shape[1])


def _load_synth(doc: _TomlDoc) -> Catalog:
    for other in ("camera", "frames", "truth"):
        if other in doc.data:
            raise doc.error(
                other,
                None,
                "a catalog with a [synth] table takes its camera, frames and "
                f"truth from the rendered archive; remove [{other}] or remove [synth]",
            )
    name, description, params = _archive_and_params(doc)
    archetype = doc.get("synth", "archetype", "str", required=True)
    n_frames = doc.get("synth", "frames", "int", required=True)
    seed = doc.get("synth", "seed", "int", required=True)
    variant = doc.get("synth", "variant", "str", required=False)
    if n_frames < 1:
        raise doc.error("synth", "frames", f"must be >= 1, got {n_frames!r}")
    try:
        from .synth import ensure_archive  # lazy: rendering pulls in numba
    except ImportError as exc:
        raise doc.error("synth", None, f"the renderer is not available ({exc})") from None
    try:
        generated = ensure_archive(archetype, frames=n_frames, seed=seed, variant=variant)
    except CatalogError:
        raise
    except (ValueError, TypeError, KeyError) as exc:
        raise doc.error("synth", None, f"cannot render the archive: {exc}") from None
    except OSError as exc:
        raise doc.error(
            "synth", None, f"cannot write the rendered archive: {exc}; check $ARROYO_CACHE"
        ) from None
    inner = _TomlDoc.read(_coerce_path(generated))
    if "synth" in inner.data:
        raise inner.error("synth", None, "a rendered archive's catalog must not be [synth]")
    rendered = _load_plain(inner, source=doc.path)
    merged = {stage: dict(values) for stage, values in rendered.params.items()}
    for stage, values in params.items():
        merged.setdefault(stage, {}).update(values)
    return replace(
        rendered,
        name=name,
        description=description or rendered.description,
        params=merged,
    )


def _frames(index_path: Path, camera: Camera) -> tuple[FrameRecord, ...]:
    records = []
    for row in read_index(index_path):
        try:
            frame_camera = camera.with_overrides(row.overrides)
        except (TypeError, ValueError) as exc:  # defensive: the index checks each override
            raise CatalogError(
                f"{index_path}: line {row.line}: per-frame camera override: {exc}"
            ) from None
        records.append(
            FrameRecord(
                row.frame_id, row.left, row.right, frame_camera, row.metadata, row.overrides
            )
        )
    return tuple(records)
