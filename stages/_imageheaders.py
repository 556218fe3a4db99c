"""Image headers: format from the magic bytes, size and completeness, without decoding.

Supported: PNG, JPEG, TIFF (classic, not BigTIFF), PGM/PPM (``P2``, ``P3``, ``P5``, ``P6``)
and BMP. Completeness checks (OpenCV silently decodes some truncated files partially): a PNG
must reach its ``IEND`` chunk, a JPEG its ``FFD9`` end-of-image marker after the scan data, a
TIFF's directory, tag values and strips/tiles must lie inside the file, a PNM or uncompressed
BMP must hold all its samples. Other known formats (GIF, WebP, BigTIFF...) and text are named
in the error. Parsing is bounded by the data's length: nothing is allocated from header values.

The header also says how many bits of a sample are significant when the file declares it: a
PNG's ``sBIT`` chunk, a 16-bit PGM/PPM's maximum value (4095: 12 bits), or a 16-bit TIFF's
``MaxSampleValue`` tag (281). Ingest notes a
16-bit file that declares fewer bits than ``ingest.sample_bits``; it does not decode it
differently. A PGM/PPM's maximum value and the offset of its raster are recorded for the
decoder, which scales 8-bit samples to full scale and clips samples above the maximum.
"""

from __future__ import annotations

import dataclasses
import struct
from dataclasses import dataclass

import numpy as np

__all__ = ["HeaderError", "ImageHeader", "read_header", "SUPPORTED"]

SUPPORTED = "PNG, JPEG, TIFF, PGM/PPM or BMP"
"""Human list of the supported formats, for messages."""

_OTHER_FORMATS = (
    (b"GIF87a", "GIF"),
    (b"GIF89a", "GIF"),
    (b"II+\x00", "BigTIFF"),
    (b"MM\x00+", "BigTIFF"),
    (b"\x00\x00\x00\x0cjP  ", "JPEG 2000"),
    (b"\xff\x4f\xff\x51", "JPEG 2000 codestream"),
    (b"v/1\x01", "OpenEXR"),
    (b"#?RADIANCE", "Radiance HDR"),
    (b"%PDF", "PDF"),
    (b"PK\x03\x04", "ZIP archive"),
    (b"\x1f\x8b", "gzip archive"),
    (b"P1", "PBM bitmap"),
    (b"P4", "PBM bitmap"),
    (b"8BPS", "Photoshop"),
)
# JPEG start-of-frame markers (baseline, progressive, lossless...); not DHT/JPG/DAC.
_JPEG_SOF = frozenset({*range(0xC0, 0xC4), *range(0xC5, 0xC8), *range(0xC9, 0xCC)} | {
    0xCD, 0xCE, 0xCF
})  # fmt: skip


class HeaderError(ValueError):
    """The bytes are not a complete image of a supported format; the message says why."""


@dataclass(frozen=True)
class ImageHeader:
    """What the header says, read without decoding the pixels.

    Attributes
    ----------
    format : {'PNG', 'JPEG', 'TIFF', 'PNM', 'BMP'}
    width, height : int
        Pixels, > 0.
    bit_depth : int
        Bits per stored sample: 8, or 16 for a 16-bit PNG, PGM/PPM or TIFF (others: 8, not
        read).
    significant_bits : int or None
        Significant bits per sample the file declares, 1 to ``bit_depth`` (the largest of
        the colour channels' for a PNG ``sBIT`` chunk); None when it declares none.
    significant_from : str
        Where ``significant_bits`` was read, for messages (``"its sBIT chunk"``); empty
        when None.
    more_pages : bool
        A TIFF whose first image directory links to another: only the first page is decoded.
    max_value : int or None
        A PGM/PPM's maximum value, 1 to 65535: a sample is ``value / max_value`` of full
        intensity (1 or 2 bytes per binary sample for up to 255 or more); None for the other
        formats.
    raster_offset : int or None
        A PGM/PPM's byte offset of its raster (the first byte after the whitespace that
        ends the header); None for the other formats.
    """

    format: str
    width: int
    height: int
    bit_depth: int = 8
    significant_bits: int | None = None
    significant_from: str = ""
    more_pages: bool = False
    max_value: int | None = None
    raster_offset: int | None = None


