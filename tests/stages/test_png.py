"""Tests of the PNG encoder of the quicklooks (ISA-L deflate)."""

from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image

from stages._png import encode_png


def _decoded_by_opencv(content: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(content, np.uint8), cv2.IMREAD_UNCHANGED)


def _decoded_by_pillow(content: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(content)) as image:
        image.load()  # Pillow checks each chunk's CRC and the zlib stream here
        pixels = np.asarray(image)
    return pixels[..., ::-1] if pixels.ndim == 3 else pixels  # RGB -> OpenCV's BGR


@pytest.mark.parametrize(
    "shape", [(1, 1), (1, 1, 3), (7, 5), (7, 5, 3), (3, 1, 3), (1, 9), (61, 83, 3)]
)
def test_round_trip_through_two_decoders(shape):
    image = np.random.default_rng(sum(shape)).integers(0, 256, shape, dtype=np.uint8)
    content = encode_png(image)
    np.testing.assert_array_equal(_decoded_by_opencv(content), image)
    np.testing.assert_array_equal(_decoded_by_pillow(content), image)


def test_non_contiguous_view_is_encoded_as_its_pixels():
    base = np.random.default_rng(1).integers(0, 256, (40, 60, 3), dtype=np.uint8)
    view = base[::2, ::3]
    np.testing.assert_array_equal(_decoded_by_opencv(encode_png(view)), view)


def test_drawn_image_compresses_like_opencv_fastest_level():
    # a smooth gray photograph with coloured lines, like a quicklook
    rng = np.random.default_rng(3)
    gray = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 1.5)
    image = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    cv2.circle(image, (80, 60), 30, (40, 39, 214), 1)
    content = encode_png(image)
    np.testing.assert_array_equal(_decoded_by_opencv(content), image)
    ok, reference = cv2.imencode(".png", image, (cv2.IMWRITE_PNG_COMPRESSION, 1))
    assert ok and len(content) < 1.2 * len(reference)


def test_chunks_are_well_formed():
    content = encode_png(np.zeros((4, 6, 3), dtype=np.uint8))
    assert content[:8] == b"\x89PNG\r\n\x1a\n"
    pos, tags = 8, []
    while pos < len(content):
        (length,) = struct.unpack(">I", content[pos : pos + 4])
        tag, data = content[pos + 4 : pos + 8], content[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", content[pos + 8 + length : pos + 12 + length])
        assert crc == zlib.crc32(tag + data)
        tags.append(tag)
        pos += 12 + length
    assert tags == [b"IHDR", b"IDAT", b"IEND"]
    assert struct.unpack(">IIBBBBB", content[16:29]) == (6, 4, 8, 2, 0, 0, 0)


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((0, 3), dtype=np.uint8),
        np.zeros((3, 3, 4), dtype=np.uint8),
        np.zeros((3, 3), dtype=np.float32),
        np.zeros(5, dtype=np.uint8),
    ],
)
def test_rejects_what_it_cannot_encode(image):
    with pytest.raises(ValueError, match="uint8"):
        encode_png(image)
