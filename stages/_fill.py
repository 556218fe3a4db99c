"""Black fill along a frame's border: where a rectified pair has no camera pixel.

Rectifying a stereo pair warps each image, and the corners or strips no camera pixel maps
to come out as exactly 0. The study's frames had none, nor have the built-in archives (none
of their 480 images holds a zero region touching the border), but a scientist's rectified
frames often do: a frame with 8 % of it in such wedges had its fill segmented as one
21,000 px dark "obstacle". Ingest notes the fill (:func:`stages.ingest.run_ingest`), and the
segment stage leaves it out of its sector histograms and of every object
(:func:`stages.segment.segment_image`).

The depth stage matches the two images with their fill smoothly extended from the imaged
pixels around it (:func:`extend_into_fill`) and gives no disparity on the fill or where a
match lands in the other image's fill (:func:`disparity_without_fill`). Matched as it
comes, the fill's edge (at another place in each image) drew every window across it, and
the fill itself got disparities. ``benchmarks/bench_fill.py runs/eval/mojave`` (6 frames,
a corner wedge 90 / 100 px deep and a 30 px strip): bad-2 within 0-3 / 3-6 / 6-10 / 10-20
px of the edge 0.38 / 0.38 / 0.32 / 0.22 as matched before, 0.17 / 0.07 / 0.04 / 0.01 now;
24,570 fill pixels had a disparity, none now; segmentation F1 with the wedges 0.921, the
same frames without them 0.923.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "FILL_MIN_SHARE",
    "border_fill",
    "disparity_without_fill",
    "extend_into_fill",
    "histograms_without_fill",
]

FILL_MIN_SHARE = 0.01
"""Share of the frame the black regions touching its border must cover to count as fill:
a dark rock cut by the border holds a few pixels of exactly 0 at most."""


def border_fill(image: np.ndarray, *, min_share: float = FILL_MIN_SHARE) -> np.ndarray | None:
    """The black (exactly 0) regions touching the image border, when they are fill.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Gray image.
    min_share : float
        In ``[0, 1]``: the regions (4-connected) must cover more than this share of the
        frame together.

    Returns
    -------
    (M, N) ndarray of bool or None
        True on the fill; None when there is none (or less than ``min_share``), and for a
        constant image (all 0: a dead camera is ingest's own note, not fill).
    """
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise TypeError(
            "image must be a 2-D uint8 numpy array, got "
            f"{getattr(image, 'dtype', type(image).__name__)} of shape {np.shape(image)}; "
            "convert a gray image with stages._imageio.to_gray_uint8, as ingest does"
        )
    if not 0 <= min_share <= 1:
        raise ValueError(f"min_share must be in [0, 1], got {min_share}")
    black = image == 0
    n_black = np.count_nonzero(black)
    if n_black <= min_share * image.size or n_black == image.size:
        return None  # the common case costs one comparison and one count
    _, labels = cv2.connectedComponents(black.view(np.uint8), connectivity=4)
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    edge = edge[edge > 0]
    if edge.size == 0:
        return None
    fill = np.isin(labels, edge)
    return fill if np.count_nonzero(fill) > min_share * image.size else None


def histograms_without_fill(
    histograms: np.ndarray, fill: np.ndarray, *, row_edges: np.ndarray, col_edges: np.ndarray
) -> np.ndarray:
    """Sector histograms with the fill's pixels (all of gray level 0) taken out.

    Parameters
    ----------
    histograms : (S, T, 256) ndarray of int
        :func:`stages._sectors.sector_histograms` of the image ``fill`` belongs to.
    fill : (M, N) ndarray of bool
        :func:`border_fill` of that image.
    row_edges, col_edges : (S + 1,), (T + 1,) ndarray of int
        The sectors' edges (:func:`stages._sectors.sector_edges`).

    Returns
    -------
    (S, T, 256) ndarray of int64
        A copy; a sector all fill has an empty histogram (the continuity pass then gives it
        a phantom peak at the level its neighbours predict).
    """
    counts = np.add.reduceat(
        np.add.reduceat(fill.astype(np.int64), row_edges[:-1], axis=0), col_edges[:-1], axis=1
    )
    out = np.array(histograms, dtype=np.int64, copy=True)
    if np.any(counts > out[..., 0]):
        raise ValueError(
            "fill holds more pixels of a sector than the histogram has at gray level 0: the "
            "histograms are not of the image the fill was found in; pass both of one image"
        )
    out[..., 0] -= counts
    return out


_EXTEND_SIGMA_PX = 15.0
"""Gaussian reach of :func:`extend_into_fill`: about the half-width of the matcher's larger
windows, so a window across the edge sees a smooth continuation, not a step."""


def extend_into_fill(image: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """The image with its fill replaced by a smooth continuation of the pixels around it.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Gray image.
    fill : (M, N) ndarray of bool
        :func:`border_fill` of the image.

    Returns
    -------
    (M, N) ndarray of uint8
        A copy: outside the fill the same pixels, on it a Gaussian-weighted mean
        (normalised convolution) of the imaged pixels near each fill pixel, without texture,
        so the matcher's windows across the edge are driven by the imaged side.
    """
    valid = (~fill).astype(np.float32)
    sums = cv2.GaussianBlur(image.astype(np.float32) * valid, (0, 0), _EXTEND_SIGMA_PX)
    weights = cv2.GaussianBlur(valid, (0, 0), _EXTEND_SIGMA_PX)
    mean = float(image[~fill].mean())  # far inside a wide fill the weights underflow
    smooth = np.where(weights[fill] > 1e-6, sums[fill] / np.maximum(weights[fill], 1e-6), mean)
    out = image.copy()
    out[fill] = np.clip(np.rint(smooth), 0, 255).astype(np.uint8)
    return out


def disparity_without_fill(
    disparity: np.ndarray, fill_reference: np.ndarray | None, fill_other: np.ndarray | None
) -> np.ndarray:
    """Disparity with NaN on the reference's fill and where a match lands in the other's.

    Parameters
    ----------
    disparity : (M, N) ndarray of float32
        Reference pixel ``x`` matches the other image's ``x + d`` (the matcher's convention;
        a left-reference frame is matched mirrored), NaN where invalid.
    fill_reference, fill_other : (M, N) ndarray of bool or None
        :func:`border_fill` of the two images as matched; None for no fill.

    Returns
    -------
    (M, N) ndarray of float32
        A copy.
    """
    out = np.array(disparity, dtype=np.float32, copy=True)
    if fill_reference is not None:
        out[fill_reference] = np.nan
    if fill_other is not None:
        rows, cols = np.nonzero(np.isfinite(out))
        target = np.rint(cols + out[rows, cols]).astype(np.int64)
        inside = (target >= 0) & (target < out.shape[1])
        lands = np.zeros(rows.shape, bool)
        lands[inside] = fill_other[rows[inside], target[inside]]
        out[rows[lands], cols[lands]] = np.nan
    return out
