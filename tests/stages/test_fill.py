from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages._fill import (
    border_fill,
    disparity_without_fill,
    extend_into_fill,
    histograms_without_fill,
)
from stages._sectors import sector_edges, sector_histograms


def _ground(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(120, 10, shape), 1, 255).astype(np.uint8)


def test_a_wedge_along_the_border_is_fill_and_black_inside_is_not() -> None:
    image = _ground((60, 80))
    ys, xs = np.indices(image.shape)
    wedge = xs + ys < 20
    image[wedge] = 0
    image[30:40, 30:40] = 0  # a black rock inside the frame
    fill = border_fill(image)
    assert fill is not None
    assert np.array_equal(fill, wedge)


def test_no_fill_below_the_share_and_none_on_a_constant_frame() -> None:
    image = _ground((60, 80))
    assert border_fill(image) is None
    image[0, :10] = 0  # 10 px of a dark rock cut by the border: 0.2 % of the frame
    assert border_fill(image) is None
    assert border_fill(image, min_share=0.001) is not None
    assert border_fill(np.zeros((20, 20), np.uint8)) is None


def test_bad_inputs_say_what_was_expected() -> None:
    # and how to fix it: a gray uint8 image as ingest makes it
    with pytest.raises(TypeError, match=r"2-D uint8.*float32.*to_gray_uint8"):
        border_fill(np.zeros((20, 20), np.float32))
    with pytest.raises(ValueError, match=r"min_share must be in \[0, 1\]"):
        border_fill(np.zeros((20, 20), np.uint8), min_share=2.0)
    image = _ground((40, 40))
    image[:, :8] = 0
    fill = border_fill(image)
    assert fill is not None
    other = sector_histograms(_ground((40, 40), seed=1), sectors=4)
    edges = sector_edges(40, 4)
    with pytest.raises(ValueError, match="not of the image the fill was found in"):
        histograms_without_fill(other, fill, row_edges=edges, col_edges=edges)


@settings(max_examples=30, deadline=None)
@given(
    rows=st.integers(16, 48),
    cols=st.integers(16, 48),
    sectors=st.integers(2, 4),
    reach=st.integers(0, 30),
    seed=st.integers(0, 10_000),
)
def test_histograms_without_fill_count_only_the_imaged_pixels(rows, cols, sectors, reach, seed):
    image = _ground((rows, cols), seed)
    ys, xs = np.indices(image.shape)
    image[(cols - 1 - xs) + ys < reach] = 0  # a top-right wedge
    fill = border_fill(image, min_share=0.0)
    fill = np.zeros(image.shape, bool) if fill is None else fill
    row_edges, col_edges = sector_edges(rows, sectors), sector_edges(cols, sectors)
    got = histograms_without_fill(
        sector_histograms(image, sectors=sectors), fill, row_edges=row_edges, col_edges=col_edges
    )
    for i in range(sectors):
        for j in range(sectors):
            block = np.s_[row_edges[i] : row_edges[i + 1], col_edges[j] : col_edges[j + 1]]
            want = np.bincount(image[block][~fill[block]], minlength=256)
            assert np.array_equal(got[i, j], want)


def test_extend_into_fill_keeps_the_imaged_pixels_and_continues_them_smoothly() -> None:
    image = _ground((80, 120))
    image[:, 60:] = np.clip(image[:, 60:].astype(int) + 60, 0, 255).astype(np.uint8)
    ys, xs = np.indices(image.shape)
    fill = ys + xs < 30
    wedged = image.copy()
    wedged[fill] = 0
    out = extend_into_fill(wedged, fill)
    assert np.array_equal(out[~fill], image[~fill])
    assert abs(float(out[fill].mean()) - float(image[:30, :30].mean())) < 8
    assert out[fill].std() < image[:30, :30].std() / 2  # no texture, no step
    whole = np.zeros((40, 40), bool)
    whole[:, :36] = True  # a fill far wider than the smoothing reaches
    narrow = _ground((40, 40))
    narrow[whole] = 0
    assert np.all(extend_into_fill(narrow, whole)[whole] > 0)


def test_disparity_without_fill_drops_the_fill_and_matches_landing_in_the_other() -> None:
    disparity = np.full((4, 10), 3.0, np.float32)
    disparity[0, 0] = np.nan
    fill_reference = np.zeros((4, 10), bool)
    fill_reference[:, 0] = True
    fill_other = np.zeros((4, 10), bool)
    fill_other[:, 7:] = True  # columns 4-6 land on it; 7-9 land beyond the image
    out = disparity_without_fill(disparity, fill_reference, fill_other)
    assert np.isnan(out[:, 0]).all() and np.isnan(out[:, 4:7]).all()
    assert np.all(out[:, 1:4] == 3.0) and np.all(out[:, 7:] == 3.0)
    assert np.array_equal(disparity_without_fill(disparity, None, None), disparity, equal_nan=True)
    assert disparity_without_fill(disparity, None, None) is not disparity
