"""``--set STAGE.PARAM=VALUE`` of the benchmark scripts (benchmarks/_overrides.py).

The depth stage's parameters used to be unreachable from ``bench_segment.py --depth stage``
and ``bench_describe.py --inputs depth|pipeline``: they ran it with its defaults only.
"""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark

from pipeline.camera import Camera
from pipeline.errors import ParamError
from pipeline.synth import render_pair
from stages import depth as depth_stage

overrides = load_benchmark("_overrides.py")


def test_values_are_parsed_to_the_params_types():
    parsed = overrides.stage_overrides(
        ["depth.subpixel=parabola", "depth.min_texture=4", "describe.gap_px=3"],
        runs=("depth", "describe"),
        mode="--inputs depth",
    )
    assert parsed == {
        "depth": {"subpixel": "parabola", "min_texture": 4.0},
        "describe": {"gap_px": 3},
    }


def test_an_unknown_depth_param_names_the_valid_ones():
    with pytest.raises(ParamError, match="no parameter 'subpix'") as caught:
        overrides.stage_overrides(["depth.subpix=parabola"], runs=("depth",), mode="--x")
    for param in depth_stage.STAGE.params:
        assert param.name in str(caught.value)


def test_a_value_the_param_refuses_is_an_error():
    with pytest.raises(ParamError, match="blend"):
        overrides.stage_overrides(["depth.subpixel=cubic"], runs=("depth",), mode="--x")


def test_a_stage_the_mode_does_not_run_is_refused():
    with pytest.raises(ParamError, match=r"depth\.PARAM=VALUE does not apply to --inputs truth"):
        overrides.stage_overrides(
            ["depth.subpixel=parabola"], runs=("describe",), mode="--inputs truth"
        )


def test_depth_params_reach_the_depth_stage():
    left, right, truth, _, camera = render_pair("lava", seed=0, size=96)
    camera = Camera(**camera)
    default = overrides.depth_products(left, right, camera=camera)["disparity"]
    parabola = overrides.depth_products(
        left, right, camera=camera, params={"subpixel": "parabola"}
    )["disparity"]
    both = np.isfinite(default) & np.isfinite(parabola)
    assert both.mean() > 0.5
    # the two subpixel estimators agree to a fraction of a pixel but not exactly
    assert 0 < np.abs(default - parabola)[both].max() < 1
    with pytest.raises(ParamError, match="window sizes must be odd"):
        overrides.depth_products(left, right, camera=camera, params={"windows": "4x4"})
