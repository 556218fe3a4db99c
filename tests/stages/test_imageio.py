"""Image decoding: formats, content conversions, every bad file, fuzzing."""

from __future__ import annotations

import hashlib
import os
import struct
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.errors import FrameError
from stages import _imageio
from stages._imageio import DecodedImage, decode_gray, read_gray, read_header, to_gray_uint8

EXTENSIONS = (".png", ".jpg", ".tif", ".pgm", ".bmp")


@pytest.fixture(scope="module")
def gray() -> np.ndarray:
    rng = np.random.default_rng(7)
    return rng.integers(0, 256, size=(48, 64), dtype=np.uint8)


@pytest.fixture(scope="module")
def colour() -> np.ndarray:
    rng = np.random.default_rng(8)
    return rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)


def write(path: Path, image: np.ndarray, *params: int) -> Path:
    assert cv2.imwrite(str(path), image, list(params)), path
    return path


def encoded(extension: str, image: np.ndarray) -> bytes:
    ok, buffer = cv2.imencode(extension, image)
    assert ok
    return buffer.tobytes()


def assert_frame_error(path: Path, *fragments: str, **kwargs: int) -> str:
    with pytest.raises(FrameError) as info:
        read_gray(path, **kwargs)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


# --- good files ---------------------------------------------------------------------------


@pytest.mark.parametrize("extension", [".png", ".tif", ".tiff", ".pgm", ".bmp"])
def test_lossless_gray_roundtrip(tmp_path: Path, gray: np.ndarray, extension: str) -> None:
    path = write(tmp_path / f"f{extension}", gray)
    decoded = read_gray(path)
    assert isinstance(decoded, DecodedImage)
    np.testing.assert_array_equal(decoded.image, gray)
    assert decoded.image.dtype == np.uint8 and decoded.image.flags.c_contiguous
    assert decoded.notes == []
    assert decoded.nbytes == path.stat().st_size
    assert decoded.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_ascii_pgm_and_jpeg(tmp_path: Path, gray: np.ndarray) -> None:
    ascii_pgm = write(tmp_path / "a.pgm", gray, cv2.IMWRITE_PXM_BINARY, 0)
    assert ascii_pgm.read_bytes().startswith(b"P2")
    np.testing.assert_array_equal(read_gray(ascii_pgm).image, gray)
    smooth = cv2.GaussianBlur(gray, (0, 0), 3)
    jpeg = read_gray(write(tmp_path / "a.jpg", smooth, cv2.IMWRITE_JPEG_QUALITY, 95))
    assert jpeg.format == "JPEG" and jpeg.image.shape == gray.shape
    assert np.abs(jpeg.image.astype(int) - smooth).mean() < 2


@pytest.mark.parametrize("extension", [".png", ".jpg", ".tif", ".ppm", ".bmp"])
def test_colour_converted_to_gray_with_note(
    tmp_path: Path, colour: np.ndarray, extension: str
) -> None:
    decoded = read_gray(write(tmp_path / f"c{extension}", colour))
    assert decoded.image.shape == colour.shape[:2]
    assert any("converted to gray" in note for note in decoded.notes)
    if extension != ".jpg":
        np.testing.assert_array_equal(decoded.image, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))


def test_identical_channels_and_alpha(tmp_path: Path, gray: np.ndarray) -> None:
    decoded = read_gray(write(tmp_path / "g3.png", np.dstack([gray] * 3)))
    np.testing.assert_array_equal(decoded.image, gray)
    assert decoded.notes == ["3 identical colour channels reduced to one"]
    bgra = np.dstack([gray, gray, gray, np.full_like(gray, 9)])
    decoded = read_gray(write(tmp_path / "g4.png", bgra))
    np.testing.assert_array_equal(decoded.image, gray)
    assert "alpha channel ignored" in decoded.notes


@pytest.mark.parametrize("extension", [".png", ".tif", ".pgm"])
def test_16bit_scaled_by_shift(tmp_path: Path, gray: np.ndarray, extension: str) -> None:
    wide = gray.astype(np.uint16) * 257 + 3
    decoded = read_gray(write(tmp_path / f"w{extension}", wide))
    np.testing.assert_array_equal(decoded.image, (wide >> 8).astype(np.uint8))
    assert any("16-bit samples scaled to 8 bits by >> 8" in note for note in decoded.notes)
    assert not any("dark" in note for note in decoded.notes)


def test_12bit_data_in_16bit_file_gets_dark_note(tmp_path: Path, gray: np.ndarray) -> None:
    twelve = gray.astype(np.uint16) * 16
    decoded = read_gray(write(tmp_path / "t.png", twelve))
    np.testing.assert_array_equal(decoded.image, (twelve >> 8).astype(np.uint8))
    assert any("only 12 bits" in note and "dark" in note for note in decoded.notes)


