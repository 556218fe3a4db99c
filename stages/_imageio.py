"""Robust reading of survey images into 8-bit gray arrays.

Every problem with a file (missing, a directory, unreadable, empty, truncated, corrupt, an
unsupported format, too large) raises :class:`pipeline.errors.FrameError` whose message
names the file and the cause, so the engine can fail that frame and go on with the others.

Supported formats, recognised by their magic bytes (not by the file extension): PNG,
JPEG, TIFF (classic, not BigTIFF), PGM/PPM (``P2``, ``P3``, ``P5``, ``P6``) and BMP.
The image's size is read from its header *before* decoding, so an oversized image is
rejected without allocating its pixels, and truncation is checked from the header too
(OpenCV silently decodes some truncated files partially): see :mod:`stages._imageheaders`.

Corrupt JPEG scan data (bytes zeroed or flipped inside the entropy-coded data, a scan cut
short with an end-of-image marker still after it) decodes *without error*: libjpeg only
writes a warning such as ``Corrupt JPEG data: premature end of data segment`` to the
process's standard error and fills the damaged blocks with made-up pixels. OpenCV offers no
hook for these warnings (nor does Pillow, which swallows them), so a JPEG is decoded with
file descriptor 2 redirected to a temporary file and libjpeg's corruption warnings found
there fail the frame (:func:`_imdecode_jpeg`); other lines written meanwhile are passed on.
Damage that still decodes to valid Huffman codes in the right number is invisible to libjpeg
and is not detected.

Conversion to 8-bit gray (each step adds a note to the frame's record):

* PGM/PPM samples are ``value / max_value`` of full intensity (the Netpbm definition), in
  binary (``P5``/``P6``) and plain (ASCII, ``P2``/``P3``) files alike: 8-bit samples with a
  maximum value other than 255 are scaled to 0..255 by ``round(value * 255 / max_value)``
  (OpenCV left binary ones as stored and rounded plain ones down). A sample above the
  header's maximum value makes the file inconsistent: it is clipped to the maximum value
  and the note counts such samples, names the file and the largest value (the frame does
  not fail, as for samples above ``sample_bits`` below). 16-bit PGM/PPM samples (maximum
  value 256 to 65535) are then scaled like any 16-bit samples.
* colour (BGR/BGRA) -> gray with OpenCV's ``COLOR_BGR2GRAY`` weights
  (0.299 R + 0.587 G + 0.114 B); an alpha channel is ignored; three identical channels
  are reduced to one without a weighted sum.
* 16-bit -> 8-bit by ``>> (sample_bits - 8)``: a fixed scale, so the left and right images
  of a pair and all frames of an archive keep the same gray scale (a per-image min-max
  stretch would give the two views different gains and hurt stereo matching).
  ``sample_bits`` (``ingest.sample_bits``, 8 to 16, default 16: ``>> 8``) is how many bits
  of each 16-bit sample the camera really uses: scientific cameras write 10-, 12- or 14-bit
  data in 16-bit PNG/TIFF files, and with the default such data comes out dark (12-bit data
  as gray levels 0-15); the note then says how many bits the data uses and names the
  setting. With ``sample_bits`` below 16 a sample above ``2**sample_bits - 1`` cannot come
  from such a camera: it is clipped to 255 and the note counts the clipped samples, names
  the file and says the setting looks wrong (the frame does not fail: its other pixels are
  good, and the note is in the frame's record). A 16-bit file that declares fewer
  significant bits than ``sample_bits`` (a PNG ``sBIT`` chunk, a PGM/PPM maximum value
  such as 4095, a TIFF ``MaxSampleValue`` tag) gets a note with the value to set; it is
  decoded as before, by ``sample_bits`` alone (the declaration is optional and sometimes
  wrong, and following it would change the products of existing runs).
  8-bit and float samples are not affected by ``sample_bits`` (a note says so when it is
  not 16).
* float (TIFF) -> 8-bit: samples in [0, 1] are scaled by 255, samples in [0, 255] are
  used as gray levels; both rounded to nearest. NaN or infinite samples fail the frame
  (arroyo does not invent pixel values), as do negative values or values above 255.
* signed or 32-bit integer samples fail the frame (no unambiguous gray scale).
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pipeline.errors import FrameError

from ._imageheaders import ImageHeader, read_header

__all__ = [
    "DEFAULT_MAX_PIXELS",
    "DEFAULT_SAMPLE_BITS",
    "DecodedImage",
    "ImageHeader",
    "coerce_sample_bits",
    "read_gray",
    "decode_gray",
    "read_header",
    "to_gray_uint8",
]

DEFAULT_MAX_PIXELS = 8192 * 8192
"""Largest image (width x height) decoded by default."""

DEFAULT_SAMPLE_BITS = 16
"""Significant bits of a 16-bit sample by default: all 16, scaled by ``>> 8``."""

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
    path: str | os.PathLike[str],
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    sample_bits: int = DEFAULT_SAMPLE_BITS,
) -> DecodedImage:
    """Read an image file as 8-bit gray, or raise FrameError naming the file and the cause.

    Parameters
    ----------
    path : str or os.PathLike
        Image file (PNG, JPEG, TIFF, PGM/PPM, BMP; recognised by content).
    max_pixels : int
        Largest accepted width x height, >= 1; checked from the header before decoding.
    sample_bits : int, 8 to 16
        Significant bits of 16-bit samples, scaled to 8 bits by ``>> (sample_bits - 8)``;
        see the module docstring. 8-bit and float samples are not affected.

    Returns
    -------
    decoded : DecodedImage

    Raises
    ------
    TypeError, ValueError
        ``max_pixels`` or ``sample_bits`` of the wrong type or out of range.
    FrameError
        Any problem with the file.
    """
    max_pixels = _coerce_max_pixels(max_pixels)
    sample_bits = coerce_sample_bits(sample_bits)
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    name = os.fspath(path)
    data = _read_file(Path(name), max_bytes=32 * max_pixels + (64 << 20))
    return decode_gray(data, name=str(name), max_pixels=max_pixels, sample_bits=sample_bits)


def decode_gray(
    data: bytes,
    *,
    name: str = "<bytes>",
    max_pixels: int = DEFAULT_MAX_PIXELS,
    sample_bits: int = DEFAULT_SAMPLE_BITS,
) -> DecodedImage:
    """Decode image bytes as 8-bit gray; see :func:`read_gray` (``name`` labels messages)."""
    max_pixels = _coerce_max_pixels(max_pixels)
    sample_bits = coerce_sample_bits(sample_bits)
    try:
        header = read_header(data)
        if header.width * header.height > max_pixels:
            raise ValueError(
                f"the image is {header.height}x{header.width} (HxW) = "
                f"{header.width * header.height} pixels, more than the limit of {max_pixels} "
                "(ingest.max_pixels); raise the limit or tile/downsample the image"
            )
        buffer = np.frombuffer(data, dtype=np.uint8)
        corrupt: list[str] = []
        try:
            if header.format == "JPEG":
                decoded, corrupt = _imdecode_jpeg(buffer)
            else:
                decoded = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raise ValueError(
                f"{header.format} data cannot be decoded ({_first_line(exc)})"
            ) from None
        if corrupt:
            raise ValueError(
                f"corrupt JPEG data ({'; '.join(corrupt)}); re-export or replace the file"
            )
        if decoded is None or decoded.size == 0:
            raise ValueError(
                f"{header.format} data is corrupt or an unsupported variant of the format"
            )
        pnm_notes: list[str] = []
        if header.format == "PNM":
            decoded, pnm_notes = _pnm_full_scale(decoded, data, header, name=name)
        image, notes = to_gray_uint8(decoded, sample_bits=sample_bits, name=name)
        notes[:0] = pnm_notes
        if decoded.dtype == np.uint16:
            notes.extend(_declared_bits_notes(header, sample_bits))
        if header.more_pages:
            # a stereo camera's left and right as two pages of one file read as a pair of
            # identical first pages without a word
            notes.append("the TIFF holds more than one page: only the first is read")
    except ValueError as exc:
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


def _pnm_full_scale(
    decoded: np.ndarray, data: bytes, header: ImageHeader, *, name: str
) -> tuple[np.ndarray, list[str]]:
    """A PGM/PPM's samples as ``cv2.imdecode`` should give them, with the notes.

    OpenCV returns a binary (``P5``/``P6``) file's samples as stored, but scales a plain
    (ASCII, ``P2``/``P3``) 8-bit file's by ``value * 255 // max_value`` (rounded down) and
    clips a plain file's samples above the maximum value, so one image decoded differently
    in the two encodings. Here the stored samples (read again from the text of a plain
    file) are the input for both:

    * samples above the header's maximum value (an inconsistent file) are clipped to it,
      with a note;
    * 8-bit samples (maximum value up to 255) are scaled to 0..255 by
      ``round(value * 255 / max_value)``, halves up as Netpbm's own tools round, with a
      note; a maximum value of 255 changes nothing;
    * 16-bit samples (maximum value 256 to 65535) are returned as stored, for the
      ``sample_bits`` scaling of :func:`to_gray_uint8` (as before).

    Parameters
    ----------
    decoded : (H, W) or (H, W, 3) ndarray of {uint8, uint16}
        ``cv2.imdecode`` of ``data``; BGR for a PPM.
    data : bytes
        The file's bytes.
    header : ImageHeader
        ``read_header(data)``, with ``max_value`` and ``raster_offset``.
    name : str
        Names the file in the note on samples above the maximum value.

    Returns
    -------
    samples : ndarray of {uint8, uint16}, shape of ``decoded``
        uint8 for a maximum value up to 255, uint16 above.
    notes : list of str

    Raises
    ------
    ValueError
        A plain file's numbers cannot be read back as OpenCV read them.
    """
    maxval, offset = header.max_value, header.raster_offset
    if maxval is None or offset is None:
        raise ValueError("expected a PGM/PPM header with its maximum value and raster offset")
    stored: np.ndarray = decoded
    if data[1:2] in (b"2", b"3"):
        values = _plain_pnm_values(data, offset=offset, count=decoded.size)
        stored = values.reshape(decoded.shape)
        if stored.ndim == 3:
            stored = stored[:, :, ::-1]  # RGB in the file, BGR from OpenCV
        within = np.minimum(stored, maxval)
        opencv = within if maxval > 255 else within * 255 // maxval
        if not np.array_equal(opencv, decoded):
            raise ValueError(
                "the plain (ASCII) PNM sample values cannot be read consistently; "
                "re-save the file as binary PGM/PPM or PNG"
            )
    notes: list[str] = []
    peak = int(stored.max())
    if peak > maxval:
        over = int(np.count_nonzero(stored > maxval))
        scale = " (full scale)" if maxval <= 255 else ""
        notes.append(
            f"{over} of the {stored.size} samples of {name} exceed the header's maximum value "
            f"{maxval} (up to {peak}): clipped to {maxval}{scale}; the file is inconsistent, "
            "check the program that wrote it"
        )
        stored = np.minimum(stored, maxval)
    if maxval > 255:
        return stored.astype(np.uint16, copy=False), notes
    if maxval != 255:
        # round half up in integers: (2 v 255 + maxval) // (2 maxval)
        table = (np.arange(maxval + 1) * 510 + maxval) // (2 * maxval)
        stored = table.astype(np.uint8)[stored]
        notes.append(
            f"samples with the maximum value {maxval} scaled to 0-255 by "
            f"round(value * 255 / {maxval})"
        )
    return stored.astype(np.uint8, copy=False), notes


def _plain_pnm_values(data: bytes, *, offset: int, count: int) -> np.ndarray:
    """The first ``count`` decimal numbers of a plain PGM/PPM raster, as int64.

    Comments (``#`` to the end of the line) are left out, as OpenCV leaves them out. Only
    called once OpenCV has decoded the file, so every number is below 2**31 (OpenCV fails
    larger ones): a run of more than 10 digits starts with zeros.
    """
    body = data[offset:]
    if b"#" in body:
        body = re.sub(rb"#[^\r\n]*", b"", body)
    raw = np.frombuffer(body, dtype=np.uint8)
    digit = np.zeros(len(raw) + 2, dtype=np.int8)
    digit[1:-1] = (raw >= 48) & (raw <= 57)
    change = np.diff(digit)
    starts = np.flatnonzero(change == 1)[:count]
    ends = np.flatnonzero(change == -1)[:count]  # one past each number's last digit
    if len(starts) < count:
        raise ValueError(
            f"truncated PNM file: {len(starts)} of {count} sample values present; the file "
            "was cut short (re-copy it)"
        )
    lengths = ends - starts
    values = np.zeros(count, dtype=np.int64)
    for k in range(min(int(lengths.max(initial=0)), 10)):
        has = lengths > k
        values[has] += (raw[ends[has] - 1 - k].astype(np.int64) - 48) * 10**k
    return values


def _declared_bits_notes(header: ImageHeader, sample_bits: int) -> list[str]:
    """A note when a 16-bit file declares fewer significant bits than ``sample_bits``.

    Only a note: decoding by the declaration would change the products of runs made
    before it was read.
    """
    declared = header.significant_bits
    if header.bit_depth != 16 or declared is None or declared >= sample_bits:
        return []
    # sample_bits cannot go below 8: a file declaring fewer is scaled as 8-bit data
    suggest = max(declared, 8)
    advice = (
        f"set ingest.sample_bits = {suggest} (catalog [params] or --set)"
        if suggest < sample_bits
        else f"ingest.sample_bits is already at its lowest, {sample_bits}"
    )
    return [
        f"the file declares {declared} significant bits of 16 ({header.significant_from}) "
        f"but ingest.sample_bits = {sample_bits}: {advice}"
    ]


# libjpeg's warnings that mean damaged entropy-coded data (jerror.h: JWRN_HIT_MARKER,
# JWRN_EXTRANEOUS_DATA, JWRN_HUFF_BAD_CODE, JWRN_ARITH_BAD_CODE, JWRN_MUST_RESYNC,
# JWRN_JPEG_EOF, JWRN_BOGUS_PROGRESSION, JWRN_NOT_SEQUENTIAL); harmless ones ("Warning:
# unknown JFIF revision number") are passed on.
_LIBJPEG_CORRUPT = (
    "Corrupt JPEG data: ",
    "Premature end of JPEG file",
    "Inconsistent progression sequence",
    "Invalid SOS parameters",
)
# fd 2 is one per process: a single JPEG decode at a time may redirect it.
_STDERR_LOCK = threading.Lock()


def _imdecode_jpeg(buffer: np.ndarray) -> tuple[np.ndarray | None, list[str]]:
    """``cv2.imdecode`` of JPEG bytes, with libjpeg's corruption warnings.

    libjpeg reports damaged scan data only by a line on the C ``stderr`` (file descriptor 2),
    then decodes on with made-up blocks. The descriptor is pointed at a temporary file for
    the decode; the corruption lines are returned (their ``Corrupt JPEG data: `` prefix
    dropped) and every other line, perhaps written by another thread meanwhile, is written
    on to the real standard error.
    """
    with _STDERR_LOCK, tempfile.TemporaryFile() as sink:
        try:
            sys.stderr.flush()  # Python's buffered text must not land in the sink
        except (AttributeError, OSError, ValueError):
            pass
        try:
            saved: int | None = os.dup(2)
        except OSError:
            saved = None  # fd 2 closed: libjpeg's fprintf would go nowhere
        try:
            os.dup2(sink.fileno(), 2)
            try:
                decoded = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
            finally:
                if saved is None:
                    os.close(2)
                else:
                    os.dup2(saved, 2)
            sink.seek(0)
            lines = sink.read().decode("utf-8", "replace").splitlines(keepends=True)
            corrupt, other = [], []
            for line in lines:
                text = line.strip()
                if text.startswith(_LIBJPEG_CORRUPT):
                    corrupt.append(text.removeprefix("Corrupt JPEG data: "))
                elif text:
                    other.append(line)
            passed = "".join(other).encode("utf-8", "replace")
            while passed and saved is not None:
                passed = passed[os.write(saved, passed) :]
        finally:
            if saved is not None:
                os.close(saved)
    return decoded, corrupt


def _coerce_max_pixels(max_pixels: Any) -> int:
    if not isinstance(max_pixels, int | np.integer) or isinstance(max_pixels, bool):
        raise TypeError(f"max_pixels must be an int, got {type(max_pixels).__name__}")
    if max_pixels < 1:
        raise ValueError(f"max_pixels must be >= 1, got {max_pixels}")
    return int(max_pixels)


def coerce_sample_bits(sample_bits: Any) -> int:
    """``sample_bits`` as an int from 8 to 16, or TypeError/ValueError saying how to fix it."""
    if not isinstance(sample_bits, int | np.integer) or isinstance(sample_bits, bool):
        raise TypeError(
            "sample_bits (the significant bits of 16-bit samples) must be an int from 8 to "
            f"16, got {type(sample_bits).__name__} {sample_bits!r}; write it without quotes "
            "or decimals, for example ingest.sample_bits = 12"
        )
    if not 8 <= sample_bits <= 16:
        raise ValueError(
            "sample_bits (the significant bits of 16-bit samples) must be from 8 to 16, got "
            f"{sample_bits}; set it to the camera's bit depth (12 for a 12-bit sensor), or "
            "leave it at 16 (the default) for data that uses the full 16-bit range"
        )
    return int(sample_bits)


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
        raise FrameError(
            f"{path}: missing file (no such file or directory){_missing_hint(path)}"
        ) from None
    except PermissionError:
        raise FrameError(f"{path}: cannot be read (permission denied)") from None
    except (OSError, ValueError) as exc:
        raise FrameError(f"{path}: cannot be read ({exc})") from None
    if not data:
        raise FrameError(f"{path}: the file is empty (zero bytes)")
    if len(data) > max_bytes:
        raise FrameError(f"{path}: the file grew past {max_bytes} bytes while being read")
    return data


def _missing_hint(path: Path) -> str:
    """Where a missing image may be: a message that named only the path left a user to
    guess between a wrong directory, a wrong extension and a wrong case."""
    if "\\" in path.name:
        return "; the path holds backslashes: write it with / in the index"
    parent = path.parent
    if not parent.is_dir():
        return (
            f"; its directory {parent} does not exist either: paths in the index are "
            "relative to the index CSV's directory, or absolute"
        )
    try:
        names = sorted(os.listdir(parent))
    except OSError:
        return ""
    stem, name = path.stem.lower(), path.name.lower()
    near = [n for n in names if n.lower() == name or os.path.splitext(n)[0].lower() == stem]
    if not near:
        return "; fix the path in the index, or remove the frame"
    shown = ", ".join(near[:3])
    return f"; {parent} holds {shown}: fix the path in the index (names are case-sensitive)"


def to_gray_uint8(
    image: np.ndarray, *, sample_bits: int = DEFAULT_SAMPLE_BITS, name: str = "the image"
) -> tuple[np.ndarray, list[str]]:
    """Convert a decoded image to 8-bit gray (see the module docstring for the rules).

    Parameters
    ----------
    image : (H, W) or (H, W, C) ndarray of {uint8, uint16, float32, float64}
        As decoded by OpenCV: channels in BGR(A) order, C in {1, 2, 3, 4}.
    sample_bits : int, 8 to 16
        Significant bits of uint16 samples, scaled by ``>> (sample_bits - 8)``; samples
        above ``2**sample_bits - 1`` are clipped to 255 (and noted). Ignored for uint8 and
        float samples.
    name : str
        Names the file in the note on clipped samples.

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
        an unexpected number of channels or dimensions, ``sample_bits`` out of range.
    TypeError
        ``sample_bits`` not an int.
    """
    sample_bits = coerce_sample_bits(sample_bits)
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
        image, scaling = _uint16_to_uint8(image, sample_bits=sample_bits, name=name)
        notes.extend(scaling)
    elif sample_bits != DEFAULT_SAMPLE_BITS:
        # a setting that changes nothing is worth a word: the files may not be what the
        # user thinks they are
        kind = "8-bit" if image.dtype == np.uint8 else f"{image.dtype}"
        notes.append(f"{kind} samples: ingest.sample_bits = {sample_bits} does not apply")
    if image.dtype.kind == "f":
        image, note = _float_to_uint8(image)
        notes.append(note)
    low, high = int(image.min()), int(image.max())
    if low == high:
        notes.append(f"constant frame: every pixel is {low}")
    return np.ascontiguousarray(image), notes


def _uint16_to_uint8(
    image: np.ndarray, *, sample_bits: int, name: str
) -> tuple[np.ndarray, list[str]]:
    """``image >> (sample_bits - 8)`` clipped to 255, with the notes that explain it."""
    shift = sample_bits - 8
    top = (1 << sample_bits) - 1
    peak = int(image.max())
    used = max(peak.bit_length(), 1)
    if sample_bits == 16:  # the default, and the rule before sample_bits existed
        scaled = (image >> 8).astype(np.uint8)
        note = f"16-bit samples scaled to 8 bits by >> 8 (max {peak} -> {peak >> 8})"
    else:
        scaled = np.minimum(image >> shift, 255).astype(np.uint8)
        note = (
            f"16-bit samples with {sample_bits} significant bits (ingest.sample_bits) scaled "
            f"to 8 bits by >> {shift} (max {peak} -> {min(peak >> shift, 255)})"
        )
    if peak >> shift < 16:  # at most 15 of 255 gray levels: segmentation finds nothing
        note += f"; the data uses only {used} bits, so it comes out dark"
        if max(used, 8) < sample_bits:
            note += (
                f": if the camera writes {max(used, 8)}-bit samples, set "
                f"ingest.sample_bits = {max(used, 8)} (catalog [params] or --set)"
            )
    notes = [note]
    if peak > top:
        clipped = int(np.count_nonzero(image > top))
        fix = (
            f"set ingest.sample_bits = {used}" if used < 16 else "leave ingest.sample_bits at 16"
        )
        notes.append(
            f"{clipped} samples of {name} are above {top}, the largest {sample_bits}-bit "
            f"value (max {peak}, {used} bits), and were clipped to 255: ingest.sample_bits = "
            f"{sample_bits} looks wrong for this file; {fix}"
        )
    return scaled, notes


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
