"""Significant bits in image headers (PNG sBIT chunk, PGM/PPM maximum value, TIFF tag 281)."""

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


def tiff_bytes(samples: np.ndarray, *, max_sample: int | None) -> bytes:
    """A baseline little-endian gray 16-bit TIFF, one strip, with or without tag 281."""
    h, w = samples.shape
    pixels = samples.astype("<u2").tobytes()
    tags = [
        (256, 3, w), (257, 3, h), (258, 3, 16), (259, 3, 1), (262, 3, 1),
        (273, 4, 0), (277, 3, 1), (278, 3, h), (279, 4, len(pixels)),
    ]  # fmt: skip
    if max_sample is not None:
        tags.append((281, 3, max_sample))
    data_offset = 8 + 2 + 12 * len(tags) + 4
    entries = b"".join(
        struct.pack("<HHI", tag, kind, 1)
        + (struct.pack("<I", data_offset if tag == 273 else value) if kind == 4
           else struct.pack("<HH", value, 0))
        for tag, kind, value in tags
    )  # fmt: skip
    return (
        b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(tags)) + entries
        + b"\x00\x00\x00\x00" + pixels
    )  # fmt: skip


def test_tiff_max_sample_value_gives_the_significant_bits(sixteen: np.ndarray) -> None:
    data = tiff_bytes(sixteen, max_sample=4095)
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.dtype == np.uint16 and np.array_equal(decoded, sixteen)  # a valid TIFF
    header = read_header(data)
    assert (header.format, header.width, header.height) == ("TIFF", 20, 12)
    assert (header.bit_depth, header.significant_bits) == (16, 12)
    assert "MaxSampleValue tag 4095" in header.significant_from


def test_tiff_without_max_sample_value_declares_nothing(sixteen: np.ndarray) -> None:
    for data in (tiff_bytes(sixteen, max_sample=None), tiff_bytes(sixteen, max_sample=65535)):
        header = read_header(data)
        assert (header.bit_depth, header.significant_bits) == (16, None)


def test_tiff_declaring_12_significant_bits_is_noted_at_ingest(tmp_path, sixteen) -> None:
    """A 16-bit TIFF's MaxSampleValue tag (4095) gets ingest's note, as a PNG's sBIT chunk
    does; the pixels are decoded by ``sample_bits`` alone."""
    from stages._imageio import read_gray

    path = tmp_path / "max4095.tif"
    path.write_bytes(tiff_bytes(sixteen, max_sample=4095))
    decoded = read_gray(path)
    np.testing.assert_array_equal(decoded.image, (sixteen >> 8).astype(np.uint8))
    declared = [n for n in decoded.notes if "declares 12 significant bits" in n]
    assert len(declared) == 1 and "MaxSampleValue tag 4095" in declared[0], decoded.notes
    assert not any("declares" in n for n in read_gray(path, sample_bits=12).notes)


def test_pnm_header_records_its_maximum_value_and_raster_offset() -> None:
    samples = np.arange(6, dtype=np.uint8).reshape(2, 3)
    data = b"P5\n# comment\n3 2\n100\n" + samples.tobytes()
    header = read_header(data)
    assert (header.max_value, header.bit_depth) == (100, 8)
    assert data[header.raster_offset or 0 :] == samples.tobytes()
    plain = read_header(b"P2 3 2 4095\n0 1 2\n3 4 4095\n")
    assert (plain.max_value, plain.raster_offset, plain.bit_depth) == (4095, 12, 16)
    other = read_header(png_bytes(samples))
    assert (other.max_value, other.raster_offset) == (None, None)