def read_header(data: bytes) -> ImageHeader:
    """Format and size from the image bytes' header; raise HeaderError when invalid.

    Also checks that the data is complete (see the module docstring). Never decodes pixels.
    """
    if len(data) < 8:
        raise HeaderError(f"the file is only {len(data)} bytes long, too short to be an image")
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return _png_header(data)
    if data.startswith(b"\xff\xd8\xff"):
        return _jpeg_header(data)
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_header(data)
    if data[:2] in (b"P2", b"P3", b"P5", b"P6") and data[2:3].isspace():
        return _pnm_header(data)
    if data.startswith(b"BM"):
        return _bmp_header(data)
    for magic, label in _OTHER_FORMATS:
        if data.startswith(magic):
            raise HeaderError(f"{label} is not a supported image format; convert it to {SUPPORTED}")
    if data[8:12] == b"WEBP" and data.startswith(b"RIFF"):
        raise HeaderError(f"WebP is not a supported image format; convert it to {SUPPORTED}")
    head = data[:512]
    if all(32 <= b < 127 or b in b"\t\n\r" for b in head):
        raise HeaderError(f"the file is text, not an image; expected {SUPPORTED}")
    raise HeaderError(
        f"unrecognised content (first bytes {data[:8].hex(' ')}); expected {SUPPORTED}"
    )


def _size(fmt: str, width: int, height: int) -> ImageHeader:
    if width <= 0 or height <= 0:
        raise HeaderError(f"{fmt} header gives an invalid size {width}x{height}")
    return ImageHeader(fmt, width, height)


def _truncated(fmt: str, detail: str) -> HeaderError:
    return HeaderError(f"truncated {fmt} file: {detail}; the file was cut short (re-copy it)")


def _png_header(data: bytes) -> ImageHeader:
    if len(data) < 33:
        raise _truncated("PNG", "it ends inside the IHDR header")
    length, kind, width, height = struct.unpack(">I4sII", data[8:24])
    if kind != b"IHDR" or length != 13:
        raise HeaderError("corrupt PNG: the first chunk is not a valid IHDR header")
    depth, colour = data[24], data[25]
    significant = None
    position = 8
    while True:
        if position + 8 > len(data):
            raise _truncated("PNG", "it ends before the IEND chunk")
        length, kind = struct.unpack(">I4s", data[position : position + 8])
        end = position + 12 + length
        if end > len(data):
            raise _truncated(
                "PNG", f"chunk {kind.decode('latin-1')!r} runs past the end of the file"
            )
        if kind == b"IEND":
            header = _size("PNG", width, height)
            return ImageHeader(
                "PNG", header.width, header.height, bit_depth=depth,
                significant_bits=significant,
                significant_from="its sBIT chunk" if significant else "",
            )  # fmt: skip
        if kind == b"sBIT":
            significant = _png_significant_bits(data[position + 8 : end - 4], depth, colour)
        position = end


# Colour channels (alpha left out) of a PNG colour type, in the order of its sBIT bytes.
_PNG_COLOUR_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 1, 6: 3}


def _png_significant_bits(payload: bytes, depth: int, colour: int) -> int | None:
    """The largest colour channel's significant bits from an sBIT payload; None when the
    chunk does not fit the colour type or its values lie outside 1..depth (an ancillary
    chunk: a bad one is ignored, as decoders do, rather than failing the frame)."""
    channels = _PNG_COLOUR_CHANNELS.get(colour)
    # palette images declare against 8 bits, whatever their index depth
    top = 8 if colour == 3 else depth
    if channels is None or len(payload) < channels:
        return None
    values = payload[:channels]
    if not all(1 <= v <= top for v in values):
        return None
    return max(values)


