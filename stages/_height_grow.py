"""Rule R7f: a near rock found in part grows over the rest of its raised support.

It acts on labelled objects after R7e (:mod:`stages._shadow_sides`) and before R8
(:mod:`stages._blobs`), in rows where the heights are precise:

* **R7f raised rest** -- lava's large near rocks (300-3000 px within 2 m) are often found
  in part only: a lit face, a shaded crescent or a few pieces, while the rest of the rock is
  barely lighter or darker than the blotchy ground (1-2 ground spreads) and no threshold
  reaches it. Their heights do: the rock stands 2-8 cm above the ground, 5-15 row sigmas,
  over its whole footprint. An object of at least ``min_object_px`` pixels (150) whose core
  (75th percentile of its relative heights) stands at least ``core_sigmas`` (5) row sigmas
  and ``min_height_m`` above the local ground, in a row whose ground height noise (R0b's
  band MAD, as in R7e) is at most ``max_noise_m`` (10 mm, the noise bar below), grows, up
  to ``max_steps`` (12) px, over connected background pixels raised above ``fraction``
  (0.5) of its core that lie on its own side of the ground's gray level: their gray
  contrast, averaged over the background pixels of a 5x5 window, at least
  ``min_contrast`` (0.25) threshold bands lighter (a light object) or darker (a dark
  one). A growth of more than ``max_gain`` (3)
  times the object is not made. Objects are grown from the highest core down; a pixel goes
  to the first. The growth stays at or below the object's top row and loses what an
  opening with a disk of radius 2 px cuts off.

  Why the gray side: the stereo windows (up to 63 px wide) spread a rock's height over
  the ground around it, 5-20 px: grown on heights alone (over 30 px objects whose core
  stands 4 sigmas), 13 whole rocks of lava's catalog frames fell below IoU 0.5 for 6 partial
  ones matched (object F1 0.819 -> 0.809, segment v28). The fringe's ground is as often
  lighter as darker than the ground's gray level, a rock's rest mostly on the object's side;
  its own pixels are left out of the mean, or a dark object would make the fringe next to
  it look dark. Why 150 px and 5 sigmas: a small object's support is mostly the fringe
  (with 100 px and 4 sigmas lava seed 4 lost 0.003). Minimum contrasts of 0.2-0.3 score
  within a rock of each other; 0.1 lost 0.003 on mojave's catalog frames, 0.4 gained less
  on lava (catalog +0.004, seed 2 +0.001). Why not upwards and the opening: grown
  there, rocks already matched widened by 15-50 % (the width is a
  footprint's widest spread) into raised dark ground behind them or strands of fringe
  (lava seed 4 lava_0010 rock 12: a sample read as an obstacle); near-rock median width
  error (``bench_describe.py --rundir DIR --labels segment``) lava catalog 9.3 -> 10.7 %,
  seed 4 11.1 -> 12.6 % without them, 9.7 and 11.5 % with them.

  With ``bench_segment.py --rundir DIR`` (``--set height_grow_fraction=0`` for the old
  rules; segment v30, the catalogs' current settings) object F1 on lava's catalog frames
  0.825 -> 0.830 (tp 557 -> 561, fp 87 -> 83), seeds 2-5 (runs of the catalog with ``seed
  =`` changed) 0.819 -> 0.822, 0.825 -> 0.829, 0.818 -> 0.821, 0.832 -> 0.833; mojave's
  catalog frames 0.912 -> 0.915, seed 3 0.892 -> 0.895, seeds 2, 4, 5 unchanged; lab
  (catalog, seeds 2, 3) unchanged; dunes (catalog, seeds 2, 3, 4, 5, 7, 11) unchanged,
  precision too. The rocks gained are near ones found in part: lava_0005 rock 1 (IoU 0.37
  before), lava_0007 rock 3 (0.28), lava_0004 rock 4, lava_0010 rock 20. Near rocks (within
  2 m; ``bench_describe.py --rundir DIR --labels segment``) class right / median width
  error, lava catalog and seeds 2-5: 0.955 / 0.930 / 0.933 / 0.929 / 0.910 -> 0.957 /
  0.931 / 0.935 / 0.920 / 0.911, 9.3 / 9.1 / 12.3 / 11.1 / 12.8 -> 9.7 / 9.2 / 12.6 / 11.5
  / 13.1 %: the 12 near rocks gained are measured 11-20 % off (median per run; a rock
  found in part is a hard one, 11 of 12 classed right); on the near rocks matched before
  and after, class right is unchanged on every run and the median width error is too on
  the catalog frames and seed 2, 0.3-0.5 points higher on seeds 3-5 (2-3 rocks per run
  widened by the growth more than 2 points). Mojave catalog and seed 3 0.930 / 0.896 ->
  0.932 / 0.898, 7.6 / 7.3 -> 7.4 / 8.0 % (seed 3: 3 rocks widened). The cost: 5-8 ms of
  CPU per frame (R0b's noise measured again and the growth; lava and mojave catalog frames).

* **R7f second case** -- after the first case, on its result: objects of at least
  ``strong_min_object_px`` (60) pixels whose core stands ``strong_core_sigmas`` (2.5) row
  sigmas (and ``min_height_m``) grow the same way over pixels raised above
  ``strong_fraction`` (0.25) of their core whose mean contrast is at least
  ``strong_contrast`` (0.45) bands out on their side. Why: ``bench_misses.py`` sorts
  mojave's seed 3 partial rocks (mojave_0000 rock 4, mojave_0006 rock 5, mojave_0001 rock
  6) as objects of 95-145 px, or cores of 3 sigmas, whose rest stands 1-2.5 cm high and
  0.65 bands darker or lighter than the ground (no pixel of it within 0.25 bands): the
  first case's 150 px and 5 sigmas leave them out. The fringe's ground scatters around
  the ground's gray level, so the stronger side keeps it out where the lower bars would
  not (a second case over 200 px objects of 1.5 sigmas at 0.25 bands and half the core
  lost a rock of lava's catalog frames, F1 0.8371 -> 0.8357; 0.4 bands lost as much there;
  0.6 bands gained less on mojave's seed 3 and lava's seed 2; 0.35 of the core a rock less
  on mojave's seed 3, near-rock widths the same).

  The lava catalog's partial rocks are not reached: lit objects whose shaded rest lies on
  the other gray side (lava_0000 rock 20, lava_0011 rocks 8, 20 and 30; the second case run
  on the other side grew nothing there), far rocks in noisy rows (lava_0003), and large
  flat dark rocks whose rest stands 0.5-1 cm (1-2 sigmas) and 0.4-0.55 bands dark
  (lava_0002 rock 4, lava_0005 rock 2): the third case's.

* **R7f third case** -- after the second, on its result: objects of at least 150 px whose
  core stands a row sigma and 4 mm grow, up to 30 px and 4 times themselves, over pixels
  raised above ``broad_fraction`` (0.1) of their core whose mean contrast is at least 0.15
  bands out on their side; what an opening of the grown object with a disk of 7 px radius
  (not 2) cuts off is not added, so the growth stays where a 15-px disk fits in the object
  and it together: a broad missing half, not the tongues and strands the faint bars let
  through. With the 2-px opening (and 0.2 bands, a quarter of the core, 200 px, 1.5
  sigmas, 20 px) 24 rocks of lava's catalog frames changed IoU by more than 0.03, 19 of
  them down (lava_0009 rock 7 0.87 -> 0.54, lava_0007 rock 17 lost); with a 4-px disk 10,
  one lost; with 6 px 5, all up. Gained: lava_0002 rock 4 (IoU 0.09 ->
  0.55); raised: lava_0000 rock 8 0.84 -> 0.88, lava_0001 rock 14 0.69 -> 0.91, lava_0005
  rock 2 0.28 -> 0.36, lava_0006 rock 1 0.27 -> 0.36; lava_0007 rock 9 0.74 -> 0.68 the
  one widened (``bench_segment.py``'s scoring per rock). A 9-px disk gained a rock less on
  lava's seed 2.

  With ``bench_segment.py --rundir DIR`` (lava seeds with ``--set two_face_sigmas=3``)
  object F1, second case alone (v35 -> second case) -> third case too:
  lava catalog 0.8371 -> 0.8371 -> 0.8386, mojave catalog 0.9145 -> 0.9145 -> 0.9171, lab
  catalog 0.9784 and dunes (catalog, seeds 2, 3, 4, 5, 7, 11; precision too) unchanged;
  mojave seeds 2-5 0.9199 / 0.8975 / 0.8927 / 0.8870 -> 0.9199 / 0.9055 / 0.8953 / 0.8898
  (third case: unchanged), lava seeds 2-5 0.8332 / 0.8429 / 0.8292 / 0.8407 -> 0.8376 /
  0.8459 / 0.8308 / 0.8470 -> 0.8406 / 0.8459 / 0.8324 / 0.8486; lab seeds 2, 3 unchanged.
  Near rocks (``bench_describe.py --rundir DIR --labels segment``), count / class right /
  median width error, v35 -> both cases: lava catalog 117 / 0.966 / 9.1 % -> 118 / 0.958
  / 9.4 % (lava_0009 rock 8, grown from IoU 0.58 to 0.52, now an obstacle), mojave catalog
  44 / 0.955 / 7.4 % -> 45 / 0.956 / 7.9 %, mojave seed 3 49 / 0.898 / 8.9 % -> 51 / 0.882
  / 8.9 %, lava seeds 2, 4, 5 108 / 0.926 / 9.1 %, 103 / 0.922 / 11.7 %, 103 / 0.932 /
  11.0 % -> 111 / 0.892 / 9.3 %, 105 / 0.905 / 11.3 %, 108 / 0.926 / 10.9 %: the rocks
  gained are hard ones, classed wrong as often as right.

* **R7f noise bar** (all three cases) -- until segment v38 R7f read rows whose ground height
  noise was at most R7e's 7.5 mm, 4-6 mm within 2 m on lava and mojave. Lava's rocks at
  2-2.8 m lie in rows of 7.5-10 mm, and those found in part stayed so: of lava's catalog
  false objects 60 lie on a rock they do not match (``bench_misses.py``'s on_missed), 23
  of them covering less than half of it (with the rest added they would match), several
  in such rows (lava_0004 rocks 22 and 27, lava_0001 rocks 22 and 24: 7.6-9.5 mm). The
  cores' own bars still scale with the row's noise (5, 2.5 and 1 row sigmas), so a
  noisier row asks a higher core: the bar is now 10 mm. With ``bench_segment.py --rundir
  DIR`` (lava seeds with ``--set two_face_sigmas=3``) object F1, v37 -> v38: lava catalog
  0.8386 -> 0.8401 (tp 569 -> 570, fp 81 -> 80: lava_0003 rock 26, IoU 0.44 -> 0.61),
  seeds 2-5 0.8433 / 0.8465 / 0.8324 / 0.8488 -> 0.8454 / 0.8465 / 0.8324 / 0.8504 (seed
  2 lava_0000 rock 16 0.46 -> 0.52, seed 5 lava_0002 rock 26 0.33 -> 0.71); mojave
  (catalog, seeds 2-5), lab (catalog, seeds 2, 3) and dunes (catalog, seeds 2, 3, 4, 5,
  7, 11; precision too) unchanged. Any bar from 10 to 40 mm gives these figures (9 mm
  loses the catalog's rock). Near rocks (``bench_describe.py --rundir DIR --labels
  segment``) count / class right / median width error unchanged on lava's catalog and
  seeds 2-5 (118 / 0.958 / 9.4 %, 111 / 0.892 / 9.4 %, 112 / 0.955 / 13.8 %, 105 / 0.905
  / 10.8 %, 108 / 0.926 / 10.9 %): the rows it adds lie beyond 2 m. Matched rocks there
  widen a little (mean IoU of lava's catalog matches 0.8106 -> 0.8094; lava_0005 rock 24
  0.95 -> 0.78, lava_0010 rock 25 0.79 -> 0.69). Tried with it: the second case at 1.5
  (or 2) row sigmas instead of 2.5 gained lava seeds 3 and 4 (0.8510, 0.8340) but took
  near rocks' size class on seeds 3 and 5 from 0.955 / 0.926 to 0.947 / 0.907; R7e's bar
  (``shadow_noise_m``) at 10 mm too lost a rock on seeds 2 and 3.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from ._heights import _percentiles_by_label, check_height_inputs
from ._regions import _box_window, _extend_box

# R7f: rows whose ground height noise is at most this (metres) are read (R7e's 7.5 mm until
# segment v38: lava's rocks at 2-2.8 m lie in rows of 7.5-10 mm) ...
_MAX_NOISE_M = 0.010
# ... objects this large (pixels) ...
_MIN_OBJECT_PX = 150
# ... whose core (this percentile of their heights) ...
_CORE_PERCENTILE = 75.0
# ... stands this many row sigmas above the ground ...
_CORE_SIGMAS = 5.0
# ... grow over pixels raised above this fraction of the core ...
_FRACTION = 0.5
# ... whose gray contrast, averaged over this window (px) ...
_CONTRAST_WINDOW_PX = 5
# ... is at least this many bands out on the object's side of the ground's gray level,
_MIN_CONTRAST = 0.25
# ... up to this many pixels out, and by no more than this many times themselves.
_MAX_STEPS = 12
_MAX_GAIN = 3.0
# R7f's second case: smaller or lower objects (this many pixels, this many row sigmas) grow
# over pixels raised above this fraction of their core that lie this many bands out on their
# side of the ground's gray level.
_STRONG_MIN_OBJECT_PX = 60
_STRONG_CORE_SIGMAS = 2.5
_STRONG_FRACTION = 0.25
_STRONG_CONTRAST = 0.45
# R7f's third case: objects this large whose core stands this many row sigmas and this high
# grow, up to this many px and times themselves, over pixels raised above this fraction of
# their core this many bands out on their side; what an opening with a disk of this radius
# (px) cuts off the growth is not added.
_BROAD_MIN_OBJECT_PX = 150
_BROAD_CORE_SIGMAS = 1.0
_BROAD_MIN_HEIGHT_M = 0.004
_BROAD_FRACTION = 0.1
_BROAD_CONTRAST = 0.15
_BROAD_STEPS = 30
_BROAD_GAIN = 4.0
_BROAD_OPEN_PX = 7
# What a grown object's opening with a disk of this radius (px) cuts off is not added.
_OPEN_PX = 2

__all__ = ["grow_raised_parts"]


def grow_raised_parts(
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    row_noise: np.ndarray,
    *,
    fraction: float = _FRACTION,
    max_noise_m: float = _MAX_NOISE_M,
    min_height_m: float = 0.008,
    min_object_px: int = _MIN_OBJECT_PX,
    core_sigmas: float = _CORE_SIGMAS,
    min_contrast: float = _MIN_CONTRAST,
    max_steps: int = _MAX_STEPS,
    max_gain: float = _MAX_GAIN,
    strong_fraction: float = _STRONG_FRACTION,
    strong_min_object_px: int = _STRONG_MIN_OBJECT_PX,
    strong_core_sigmas: float = _STRONG_CORE_SIGMAS,
    strong_contrast: float = _STRONG_CONTRAST,
    broad_fraction: float = _BROAD_FRACTION,
) -> tuple[np.ndarray, int]:
    """Rule R7f: raised objects grow over the raised rest of their rock (see module doc).

    Parameters
    ----------
    labels : (M, N) ndarray of int32
        0 background, 1..n objects.
    contrast : (M, N) ndarray of float32
        Gray-level distance from the ground level in threshold bands (negative: darker).
    relative : (M, N) ndarray of float32
        Metres above the local ground (R0's relative heights), NaN where invalid.
    row_noise : (M,) ndarray of float
        Ground height noise of each row (metres, R0b's band MAD sigma).
    fraction : float
        In ``(0, 1]``: pixels raised above this fraction of an object's core height can be
        grown over; 0 disables the rule.
    max_noise_m : float
        ``> 0``; objects whose median row is noisier are not grown.
    min_height_m : float
        ``> 0``; least core height.
    min_object_px : int
        ``>= 1``; smaller objects are not grown.
    core_sigmas : float
        ``>= 0``; least core height in row sigmas.
    min_contrast : float
        ``>= 0``; least mean contrast of the background pixels of its 5x5 window, in bands
        on the object's side, of a grown pixel.
    max_steps : int
        ``>= 1``; farthest growth, px (8-connected steps).
    max_gain : float
        ``> 0``; a growth larger than this times the object is not made.
    strong_fraction : float
        In ``[0, 1]``: R7f's second case, after the first on its result: objects of at least
        ``strong_min_object_px`` pixels whose core stands ``strong_core_sigmas`` row sigmas
        (and ``min_height_m``) grow over pixels raised above this fraction of their core
        whose mean contrast is at least ``strong_contrast`` bands out on their side; 0
        leaves the second case out.
    strong_min_object_px : int
        ``>= 1``.
    strong_core_sigmas : float
        ``>= 0``.
    strong_contrast : float
        ``>= 0``.
    broad_fraction : float
        In ``[0, 1]``: R7f's third case, after the second: objects of at least 150 px
        whose core stands a row sigma and 4 mm grow, up to 30 px and 4 times themselves,
        over pixels raised above this fraction of their core whose mean contrast is 0.15
        bands out on their side, less what an opening with a disk of 7 px radius cuts off
        the growth; 0 leaves the third case out.

    Returns
    -------
    labels : (M, N) ndarray of int32
        The objects grown (ids unchanged; a new array when anything grew).
    grown : int
        Pixels added.
    """
    check_height_inputs(labels, contrast, relative, row_noise)
    if not 0 <= fraction <= 1:
        raise ValueError(f"fraction must be in [0, 1] (0 disables), got {fraction}")
    if not (max_noise_m > 0 and min_height_m > 0 and max_gain > 0):
        raise ValueError(
            "max_noise_m, min_height_m and max_gain must be > 0, got "
            f"{max_noise_m}, {min_height_m} and {max_gain}"
        )
    if min_object_px < 1 or max_steps < 1 or not core_sigmas >= 0 or not min_contrast >= 0:
        raise ValueError(
            "need min_object_px >= 1, max_steps >= 1, core_sigmas >= 0 and min_contrast >= 0, "
            f"got {min_object_px}, {max_steps}, {core_sigmas} and {min_contrast}"
        )
    if not 0 <= strong_fraction <= 1:
        raise ValueError(
            f"strong_fraction must be in [0, 1] (0 leaves the second case out), got "
            f"{strong_fraction}"
        )
    if strong_min_object_px < 1 or not strong_core_sigmas >= 0 or not strong_contrast >= 0:
        raise ValueError(
            "need strong_min_object_px >= 1, strong_core_sigmas >= 0 and strong_contrast >= 0, "
            f"got {strong_min_object_px}, {strong_core_sigmas} and {strong_contrast}"
        )
    if not 0 <= broad_fraction <= 1:
        raise ValueError(
            f"broad_fraction must be in [0, 1] (0 leaves the third case out), got "
            f"{broad_fraction}"
        )
    if fraction == 0:
        return labels, 0
    # the objects' sizes, cores, sides and boxes, measured once and kept up to date by each
    # case for the objects it grows (the others' pixels do not change)
    common = {
        "max_noise_m": max_noise_m,
        "min_height_m": min_height_m,
        "max_steps": max_steps,
        "_measures": {},
    }
    labels, grown = _grow(
        labels,
        contrast,
        relative,
        row_noise,
        fraction=fraction,
        min_object_px=min_object_px,
        core_sigmas=core_sigmas,
        min_contrast=min_contrast,
        max_gain=max_gain,
        **common,
    )
    if strong_fraction > 0:
        # on the first case's result: its grown objects' cores are measured again
        labels, more = _grow(
            labels,
            contrast,
            relative,
            row_noise,
            fraction=strong_fraction,
            min_object_px=strong_min_object_px,
            core_sigmas=strong_core_sigmas,
            min_contrast=strong_contrast,
            max_gain=max_gain,
            **common,
        )
        grown += more
    if broad_fraction > 0:
        # on the second case's result, with a wide opening: a rim of fringe around a rock
        # found whole is a few px wide, a rock's missing half is broad
        labels, more = _grow(
            labels,
            contrast,
            relative,
            row_noise,
            fraction=broad_fraction,
            max_noise_m=max_noise_m,
            min_height_m=_BROAD_MIN_HEIGHT_M,
            min_object_px=_BROAD_MIN_OBJECT_PX,
            core_sigmas=_BROAD_CORE_SIGMAS,
            min_contrast=_BROAD_CONTRAST,
            max_steps=_BROAD_STEPS,
            max_gain=_BROAD_GAIN,
            open_px=_BROAD_OPEN_PX,
            _measures=common["_measures"],
        )
        grown += more
    return labels, grown


def _grow(
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    row_noise: np.ndarray,
    *,
    fraction: float,
    max_noise_m: float,
    min_height_m: float,
    min_object_px: int,
    core_sigmas: float,
    min_contrast: float,
    max_steps: int,
    max_gain: float,
    open_px: int = _OPEN_PX,
    _measures: dict | None = None,
) -> tuple[np.ndarray, int]:
    """One case of R7f with its thresholds (checked by :func:`grow_raised_parts`).

    ``_measures`` (empty at first) keeps :func:`_measure`'s sizes, cores, sides and boxes of
    ``labels`` and its ground's mean contrast for the next case, which must be given this
    call's result.
    """
    count = int(labels.max())
    if count == 0:
        return labels, 0
    if _measures is None:
        _measures = {}
    if not _measures:
        _measures.update(_measure(labels, contrast, relative, count))
    sizes, core, side, boxes = (_measures[key] for key in ("sizes", "core", "side", "boxes"))
    candidates = np.flatnonzero((sizes >= min_object_px) & (core >= min_height_m) & (side != 0))
    candidates = candidates[candidates > 0]
    if candidates.size == 0:
        return labels, 0
    rows, cols = labels.shape
    # the objects that may grow and their windows, highest core first
    windows = []
    for k in candidates[np.argsort(-core[candidates], kind="stable")]:
        sy, sx = _box_window(boxes[k])
        noise = float(row_noise[sy.start + _median_row(labels[sy, sx], k)])
        if noise > max_noise_m or core[k] < core_sigmas * noise:
            continue
        y0, x0 = max(0, sy.start - max_steps), max(0, sx.start - max_steps)
        y1, x1 = min(rows, sy.stop + max_steps), min(cols, sx.stop + max_steps)
        windows.append((k, sy.start, y0, y1, x0, x1))
    if not windows:
        return labels, 0
    mean_contrast = _kept_ground_mean(
        _measures, contrast, labels, [(x0, x1) for *_, x0, x1 in windows]
    )
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * open_px + 1,) * 2)
    out = labels.copy()
    grown = 0
    changed = []
    for k, top, y0, y1, x0, x1 in windows:
        box = out[y0:y1, x0:x1]
        obj = np.empty(box.shape, bool)
        free = np.empty(box.shape, bool)
        # the object, and the ground pixels raised enough on its gray side; not above the
        # object's top row: the stereo windows spread a rock's heights up onto the ground
        # behind it, which the camera sees beyond its top
        _window_masks(
            box,
            relative[y0:y1, x0:x1],
            mean_contrast[y0:y1, x0:x1],
            k,
            fraction * core[k],
            side[k],
            min_contrast,
            top - y0,
            obj,
            free,
        )
        # up to max_steps 8-connected steps over free pixels (one compiled breadth-first
        # pass: the pixels max_steps rounds of a 3x3 dilation within ``free`` reach)
        reached = obj.copy()
        _reach_steps(reached, free, max_steps)
        # less the tongues a grown object's opening cuts off: a rock's width is its widest
        # spread, and the fringe reaches out in strands
        added = cv2.morphologyEx(reached.view(np.uint8), cv2.MORPH_OPEN, disk).view(bool) & ~obj
        n_added = int(np.count_nonzero(added))
        if n_added == 0 or n_added > max_gain * sizes[k]:
            continue
        box[added] = k
        grown += n_added
        changed.append((k, y0, y1, x0, x1))
    if not grown:
        return labels, 0
    for k, y0, y1, x0, x1 in changed:
        _remeasure(_measures, out, contrast, relative, k, (y0, y1, x0, x1))
        # the grown pixels left the ground in these columns
        _measures["stale"].append((x0, x1))
    return out, grown


@njit(cache=True)
def _window_masks(  # pragma: no cover - numba
    box, heights, mean, k, level, side, min_contrast, top, obj, free
):
    """``obj = box == k`` and ``free = (box == 0) & (heights > level) & (side * mean >=
    min_contrast)`` below row ``top`` of the window, in one pass (``level`` and ``side``
    float64: the comparisons numpy makes of float32 maps with float64 scalars; NaN heights
    are not free; ``test_height_grow.py`` compares)."""
    rows, cols = box.shape
    for y in range(rows):
        for x in range(cols):
            label = box[y, x]
            obj[y, x] = label == k
            free[y, x] = (
                y >= top
                and label == 0
                and heights[y, x] > level
                and side * mean[y, x] >= min_contrast
            )


@njit(cache=True)
def _reach_steps(reached, free, max_steps):  # pragma: no cover - numba
    # ``reached`` (the object, in place) grows by breadth-first 8-connected steps over
    # ``free`` pixels, at most ``max_steps`` of them
    rows, cols = reached.shape
    frontier = np.empty((rows * cols, 2), np.int64)
    n = 0
    for y in range(rows):
        for x in range(cols):
            if reached[y, x]:
                frontier[n, 0] = y
                frontier[n, 1] = x
                n += 1
    start = 0
    for _ in range(max_steps):
        stop = n
        for i in range(start, stop):
            y, x = frontier[i, 0], frontier[i, 1]
            for ny in range(max(y - 1, 0), min(y + 2, rows)):
                for nx in range(max(x - 1, 0), min(x + 2, cols)):
                    if free[ny, nx] and not reached[ny, nx]:
                        reached[ny, nx] = True
                        frontier[n, 0] = ny
                        frontier[n, 1] = nx
                        n += 1
        if n == stop:
            break
        start = stop


def _measure(
    labels: np.ndarray, contrast: np.ndarray, relative: np.ndarray, count: int
) -> dict[str, np.ndarray]:
    """Per label 0..count: pixels, core (75th percentile of the valid relative heights,
    -inf without any), the sign of the median contrast, and the inclusive box."""
    labels = np.ascontiguousarray(labels)
    sizes = np.zeros(count + 1, np.int64)
    boxes = np.empty((count + 1, 4), np.int64)
    boxes[:, 0::2] = np.iinfo(np.int64).max
    boxes[:, 1::2] = -1
    # the object pixels' ids, (finite) heights and contrasts, as float32, in raster order
    owners = np.empty((2, labels.size), labels.dtype)
    values = np.empty((2, labels.size), np.float32)
    n_heights, n_pixels = _measure_pass(labels, relative, contrast, sizes, boxes, owners, values)
    core = _percentiles_by_label(
        values[0, :n_heights], owners[0, :n_heights], count + 1, (_CORE_PERCENTILE,)
    )[0]
    side = np.sign(
        _percentiles_by_label(values[1, :n_pixels], owners[1, :n_pixels], count + 1, (50.0,))[0]
    )
    core[~np.isfinite(core)] = -np.inf
    return {"sizes": sizes, "core": core, "side": side, "boxes": boxes}


@njit(cache=True)
def _measure_pass(  # pragma: no cover - numba
    labels, relative, contrast, sizes, boxes, owners, values
):
    """One raster pass for :func:`_measure`: ``_label_areas``' sizes, ``_object_boxes``'
    boxes, and the gathers ``labels[judged]``, ``relative[judged].astype(np.float32)``
    (``judged``: object pixels with a finite height) and ``labels[inside]``,
    ``contrast[inside].astype(np.float32)`` (object pixels) in ``owners`` and ``values``
    rows 0 and 1; returns the two counts (``test_height_grow.py`` compares)."""
    rows, cols = labels.shape
    n_heights = 0
    n_pixels = 0
    ground = 0
    for y in range(rows):
        for x in range(cols):
            k = labels[y, x]
            if k == 0:
                ground += 1
                continue
            sizes[k] += 1
            _extend_box(boxes, k, y, x)
            height = relative[y, x]
            if np.isfinite(height):
                owners[0, n_heights] = k
                values[0, n_heights] = np.float32(height)
                n_heights += 1
            owners[1, n_pixels] = k
            values[1, n_pixels] = np.float32(contrast[y, x])
            n_pixels += 1
    sizes[0] += ground
    return n_heights, n_pixels


def _remeasure(
    measures: dict[str, np.ndarray],
    labels: np.ndarray,
    contrast: np.ndarray,
    relative: np.ndarray,
    k: int,
    window: tuple[int, int, int, int],
) -> None:
    """:func:`_measure`'s values of object ``k`` after it grew inside ``window`` (y0, y1,
    x0, x1, exclusive ends; it holds the old box): the same numbers, since a nearest-rank
    percentile of one label is the value of that rank among its own values alone (selected
    here; at most the sign of a zero differs, which no test reads)."""
    y0, y1, x0, x1 = window
    box = np.empty(4, np.int64)
    # its pixels' float32 heights (the finite ones) and contrasts, in raster order
    heights = np.empty((y1 - y0) * (x1 - x0), np.float32)
    values = np.empty((y1 - y0) * (x1 - x0), np.float32)
    window_of = np.s_[y0:y1, x0:x1]
    n_heights, n_pixels = _remeasure_pass(
        labels[window_of], relative[window_of], contrast[window_of], k, box, heights, values
    )
    measures["boxes"][k] = (y0 + box[0], y0 + box[1], x0 + box[2], x0 + box[3])
    measures["sizes"][k] = n_pixels
    core = _nearest_rank(heights[:n_heights], _CORE_PERCENTILE)
    measures["core"][k] = core if np.isfinite(core) else -np.inf
    measures["side"][k] = np.sign(_nearest_rank(values[:n_pixels], 50.0))


@njit(cache=True)
def _remeasure_pass(window, relative, contrast, k, box, heights, values):  # pragma: no cover
    """Object ``k``'s box in ``window`` (inclusive), and in raster order its pixels'
    heights as float32 (those finite after the cast) and contrasts as float32; returns the
    two counts."""
    rows, cols = window.shape
    box[0], box[1], box[2], box[3] = rows, -1, cols, -1
    n_heights = 0
    n_pixels = 0
    for y in range(rows):
        for x in range(cols):
            if window[y, x] != k:
                continue
            box[0] = min(box[0], y)
            box[1] = y
            box[2] = min(box[2], x)
            box[3] = max(box[3], x)
            height = np.float32(relative[y, x])
            if np.isfinite(height):
                heights[n_heights] = height
                n_heights += 1
            values[n_pixels] = np.float32(contrast[y, x])
            n_pixels += 1
    return n_heights, n_pixels


def _nearest_rank(values: np.ndarray, percentile: float) -> float:
    """:func:`stages._heights._percentiles_by_label`'s percentile of one label's values
    (+inf if none): the value of rank ``floor(percentile / 100 * (n - 1))``."""
    if values.size == 0:
        return np.inf
    rank = int(np.floor((percentile / 100.0) * (values.size - 1)))
    return float(np.partition(values, rank)[rank])


def _median_row(window: np.ndarray, k: int) -> int:
    """``int(np.median(np.nonzero(window == k)[0]))`` (``window`` holds a pixel of ``k``)
    from the row counts, in one compiled pass (``test_height_grow.py`` compares)."""
    return int(_median_row_pass(window, k))


@njit(cache=True)
def _median_row_pass(window, k):  # pragma: no cover - numba
    rows, cols = window.shape
    counts = np.zeros(rows, np.int64)
    for y in range(rows):
        for x in range(cols):
            if window[y, x] == k:
                counts[y] += 1
    n = counts.sum()
    # the rows of the pixels of rank n // 2 (and n // 2 - 1 when n is even) in raster order
    upper, lower = -1, -1
    seen = 0
    for y in range(rows):
        seen += counts[y]
        if lower < 0 and seen > n // 2 - 1:
            lower = y
        if seen > n // 2:
            upper = y
            break
    if n % 2:
        return upper
    # the mean of the two middle rows, truncated as int() truncates np.median's float
    return (lower + upper) // 2


def _kept_ground_mean(
    measures: dict, contrast: np.ndarray, labels: np.ndarray, spans: list[tuple[int, int]]
) -> np.ndarray:
    """:func:`_ground_mean` of ``labels == 0`` in the columns of ``spans`` ((x0, x1), ends
    exclusive), kept in ``measures`` for the next case; other columns hold stale or no values.

    A column's means read only the columns within 2 (the 5x5 window; the pass's sums run
    down each column), so a column is made once, and again only when a case grew within 2
    columns of it (``measures["stale"]``, (x0, x1) ranges): the same floats as
    :func:`_ground_mean` of the whole frame where it is read (``test_height_grow.py``).
    """
    ground = labels == 0
    rows, cols = labels.shape
    if min(rows, cols) < _CONTRAST_WINDOW_PX:
        # a frame narrower than the window: OpenCV's, whole; nothing kept, but _grow still
        # records its growth here
        measures["stale"] = []
        return _ground_mean(contrast, ground)
    if "mean" not in measures:
        measures["mean"] = np.empty((rows, cols), np.float32)
        measures["fresh"] = np.zeros(cols, bool)
        measures["stale"] = []
    mean, fresh = measures["mean"], measures["fresh"]
    half = _CONTRAST_WINDOW_PX // 2
    for x0, x1 in measures["stale"]:
        fresh[max(0, x0 - half) : x1 + half] = False
    measures["stale"] = []
    needed = np.zeros(cols, bool)
    for x0, x1 in spans:
        needed[x0:x1] = True
    todo = needed & ~fresh
    # runs of columns to make: where ``todo`` switches on and off
    edges = np.flatnonzero(np.diff(np.concatenate(([False], todo, [False]))))
    values = np.ascontiguousarray(contrast, dtype=np.float32)
    for c0, c1 in edges.reshape(-1, 2):
        _ground_mean_pass(values, ground, mean, c0, c1)
    fresh |= todo
    return mean


def _ground_mean(contrast: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Mean contrast of the ``ground`` pixels in each pixel's 5x5 window (0 where none):
    a pixel's gray side over a few pixels, since the ground's single pixels scatter both
    ways; the objects' own pixels are left out, or a dark object's would make the raised
    fringe next to it look dark.

    The same floats as ``cv2.blur`` of ``contrast * ground`` over ``cv2.blur`` of
    ``ground`` (float32, 5x5, mirrored border), divided where the latter is positive, in
    one compiled pass without the five whole-frame temporaries (``test_height_grow.py``
    compares them).
    """
    rows, cols = contrast.shape
    if min(rows, cols) < _CONTRAST_WINDOW_PX:
        # the pass mirrors the border once: a frame narrower than the window is OpenCV's
        window = (_CONTRAST_WINDOW_PX, _CONTRAST_WINDOW_PX)
        weight = ground.astype(np.float32)
        total = cv2.blur(contrast.astype(np.float32) * weight, window)
        share = cv2.blur(weight, window)
        return np.where(share > 0, total / np.maximum(share, np.float32(1e-6)), np.float32(0.0))
    out = np.empty((rows, cols), np.float32)
    _ground_mean_pass(
        np.ascontiguousarray(contrast, dtype=np.float32), np.ascontiguousarray(ground), out, 0, cols
    )
    return out


