"""Numba kernel of the segmentation's growth rules: objects grown step by step into a mask.

Private helper of :mod:`stages._rock_parts` (rules R7 and R7c). One step of growth is a
grey dilation of the object ids with a 3x3 square (the higher id wins where two objects
reach a pixel at once) restricted to the pixels an object may take; repeated with
``cv2.dilate`` over the whole frame, twelve steps cost 2-3 ms a frame on each side of the
ground's gray level. The kernel visits only the pixels next to the last step's growth and
gives the same ids (``tests/stages/test_fronts.py`` compares it with the dilation loop).

:func:`merge_fronts` is R7's whole-frame step after the growth (the growth written back,
the objects that grew and their boxes): one compiled pass instead of five numpy passes
and a pass for the boxes (0.8 ms -> 0.4 ms a call; ``test_fronts.py`` compares).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._regions import _extend_box

__all__ = ["grow_fronts", "merge_fronts"]


@njit(cache=True)
def _window_max(front, y, x):  # pragma: no cover - numba
    """Largest value of ``front`` in the 3x3 window around ``(y, x)``, inside the frame."""
    rows, cols = front.shape
    best = front[y, x]
    for v in range(max(y - 1, 0), min(y + 2, rows)):
        for u in range(max(x - 1, 0), min(x + 2, cols)):
            if front[v, u] > best:
                best = front[v, u]
    return best


@njit(cache=True)
def _grow(front, reach, first, weak, max_steps):  # pragma: no cover - numba
    rows, cols = front.shape
    size = rows * cols
    queued_y = np.empty(size, np.int64)
    queued_x = np.empty(size, np.int64)
    values = np.empty(size, front.dtype)
    # the first step: every weak pixel next to an object (``first``, in raster order;
    # ``reach``: the 3x3 maximum of ``front``), found by vectorised numpy passes
    n = first.size
    for k in range(n):
        y, x = divmod(first[k], cols)
        queued_y[k], queued_x[k], values[k] = y, x, reach[y, x]
    taken = 0
    m = 0
    previous_y = np.empty(size, np.int64)
    previous_x = np.empty(size, np.int64)
    for step in range(max_steps):
        if n == 0:
            break
        if step > 0:
            # only weak pixels next to the last step's growth can be reached now: one next
            # to older growth was reached then (values read before this step's writes)
            n = 0
            for k in range(m):
                y0, x0 = previous_y[k], previous_x[k]
                for y in range(max(y0 - 1, 0), min(y0 + 2, rows)):
                    for x in range(max(x0 - 1, 0), min(x0 + 2, cols)):
                        if weak[y, x]:
                            weak[y, x] = False
                            queued_y[n], queued_x[n] = y, x
                            values[n] = _window_max(front, y, x)
                            n += 1
        for k in range(n):
            y, x = queued_y[k], queued_x[k]
            weak[y, x] = False
            front[y, x] = values[k]
            previous_y[k], previous_x[k] = y, x
        m = n
        taken += n
    return taken


def grow_fronts(front: np.ndarray, weak: np.ndarray, *, max_steps: int) -> int:
    """Grow the ids of ``front`` into ``weak`` by up to ``max_steps`` 8-connected steps.

    Equal to repeating ``reach = cv2.dilate(front, np.ones((3, 3)))``,
    ``new = weak & (reach > 0)``, ``front[new] = reach[new]``, ``weak &= ~new`` until no
    pixel is new or ``max_steps`` steps are done.

    Parameters
    ----------
    front : (M, N) ndarray of uint16, int32 or float32
        Object ids, 0 elsewhere (``>= 0``); changed in place.
    weak : (M, N) ndarray of bool
        Pixels an object may take, where ``front`` is 0; changed in place (taken pixels
        become False).
    max_steps : int
        ``>= 0``.

    Returns
    -------
    taken : int
        Pixels taken.
    """
    if front.shape != weak.shape or front.ndim != 2:
        raise ValueError(
            f"front {front.shape} and weak {weak.shape} must be 2-D arrays of one shape"
        )
    if weak.dtype != bool:
        raise TypeError(f"weak must be a bool array, got {weak.dtype}; use weak != 0")
    if max_steps < 0:
        raise ValueError(f"max_steps must be >= 0, got {max_steps}")
    if not (front.flags.c_contiguous and weak.flags.c_contiguous):
        raise ValueError("front and weak must be C-contiguous (they are changed in place)")
    if max_steps == 0:
        return 0
    reach = cv2.dilate(front, np.ones((3, 3), np.uint8))
    first = np.flatnonzero(weak & (reach > 0)).astype(np.int64, copy=False)
    return int(_grow(front, reach, first, weak, int(max_steps)))


def merge_fronts(
    labels: np.ndarray, dark_front: np.ndarray, light_front: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R7's grown fronts written over the background of ``labels``, in one pass.

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    dark_front, light_front : (M, N) ndarray of uint16 or float32
        The two sides' grown fronts (:func:`grow_fronts`); they take no background pixel
        in common.

    Returns
    -------
    out : (M, N) ndarray of ``labels.dtype``
        ``labels`` with the fronts' ids on its background pixels.
    grew : (K,) ndarray of int64
        The objects that took a background pixel, ascending.
    boxes : (n + 1, 4) ndarray of int64
        The inclusive (y0, y1, x0, x1) box of each object of ``out``, as
        :func:`stages._regions._object_boxes` gives them (ids above n left out).
    """
    if not labels.shape == dark_front.shape == light_front.shape or labels.ndim != 2:
        raise ValueError(
            f"labels {labels.shape} and fronts {dark_front.shape}, {light_front.shape} "
            "must be 2-D of one shape"
        )
    count = int(labels.max()) if labels.size else 0
    out = np.empty(labels.shape, labels.dtype)
    grew = np.zeros(count + 1, np.bool_)
    boxes = np.empty((count + 1, 4), np.int64)
    boxes[:, 0::2] = np.iinfo(np.int64).max
    boxes[:, 1::2] = -1
    _merge_pass(
        np.ascontiguousarray(labels),
        np.ascontiguousarray(dark_front),
        np.ascontiguousarray(light_front),
        out,
        grew,
        boxes,
    )
    return out, np.flatnonzero(grew), boxes


@njit(cache=True)
def _merge_pass(labels, dark_front, light_front, out, grew, boxes):  # pragma: no cover
    rows, cols = labels.shape
    count = grew.size - 1
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                # the light front last, as np.copyto of the dark then of the light one
                k = int(light_front[y, x]) if light_front[y, x] > 0 else int(dark_front[y, x])
                if 0 < k <= count:
                    grew[k] = True
            out[y, x] = k
            if 0 < k <= count:
                _extend_box(boxes, k, y, x)
