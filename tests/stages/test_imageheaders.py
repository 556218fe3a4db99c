"""Significant bits in image headers (PNG sBIT chunk, PGM/PPM maximum value)."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from stages._imageheaders import read_header


def png_bytes(image: np.ndarray) -> bytes:
    ok, buffer = cv2.imencode(".png", image)
    assert ok
    return buffer.tobytes()


def with_sbit(png: bytes, payload: bytes) -> bytes:
    """The PNG with an sBIT chunk (correct CRC) right after its IHDR chunk."""
    chunk = b"sBIT" + payload
    crc = struct.pack(">I", zlib.crc32(chunk) & 0xFFFFFFFF)
    ihdr_end = 8 + 12 + 13
    return png[:ihdr_end] + struct.pack(">I", len(payload)) + chunk + crc + png[ihdr_end:]


def pgm_bytes(samples: np.ndarray, maxval: int) -> bytes:
    h, w = samples.shape
    return f"P5\n{w} {h}\n{maxval}\n".encode() + samples.astype(">u2").tobytes()


@pytest.fixture(scope="module")
def sixteen() -> np.ndarray:
    return np.random.default_rng(3).integers(0, 4096, size=(12, 20), dtype=np.uint16)


def test_png_sbit_chunk_read_for_gray_and_colour(sixteen: np.ndarray) -> None:
    gray = read_header(with_sbit(png_bytes(sixteen), b"\x0c"))
    assert (gray.bit_depth, gray.significant_bits) == (16, 12)
    assert "sBIT" in gray.significant_from
    colour = np.dstack([sixteen, sixteen // 2, sixteen // 4])
    header = read_header(with_sbit(png_bytes(colour), bytes([10, 12, 11])))
    assert (header.width, header.height, header.significant_bits) == (20, 12, 12)
    # the file still decodes: the chunk is where the PNG specification puts it
    decoded = cv2.imdecode(
        np.frombuffer(with_sbit(png_bytes(sixteen), b"\x0c"), np.uint8), cv2.IMREAD_UNCHANGED
    )
    np.testing.assert_array_equal(decoded, sixteen)


def test_png_without_or_with_a_bad_sbit_chunk_declares_nothing(sixteen: np.ndarray) -> None:
    plain = read_header(png_bytes(sixteen))
    assert (plain.bit_depth, plain.significant_bits, plain.significant_from) == (16, None, "")
    assert read_header(png_bytes(sixteen.astype(np.uint8))).bit_depth == 8
    for payload in (b"\x00", b"\x11", b""):  # 0 bits, 17 bits of 16, too short
        assert read_header(with_sbit(png_bytes(sixteen), payload)).significant_bits is None


@pytest.mark.parametrize(("maxval", "bits"), [(4095, 12), (1023, 10), (65535, 16), (4000, 12)])
def test_pgm_maximum_value_gives_the_significant_bits(
    sixteen: np.ndarray, maxval: int, bits: int
) -> None:
    header = read_header(pgm_bytes(np.minimum(sixteen, maxval), maxval))
    assert (header.bit_depth, header.significant_bits) == (16, bits)
    assert str(maxval) in header.significant_from


def test_8bit_pgm_declares_nothing(sixteen: np.ndarray) -> None:
    data = b"P5\n20 12\n255\n" + (sixteen % 256).astype(np.uint8).tobytes()
    assert (read_header(data).bit_depth, read_header(data).significant_bits) == (8, None)
