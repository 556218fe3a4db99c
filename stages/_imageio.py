"""Robust reading of survey images into 8-bit gray arrays.

Every problem with a file (missing, a directory, unreadable, empty, truncated, corrupt, an
unsupported format, too large) raises :class:`pipeline.errors.FrameError` whose message
names the file and the cause, so the engine can fail that frame and go on with the others.

Supported formats, recognised by their magic bytes (not by the file extension): PNG,
JPEG, TIFF (classic, not BigTIFF), PGM/PPM (``P2``, ``P3``, ``P5``, ``P6``) and BMP.
The image's size is read from its header *before* decoding, so an oversized image is
rejected without allocating its pixels, and truncation is checked from the header too
(OpenCV silently decodes some truncated files partially): a PNG must reach its ``IEND``
chunk, a JPEG its ``FFD9`` end-of-image marker after the scan data, a TIFF's directory and
strips/tiles must lie inside the file, a binary PNM/BMP must hold all its pixel rows.

Conversion to 8-bit gray (each step adds a note to the frame's record):

* colour (BGR/BGRA) -> gray with OpenCV's ``COLOR_BGR2GRAY`` weights
  (0.299 R + 0.587 G + 0.114 B); an alpha channel is ignored; three identical channels
  are reduced to one without a weighted sum.
* 16-bit -> 8-bit by ``>> 8`` (``v // 256``): a fixed scale, so the left and right images
  of a pair and all frames of an archive keep the same gray scale (a per-image min-max
  stretch would give the two views different gains and hurt stereo matching). Data with
  fewer significant bits (12-bit cameras) therefore comes out dark; the note says so.
* float (TIFF) -> 8-bit: samples in [0, 1] are scaled by 255, samples in [0, 255] are
  used as gray levels; both rounded to nearest. NaN or infinite samples fail the frame
  (arroyo does not invent pixel values), as do negative values or values above 255.
* signed or 32-bit integer samples fail the frame (no unambiguous gray scale).
"""

from __future__ import annotations

import hashlib
import os
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pipeline.errors import FrameError

__all__ = [
    "DEFAULT_MAX_PIXELS",
    "DecodedImage",
    "ImageHeader",
    "read_gray",
    "decode_gray",
    "read_header",
    "to_gray_uint8",
]

DEFAULT_MAX_PIXELS = 8192 * 8192
"""Largest image (width x height) decoded by default."""

_EXTENSIONS = {
    ".png": "PNG",
    ".jpg": "JPEG",
    ".jpeg": "JPEG",
    ".jpe": "JPEG",
    ".tif": "TIFF",
    ".tiff": "TIFF",
    ".pgm": "PNM",
    ".ppm": "PNM",
    ".pnm": "PNM",
    ".bmp": "BMP",
    ".dib": "BMP",
}
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
_SUPPORTED = "PNG, JPEG, TIFF, PGM/PPM or BMP"
# JPEG start-of-frame markers (baseline, progressive, lossless...); not DHT/JPG/DAC.
_JPEG_SOF = frozenset({*range(0xC0, 0xC4), *range(0xC5, 0xC8), *range(0xC9, 0xCC)} | {
    0xCD, 0xCE, 0xCF
})  # fmt: skip


class _Bad(ValueError):
    """A problem with the file's content; turned into a FrameError naming the file."""


@dataclass(frozen=True)
class ImageHeader:
    """What the header says, read without decoding the pixels.

    Attributes
    ----------
    format : {'PNG', 'JPEG', 'TIFF', 'PNM', 'BMP'}
    width, height : int
        Pixels, > 0.
    """

    format: str
    width: int
    height: int


@dataclass(frozen=True)
class DecodedImage:
    """An image read as 8-bit gray.

    Attributes
    ----------
    image : (H, W) ndarray of uint8
        C-contiguous gray levels.
    notes : list of str
        Conversions applied (``"colour (3 channels) converted to gray ..."``).
    sha256 : str
        Hex digest of the file's bytes.
    nbytes : int
        File size in bytes.
    format : {'PNG', 'JPEG', 'TIFF', 'PNM', 'BMP'}
        Format recognised from the content.
    """

    image: np.ndarray
    notes: list[str] = field(default_factory=list)
    sha256: str = ""
    nbytes: int = 0
    format: str = ""


