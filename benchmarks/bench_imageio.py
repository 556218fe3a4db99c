"""CPU cost of reading a JPEG frame: arroyo's ``decode_gray`` against a bare ``cv2.imdecode``.

``decode_gray`` checks the header, decodes JPEGs with file descriptor 2 redirected to catch
libjpeg's corrupt-data warnings (see :mod:`stages._imageio`) and converts to gray; the bare
figure is ``cv2.imdecode`` plus the same gray conversion. Times are CPU milliseconds of this
process (``time.process_time``), median of ``--repeats`` blocks of ``--loops`` decodes, on
synthetic textured JPEGs (gray and colour, quality 95) or on the files given with ``--image``.

Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_imageio.py [--size 500] [--repeats 7]
        [--loops 50] [--image FILE ...]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from stages._imageio import decode_gray, to_gray_uint8


def _synthetic(size: int) -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:size, :size]
    wave = 60 * np.sin(xx / 13.0) * np.cos(yy / 17.0)
    gray = (128 + wave + rng.normal(0, 20, (size, size))).clip(0, 255).astype(np.uint8)
    colour = np.dstack([gray, np.roll(gray, 3, 0), np.roll(gray, 5, 1)])
    files = {}
    for label, image in (("gray", gray), ("colour", colour)):
        ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        files[f"{label} {size}x{size} q95"] = buffer.tobytes()
    return files


def _bare(data: bytes) -> np.ndarray:
    decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    return to_gray_uint8(decoded)[0]


def _cpu_ms(function: Callable[[bytes], object], data: bytes, loops: int, repeats: int) -> float:
    function(data)  # warm-up
    blocks = []
    for _ in range(repeats):
        start = time.process_time()
        for _ in range(loops):
            function(data)
        blocks.append((time.process_time() - start) / loops * 1e3)
    return statistics.median(blocks)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--loops", type=int, default=50)
    parser.add_argument("--image", type=Path, nargs="*", default=[])
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    files = {str(path): path.read_bytes() for path in args.image} or _synthetic(args.size)
    print(f"{'file':28s} {'bytes':>8s} {'bare ms':>8s} {'arroyo ms':>9s} {'extra ms':>8s}")
    for label, data in files.items():
        assert np.array_equal(_bare(data), decode_gray(data, name=label).image)
        bare = _cpu_ms(_bare, data, args.loops, args.repeats)
        ours = _cpu_ms(decode_gray, data, args.loops, args.repeats)
        print(f"{label:28s} {len(data):8d} {bare:8.3f} {ours:9.3f} {ours - bare:8.3f}")


if __name__ == "__main__":
    main()
