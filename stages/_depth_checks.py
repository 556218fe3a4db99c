"""Checks of a frame's depth against the catalog's camera, as notes for the depth stage.

A scientist's own catalog can be wrong in ways the products do not show: no camera pose
(the search stops at a fixed 64 px), a pose or scale the disparity's ground disagrees with
(baseline_m in millimetres), left and right exchanged. Each function returns the notes of
:func:`stages.depth.run_depth` (never raises on a frame's content); the products are not
changed. Measured on a user audit's frames: ``arroyo synth`` archives cropped to 640x480
and 1024x768 and re-cataloged with and without a pose, with a mis-scaled camera and with
exchanged columns.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from pipeline.camera import Camera

__all__ = [
    "SWAP_CHECK_BELOW",
    "OFFSET_CHECK_BELOW",
    "pose_notes",
    "poseless_note",
    "swapped_note",
    "offset_note",
    "limit_note",
]


def pose_notes(camera: Camera, source: str, height_m: float, pitch_deg: float) -> list[str]:
    """A note when the disparity's ground disagrees with the catalog's camera pose.

    The pose bounds the search (25 % of height, a few degrees of pitch absorbed) and is the
    ground when it explains the disparity; otherwise the plane is fitted without a word. A
    user's baseline_m given in millimetres (100) put the ground 1200 m below a camera said to
    be 1.2 m up, and a focal length 20 % short (430 for 550 px) gave 1.08 m and 45 degrees
    against 1.2 m and 38: both ran 'done' with every size and range scaled. No frame of
    runs/eval is noted; of the 192 seed runs' frames one dunes frame (a plane 15.6 m down).
    """
    if not camera.has_pose or not (math.isfinite(height_m) and math.isfinite(pitch_deg)):
        return []
    assert camera.height_m is not None and camera.pitch_deg is not None
    ratio = height_m / camera.height_m
    off = abs(pitch_deg - camera.pitch_deg)
    if source != "ransac" and abs(ratio - 1.0) <= 0.25 and off <= 5.0:
        return []
    units = ""
    if 300 < ratio < 3000 or 1 / 3000 < ratio < 1 / 300:
        units = " (a factor near 1000: baseline_m in millimetres?)"
    used = "the pose was rejected and the fitted plane used" if source == "ransac" else (
        "the fitted plane is used, but the pose bounded the search"
    )  # fmt: skip
    return [
        f"the disparity's ground lies {height_m:.3g} m below the camera at {pitch_deg:.1f} deg "
        f"but [camera] says height_m = {camera.height_m:g}, pitch_deg = {camera.pitch_deg:g}"
        f"{units}; {used}: when most frames say so, check focal_px (px), baseline_m (m) and "
        "the pose; on a frame alone, its ground is hard to fit"
    ]


SWAP_CHECK_BELOW = 0.5
"""Valid share under which a frame is checked for exchanged left and right images."""

OFFSET_CHECK_BELOW = 0.3
"""Valid share under which a frame is checked for a vertical offset (an unrectified pair):
mojave and lab pairs 6 or 8 rows off match 13-24 %; no frame of runs/eval and the seed runs
matches under 56 % (dunes), where the check reads 3 of 240 rectified pairs as offset."""


def swapped_note(left: np.ndarray, right: np.ndarray, hi: int) -> list[str]:
    """A note when the pair matches far better with left and right exchanged.

    A pair entered the other way round in the index matched 12 % of the frame, and only
    segment's 'height valid on 12 %' hinted at it. Block matching at half size (OpenCV
    StereoBM, 4 ms a frame) this way round and exchanged (both mirrored, which turns the
    exchanged pair into a pair of positive disparities): on the built-in archives 67-88 %
    against 8-19 %, and the reverse when exchanged; dunes' ripples match either way
    (0.65-0.76), so the note needs twice as much and at least 30 %.
    """
    quick = _QuickMatch.of(left, right, hi)
    if quick is None:
        return []
    as_given = quick.matched(quick.left, quick.right)
    exchanged = quick.matched(
        np.ascontiguousarray(quick.left[:, ::-1]), np.ascontiguousarray(quick.right[:, ::-1])
    )
    if exchanged < 0.3 or exchanged < 2 * as_given:
        return []
    return [
        f"left and right look exchanged: a quick block matching finds {as_given:.0%} of the "
        f"frame as given and {exchanged:.0%} with the two images exchanged; swap the frame's "
        "left and right columns in the index"
    ]


def offset_note(left: np.ndarray, right: np.ndarray, hi: int) -> list[str]:
    """A note when the pair matches far better with the right image moved up or down.

    Stereo needs rectified pairs, a point on the same row in both images; a right image
    6 rows low matched 16 % of a mojave frame (3 rows: 55 %, 0: 94 %) without a word. Block
    matching at half size with the right image moved by -10..10 rows in steps of 2 (11
    StereoBM runs, ~25 ms, only on frames matched under ``OFFSET_CHECK_BELOW``): on mojave,
    lab and dunes frames the best shift is the true one for offsets of 6 and -8 rows; the
    note needs twice the share matched as given and at least 30 %. Of the 240 rectified
    built-in pairs (12 frames of each cached archive and seed) it reads 3 dunes pairs as
    offset (ripples match at several shifts), none of which the stage checks.
    """
    quick = _QuickMatch.of(left, right, hi)
    if quick is None:
        return []
    margin = 6  # rows lost to the largest shift at half size
    scores = {
        2 * s: quick.matched(
            quick.left[margin:-margin], np.roll(quick.right, -s, axis=0)[margin:-margin]
        )
        for s in range(-5, 6)
    }
    best = max(scores, key=scores.__getitem__)
    if best == 0 or scores[best] < 0.3 or scores[best] < 2 * scores[0]:
        return []
    where = "lower" if best > 0 else "higher"
    return [
        f"the pair looks unrectified: a quick block matching finds {scores[0]:.0%} of the "
        f"frame as given and {scores[best]:.0%} with the right image about {abs(best)} rows "
        f"{where} than the left; stereo needs rectified pairs (a point on the same row in "
        "both images): rectify them, or check that left and right are one exposure"
    ]


class _QuickMatch:
    """OpenCV block matching of a half-size pair, for the checks above (not the products)."""

    def __init__(self, left: np.ndarray, right: np.ndarray, n_disp: int) -> None:
        self.left, self.right, self.n_disp = left, right, n_disp
        self._matcher = cv2.StereoBM_create(numDisparities=n_disp, blockSize=15)
        self._matcher.setUniquenessRatio(10)
        self._matcher.setTextureThreshold(10)

    @classmethod
    def of(cls, left: np.ndarray, right: np.ndarray, hi: int) -> _QuickMatch | None:
        """The half-size pair and a matcher up to ``hi / 2`` (in 16s), None when too small."""
        if min(left.shape) < 64:
            return None
        half = [cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                for img in (left, right)]  # fmt: skip
        n_disp = int(min(max(16, 16 * math.ceil(hi / 32)), 16 * ((half[0].shape[1] - 16) // 16)))
        return cls(half[0], half[1], n_disp) if n_disp >= 16 else None

    def matched(self, left: np.ndarray, right: np.ndarray) -> float:
        """Share of ``left``'s pixels (beyond the first ``n_disp`` columns) matched."""
        return float(np.mean(self._matcher.compute(left, right)[:, self.n_disp :] > 0))