@njit(cache=True)
def _mirror(i, n):  # pragma: no cover - numba
    # OpenCV's BORDER_REFLECT_101 of an index at most n - 1 outside [0, n)
    if i < 0:
        return -i
    if i >= n:
        return 2 * n - 2 - i
    return i


@njit(cache=True)
def _ground_mean_pass(contrast, ground, out, c0, c1):  # pragma: no cover - numba
    # cv2.blur's float32 box filter, step by step: each row's 5-sums in double, added left
    # to right (RowSum<float, double>), then down each column a running double sum that
    # adds the new row and subtracts the old one (ColumnSum<double, float>), scaled by 1/25
    # and rounded to float32; the row sums of the five rows in reach are kept in a ring.
    # Columns c0..c1-1 only: each column's floats are the same whatever the range
    rows, cols = contrast.shape
    width = c1 - c0
    half = _CONTRAST_WINDOW_PX // 2
    scale = 1.0 / (_CONTRAST_WINDOW_PX * _CONTRAST_WINDOW_PX)
    ring_t = np.empty((_CONTRAST_WINDOW_PX, width))
    ring_w = np.empty((_CONTRAST_WINDOW_PX, width))
    padded_t = np.empty(width + 2 * half, np.float32)
    padded_w = np.empty(width + 2 * half, np.float32)
    floor = np.float32(1e-6)

    def row_sums(y):
        slot = y % _CONTRAST_WINDOW_PX
        for i in range(width + 2 * half):
            x = _mirror(c0 + i - half, cols)
            w = np.float32(1.0) if ground[y, x] else np.float32(0.0)
            padded_t[i] = contrast[y, x] * w
            padded_w[i] = w
        for x in range(width):
            t = np.float64(padded_t[x])
            w = np.float64(padded_w[x])
            for j in range(1, _CONTRAST_WINDOW_PX):
                t += np.float64(padded_t[x + j])
                w += np.float64(padded_w[x + j])
            ring_t[slot, x] = t
            ring_w[slot, x] = w

    for y in range(min(half + 1, rows)):
        row_sums(y)
    sum_t = np.zeros(width)
    sum_w = np.zeros(width)
    for j in range(_CONTRAST_WINDOW_PX - 1):
        slot = _mirror(j - half, rows) % _CONTRAST_WINDOW_PX
        for x in range(width):
            sum_t[x] += ring_t[slot, x]
            sum_w[x] += ring_w[slot, x]
    for y in range(rows):
        if y + half < rows and y >= 1:
            row_sums(y + half)
        new = _mirror(y + half, rows) % _CONTRAST_WINDOW_PX
        old = _mirror(y - half, rows) % _CONTRAST_WINDOW_PX
        for x in range(width):
            s_t = sum_t[x] + ring_t[new, x]
            s_w = sum_w[x] + ring_w[new, x]
            total = np.float32(s_t * scale)
            share = np.float32(s_w * scale)
            out[y, c0 + x] = total / max(share, floor) if share > 0 else np.float32(0.0)
            sum_t[x] = s_t - ring_t[old, x]
            sum_w[x] = s_w - ring_w[old, x]
