from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages._fill import border_fill, histograms_without_fill
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
    with pytest.raises(TypeError, match="2-D uint8"):
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
