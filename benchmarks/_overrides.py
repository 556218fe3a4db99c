"""Stage parameter overrides (``--set STAGE.PARAM=VALUE``) of the benchmarks that run stages.

``bench_segment.py --depth stage`` and ``bench_describe.py --inputs depth|pipeline`` run the
engine's stages on rendered pairs themselves. Their ``--set`` items name the stage and the
parameter as ``arroyo run --set`` does and are checked the same way
(:func:`pipeline.graph.parse_set_overrides`): an unknown stage or parameter is an error that
lists the valid ones, and each value is parsed and checked by the stage's ``Param``. An
override of a stage that the chosen mode does not run would change nothing, so it is an
error too. Rules that tie several depth parameters together (e.g. the ``windows`` string,
:func:`stages._stereo.check_settings`) are checked by the stage itself when it runs, as in
``arroyo run``, and raise the same ``ParamError``.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from typing import Any

import numpy as np

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.graph import default_graph, parse_set_overrides
from pipeline.stage import FrameContext
from stages.depth import STAGE as DEPTH

__all__ = ["depth_products", "keyword_overrides", "matching_settings", "stage_overrides"]


def stage_overrides(
    items: Iterable[str], *, runs: Collection[str], mode: str, other: str = ""
) -> dict[str, dict[str, Any]]:
    """Validated parameter overrides per stage from ``--set STAGE.PARAM=VALUE`` items.

    Parameters
    ----------
    items : iterable of str
        ``STAGE.PARAM=VALUE`` each, e.g. ``'depth.subpixel=parabola'``.
    runs : collection of str
        The stages the benchmark runs in this mode, whose parameters may be set.
    mode : str
        The mode as the command line chose it (e.g. ``'--inputs truth'``), for the message.
    other : str, optional
        What else the script's ``--set`` takes, for the message.

    Returns
    -------
    dict of str to dict
        Stage name to ``{param: value}``, values of the parameter's type; stages without
        overrides are absent.

    Raises
    ------
    ParamError
        When an item is not ``STAGE.PARAM=VALUE``, names an unknown stage or parameter (the
        message lists the valid ones), holds a value the parameter refuses, or sets a stage
        that ``mode`` does not run.
    """
    overrides = parse_set_overrides(default_graph(), items)
    idle = sorted(set(overrides) - set(runs))
    if idle:
        allowed = [f"{name}.PARAM=VALUE" for name in runs] + ([other] if other else [])
        raise ParamError(
            f"--set {idle[0]}.PARAM=VALUE does not apply to {mode}, which takes "
            f"{' and '.join(allowed) or 'no --set'}; drop it or choose another mode"
        )
    return overrides


def depth_products(
    left: np.ndarray,
    right: np.ndarray,
    *,
    camera: Camera,
    params: Mapping[str, Any] | None = None,
    frame_id: str = "bench",
    archive: str = "bench",
) -> dict[str, np.ndarray]:
    """The depth stage's products of one pair, as ``arroyo run`` computes them.

    Parameters
    ----------
    left, right : (M, N) ndarray of uint8
        Rectified gray pair.
    camera : Camera
    params : mapping, optional
        Depth parameters over the stage's defaults (validated by its ``Param``s).
    frame_id, archive : str
        What the stage is told about the frame (its log messages name them).

    Returns
    -------
    dict of str to ndarray
        ``disparity``, ``range``, ``residual``, ``height``: (M, N) float32;
        ``ground_plane``: (4,) float64.

    Raises
    ------
    ParamError
        When a parameter or a combination of them is refused.
    """
    frame = FrameContext(frame_id=frame_id, archive=archive, camera=camera)
    result = DEPTH.run(
        {"left": left, "right": right}, frame=frame, params=DEPTH.resolve_params(params or {})
    )
    return result.arrays


def matching_settings(items: Iterable[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``match_disparity`` keywords and the depth stage's params from ``PARAM=VALUE`` items.

    For the depth benchmarks that call the matcher directly (``bench_depth_speed.py``,
    ``bench_depth_accuracy.py``): the items name depth stage parameters without the
    ``depth.`` prefix and are parsed and checked by the engine's own ``--set`` parsing.

    Returns
    -------
    settings : dict
        Keywords of :func:`stages._stereo.match_disparity` (the overrides less the search
        band's stage parameters).
    stage_params : dict
        The depth stage's defaults with the overrides, for
        :func:`stages.depth.resolve_row_band`.
    """
    settings = parse_set_overrides(default_graph(), [f"depth.{i}" for i in items]).get("depth", {})
    stage_params = {**DEPTH.defaults(), **settings}
    for name in ("floor_margin", "ceiling_ratio"):  # the search band's, not the matcher's
        settings.pop(name, None)
    return settings, stage_params


def keyword_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``segment_image`` keywords from ``KEY=VALUE`` items (``bench_segment.py --rundir``).

    A value is an int if it parses as one, else a float, else ``true``/``false`` (any case)
    as a bool, else the text; the function that takes the keywords checks them.
    """
    overrides: dict[str, Any] = {}
    for item in items:
        key, _, text = item.partition("=")
        for cast in (int, float):
            try:
                overrides[key] = cast(text)
                break
            except ValueError:
                continue
        else:
            overrides[key] = {"true": True, "false": False}.get(text.lower(), text)
    return overrides
