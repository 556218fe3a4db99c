"""Declarations: products, typed stage parameters, stages.

A stage module in ``stages/`` declares one module-level ``STAGE = Stage(...)``. The engine
finds every such module, builds the graph from the product names the stages read and
write, and calls ``STAGE.run(inputs, frame=..., params=...)`` once per frame.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from .camera import Camera
from .errors import ParamError

__all__ = [
    "Param",
    "Product",
    "Stage",
    "StageResult",
    "FrameContext",
    "IMAGE_DIMS",
]

IMAGE_DIMS: tuple[str, str, str] = ("frame", "y", "x")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_PARAM_TYPES: tuple[type, ...] = (int, float, str, bool)


def _check_name(what: str, name: object) -> None:
    """Names become paths (products), SQL views (tables) and ``--set STAGE.PARAM`` keys."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(
            f"{what} name must be an identifier (letters, digits, '_'; no '.', '/' or "
            f"spaces), got {name!r}"
        )


@dataclass(frozen=True)
class Param:
    """A typed stage parameter with a default.

    Parameters
    ----------
    name : str
        Identifier, unique within the stage.
    type : {int, float, str, bool}
        Python type of the value; an int is accepted where a float is expected.
    default : object
        Default value; must itself be valid.
    doc : str
        One line for ``arroyo graph``.
    choices : tuple, optional
        Allowed values.
    minimum, maximum : float, optional
        Inclusive bounds for numbers.
    omit_default_from_key : bool
        Leave the parameter out of the cache key while it has its default value. For a
        parameter added to an existing stage whose default reproduces the stage's output
        before the parameter existed: run directories made then keep their results, instead
        of every frame recomputing every stage. A non-default value is in the key as usual.
    """

    name: str
    type: type
    default: Any
    doc: str = ""
    choices: tuple[Any, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    omit_default_from_key: bool = False

    def __post_init__(self) -> None:
        if self.type not in _PARAM_TYPES:
            raise TypeError(f"Param {self.name!r}: type must be one of int, float, str, bool")
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            raise ParamError(
                f"Param {self.name!r}: minimum {self.minimum} is above maximum {self.maximum}; "
                "swap them"
            )
        self.validate(self.default, where="default")

    def validate(self, value: Any, *, where: str = "") -> Any:
        """Return ``value`` in canonical form or raise ParamError saying what was expected."""
        label = f"parameter {self.name!r}" + (f" ({where})" if where else "")
        expected = self.type.__name__
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        wrong_bool = self.type is not bool and isinstance(value, bool)
        if wrong_bool or not isinstance(value, self.type):
            raise ParamError(f"{label} expects {expected}, got {type(value).__name__} {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ParamError(f"{label} expects a finite float, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ParamError(f"{label} must be one of {list(self.choices)}, got {value!r}")
        number = float(value) if isinstance(value, int | float) else None
        if number is not None and self.minimum is not None and number < self.minimum:
            raise ParamError(f"{label} must be >= {self.minimum}, got {value!r}")
        if number is not None and self.maximum is not None and number > self.maximum:
            raise ParamError(f"{label} must be <= {self.maximum}, got {value!r}")
        return value

    def parse(self, text: str) -> Any:
        """Parse a command-line string (``--set stage.name=TEXT``) into a valid value."""
        raw: Any
        try:
            if self.type is bool:
                lowered = text.strip().lower()
                if lowered not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(text)
                raw = lowered in ("true", "1", "yes")
            elif self.type is int:
                raw = int(text)
            elif self.type is float:
                raw = float(text)
            else:
                raw = text
        except ValueError:
            raise ParamError(
                f"parameter {self.name!r} expects {self.type.__name__}, got {text!r}"
            ) from None
        return self.validate(raw)


@dataclass(frozen=True)
class Product:
    """A named product a stage writes.

    Parameters
    ----------
    name : str
        Product name, unique in the graph (``disparity``, ``labels``, ``descriptors``...).
    kind : {'array', 'table', 'files'}
        ``array``: one zarr array in ``products.zarr`` with a leading ``frame`` dimension.
        ``table``: rows appended to ``<name>.parquet`` (the engine adds archive, run_id,
        frame_id columns). ``files``: loose files under the products root (quicklooks), a
        frame's under ``<name>/<frame_id>/``: when the stage completes for a frame, that
        folder keeps only the files it returned.
    dtype : str, optional
        NumPy dtype of an array product (``'uint8'``, ``'float32'``, ``'int32'``...).
    dims : tuple of str
        Dimension names of an array product; ``('frame', 'y', 'x')`` for images.
    shape : callable, optional
        ``shape(frame_shape, params) -> tuple`` of the per-frame shape for arrays whose
        shape is not the image's (for example the sector grid of the segmentation).
    fill_value : scalar
        Value of never-written cells (NaN for floats, 0 otherwise).
    attrs : dict
        ``units``, ``long_name`` and any other attributes recorded in zarr.
    camera_attrs : callable, optional
        ``camera_attrs(camera) -> dict`` of attributes that depend on the run's camera
        (the depth residual's ``long_name`` names the reference camera), applied over
        ``attrs``; see :meth:`resolved_attrs`.
    schema : pyarrow.Schema
        Column types of a table product (without archive/run_id/frame_id); required for
        tables. A stage returns exactly these columns; frames with zero rows still write
        typed columns.
    """

    name: str
    kind: str = "array"
    dtype: str | None = None
    dims: tuple[str, ...] = IMAGE_DIMS
    shape: Callable[[tuple[int, int], Mapping[str, Any]], tuple[int, ...]] | None = None
    fill_value: Any = None
    attrs: Mapping[str, Any] = field(default_factory=dict)
    schema: Any = None
    camera_attrs: Callable[[Camera], Mapping[str, Any]] | None = None

    def __post_init__(self) -> None:
        _check_name("Product", self.name)
        if self.kind not in ("array", "table", "files"):
            raise ValueError(f"Product {self.name!r}: kind must be array, table or files")
        if self.kind == "array" and self.dtype is None:
            raise ValueError(f"Product {self.name!r}: an array product needs a dtype")
        if self.kind == "array":
            try:
                np.dtype(self.dtype)
            except TypeError:
                raise ValueError(
                    f"Product {self.name!r}: dtype {self.dtype!r} is not a NumPy dtype; use "
                    "'uint8', 'int32', 'float32'..."
                ) from None
        if self.kind == "table" and not isinstance(self.schema, pa.Schema):
            # without one the journal kept only archive/run_id/frame_id: every column lost
            raise ValueError(
                f"Product {self.name!r}: a table product needs schema=pyarrow.schema([...]) "
                f"of its columns (without archive/run_id/frame_id), got "
                f"{type(self.schema).__name__}"
            )

    def frame_shape(self, image_shape: tuple[int, int], params: Mapping[str, Any]) -> tuple:
        """Per-frame shape of an array product: one positive int per dim after ``frame``.

        Raises ValueError naming the product when a ``shape`` callable fails or disagrees
        with ``dims`` (found when the run creates the store, before any frame runs).
        """
        if self.shape is None:
            shape = tuple(image_shape)
        else:
            try:
                shape = tuple(self.shape(image_shape, params))
            except Exception as exc:  # a user's callable: name it, whatever it raised
                raise ValueError(
                    f"Product {self.name!r}: shape(image_shape={tuple(image_shape)}, params) "
                    f"raised {type(exc).__name__}: {exc}"
                ) from exc
        ints = all(isinstance(n, int | np.integer) and not isinstance(n, bool) for n in shape)
        if len(shape) != len(self.dims) - 1 or not ints or min(shape, default=1) < 1:
            raise ValueError(
                f"Product {self.name!r}: per-frame shape {shape!r} does not fit dims "
                f"{self.dims} (one positive int per dim after 'frame'); fix Product(shape=...) "
                "or dims"
            )
        return tuple(int(n) for n in shape)

    def resolved_attrs(self, camera: Camera) -> dict[str, Any]:
        """``attrs`` with ``camera_attrs(camera)`` applied over them, for this run's camera."""
        attrs = dict(self.attrs)
        if self.camera_attrs is not None:
            attrs.update(self.camera_attrs(camera))
        return attrs

    def resolved_fill(self) -> Any:
        if self.fill_value is not None:
            return self.fill_value
        return np.nan if np.dtype(self.dtype).kind == "f" else 0


@dataclass(frozen=True)
class FrameContext:
    """What a stage knows about the frame besides its input arrays.

    ``left_path``/``right_path`` are only meaningful to ``ingest``.
    """

    frame_id: str
    archive: str
    camera: Camera
    metadata: Mapping[str, Any] = field(default_factory=dict)
    left_path: Path | None = None
    right_path: Path | None = None
    image_shape: tuple[int, int] | None = None


@dataclass
class StageResult:
    """What a stage returns for one frame.

    Attributes
    ----------
    arrays : dict of str to ndarray
        One entry per array product the stage writes, per-frame shape and declared dtype.
    tables : dict of str to dict of str to sequence
        Columns (equal lengths, exactly the product's schema) of each table product the
        stage declares; the engine adds archive/run_id/frame_id.
    figures : dict of str to number or str
        Per-frame scalars (int, float, bool, str, None; NumPy scalars accepted) for
        ``frames.parquet``, stored as ``<stage>_<name>``; names are identifiers.
    files : dict of str to bytes
        ``<files product>/<frame_id>/<name>`` (under the products root) to file content
        (quicklooks); a path elsewhere fails the frame.
    notes : list of str
        Human remarks recorded with the frame (``"colour converted to gray"``).
    """

    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    tables: dict[str, dict[str, Any]] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    files: dict[str, bytes] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


StageRun = Callable[..., StageResult]


@dataclass(frozen=True)
class Stage:
    """A declared processing stage.

    Parameters
    ----------
    name : str
        Stage name (``depth``), also the prefix of its parameters (``depth.max_disparity``).
    version : str
        Bump when the stage's output for the same inputs and params changes; part of the
        cache key.
    inputs : tuple of str
        Product names read (the frame's arrays are passed to ``run`` under these names).
    outputs : tuple of Product
        Products written.
    params : tuple of Param
        Typed parameters with defaults.
    run : callable
        ``run(inputs: dict[str, ndarray], *, frame: FrameContext, params: dict) -> StageResult``.
    doc : str
        One line for ``arroyo graph``.
    optional_inputs : tuple of str
        Inputs read when present in the graph, tolerated when absent.
    check_params : callable, optional
        ``check_params(params)`` raises ValueError/TypeError when the effective params
        (each valid alone) are invalid in a way a Param's type, choices and bounds cannot
        say (a window list's syntax, an odd size, two params that contradict each other):
        the run then stops before any work instead of failing every frame.
    """

    name: str
    version: str
    inputs: tuple[str, ...]
    outputs: tuple[Product, ...]
    params: tuple[Param, ...]
    run: StageRun
    doc: str = ""
    optional_inputs: tuple[str, ...] = ()
    check_params: Callable[[Mapping[str, Any]], object] | None = None

    def __post_init__(self) -> None:
        _check_name("Stage", self.name)
        for attr, kind in (
            ("inputs", str),
            ("optional_inputs", str),
            ("outputs", Product),
            ("params", Param),
        ):
            value = getattr(self, attr)
            if not isinstance(value, tuple | list) or not all(isinstance(v, kind) for v in value):
                raise TypeError(
                    f"Stage {self.name!r}: {attr} must be a tuple of {kind.__name__}, got "
                    f"{value!r} (a single item needs a trailing comma: (item,))"
                )
        if not isinstance(self.version, str):
            raise TypeError(
                f"Stage {self.name!r}: version must be a str such as '1', got "
                f"{type(self.version).__name__} {self.version!r}"
            )
        if not callable(self.run):
            raise TypeError(f"Stage {self.name!r}: run must be callable, got {self.run!r}")
        for attr, names in (
            ("outputs", [p.name for p in self.outputs]),
            ("params", [p.name for p in self.params]),
        ):
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:
                raise ValueError(
                    f"Stage {self.name!r}: {attr} name {', '.join(map(repr, twice))} more "
                    "than once; each must be unique within the stage"
                )

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.outputs)

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        known = ", ".join(p.name for p in self.params) or "none"
        raise ParamError(
            f"stage {self.name!r} has no parameter {name!r}; its parameters are: {known}"
        )

    def defaults(self) -> dict[str, Any]:
        return {p.name: p.default for p in self.params}

    def key_params(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The effective ``params`` that enter the cache key: all but those declared
        ``omit_default_from_key`` while at their default."""
        omitted = {p.name: p.default for p in self.params if p.omit_default_from_key}
        return {
            name: value
            for name, value in params.items()
            if not (
                name in omitted
                and value == omitted[name]
                and type(value) is type(omitted[name])
            )
        }

    def resolve_params(self, overrides: Mapping[str, Any]) -> dict[str, Any]:
        """Defaults updated with validated overrides."""
        params = self.defaults()
        for key, value in overrides.items():
            params[key] = self.param(key).validate(value, where=f"{self.name}.{key}")
        if self.check_params is not None:
            try:
                self.check_params(params)
            except ParamError:
                raise
            except (ValueError, TypeError) as exc:
                raise ParamError(f"stage {self.name!r}: {exc}") from None
        return params