def _jpeg_header(data: bytes) -> ImageHeader:
    position, size = 2, None
    while True:
        if position >= len(data):
            raise _truncated("JPEG", "it ends before the scan data")
        if data[position] != 0xFF:
            raise HeaderError(f"corrupt JPEG: expected a marker at byte {position}")
        while position < len(data) and data[position] == 0xFF:
            position += 1  # fill bytes
        if position + 2 >= len(data):
            raise _truncated("JPEG", "it ends inside a marker")
        marker = data[position]
        position += 1
        if marker == 0xD8 or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue  # markers without a length
        if marker == 0xD9:
            raise HeaderError("corrupt JPEG: end-of-image marker before any scan data")
        (length,) = struct.unpack(">H", data[position : position + 2])
        if length < 2:
            raise HeaderError(f"corrupt JPEG: segment of length {length} at byte {position}")
        if marker in _JPEG_SOF:
            if position + 7 > len(data):
                raise _truncated("JPEG", "it ends inside the frame header")
            height, width = struct.unpack(">HH", data[position + 3 : position + 7])
            if height == 0:
                raise HeaderError("JPEG with the height defined by a DNL marker is not supported")
            size = (width, height)
        if marker == 0xDA:
            break
        position += length
    if size is None:
        raise HeaderError("corrupt JPEG: no frame header (SOF) before the scan data")
    # Entropy-coded data never contains FF D9 (FF is stuffed as FF 00), so the end of
    # image marker after the first scan means the data is complete.
    if data.rfind(b"\xff\xd9") < position:
        raise _truncated("JPEG", "no end-of-image marker (FF D9) after the scan data")
    return _size("JPEG", *size)


_TIFF_TYPES = {1: "B", 3: "H", 4: "I", 16: "Q"}  # BYTE, SHORT, LONG, LONG8
# Byte size of every TIFF field type, to check that each tag's values lie inside the file.
_TIFF_SIZES = {
    1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4, 16: 8
}  # fmt: skip


def _tiff_header(data: bytes) -> ImageHeader:
    order = "<" if data[:2] == b"II" else ">"
    if len(data) < 8:
        raise _truncated("TIFF", "it ends inside the file header")
    (ifd,) = struct.unpack(order + "I", data[4:8])
    if ifd + 2 > len(data):
        raise _truncated("TIFF", "the image directory lies past the end of the file")
    (count,) = struct.unpack(order + "H", data[ifd : ifd + 2])
    if ifd + 2 + 12 * count + 4 > len(data):
        raise _truncated("TIFF", "the image directory runs past the end of the file")
    tags: dict[int, np.ndarray] = {}
    for i in range(count):
        entry = data[ifd + 2 + 12 * i : ifd + 14 + 12 * i]
        tag, kind, n = struct.unpack(order + "HHI", entry[:8])
        nbytes = n * _TIFF_SIZES.get(kind, 1)
        offset = None
        if nbytes > 4:
            (offset,) = struct.unpack(order + "I", entry[8:12])
            if offset + nbytes > len(data):
                raise _truncated("TIFF", f"the values of tag {tag} lie past the end of the file")
        if tag not in (256, 257, 258, 273, 279, 281, 324, 325) or kind not in _TIFF_TYPES:
            continue
        dtype = np.dtype(order + _TIFF_TYPES[kind])
        raw = entry[8 : 8 + nbytes] if offset is None else data[offset : offset + nbytes]
        tags[tag] = np.frombuffer(raw, dtype=dtype).astype(np.int64)
    if 256 not in tags or 257 not in tags or not len(tags[256]) or not len(tags[257]):
        raise HeaderError("corrupt TIFF: the image directory has no width/height")
    offsets, counts = (tags.get(273), tags.get(279)) if 273 in tags else (
        tags.get(324), tags.get(325)
    )  # fmt: skip
    if offsets is None or counts is None or len(offsets) != len(counts) or not len(offsets):
        raise HeaderError(
            "corrupt TIFF: missing or inconsistent strip/tile offsets and byte counts"
        )
    if int((offsets + counts).max()) > len(data):
        raise _truncated("TIFF", "image data (strips/tiles) lies past the end of the file")
    header = _size("TIFF", int(tags[256][0]), int(tags[257][0]))
    (following,) = struct.unpack(order + "I", data[ifd + 2 + 12 * count : ifd + 6 + 12 * count])
    if following:
        header = dataclasses.replace(header, more_pages=True)
    bits = tags.get(258)
    if bits is None or not len(bits) or int(bits.max()) != 16:
        return header
    # MaxSampleValue (tag 281): a 12-bit camera's 4095 declares 12 significant bits
    top = tags.get(281)
    largest = int(top.max()) if top is not None and len(top) else 0
    declared = largest.bit_length()
    if not 1 <= declared < 16:
        return dataclasses.replace(header, bit_depth=16)
    return dataclasses.replace(
        header,
        bit_depth=16,
        significant_bits=declared,
        significant_from=f"its MaxSampleValue tag {largest}",
    )