def camera_samples(image: np.ndarray, bits: int) -> np.ndarray:
    """8-bit gray levels as the ``bits``-bit samples of a camera (0 -> 0, 255 -> top)."""
    wide = image.astype(np.uint32)
    return ((wide << (bits - 8)) | (wide >> (16 - bits))).astype(np.uint16)


@pytest.mark.parametrize("extension", [".png", ".tif"])
def test_regression_12bit_data_in_16bit_files_came_out_as_gray_levels_0_15(
    tmp_path: Path, gray: np.ndarray, extension: str
) -> None:
    """Bug (user audit): a scientific camera's 12-bit samples in 16-bit PNG/TIFF files were
    scaled by >> 8 to gray levels 0-15, so segmentation found 0 objects; only a note said
    so. ingest.sample_bits = 12 scales them by >> 4 to the full 0-255 range, and the note
    of the default names the setting."""
    twelve = camera_samples(gray, 12)
    assert twelve.max() == 4095 and twelve.min() == 0
    path = write(tmp_path / f"t{extension}", twelve)
    dark = read_gray(path)
    assert int(dark.image.max()) == 15
    assert any(
        "only 12 bits" in note and "set ingest.sample_bits = 12" in note for note in dark.notes
    ), dark.notes
    decoded = read_gray(path, sample_bits=12)
    np.testing.assert_array_equal(decoded.image, gray)
    assert decoded.image.min() == 0 and decoded.image.max() == 255
    assert decoded.notes == [
        "16-bit samples with 12 significant bits (ingest.sample_bits) scaled to 8 bits by >> 4 "
        "(max 4095 -> 255)"
    ]


@pytest.mark.parametrize("bits", [8, 10, 14, 16])
def test_sample_bits_scale_other_bit_depths_to_full_range(gray: np.ndarray, bits: int) -> None:
    samples = camera_samples(gray, bits)
    image, notes = to_gray_uint8(samples, sample_bits=bits)
    np.testing.assert_array_equal(image, gray)
    assert not any("dark" in note or "clipped" in note for note in notes), notes


def with_sbit(png: bytes, payload: bytes) -> bytes:
    """The PNG with an sBIT chunk (correct CRC) right after its IHDR chunk."""
    chunk = b"sBIT" + payload
    ihdr_end = 8 + 12 + 13
    crc = struct.pack(">I", zlib.crc32(chunk) & 0xFFFFFFFF)
    return png[:ihdr_end] + struct.pack(">I", len(payload)) + chunk + crc + png[ihdr_end:]


def test_regression_declared_12_significant_bits_were_not_noted(
    tmp_path: Path, gray: np.ndarray
) -> None:
    """Bug (user audit): a 16-bit PNG whose sBIT chunk, or a PGM whose maximum value (4095),
    declares 12 significant bits was read at the default ingest.sample_bits = 16 without a
    word about the declaration. Now the frame's note names it and the value to set; the
    pixels are decoded as before (changing them would change existing runs' products)."""
    twelve = camera_samples(gray, 12)
    png = tmp_path / "sbit.png"
    png.write_bytes(with_sbit(encoded(".png", twelve), b"\x0c"))
    pgm = tmp_path / "max4095.pgm"
    pgm.write_bytes(b"P5\n64 48\n4095\n" + twelve.astype(">u2").tobytes())
    for path, source in ((png, "sBIT chunk"), (pgm, "maximum value 4095")):
        decoded = read_gray(path)
        np.testing.assert_array_equal(decoded.image, (twelve >> 8).astype(np.uint8))
        declared = [n for n in decoded.notes if "declares 12 significant bits" in n]
        assert len(declared) == 1, decoded.notes
        assert source in declared[0] and "set ingest.sample_bits = 12" in declared[0]
        # at the declared setting (or a 16-bit file that declares 16) there is nothing to say
        assert not any("declares" in n for n in read_gray(path, sample_bits=12).notes)
    full = tmp_path / "sbit16.png"
    full.write_bytes(with_sbit(encoded(".png", twelve << 4), b"\x10"))
    assert not any("declares" in n for n in read_gray(full).notes)
    # an 8-bit file's sBIT says nothing about 16-bit scaling
    eight = tmp_path / "sbit8.png"
    eight.write_bytes(with_sbit(encoded(".png", gray), b"\x06"))
    assert not any("declares" in n for n in read_gray(eight).notes)