def read_gray(
    path: str | os.PathLike[str], *, max_pixels: int = DEFAULT_MAX_PIXELS
) -> DecodedImage:
    """Read an image file as 8-bit gray, or raise FrameError naming the file and the cause.

    Parameters
    ----------
    path : str or os.PathLike
        Image file (PNG, JPEG, TIFF, PGM/PPM, BMP; recognised by content).
    max_pixels : int
        Largest accepted width x height, >= 1; checked from the header before decoding.

    Returns
    -------
    decoded : DecodedImage
    """
    max_pixels = _coerce_max_pixels(max_pixels)
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    name = os.fspath(path)
    data = _read_file(Path(name), max_bytes=32 * max_pixels + (64 << 20))
    return decode_gray(data, name=str(name), max_pixels=max_pixels)


def decode_gray(
    data: bytes, *, name: str = "<bytes>", max_pixels: int = DEFAULT_MAX_PIXELS
) -> DecodedImage:
    """Decode image bytes as 8-bit gray; see :func:`read_gray` (``name`` labels messages)."""
    max_pixels = _coerce_max_pixels(max_pixels)
    try:
        header = read_header(data)
        if header.width * header.height > max_pixels:
            raise _Bad(
                f"the image is {header.height}x{header.width} (HxW) = "
                f"{header.width * header.height} pixels, more than the limit of {max_pixels} "
                "(ingest.max_pixels); raise the limit or tile/downsample the image"
            )
        try:
            decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raise _Bad(f"{header.format} data cannot be decoded ({_first_line(exc)})") from None
        if decoded is None or decoded.size == 0:
            raise _Bad(f"{header.format} data is corrupt or an unsupported variant of the format")
        image, notes = to_gray_uint8(decoded)
    except (_Bad, ValueError) as exc:
        raise FrameError(f"{name}: {exc}") from None
    extension = os.path.splitext(name)[1].lower()
    expected = _EXTENSIONS.get(extension)
    if expected is not None and expected != header.format:
        notes.insert(0, f"content is {header.format} although the file name ends in {extension}")
    return DecodedImage(
        image=image,
        notes=notes,
        sha256=hashlib.sha256(data).hexdigest(),
        nbytes=len(data),
        format=header.format,
    )


def _coerce_max_pixels(max_pixels: Any) -> int:
    if not isinstance(max_pixels, int | np.integer) or isinstance(max_pixels, bool):
        raise TypeError(f"max_pixels must be an int, got {type(max_pixels).__name__}")
    if max_pixels < 1:
        raise ValueError(f"max_pixels must be >= 1, got {max_pixels}")
    return int(max_pixels)


def _first_line(exc: BaseException) -> str:
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[-1] if lines else type(exc).__name__


def _read_file(path: Path, *, max_bytes: int) -> bytes:
    try:
        info = path.stat()
        if stat.S_ISDIR(info.st_mode):
            raise FrameError(f"{path}: is a directory, expected an image file")
        if not stat.S_ISREG(info.st_mode):
            raise FrameError(f"{path}: is not a regular file (a device, pipe or socket)")
        if info.st_size == 0:
            raise FrameError(f"{path}: the file is empty (zero bytes)")
        if info.st_size > max_bytes:
            raise FrameError(
                f"{path}: the file is {info.st_size} bytes, more than an image within the "
                f"pixel limit can need ({max_bytes}); raise ingest.max_pixels if it is genuine"
            )
        with open(path, "rb") as stream:
            data = stream.read(max_bytes + 1)
    except FileNotFoundError:
        raise FrameError(f"{path}: missing file (no such file or directory)") from None
    except PermissionError:
        raise FrameError(f"{path}: cannot be read (permission denied)") from None
    except (OSError, ValueError) as exc:
        raise FrameError(f"{path}: cannot be read ({exc})") from None
    if not data:
        raise FrameError(f"{path}: the file is empty (zero bytes)")
    if len(data) > max_bytes:
        raise FrameError(f"{path}: the file grew past {max_bytes} bytes while being read")
    return data


def read_header(data: bytes) -> ImageHeader:
    """Format and size from the image bytes' header; raise ValueError when invalid.

    Also checks that the data is complete (see the module docstring). Never decodes pixels.
    """
    if len(data) < 8:
        raise _Bad(f"the file is only {len(data)} bytes long, too short to be an image")
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
            raise _Bad(f"{label} is not a supported image format; convert it to {_SUPPORTED}")
    if data[8:12] == b"WEBP" and data.startswith(b"RIFF"):
        raise _Bad(f"WebP is not a supported image format; convert it to {_SUPPORTED}")
    head = data[:512]
    if all(32 <= b < 127 or b in b"\t\n\r" for b in head):
        raise _Bad(f"the file is text, not an image; expected {_SUPPORTED}")
    raise _Bad(f"unrecognised content (first bytes {data[:8].hex(' ')}); expected {_SUPPORTED}")


