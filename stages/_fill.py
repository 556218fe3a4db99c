"""Black fill along a frame's border: where a rectified pair has no camera pixel.

Rectifying a stereo pair warps each image, and the corners or strips no camera pixel maps
to come out as exactly 0. The study's frames had none, nor have the built-in archives (none
of their 480 images holds a zero region touching the border), but a scientist's rectified
frames often do: a frame with 8 % of it in such wedges had its fill segmented as one
21,000 px dark "obstacle". Ingest notes the fill (:func:`stages.ingest.run_ingest`), and the
segment stage leaves it out of its sector histograms and of every object
(:func:`stages.segment.segment_image`).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["FILL_MIN_SHARE", "border_fill", "histograms_without_fill"]

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
            f"{getattr(image, 'dtype', type(image).__name__)} of shape {np.shape(image)}"
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