def test_sample_bits_16_is_the_old_rule_bit_for_bit() -> None:
    samples = np.random.default_rng(3).integers(0, 65536, size=(40, 50), dtype=np.uint16)
    for image in (samples, samples >> 4, samples >> 9):  # full, 12-bit, 7-bit data
        default, notes = to_gray_uint8(image)
        explicit, explicit_notes = to_gray_uint8(image, sample_bits=16)
        np.testing.assert_array_equal(default, (image >> 8).astype(np.uint8))
        np.testing.assert_array_equal(explicit, default)
        assert explicit_notes == notes
        assert notes[0].startswith(f"16-bit samples scaled to 8 bits by >> 8 (max {image.max()}")


def test_dark_note_suggests_no_sample_bits_below_8(gray: np.ndarray) -> None:
    image, notes = to_gray_uint8(gray.astype(np.uint16) // 32)  # 3-bit data
    assert "the data uses only 3 bits" in notes[0] and "set ingest.sample_bits = 8" in notes[0]
    image, notes = to_gray_uint8(gray.astype(np.uint16) // 32, sample_bits=8)
    np.testing.assert_array_equal(image, gray // 32)
    assert "only 3 bits" in notes[0] and "sample_bits =" not in notes[0]  # nothing to set


def test_samples_above_sample_bits_are_clipped_and_noted(tmp_path: Path, gray: np.ndarray) -> None:
    samples = camera_samples(gray, 12)
    samples[0, :5] = [4096, 5000, 9000, 20000, 65535]
    path = write(tmp_path / "hot.tif", samples)
    decoded = read_gray(path, sample_bits=12)
    assert (decoded.image[0, :5] == 255).all()
    np.testing.assert_array_equal(decoded.image[1:], gray[1:])
    clipped = [note for note in decoded.notes if "clipped" in note]
    assert clipped == [
        f"5 samples of {path} are above 4095, the largest 12-bit value (max 65535, 16 bits), "
        "and were clipped to 255: ingest.sample_bits = 12 looks wrong for this file; leave "
        "ingest.sample_bits at 16"
    ]
    _image, notes = to_gray_uint8(samples[:4] // 8, sample_bits=10)  # max 8191: 13 bits
    assert "ingest.sample_bits = 10 looks wrong" in notes[1] and "sample_bits = 13" in notes[1]


def test_sample_bits_do_not_affect_8bit_and_float_images(tmp_path: Path, gray: np.ndarray) -> None:
    for path in (write(tmp_path / "g.png", gray), write(tmp_path / "f.tif", gray / 255.0)):
        plain = read_gray(path)
        decoded = read_gray(path, sample_bits=12)
        np.testing.assert_array_equal(decoded.image, plain.image)
        np.testing.assert_array_equal(decoded.image, gray)
        assert decoded.notes[0].endswith("samples: ingest.sample_bits = 12 does not apply")
        assert decoded.notes[1:] == plain.notes


def test_float_tiff_unit_and_255_ranges(tmp_path: Path, gray: np.ndarray) -> None:
    unit = gray.astype(np.float32) / 255.0
    decoded = read_gray(write(tmp_path / "u.tif", unit))
    np.testing.assert_array_equal(decoded.image, gray)
    assert any("[0, 1] scaled by 255" in note for note in decoded.notes)
    levels = np.minimum(gray.astype(np.float32) + 0.25, 255)
    decoded = read_gray(write(tmp_path / "l.tif", levels))
    np.testing.assert_array_equal(decoded.image, gray)
    assert any("[0, 255] rounded" in note for note in decoded.notes)


@pytest.mark.parametrize(
    ("bad_value", "fragments"),
    [
        (np.nan, ("1 NaN and 0 infinite pixels",)),
        (np.inf, ("0 NaN and 1 infinite pixels",)),
        (-np.inf, ("infinite",)),
        (-3.0, ("span [-3", "expected [0, 1] or [0, 255]")),
        (300.0, ("300]",)),
    ],
)
def test_float_tiff_bad_values_fail_the_frame(
    tmp_path: Path, gray: np.ndarray, bad_value: float, fragments: tuple[str, ...]
) -> None:
    image = gray.astype(np.float32)
    image[5, 7] = bad_value
    assert_frame_error(write(tmp_path / "bad.tif", image), *fragments)


@pytest.mark.parametrize("value", [0, 128, 255])
def test_constant_and_saturated_frames_decode(tmp_path: Path, value: int) -> None:
    image = np.full((40, 50), value, dtype=np.uint8)
    decoded = read_gray(write(tmp_path / "k.png", image))
    np.testing.assert_array_equal(decoded.image, image)
    assert decoded.notes == [f"constant frame: every pixel is {value}"]


def test_regression_multi_page_tiff_read_its_first_page_without_a_note(
    tmp_path: Path, gray: np.ndarray
) -> None:
    # a camera's left and right as two pages of one TIFF: the catalog names the file for
    # both sides and ingest read the first page twice, silently
    path = tmp_path / "pair.tif"
    assert cv2.imwritemulti(str(path), [gray, 255 - gray])
    decoded = read_gray(path)
    np.testing.assert_array_equal(decoded.image, gray)
    assert decoded.notes == ["the TIFF holds more than one page: only the first is read"]
    assert read_header(path.read_bytes()).more_pages
    single = write(tmp_path / "one.tif", gray)
    assert read_gray(single).notes == [] and not read_header(single.read_bytes()).more_pages


def test_extension_mismatch_is_noted(tmp_path: Path, gray: np.ndarray) -> None:
    path = tmp_path / "really_png.jpg"
    path.write_bytes(encoded(".png", gray))
    decoded = read_gray(path)
    np.testing.assert_array_equal(decoded.image, gray)
    assert decoded.format == "PNG"
    assert "content is PNG although the file name ends in .jpg" in decoded.notes


def pnm_bytes(samples: np.ndarray, maxval: int, *, plain: bool) -> bytes:
    """A PGM (2-D ``samples``) or PPM ((H, W, 3), RGB), binary or plain (ASCII)."""
    h, w = samples.shape[:2]
    colour = samples.ndim == 3
    magic = {(False, False): "P5", (True, False): "P6", (False, True): "P2", (True, True): "P3"}
    header = f"{magic[colour, plain]}\n{w} {h}\n{maxval}\n".encode()
    if plain:
        rows = (" ".join(str(int(v)) for v in row.ravel()) for row in samples)
        return header + "\n".join(rows).encode() + b"\n"
    return header + samples.astype(">u2" if maxval > 255 else np.uint8).tobytes()


def netpbm_full_scale(samples: np.ndarray, maxval: int) -> np.ndarray:
    """``value / maxval`` of full intensity as 8-bit gray levels, rounded to nearest."""
    return np.floor(samples.astype(np.float64) * 255 / maxval + 0.5).astype(np.uint8)


@pytest.mark.parametrize("maxval", [1, 100, 255, 4095, 65535])
@pytest.mark.parametrize("colour", [False, True], ids=["pgm", "ppm"])
def test_regression_binary_and_plain_pnm_of_one_image_decoded_differently(
    maxval: int, colour: bool
) -> None:
    """Bug (user PGMs): OpenCV left a binary (P5/P6) 8-bit file's samples as stored and
    scaled a plain (P2/P3) one's by value * 255 // maxval, so one image with maximum value
    100 decoded as gray levels 0-100 from P5 and 0-255 (rounded down) from P2. Now both
    are value / maxval of full scale, rounded to nearest; 16-bit files keep the
    sample_bits rule (>> 8 by default) in both encodings."""
    shape = (12, 17, 3) if colour else (12, 17)
    samples = np.random.default_rng(maxval).integers(0, maxval + 1, size=shape)
    samples.flat[:2] = (0, maxval)
    binary = decode_gray(pnm_bytes(samples, maxval, plain=False))
    plain = decode_gray(pnm_bytes(samples, maxval, plain=True))
    np.testing.assert_array_equal(binary.image, plain.image)
    assert binary.notes == plain.notes
    # 16-bit samples as stored (the sample_bits rule follows), 8-bit ones at full scale
    full = samples.astype(np.uint16) if maxval > 255 else netpbm_full_scale(samples, maxval)
    expected = to_gray_uint8(full[:, :, ::-1] if colour else full)[0]  # BGR, as OpenCV's
    np.testing.assert_array_equal(binary.image, expected)
    if maxval > 255 and not colour:
        np.testing.assert_array_equal(binary.image, (samples >> 8).astype(np.uint8))
    scaled = [n for n in binary.notes if f"maximum value {maxval} scaled to 0-255" in n]
    assert len(scaled) == (0 < maxval < 255)
    assert not any("exceed" in n for n in binary.notes)


def test_pnm_with_maximum_value_255_is_decoded_as_before(colour: np.ndarray) -> None:
    """The samples of 8-bit files at full scale are OpenCV's, bit for bit, without a note."""
    rgb = colour[:, :, ::-1]
    for samples in (colour[:, :, 0], rgb):
        for plain in (False, True):
            data = pnm_bytes(samples, 255, plain=plain)
            decoded = decode_gray(data)
            raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(decoded.image, to_gray_uint8(raw)[0])
            if samples.ndim == 2:
                np.testing.assert_array_equal(decoded.image, samples)
                assert decoded.notes == []


@pytest.mark.parametrize(
    ("maxval", "above", "plain"),
    # a binary 8-bit sample cannot exceed 255
    [(100, 200, False), (100, 200, True), (255, 300, True), (4095, 5000, False),
     (4095, 5000, True)],
)  # fmt: skip
def test_regression_samples_above_the_maximum_value_were_accepted_silently(
    tmp_path: Path, gray: np.ndarray, plain: bool, maxval: int, above: int
) -> None:
    """Bug (user PGMs): a P5 with maximum value 100 holding 200 decoded as 200, a P2 as
    255, both without a word. Such samples are clipped to the maximum value (full scale)
    in both encodings and the frame's note counts them, names the file and the largest
    value; the frame does not fail (its other pixels are good)."""
    samples = (gray.astype(np.int64) * maxval) // 255
    samples[3, 4:9] = above
    path = tmp_path / ("bad.pgm")
    path.write_bytes(pnm_bytes(samples, maxval, plain=plain))
    decoded = read_gray(path, sample_bits=maxval.bit_length() if maxval > 255 else 16)
    exceed = [n for n in decoded.notes if "exceed the header's maximum value" in n]
    assert len(exceed) == 1, decoded.notes
    assert exceed[0].startswith(f"5 of the {samples.size} samples of {path} ")
    assert f"maximum value {maxval} (up to {above}): clipped to {maxval}" in exceed[0]
    assert np.all(decoded.image[3, 4:9] == 255)
    within = np.minimum(samples, maxval)
    expected = (
        netpbm_full_scale(within, maxval)
        if maxval <= 255
        else to_gray_uint8(within.astype(np.uint16), sample_bits=maxval.bit_length())[0]
    )
    np.testing.assert_array_equal(decoded.image, expected)
    other = pnm_bytes(samples, maxval, plain=not plain) if maxval != 255 else None
    if other is not None:
        again = decode_gray(
            other, name=str(path), sample_bits=maxval.bit_length() if maxval > 255 else 16
        )
        np.testing.assert_array_equal(again.image, decoded.image)
        assert again.notes == decoded.notes


def test_plain_pnm_comments_and_leading_zeros_in_the_raster(gray: np.ndarray) -> None:
    samples = (gray[:4, :5].astype(np.int64) * 100) // 255
    values = [f"{int(v):04d}" for v in samples.ravel()]
    text = " ".join(values[:7]) + " # a comment 123 456\n" + "\n".join(values[7:]) + "\n"
    data = b"P2\n5 4\n# size above\n100\n" + text.encode()
    expected = decode_gray(pnm_bytes(samples, 100, plain=False))
    decoded = decode_gray(data)
    np.testing.assert_array_equal(decoded.image, expected.image)
    assert decoded.notes == expected.notes


# --- bad files ----------------------------------------------------------------------------


def test_missing_file_and_directory(tmp_path: Path) -> None:
    assert_frame_error(tmp_path / "absent.png", "missing file")
    assert_frame_error(tmp_path, "is a directory")


def test_regression_missing_file_message_did_not_say_where_to_look(
    tmp_path: Path, gray: np.ndarray
) -> None:
    # a user's index said pair01_left.png for PAIR01_LEFT.TIF, or a directory that is not
    # there: the message named the path only
    write(tmp_path / "PAIR01_LEFT.TIF", gray)
    message = assert_frame_error(tmp_path / "pair01_left.png", "missing file")
    assert f"{tmp_path} holds PAIR01_LEFT.TIF" in message and "case-sensitive" in message
    message = assert_frame_error(tmp_path / "sol 12" / "a.png", "missing file")
    assert f"its directory {tmp_path / 'sol 12'} does not exist either" in message
    assert "relative to the index CSV's directory" in message
    message = assert_frame_error(tmp_path / "other.png", "missing file")
    assert message.endswith("fix the path in the index, or remove the frame")
    message = assert_frame_error(tmp_path / "images\\sol12\\a.png", "missing file")
    assert "backslashes: write it with / in the index" in message


def test_zero_bytes_and_too_short(tmp_path: Path) -> None:
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    assert_frame_error(empty, "empty (zero bytes)")
    short = tmp_path / "short.tif"
    short.write_bytes(b"II*")
    assert_frame_error(short, "only 3 bytes long")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo")
def test_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    assert_frame_error(fifo, "not a regular file")


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() == 0,
    reason="running as root: root reads files whatever their permissions",
)
def test_unreadable_permissions(tmp_path: Path, gray: np.ndarray) -> None:
    path = write(tmp_path / "locked.png", gray)
    path.chmod(0)
    assert_frame_error(path, "permission denied")


@pytest.mark.parametrize("extension", EXTENSIONS)
@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.9, 0.999])
def test_truncated_files_are_refused(
    tmp_path: Path, gray: np.ndarray, extension: str, fraction: float
) -> None:
    data = encoded(extension, gray)
    path = tmp_path / f"cut{extension}"
    cut = min(int(len(data) * fraction), len(data) - 2)
    path.write_bytes(data[:cut])
    message = assert_frame_error(path)
    assert "truncated" in message or "corrupt" in message or "too short" in message


def test_truncated_png_jpeg_tiff_messages(tmp_path: Path, gray: np.ndarray) -> None:
    for extension, fragment in [
        (".png", "truncated PNG file"),
        (".jpg", "no end-of-image marker"),
        (".tif", "truncated TIFF file"),
    ]:
        data = encoded(extension, gray)
        path = tmp_path / f"t{extension}"
        path.write_bytes(data[: len(data) * 2 // 3])
        assert_frame_error(path, fragment, "cut short")


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b"GIF89a\x10\x00\x10\x00\x00\x00\x00;", "GIF is not a supported image format"),
        (b"RIFF\x00\x00\x00\x00WEBPVP8 ", "WebP is not a supported"),
        (b"P4\n8 8\n" + bytes(8), "PBM bitmap is not a supported"),
        (b"frame_id,left,right\nf1,a.png,b.png\n", "the file is text, not an image"),
        (bytes(range(200, 256)) * 4, "unrecognised content (first bytes c8 c9"),
    ],
)
def test_unsupported_formats(tmp_path: Path, content: bytes, fragment: str) -> None:
    path = tmp_path / "wrong.png"
    path.write_bytes(content)
    assert_frame_error(path, fragment, "PNG, JPEG, TIFF, PGM/PPM or BMP")


