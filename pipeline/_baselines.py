"""Reference methods ``arroyo evaluate`` scores side by side with arroyo's own products.

Both are deliberately the textbook versions a reader would reach for first: OpenCV's
StereoSGBM with its usual settings, and a global Otsu threshold with connected components.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["sgbm_disparity", "otsu_labels"]


def _coerce_gray(name: str, image: object) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name} must be a numpy ndarray, got {type(image).__name__}")
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(
            f"{name} must be a 2-D uint8 gray image, got {image.dtype} {image.shape}; "
            "pass the products.zarr 'left'/'right' arrays"
        )
    return np.ascontiguousarray(image)


def sgbm_disparity(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int = 0,
    max_disparity: int = 64,
    reference: str = "right",
    block_size: int = 5,
) -> np.ndarray:
    """OpenCV StereoSGBM disparity in the geometry of the reference image.

    The depth stage's own ``opencv-sgbm`` option (:func:`stages._stereo_filters.sgbm_disparity`,
    right image as reference, OpenCV's usual settings), so the baseline is exactly what a
    user gets with ``--set depth.method=opencv-sgbm``. For ``reference='left'`` both images
    are mirrored and swapped, as the depth stage does.

    Parameters
    ----------
    left, right : (M, N) ndarray of uint8
        Rectified gray stereo pair.
    min_disparity, max_disparity : int
        Inclusive disparity search range in pixels, ``max_disparity >= min_disparity + 2``;
        OpenCV searches a multiple of 16 disparities from ``min_disparity``.
    reference : {'right', 'left'}
        Geometry of the returned map.
    block_size : int
        Odd matching block size >= 3.

    Returns
    -------
    disparity : (M, N) ndarray of float32
        Disparity in pixels (1/16 px steps), NaN where SGBM found no valid match.
    """
    from stages._stereo_filters import sgbm_disparity as _stage_sgbm

    lft, rgt = _coerce_gray("left", left), _coerce_gray("right", right)
    if lft.shape != rgt.shape:
        raise ValueError(f"left and right must have the same shape, got {lft.shape}, {rgt.shape}")
    if reference not in ("right", "left"):
        raise ValueError(f"reference must be 'right' or 'left', got {reference!r}")
    if isinstance(block_size, bool) or not isinstance(block_size, int):
        raise TypeError(f"block_size must be an int, got {type(block_size).__name__}")
    if block_size < 3 or block_size % 2 == 0:
        raise ValueError(f"block_size must be odd and >= 3, got {block_size!r}")
    settings = {
        "min_disparity": int(min_disparity),
        "max_disparity": int(max_disparity),
        "block_size": block_size,
    }
    if reference == "right":
        return _stage_sgbm(lft, rgt, **settings)
    mirrored = _stage_sgbm(
        np.ascontiguousarray(rgt[:, ::-1]), np.ascontiguousarray(lft[:, ::-1]), **settings
    )
    return np.ascontiguousarray(mirrored[:, ::-1])


def otsu_labels(image: np.ndarray, *, min_area_px: int = 30) -> np.ndarray:
    """Objects by one global Otsu threshold and 8-connected components.

    The minority side of the threshold is taken as the objects (rocks cover less of the frame
    than the ground), so dark rocks on light ground and light rocks on dark ground both work,
    but not both in one frame: that is the weakness the study's sector method addresses.

    Parameters
    ----------
    image : (M, N) ndarray of uint8
        Reference gray image.
    min_area_px : int
        Components smaller than this are dropped (specks), >= 1.

    Returns
    -------
    labels : (M, N) ndarray of int32
        0 = background, 1..n = objects.
    """
    img = _coerce_gray("image", image)
    if isinstance(min_area_px, bool) or not isinstance(min_area_px, int) or min_area_px < 1:
        raise ValueError(f"min_area_px must be an int >= 1, got {min_area_px!r}")
    _, above = cv2.threshold(img, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    objects = above.astype(bool)
    if np.count_nonzero(objects) * 2 > objects.size:
        objects = ~objects
    n, components, stats, _ = cv2.connectedComponentsWithStats(
        objects.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S
    )
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    keep[0] = False
    new_ids = np.zeros(n, dtype=np.int32)
    new_ids[keep] = np.arange(1, np.count_nonzero(keep) + 1, dtype=np.int32)
    return new_ids[components]