def _pnm_header(data: bytes) -> ImageHeader:
    kind = data[:2]
    position = 2
    numbers: list[int] = []
    while len(numbers) < 3:
        while position < len(data) and (data[position : position + 1].isspace()):
            position += 1
        if data[position : position + 1] == b"#":
            newline = data.find(b"\n", position)
            position = len(data) if newline < 0 else newline + 1
            continue
        start = position
        while position < len(data) and 48 <= data[position] <= 57 and position - start < 10:
            position += 1
        if position == start:
            raise HeaderError("corrupt PNM header: expected width, height and maximum value")
        numbers.append(int(data[start:position]))
    width, height, maxval = numbers
    if not 0 < maxval < 65536:
        raise HeaderError(f"corrupt PNM header: maximum value {maxval} is not in 1..65535")
    if position >= len(data) or not data[position : position + 1].isspace():
        raise _truncated("PNM", "no pixel data after the header")
    header = _size("PNM", width, height)
    header = dataclasses.replace(header, max_value=maxval, raster_offset=position + 1)
    if maxval > 255:
        header = dataclasses.replace(
            header, bit_depth=16, significant_bits=maxval.bit_length(),
            significant_from=f"its maximum value {maxval}",
        )  # fmt: skip
    channels = 3 if kind in (b"P3", b"P6") else 1
    samples = width * height * channels
    body = data[position + 1 :]
    if kind in (b"P5", b"P6"):
        if len(body) < samples * (1 if maxval < 256 else 2):
            raise _truncated("PNM", f"{len(body)} bytes of pixel data for {width}x{height}")
    else:
        raw = np.frombuffer(body, dtype=np.uint8)
        digits = (raw >= 48) & (raw <= 57)
        starts = np.count_nonzero(digits[1:] & ~digits[:-1]) + int(bool(digits[:1].any()))
        if starts < samples:
            raise _truncated("PNM", f"{starts} of {samples} sample values present")
    return header


def _bmp_header(data: bytes) -> ImageHeader:
    if len(data) < 26:
        raise _truncated("BMP", "it ends inside the header")
    offset, info_size = struct.unpack("<II", data[10:18])
    compression = 0
    if info_size == 12:
        width, height, _, bits = struct.unpack("<HHHH", data[18:26])
    elif info_size >= 40:
        if len(data) < 54:
            raise _truncated("BMP", "it ends inside the header")
        width, height, _, bits, compression = struct.unpack("<iiHHI", data[18:34])
    else:
        raise HeaderError(f"corrupt BMP: unknown header size {info_size}")
    header = _size("BMP", width, abs(height))
    if compression in (0, 3) and bits in (1, 4, 8, 16, 24, 32):
        needed = offset + (bits * width + 31) // 32 * 4 * abs(height)
        if needed > len(data):
            raise _truncated("BMP", f"{len(data)} bytes where the pixel rows need {needed}")
    return header