def _size(fmt: str, width: int, height: int) -> ImageHeader:
    if width <= 0 or height <= 0:
        raise _Bad(f"{fmt} header gives an invalid size {width}x{height}")
    return ImageHeader(fmt, width, height)


def _truncated(fmt: str, detail: str) -> _Bad:
    return _Bad(f"truncated {fmt} file: {detail}; the file was cut short (re-copy it)")


def _png_header(data: bytes) -> ImageHeader:
    if len(data) < 33:
        raise _truncated("PNG", "it ends inside the IHDR header")
    length, kind, width, height = struct.unpack(">I4sII", data[8:24])
    if kind != b"IHDR" or length != 13:
        raise _Bad("corrupt PNG: the first chunk is not a valid IHDR header")
    position = 8
    while True:
        if position + 8 > len(data):
            raise _truncated("PNG", "it ends before the IEND chunk")
        length, kind = struct.unpack(">I4s", data[position : position + 8])
        end = position + 12 + length
        if end > len(data):
            raise _truncated("PNG", f"chunk {kind!r} runs past the end of the file")
        if kind == b"IEND":
            return _size("PNG", width, height)
        position = end


def _jpeg_header(data: bytes) -> ImageHeader:
    position, size = 2, None
    while True:
        if position >= len(data):
            raise _truncated("JPEG", "it ends before the scan data")
        if data[position] != 0xFF:
            raise _Bad(f"corrupt JPEG: expected a marker at byte {position}")
        while position < len(data) and data[position] == 0xFF:
            position += 1  # fill bytes
        if position + 2 >= len(data):
            raise _truncated("JPEG", "it ends inside a marker")
        marker = data[position]
        position += 1
        if marker == 0xD8 or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue  # markers without a length
        if marker == 0xD9:
            raise _Bad("corrupt JPEG: end-of-image marker before any scan data")
        (length,) = struct.unpack(">H", data[position : position + 2])
        if length < 2:
            raise _Bad(f"corrupt JPEG: segment of length {length} at byte {position}")
        if marker in _JPEG_SOF:
            if position + 7 > len(data):
                raise _truncated("JPEG", "it ends inside the frame header")
            height, width = struct.unpack(">HH", data[position + 3 : position + 7])
            if height == 0:
                raise _Bad("JPEG with the height defined by a DNL marker is not supported")
            size = (width, height)
        if marker == 0xDA:
            break
        position += length
    if size is None:
        raise _Bad("corrupt JPEG: no frame header (SOF) before the scan data")
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
        if tag not in (256, 257, 273, 279, 324, 325) or kind not in _TIFF_TYPES:
            continue
        dtype = np.dtype(order + _TIFF_TYPES[kind])
        raw = entry[8 : 8 + nbytes] if offset is None else data[offset : offset + nbytes]
        tags[tag] = np.frombuffer(raw, dtype=dtype).astype(np.int64)
    if 256 not in tags or 257 not in tags or not len(tags[256]) or not len(tags[257]):
        raise _Bad("corrupt TIFF: the image directory has no width/height")
    offsets, counts = (tags.get(273), tags.get(279)) if 273 in tags else (
        tags.get(324), tags.get(325)
    )  # fmt: skip
    if offsets is None or counts is None or len(offsets) != len(counts) or not len(offsets):
        raise _Bad("corrupt TIFF: missing or inconsistent strip/tile offsets and byte counts")
    if int((offsets + counts).max()) > len(data):
        raise _truncated("TIFF", "image data (strips/tiles) lies past the end of the file")
    return _size("TIFF", int(tags[256][0]), int(tags[257][0]))


