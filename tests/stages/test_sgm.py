"""Semi-global aggregation kernels (stages._sgm) against a plain numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from stages import _sgm


def _numpy_aggregate(cost, p1, p2, n_paths):
    """Path costs cell by cell in the kernel's scan order, the disparities as numpy float32
    vectors: ``L = cost + min(L', L'[j -+ 1] + p1, min(L') + p2) - min(L')``."""
    h, w, n_disp = cost.shape
    p1, p2 = np.float32(p1), np.float32(p2)
    total = np.zeros(cost.shape, np.float32)
    for dy, dx in _sgm._DIRECTIONS_8[:n_paths]:
        path = np.zeros(cost.shape, np.float32)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    path[y, x] = cost[y, x]
                    continue
                pred = path[py, px]
                low = pred.min()
                m = pred.copy()
                m[1:] = np.minimum(m[1:], pred[:-1] + p1)
                m[:-1] = np.minimum(m[:-1], pred[1:] + p1)
                m = np.minimum(m, low + p2)
                path[y, x] = cost[y, x] + m - low
        total += path
    return total


@pytest.mark.parametrize(("n_paths", "n_disp"), [(4, 6), (8, 5), (8, 2)])
def test_aggregate_equals_numpy_reference(n_paths, n_disp):
    rng = np.random.default_rng(n_disp)
    cost = rng.uniform(0.0, 1.0, (7, 9, n_disp)).astype(np.float32)
    cost[2, 3] = 0.5  # a flat cell: ties everywhere
    expected = _numpy_aggregate(cost, 0.2, 3.0, n_paths)
    got = _sgm.aggregate(cost, 0.2, 3.0, n_paths)
    assert got.dtype == np.float32 and got.tobytes() == expected.tobytes()


def test_path_step_takes_the_cheapest_predecessor():
    pred = np.array([0.0, 1.0, 5.0, 5.0, 0.5], np.float32)
    cost = np.zeros(5, np.float32)
    out = np.empty(5, np.float32)
    _sgm._path_step(out, cost, pred, np.float32(0.0), np.float32(0.25), np.float32(2.0))
    # same disparity, a 1 px step (+p1) or any jump (+p2), less the predecessor's minimum
    np.testing.assert_array_equal(out, [0.0, 0.25, 1.25, 0.75, 0.5])


def _python_select(total, d_min, hw, lr_tolerance):
    """Winner-take-all, left-right check and parabola, pixel by pixel in plain Python: each
    pixel's costs scanned in increasing index with '<' (the first least cost wins)."""
    h, w, n_disp = total.shape
    disparity = np.full((h, w), np.nan, np.float32)
    for y in range(hw, h - hw):
        for x in range(hw, w - hw):
            j0, j1 = max(0, hw - x - d_min), min(n_disp, w - hw - x - d_min)
            if j1 - j0 < 3:
                continue
            best = min(range(j0, j1), key=lambda j: total[y, x, j])  # first of equals
            if best in (j0, j1 - 1):
                continue
            xl = x + d_min + best
            inside = [jj for jj in range(n_disp) if 0 <= xl - d_min - jj < w]
            lr_best = min(inside, key=lambda jj: total[y, xl - d_min - jj, jj])
            if abs(lr_best - best) > lr_tolerance:
                disparity[y, x] = -np.inf
                continue
            c_minus, c_0, c_plus = (float(total[y, x, best + k]) for k in (-1, 0, 1))
            curvature = c_minus - 2.0 * c_0 + c_plus
            offset = 0.0
            if curvature > 0:
                offset = min(0.5, max(-0.5, 0.5 * (c_minus - c_plus) / curvature))
            disparity[y, x] = np.float32(d_min + best + offset)
    return disparity


@pytest.mark.parametrize("d_min", [-3, 0, 2])
def test_select_equals_pixel_by_pixel_python(d_min):
    # coarse costs: many tied minima, in the pixel's own curve and in the left-reference one
    rng = np.random.default_rng(10 + d_min)
    total = (np.round(rng.uniform(0.0, 2.0, (6, 24, 7)) * 4) / 4).astype(np.float32)
    expected = _python_select(total, d_min, 1, 1.0)
    got = _sgm.select(total, d_min, 1, 1.0)
    assert np.isfinite(expected).any() and np.isneginf(expected).any()
    assert got.tobytes() == expected.tobytes()


def test_aggregate_into_a_used_volume_equals_a_fresh_one():
    # the sgm matcher reuses its volumes from frame to frame: old sums must not leak in
    rng = np.random.default_rng(3)
    cost = rng.uniform(0.0, 1.0, (7, 9, 5)).astype(np.float32)
    out = np.full(cost.shape, 7.0, np.float32)
    _sgm.aggregate(cost, 0.2, 3.0, 8, out)
    assert out.tobytes() == _sgm.aggregate(cost, 0.2, 3.0, 8).tobytes()