_AT_LIMIT_NOTED = 0.01
"""Share of matches within 1 px of the search limit above which a note says nearer ground
was likely cut off (1.5 % on 1024x768 frames that needed 90 px and got 64; 0.0 % on every
frame of runs/eval and on 640x480 frames that needed 57)."""


def _share_at_limit(disparity: np.ndarray, hi: int) -> float:
    # counts, not a copy of the valid values: 0.11 ms instead of 0.76 on a 500x500 frame,
    # run on every frame with a pose (NaN compares False)
    valid = np.count_nonzero(np.isfinite(disparity))
    return int(np.count_nonzero(disparity >= hi - 1)) / int(valid) if valid else 0.0


def limit_note(disparity: np.ndarray, hi: int, params: Mapping[str, Any]) -> list[str]:
    """A note when matches pile up at a search limit that was set or derived from the pose.

    The README's own catalog example sets ``depth = { max_disparity = 64 }``: copied into the
    catalog of a 1024x768 camera whose near ground needs 90 px, it cut the bottom rows off
    silently (the default without a pose has :func:`poseless_note`).
    """
    share = _share_at_limit(disparity, hi)
    if share < _AT_LIMIT_NOTED:
        return []
    if int(params["max_disparity"]):
        why, fix = "depth.max_disparity", "raise depth.max_disparity"
    elif float(params["nearest_range_m"]):
        why, fix = "f b / depth.nearest_range_m", "lower depth.nearest_range_m"
    else:
        why, fix = "from the camera pose", "check the pose, or set depth.max_disparity"
    # a note that starts with a count reads as a rule's report and is only counted
    return [
        f"matches pile up at the search limit: {share:.1%} within 1 px of {hi} px ({why}), "
        f"so nearer surfaces were likely cut off: {fix}"
    ]


def poseless_note(
    camera: Camera, disparity: np.ndarray, hi: int, params: Mapping[str, Any]
) -> str:
    """What a frame without a camera pose assumed: the ground plane comes from the
    disparity, and without ``nearest_range_m`` or ``max_disparity`` the search stops at a
    fixed 64 px, which a larger or nearer camera than the built-in archives' exceeds
    (1024x768 frames at f = 881 px: 7 % of the bottom 100 rows matched, 93 % with the
    pose); the share of matches piled up at that limit tells."""
    note = "no camera pose ([camera] height_m, pitch_deg): ground plane fitted from the disparity"
    fields = (("height_m", camera.height_m), ("pitch_deg", camera.pitch_deg))
    given = [f"{name} = {value:g}" for name, value in fields if value is not None]
    if given:  # one of the two was given and is not used alone: say so
        note += f" ({given[0]} alone is not used: a pose needs both)"
    if int(params["max_disparity"]) or float(params["nearest_range_m"]):
        return note
    note += (
        f"; disparities searched up to {hi} px (the default without a pose or "
        f"depth.nearest_range_m), so nothing nearer than {camera.k_m_px / hi:.2f} m is matched"
    )
    at_limit = _share_at_limit(disparity, hi)
    if at_limit < _AT_LIMIT_NOTED:
        return note
    return (
        f"{note}; {at_limit:.1%} of the matches lie within 1 px of that limit, so nearer "
        "ground was likely cut off: give the pose, depth.nearest_range_m or depth.max_disparity"
    )