def _pnm_header(data: bytes) -> ImageHeader:
    kind = data[:2]
    position, numbers = 2, []
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
            raise _Bad("corrupt PNM header: expected width, height and maximum value")
        numbers.append(int(data[start:position]))
    width, height, maxval = numbers
    if not 0 < maxval < 65536:
        raise _Bad(f"corrupt PNM header: maximum value {maxval} is not in 1..65535")
    if position >= len(data) or not data[position : position + 1].isspace():
        raise _truncated("PNM", "no pixel data after the header")
    header = _size("PNM", width, height)
    channels = 3 if kind in (b"P3", b"P6") else 1
    samples = width * height * channels
    body = data[position + 1 :]
    if kind in (b"P5", b"P6"):
        if len(body) < samples * (1 if maxval < 256 else 2):
            raise _truncated("PNM", f"{len(body)} bytes of pixel data for {width}x{height}")
    else:
        digits = np.frombuffer(body, dtype=np.uint8)
        digits = (digits >= 48) & (digits <= 57)
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
        raise _Bad(f"corrupt BMP: unknown header size {info_size}")
    header = _size("BMP", width, abs(height))
    if compression in (0, 3) and bits in (1, 4, 8, 16, 24, 32):
        needed = offset + (bits * width + 31) // 32 * 4 * abs(height)
        if needed > len(data):
            raise _truncated("BMP", f"{len(data)} bytes where the pixel rows need {needed}")
    return header


def to_gray_uint8(image: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Convert a decoded image to 8-bit gray (see the module docstring for the rules).

    Parameters
    ----------
    image : (H, W) or (H, W, C) ndarray of {uint8, uint16, float32, float64}
        As decoded by OpenCV: channels in BGR(A) order, C in {1, 2, 3, 4}.

    Returns
    -------
    gray : (H, W) ndarray of uint8
        C-contiguous.
    notes : list of str
        One per conversion applied.

    Raises
    ------
    ValueError
        NaN/infinite or out-of-range float samples, signed or 32-bit integer samples,
        an unexpected number of channels or dimensions.
    """
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise ValueError(
            f"{image.dtype} samples are not supported (no unambiguous gray scale); "
            "export the image as 8- or 16-bit unsigned"
        )
    notes: list[str] = []
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        image, notes = _drop_colour(image)
    if image.ndim != 2:
        raise ValueError(f"expected a 2-D image or (H, W, C) with C <= 4, got shape {image.shape}")
    if image.dtype == np.uint16:
        peak = int(image.max())
        image = (image >> 8).astype(np.uint8)
        note = f"16-bit samples scaled to 8 bits by >> 8 (max {peak} -> {peak >> 8})"
        if peak < 4096:
            note += f"; the data uses only {max(peak.bit_length(), 1)} bits, so it comes out dark"
        notes.append(note)
    elif image.dtype.kind == "f":
        image, note = _float_to_uint8(image)
        notes.append(note)
    low, high = int(image.min()), int(image.max())
    if low == high:
        notes.append(f"constant frame: every pixel is {low}")
    return np.ascontiguousarray(image), notes


def _drop_colour(image: np.ndarray) -> tuple[np.ndarray, list[str]]:
    channels = image.shape[2]
    notes = []
    if channels in (2, 4):
        notes.append("alpha channel ignored")
        image = image[:, :, : channels - 1]
        channels -= 1
    if channels == 1:
        return image[:, :, 0], notes
    if channels != 3:
        raise ValueError(f"images with {image.shape[2]} channels are not supported")
    blue = image[:, :, 0]
    if np.array_equal(blue, image[:, :, 1]) and np.array_equal(blue, image[:, :, 2]):
        notes.append("3 identical colour channels reduced to one")
        return blue, notes
    if image.dtype == np.float64:
        image = image.astype(np.float32)  # cvtColor does not take float64
    notes.append("colour (3 channels) converted to gray (0.299 R + 0.587 G + 0.114 B)")
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY), notes


def _float_to_uint8(image: np.ndarray) -> tuple[np.ndarray, str]:
    finite = np.isfinite(image)
    if not finite.all():
        n_nan = int(np.isnan(image).sum())
        n_inf = image.size - int(finite.sum()) - n_nan
        raise ValueError(
            f"the float image has {n_nan} NaN and {n_inf} infinite pixels; arroyo does not "
            "invent pixel values: replace them (for example with 0) when exporting"
        )
    low, high = float(image.min()), float(image.max())
    if low < 0 or high > 255:
        raise ValueError(
            f"float samples span [{low:g}, {high:g}], expected [0, 1] or [0, 255]; "
            "export the image as 8- or 16-bit"
        )
    if high <= 1:
        scaled = np.rint(image.astype(np.float64) * 255.0)
        return scaled.astype(np.uint8), f"{image.dtype} samples in [0, 1] scaled by 255"
    rounded = np.rint(image).astype(np.uint8)
    return rounded, f"{image.dtype} samples in [0, 255] rounded to gray levels"
