"""Ingest: read a frame's left and right images as 8-bit gray.

The decoding rules (formats, colour -> gray, 16-bit and float scaling, what fails a frame)
are those of :mod:`stages._imageio`. Ingest adds the pair checks: left and right must have
the same size, that size must be the archive's (``FrameContext.image_shape``) when the
engine knows it, and they must differ (one file named for both sides fails the frame).
Each conversion becomes a note in the frame's record, and the sha256 of both files becomes
a per-frame figure.

Parameters (catalog ``[params] ingest = {...}`` or ``--set ingest.NAME=VALUE``):

* ``max_pixels``: largest width x height decoded (read from the header, before decoding).
* ``sample_bits``: significant bits of 16-bit samples, 8 to 16 (default 16). A camera that
  writes 12-bit data in 16-bit PNG/TIFF files needs ``sample_bits = 12``: its samples are
  then scaled by ``>> 4`` to the full 0-255 range instead of ``>> 8`` to 0-15 (a dark frame
  in which segmentation finds nothing). Samples above ``2**sample_bits - 1`` are clipped
  to 255 and noted, naming the file; a 16-bit file that declares fewer significant bits
  (PNG ``sBIT``, PGM maximum value) is noted with the value to set. 8-bit and float
  images are not affected. At its default the parameter is left out of the cache key
  (``Param.omit_default_from_key``), so run directories made before it existed keep their
  results.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import FrameError
from pipeline.stage import FrameContext, Param, Product, Stage, StageResult

from ._fill import border_fill
from ._imageio import (
    DEFAULT_MAX_PIXELS,
    DEFAULT_SAMPLE_BITS,
    DecodedImage,
    coerce_sample_bits,
    read_gray,
)

__all__ = ["STAGE", "run_ingest", "check_pair_shapes", "MIN_SIDE_PX"]

MIN_SIDE_PX = 8
"""Smallest frame side: a smaller frame (a 1x1 placeholder) passed ingest and depth and
failed at segment with a sector-count message that named no file."""


def run_ingest(
    inputs: Mapping[str, np.ndarray], *, frame: FrameContext, params: Mapping[str, Any]
) -> StageResult:
    """Read and check one stereo pair.

    Parameters
    ----------
    inputs : dict
        Empty: ingest reads files, not products.
    frame : FrameContext
        Needs ``left_path`` and ``right_path``; ``image_shape`` (H, W) when known.
    params : dict
        ``max_pixels`` : int, largest accepted width x height; ``sample_bits`` : int, 8 to
        16, significant bits of 16-bit samples.

    Returns
    -------
    result : StageResult
        ``arrays``: ``left``, ``right`` as (H, W) uint8; ``figures``: ``left_sha256``,
        ``right_sha256``; ``notes``: the conversions applied, prefixed by the side.

    Raises
    ------
    FrameError
        An unreadable image (see :func:`stages._imageio.read_gray`) or a size mismatch.
    """
    if frame.left_path is None or frame.right_path is None:
        raise FrameError(
            f"frame {frame.frame_id}: ingest needs the left and right image paths, got "
            f"left={frame.left_path!r}, right={frame.right_path!r}"
        )
    max_pixels = params.get("max_pixels", DEFAULT_MAX_PIXELS)
    sample_bits = params.get("sample_bits", DEFAULT_SAMPLE_BITS)
    left = read_gray(frame.left_path, max_pixels=max_pixels, sample_bits=sample_bits)
    right = read_gray(frame.right_path, max_pixels=max_pixels, sample_bits=sample_bits)
    check_pair_shapes(
        left.image.shape,
        right.image.shape,
        frame_id=frame.frame_id,
        left_path=frame.left_path,
        right_path=frame.right_path,
        archive_shape=frame.image_shape,
    )
    same_file = left.sha256 == right.sha256
    if same_file or (_varies(left.image) and np.array_equal(left.image, right.image)):
        # the same file (or a copy) on both sides of the index row ran 'done' with zero
        # disparity everywhere; two constant frames (a lens cap) are noted as such instead
        same = "is the same file as" if same_file else "has the same pixels as"
        raise FrameError(
            f"frame {frame.frame_id}: left image {frame.left_path} {same} right image "
            f"{frame.right_path}; a stereo pair needs the two cameras' images: fix the "
            "frame's row in the index"
        )
    for side in (left, right):
        side.notes.extend(_border_fill_notes(side.image))
    return StageResult(
        arrays={"left": left.image, "right": right.image},
        figures={"left_sha256": left.sha256, "right_sha256": right.sha256},
        notes=_pair_notes(left, right),
    )


def check_pair_shapes(
    left_shape: tuple[int, ...],
    right_shape: tuple[int, ...],
    *,
    frame_id: str,
    left_path: Path | str,
    right_path: Path | str,
    archive_shape: tuple[int, int] | None = None,
) -> None:
    """Raise FrameError unless left and right are equally sized, at least
    ``MIN_SIDE_PX`` on a side and match the archive.

    Parameters
    ----------
    left_shape, right_shape : (H, W) tuple of int
    frame_id : str
    left_path, right_path : Path or str
        Named in the messages.
    archive_shape : (H, W) tuple of int, optional
        Size every frame of the archive must have; not checked when None.
    """
    if tuple(left_shape) != tuple(right_shape):
        raise FrameError(
            f"frame {frame_id}: left image {left_path} is {_hxw(left_shape)} but right image "
            f"{right_path} is {_hxw(right_shape)} (HxW); a stereo pair must have equal sizes: "
            "re-export both from the same rectified pair, or remove the frame from the index"
        )
    if min(left_shape) < MIN_SIDE_PX:
        raise FrameError(
            f"frame {frame_id}: {left_path} and {right_path} are {_hxw(left_shape)} (HxW), "
            f"smaller than the {MIN_SIDE_PX}x{MIN_SIDE_PX} px every frame needs (segmentation "
            "works on at least 2x2 sectors of 4x4 px); remove the frame from the index"
        )
    if archive_shape is not None and tuple(left_shape) != tuple(archive_shape):
        fix = (
            f"a run holds frames of one size: give frames of this size a catalog of their own "
            f"(with its camera: the focal length in pixels scales with the size), or resize "
            f"{left_path} and {right_path}, or remove the frame from the index (set [frames] "
            "shape in the catalog to choose the size)"
        )
        if tuple(left_shape) == tuple(archive_shape)[::-1]:
            # `shape = [640, 480]` for 640x480 frames failed every frame, each told to
            # resize its images
            fix = (
                "the transpose: [frames] shape in the catalog is [H, W], rows first, so for "
                f"this frame's size write shape = [{left_shape[0]}, {left_shape[1]}]; else {fix}"
            )
        raise FrameError(
            f"frame {frame_id} is {_hxw(left_shape)} but the archive's frames are "
            f"{_hxw(archive_shape)} (HxW); {fix}"
        )


def _check_params(params: Mapping[str, Any]) -> None:
    # the range is checked here rather than by Param bounds, so that the message can say
    # what sample_bits means and how to choose it
    coerce_sample_bits(params["sample_bits"])


def _border_fill_notes(image: np.ndarray) -> list[str]:
    """A note when black (exactly 0) regions touching the border cover over 1 % of the frame.

    Rectified stereo pairs carry such wedges where no camera pixel maps; a user's frames
    with 8 % of them had segmentation return the fill as one 21,000 px 'obstacle' per frame,
    nothing said. The segment stage now leaves the fill out (:mod:`stages._fill`).
    """
    fill = border_fill(image)
    if fill is None:
        return []
    share = np.count_nonzero(fill) / image.size
    return [
        f"{share:.1%} of the frame is black (0) fill touching its border, as rectification "
        "leaves: no depth there, and segmentation leaves it out"
    ]


def _varies(image: np.ndarray) -> bool:
    return bool(image.size) and bool(np.any(image != image.flat[0]))


def _hxw(shape: tuple[int, ...]) -> str:
    return "x".join(str(n) for n in shape)


def _pair_notes(left: DecodedImage, right: DecodedImage) -> list[str]:
    if left.notes == right.notes:
        return [f"left and right: {note}" for note in left.notes]
    return [f"left: {note}" for note in left.notes] + [f"right: {note}" for note in right.notes]


STAGE = Stage(
    name="ingest",
    # 2: 8-bit PGM/PPM with a maximum value other than 255 scaled to 0-255 in both encodings,
    # samples above the maximum value clipped (PNG, JPEG, TIFF, BMP and maxval-255 files as in 1)
    version="2",
    inputs=(),
    outputs=(
        Product(
            "left",
            dtype="uint8",
            attrs={"units": "1", "long_name": "left camera image, gray levels 0-255"},
        ),
        Product(
            "right",
            dtype="uint8",
            attrs={"units": "1", "long_name": "right camera image, gray levels 0-255"},
        ),
    ),
    params=(
        Param(
            "max_pixels",
            int,
            DEFAULT_MAX_PIXELS,
            "largest image (width x height) decoded; larger frames fail, read from the header",
            minimum=1,
        ),
        Param(
            "sample_bits",
            int,
            DEFAULT_SAMPLE_BITS,
            "significant bits of 16-bit samples, 8-16 (12 for a 12-bit camera): scaled by "
            ">> (sample_bits - 8); 8-bit and float images are not affected",
            # 16 reproduces ingest before the parameter existed: old runs keep their keys
            omit_default_from_key=True,
        ),
    ),
    run=run_ingest,
    check_params=_check_params,
    doc="read left/right images (PNG, JPEG, TIFF, PGM/PPM, BMP) as 8-bit gray",
)