@pytest.mark.parametrize("extension", EXTENSIONS)
def test_random_bytes_with_image_extension(tmp_path: Path, extension: str) -> None:
    path = tmp_path / f"noise{extension}"
    path.write_bytes(np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    assert_frame_error(path)


def _png_claiming(width: int, height: int) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body)
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")


def test_huge_image_rejected_from_header_without_decoding(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_decoding(*args: object) -> None:
        raise AssertionError("cv2.imdecode must not be called for an oversized image")

    monkeypatch.setattr(_imageio.cv2, "imdecode", no_decoding)
    path = tmp_path / "huge.png"
    path.write_bytes(_png_claiming(100_000, 100_000))
    assert_frame_error(path, "100000x100000", "more than the limit of 67108864", "max_pixels")
    assert read_header(path.read_bytes()).width == 100_000


@pytest.mark.parametrize("extension", [".png", ".jpg", ".tif", ".pgm", ".ppm", ".bmp"])
def test_pixel_limit_applies_to_every_format(
    tmp_path: Path, colour: np.ndarray, extension: str
) -> None:
    image = colour[:, :, 0] if extension == ".pgm" else colour
    path = write(tmp_path / f"big{extension}", image)
    header = read_header(path.read_bytes())
    assert (header.height, header.width) == (48, 64)
    assert_frame_error(path, "48x64 (HxW) = 3072 pixels", max_pixels=3071)
    assert read_gray(path, max_pixels=3072).image.shape == (48, 64)


def test_file_much_larger_than_the_limit_is_not_read(tmp_path: Path) -> None:
    path = tmp_path / "sparse.tif"
    with open(path, "wb") as stream:
        stream.truncate(100_000_000)  # sparse: costs no disk
    assert_frame_error(path, "100000000 bytes", "more than an image", max_pixels=10)


def test_settings_are_validated(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="max_pixels must be an int"):
        read_gray(tmp_path / "x.png", max_pixels=1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_pixels must be >= 1"):
        read_gray(tmp_path / "x.png", max_pixels=0)
    with pytest.raises(TypeError, match="path must be a str"):
        read_gray(3)  # type: ignore[arg-type]
    for bad in (12.0, "12", True, None):
        with pytest.raises(TypeError, match=r"must be an int from 8 to 16, got .*without quotes"):
            read_gray(tmp_path / "x.png", sample_bits=bad)  # type: ignore[arg-type]
    for bad in (0, 7, 17, 32):
        with pytest.raises(ValueError, match=f"must be from 8 to 16, got {bad}; set it to"):
            read_gray(tmp_path / "x.png", sample_bits=bad)
        with pytest.raises(ValueError, match="leave it at 16"):
            to_gray_uint8(np.zeros((4, 4), np.uint16), sample_bits=bad)
    ok = write(tmp_path / "ok.png", np.zeros((8, 8), np.uint8))
    assert read_gray(ok, sample_bits=np.int64(8)).image.shape == (8, 8)
    assert_frame_error(Path("nul\x00byte.png"), "cannot be read")


# --- to_gray_uint8 on arrays ----------------------------------------------------------------


def test_to_gray_rejects_unsupported_sample_types() -> None:
    with pytest.raises(ValueError, match="int16 samples are not supported"):
        to_gray_uint8(np.zeros((4, 4), dtype=np.int16))
    with pytest.raises(ValueError, match="uint32 samples are not supported"):
        to_gray_uint8(np.zeros((4, 4, 3), dtype=np.uint32))  # before any colour conversion
    with pytest.raises(ValueError, match="5 channels"):
        to_gray_uint8(np.zeros((4, 4, 5), dtype=np.uint8))
    with pytest.raises(ValueError, match="2-D image"):
        to_gray_uint8(np.zeros((4,), dtype=np.uint8))
    image, notes = to_gray_uint8(np.full((3, 3, 2), 200, dtype=np.uint8))
    assert image.shape == (3, 3) and notes[0] == "alpha channel ignored"


# --- fuzzing: nothing but FrameError ----------------------------------------------------------

FUZZ = settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _decode_or_frame_error(data: bytes, name: str) -> None:
    try:
        decoded = decode_gray(data, name=name, max_pixels=1 << 20)
    except FrameError as exc:
        assert name in str(exc)
        return
    assert decoded.image.dtype == np.uint8 and decoded.image.ndim == 2


@FUZZ
@given(data=st.binary(max_size=512), extension=st.sampled_from([*EXTENSIONS, ".ppm", ".x"]))
def test_fuzz_random_bytes(data: bytes, extension: str) -> None:
    _decode_or_frame_error(data, f"fuzz{extension}")


_MAGIC = st.sampled_from(
    [b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff", b"II*\x00", b"MM\x00*", b"P5\n", b"P2 ", b"P6\n",
     b"BM", b"P3\n"]
)  # fmt: skip


@FUZZ
@given(magic=_MAGIC, tail=st.binary(max_size=512))
def test_fuzz_magic_then_random_bytes(magic: bytes, tail: bytes) -> None:
    _decode_or_frame_error(magic + tail, "fuzz.img")


@pytest.fixture(scope="module")
def valid_files() -> dict[str, bytes]:
    rng = np.random.default_rng(11)
    image = rng.integers(0, 256, size=(16, 20, 3), dtype=np.uint8)
    files = {ext: encoded(ext, image) for ext in (".png", ".jpg", ".tif", ".ppm", ".bmp")}
    files[".pgm"] = encoded(".pgm", image[:, :, 0])
    files[".tiff"] = encoded(".tif", image.astype(np.float32))
    files[".PNG"] = encoded(".png", image.astype(np.uint16) * 200)  # 16-bit
    return files


@FUZZ
@given(
    extension=st.sampled_from([".png", ".jpg", ".tif", ".ppm", ".bmp", ".pgm", ".tiff", ".PNG"]),
    cut=st.floats(0, 1),
    flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
)
def test_fuzz_truncated_and_corrupted_valid_files(
    valid_files: dict[str, bytes],
    extension: str,
    cut: float,
    flips: list[tuple[float, int]],
) -> None:
    data = bytearray(valid_files[extension])
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    _decode_or_frame_error(bytes(data[: max(1, int(cut * len(data)))]), f"fuzz{extension}")


def test_permission_denied_message_even_as_root(
    tmp_path: Path, gray: np.ndarray, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Root reads everything, so the permission branch is also exercised by simulation."""
    path = write(tmp_path / "locked.png", gray)

    def denied(*args: object, **kwargs: object) -> None:
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(_imageio, "open", denied, raising=False)
    assert_frame_error(path, "permission denied")


# --- corrupt JPEG scan data ---------------------------------------------------------------


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    rng = np.random.default_rng(12)
    yy, xx = np.mgrid[:96, :128]
    wave = 60 * np.sin(xx / 7.0) * np.cos(yy / 9.0)
    return (128 + wave + rng.normal(0, 20, yy.shape)).clip(0, 255).astype(np.uint8)


def _jpeg(image: np.ndarray, *params: int) -> bytes:
    ok, buffer = cv2.imencode(".jpg", image, list(params))
    assert ok
    return buffer.tobytes()


def _scan(data: bytes) -> tuple[int, int]:
    """Start (after the SOS header) and end (the final FF D9) of a JPEG's scan data."""
    sos = data.index(b"\xff\xda")
    start = sos + 2 + struct.unpack(">H", data[sos + 2 : sos + 4])[0]
    assert data.endswith(b"\xff\xd9")
    return start, len(data) - 2


def _zeroed_middle(data: bytes, count: int = 64) -> bytes:
    start, end = _scan(data)
    middle = (start + end) // 2
    return data[:middle] + bytes(count) + data[middle + count :]


def _flipped(data: bytes) -> bytes:
    start, end = _scan(data)
    damaged = bytearray(data)
    for k in range(1, 6):
        damaged[start + (end - start) * k // 7] ^= 0x5A
    return bytes(damaged)


def _cut_keeping_eoi(data: bytes) -> bytes:
    start, end = _scan(data)
    return data[: (start + end) // 2] + b"\xff\xd9"


def _colour(texture: np.ndarray) -> np.ndarray:
    return np.dstack([texture, np.roll(texture, 3, 0), np.roll(texture, 5, 1)])


JPEG_VARIANTS = {
    "baseline": (),
    "restart markers": (cv2.IMWRITE_JPEG_RST_INTERVAL, 2),
    "progressive": (cv2.IMWRITE_JPEG_PROGRESSIVE, 1),
    "optimised": (cv2.IMWRITE_JPEG_OPTIMIZE, 1),
}


@pytest.mark.parametrize("variant", list(JPEG_VARIANTS))
@pytest.mark.parametrize("channels", [1, 3])
def test_good_jpeg_decodes_as_opencv_does(
    tmp_path: Path, texture: np.ndarray, variant: str, channels: int, capfd: pytest.CaptureFixture
) -> None:
    image = texture if channels == 1 else _colour(texture)
    data = _jpeg(image, *JPEG_VARIANTS[variant])
    assert (b"\xff\xd0" in data) == (variant == "restart markers")  # RST0 markers
    path = tmp_path / "good.jpg"
    path.write_bytes(data)
    expected = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if channels == 3:
        expected = cv2.cvtColor(expected, cv2.COLOR_BGR2GRAY)
    decoded = read_gray(path)
    assert decoded.format == "JPEG"
    np.testing.assert_array_equal(decoded.image, expected)
    assert "JPEG" not in capfd.readouterr().err


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (_zeroed_middle, "corrupt JPEG data ("),
        (_flipped, "corrupt JPEG data ("),
        (_cut_keeping_eoi, "corrupt JPEG data (premature end of data segment)"),
    ],
)
@pytest.mark.parametrize("variant", list(JPEG_VARIANTS))
def test_corrupt_jpeg_scan_data_fails_the_frame(
    tmp_path: Path,
    texture: np.ndarray,
    damage: Callable[[bytes], bytes],
    reason: str,
    variant: str,
    capfd: pytest.CaptureFixture,
) -> None:
    path = tmp_path / "damaged.jpg"
    path.write_bytes(damage(_jpeg(_colour(texture), *JPEG_VARIANTS[variant])))
    message = assert_frame_error(path, reason, "re-export or replace the file")
    assert message.startswith(f"{path}: corrupt JPEG data (")
    # libjpeg's own line, which names no file, is not left on the process's stderr
    assert "Corrupt JPEG data" not in capfd.readouterr().err


def test_regression_corrupt_jpeg_scan_decoded_without_error(
    tmp_path: Path, texture: np.ndarray
) -> None:
    """Audit bug: a JPEG whose scan data was zeroed in the middle (FF D9 still at the end)
    decoded through cv2.imdecode with only libjpeg's "Corrupt JPEG data: ... extraneous bytes
    before marker 0xd9" on stderr, and the frame ended done with damaged pixels."""
    data = _jpeg(texture)
    damaged = _zeroed_middle(data)
    read_header(damaged)  # complete as far as the header check can tell
    pixels = cv2.imdecode(np.frombuffer(damaged, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    assert pixels is not None and not np.array_equal(pixels, decode_gray(data).image)
    path = tmp_path / "left_0007.jpg"
    path.write_bytes(damaged)
    assert_frame_error(path, "corrupt JPEG data (", "extraneous bytes before marker 0xd9")


def test_other_stderr_lines_during_a_jpeg_decode_are_passed_on(
    texture: np.ndarray, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture
) -> None:
    data = _jpeg(texture)
    imdecode = cv2.imdecode

    def chatty(buffer: np.ndarray, flags: int) -> np.ndarray | None:
        os.write(2, b"a line from another thread\n")
        return imdecode(buffer, flags)

    monkeypatch.setattr(_imageio.cv2, "imdecode", chatty)
    assert decode_gray(data, name="a.jpg").image.shape == texture.shape
    assert "a line from another thread" in capfd.readouterr().err


def test_concurrent_jpeg_decodes_each_get_their_own_verdict(texture: np.ndarray) -> None:
    good, bad = _jpeg(texture), _cut_keeping_eoi(_jpeg(texture))

    def verdict(index: int) -> bool:
        try:
            decode_gray(bad if index % 2 else good, name=f"f{index}.jpg")
        except FrameError as exc:
            assert f"f{index}.jpg" in str(exc)
            return False
        return True

    with ThreadPoolExecutor(max_workers=4) as pool:
        verdicts = list(pool.map(verdict, range(24)))
    assert verdicts == [index % 2 == 0 for index in range(24)]
