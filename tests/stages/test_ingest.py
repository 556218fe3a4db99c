"""The ingest stage on real PNG/TIFF/JPEG files written by OpenCV."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.camera import Camera
from pipeline.errors import FrameError, ParamError
from pipeline.stage import FrameContext
from stages._imageio import DEFAULT_MAX_PIXELS, DEFAULT_SAMPLE_BITS
from stages.ingest import STAGE, check_pair_shapes, run_ingest

CAMERA = Camera(focal_px=400.0, baseline_m=0.1)


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    right = cv2.GaussianBlur(rng.integers(0, 256, (60, 80), dtype=np.uint8), (0, 0), 2)
    left = np.roll(right, 4, axis=1)  # a constant disparity of 4 px
    return left, right


def write(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image)
    return path


def context(left: Path, right: Path, shape: tuple[int, int] | None = None) -> FrameContext:
    return FrameContext(
        frame_id="f1", archive="test", camera=CAMERA, left_path=left, right_path=right,
        image_shape=shape,
    )  # fmt: skip


def ingest(frame: FrameContext, **overrides: int):
    return run_ingest({}, frame=frame, params=STAGE.resolve_params(overrides))


@pytest.mark.parametrize("extension", [".png", ".tif"])
def test_lossless_pair_is_read_exactly(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray], extension: str
) -> None:
    left = write(tmp_path / f"l{extension}", pair[0])
    right = write(tmp_path / f"r{extension}", pair[1])
    result = ingest(context(left, right, shape=(60, 80)))
    np.testing.assert_array_equal(result.arrays["left"], pair[0])
    np.testing.assert_array_equal(result.arrays["right"], pair[1])
    for name, product in zip(("left", "right"), STAGE.outputs, strict=True):
        assert result.arrays[name].dtype == np.dtype(product.dtype)
    assert result.notes == []
    assert result.figures == {
        "left_sha256": hashlib.sha256(left.read_bytes()).hexdigest(),
        "right_sha256": hashlib.sha256(right.read_bytes()).hexdigest(),
    }


def test_jpeg_colour_pair_notes(tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]) -> None:
    tint = np.array([1.0, 0.8, 0.6])
    left = write(tmp_path / "l.jpg", (pair[0][..., None] * tint).astype(np.uint8))
    right = write(tmp_path / "r.jpg", (pair[1][..., None] * tint).astype(np.uint8))
    result = ingest(context(left, right))
    assert result.arrays["left"].shape == (60, 80)
    assert len(result.notes) == 1 and result.notes[0].startswith("left and right: colour")


def test_notes_differ_per_side(tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]) -> None:
    left = write(tmp_path / "l.png", pair[0].astype(np.uint16) * 257)
    right = write(tmp_path / "r.png", pair[1])
    result = ingest(context(left, right))
    np.testing.assert_array_equal(result.arrays["left"], pair[0])
    assert len(result.notes) == 1 and result.notes[0].startswith("left: 16-bit samples")


def test_left_right_size_mismatch_names_both(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    left = write(tmp_path / "l.png", pair[0])
    right = write(tmp_path / "r.png", pair[1][:50])
    with pytest.raises(FrameError) as info:
        ingest(context(left, right))
    message = str(info.value)
    for fragment in (str(left), str(right), "60x80", "50x80", "equal sizes"):
        assert fragment in message
    # regression: the message said what was wrong but not what to do
    assert "re-export both from the same rectified pair" in message


def test_frame_of_another_size_than_the_archive(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    left = write(tmp_path / "l.png", pair[0])
    right = write(tmp_path / "r.png", pair[1])
    with pytest.raises(FrameError, match="frame f1 is 60x80 but the archive's frames are 64x64"):
        ingest(context(left, right, shape=(64, 64)))
    # regression: a user with two cameras' frames in one index was told only to resize them
    with pytest.raises(FrameError, match="give frames of this size a catalog of their own"):
        ingest(context(left, right, shape=(64, 64)))


def test_regression_transposed_frames_shape_read_as_wrong_size_frames(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    # a user's catalog said `shape = [80, 60]` (width first) for 60x80 (HxW) frames: every
    # frame failed, told to resize its images
    left = write(tmp_path / "l.png", pair[0])
    right = write(tmp_path / "r.png", pair[1])
    with pytest.raises(FrameError) as info:
        ingest(context(left, right, shape=(80, 60)))
    message = str(info.value)
    assert "is 60x80 but the archive's frames are 80x60" in message
    assert "[H, W], rows first" in message and "shape = [60, 80]" in message


def test_bad_file_fails_the_frame_naming_it(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    left = write(tmp_path / "l.png", pair[0])
    data = (tmp_path / "l.png").read_bytes()
    right = tmp_path / "r.png"
    right.write_bytes(data[: len(data) // 2])
    with pytest.raises(FrameError, match=f"{right}: truncated PNG"):
        ingest(context(left, right))
    with pytest.raises(FrameError, match="missing file"):
        ingest(context(left, tmp_path / "absent.png"))
    with pytest.raises(FrameError, match="needs the left and right image paths"):
        ingest(context(left, None))  # type: ignore[arg-type]


def test_max_pixels_param(tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]) -> None:
    assert STAGE.defaults() == {"max_pixels": DEFAULT_MAX_PIXELS, "sample_bits": 16}
    left = write(tmp_path / "l.png", pair[0])
    right = write(tmp_path / "r.png", pair[1])
    with pytest.raises(
        FrameError, match=r"60x80 \(HxW\) = 4800 pixels, more than the limit of 4799"
    ):
        ingest(context(left, right), max_pixels=4799)
    assert ingest(context(left, right), max_pixels=4800).arrays["left"].shape == (60, 80)
    with pytest.raises(ParamError):
        STAGE.resolve_params({"max_pixels": 0})


def twelve_bit(image: np.ndarray) -> np.ndarray:
    """8-bit gray levels as the 12-bit samples of a camera (0 -> 0, 255 -> 4095)."""
    return image.astype(np.uint16) * 16 + image.astype(np.uint16) // 16


@pytest.mark.parametrize("extension", [".png", ".tif"])
def test_sample_bits_param_reads_12bit_pairs_at_full_range(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray], extension: str
) -> None:
    left = write(tmp_path / f"l{extension}", twelve_bit(pair[0]))
    right = write(tmp_path / f"r{extension}", twelve_bit(pair[1]))
    result = ingest(context(left, right), sample_bits=12)
    np.testing.assert_array_equal(result.arrays["left"], pair[0])
    np.testing.assert_array_equal(result.arrays["right"], pair[1])
    assert len(result.notes) == 1
    assert result.notes[0].startswith("left and right: 16-bit samples with 12 significant bits")
    dark = ingest(context(left, right))  # the default reads them as 16-bit data: dark
    assert int(dark.arrays["left"].max()) <= 15
    assert "set ingest.sample_bits = 12" in dark.notes[0]


def test_sample_bits_out_of_range_samples_are_clipped_and_noted_per_file(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    hot = twelve_bit(pair[0])
    hot[:2, :3] = 5000  # a 13-bit value: the setting is wrong for this file
    left = write(tmp_path / "l.png", hot)
    right = write(tmp_path / "r.png", twelve_bit(pair[1]))
    result = ingest(context(left, right), sample_bits=12)
    assert (result.arrays["left"][:2, :3] == 255).all()
    np.testing.assert_array_equal(result.arrays["left"][2:], pair[0][2:])
    clipped = [note for note in result.notes if "clipped" in note]
    assert len(clipped) == 1 and clipped[0].startswith(f"left: 6 samples of {left} ")
    assert "set ingest.sample_bits = 13" in clipped[0]


@pytest.mark.parametrize(
    ("value", "error", "fragment"),
    [
        (7, ParamError, "must be from 8 to 16, got 7"),
        (17, ParamError, "leave it at 16"),
        ("12", ParamError, "expects int, got str '12'"),
        (12.0, ParamError, "expects int, got float 12.0"),
        (True, ParamError, "expects int, got bool True"),
    ],
)
def test_sample_bits_param_is_validated(value: object, error: type, fragment: str) -> None:
    with pytest.raises(error, match=fragment):
        STAGE.resolve_params({"sample_bits": value})
    assert STAGE.resolve_params({"sample_bits": 8})["sample_bits"] == 8
    assert STAGE.resolve_params({})["sample_bits"] == DEFAULT_SAMPLE_BITS == 16


def test_sample_bits_at_its_default_is_left_out_of_the_cache_key() -> None:
    default = STAGE.resolve_params({})
    assert STAGE.key_params(default) == {"max_pixels": DEFAULT_MAX_PIXELS}
    assert STAGE.key_params(STAGE.resolve_params({"sample_bits": 16})) == STAGE.key_params(
        default
    )
    assert STAGE.key_params(STAGE.resolve_params({"sample_bits": 12}))["sample_bits"] == 12


def test_stage_declaration() -> None:
    assert STAGE.name == "ingest" and STAGE.inputs == ()
    assert STAGE.output_names == ("left", "right")
    for product in STAGE.outputs:
        assert product.dtype == "uint8" and product.kind == "array"
        assert {"units", "long_name"} <= set(product.attrs)


def test_check_pair_shapes_accepts_equal_sizes() -> None:
    check_pair_shapes((8, 9), (8, 9), frame_id="f", left_path="l", right_path="r")
    check_pair_shapes(
        (8, 9), (8, 9), frame_id="f", left_path="l", right_path="r", archive_shape=(8, 9)
    )


@pytest.mark.parametrize("shape", [(1, 1), (7, 40)])
def test_frame_under_the_smallest_side_fails_naming_its_files(
    tmp_path: Path, shape: tuple[int, int]
) -> None:
    """Bug: a 1x1 frame (alone or the archive's size) passed ingest and depth and failed at
    segment with 'sectors must be in [2, 0]', naming no file."""
    image = np.full(shape, 128, np.uint8)
    left, right = write(tmp_path / "l.png", image), write(tmp_path / "r.png", image)
    with pytest.raises(FrameError, match=r"l\.png and .*r\.png are .* smaller than the 8x8"):
        ingest(context(left, right, shape=shape))


def test_regression_same_image_on_both_sides_ran_done(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    # one file named for both sides of an index row (or a copy of it) ran 'done' with zero
    # disparity everywhere
    left = write(tmp_path / "l.png", pair[0])
    copy = write(tmp_path / "copy.tif", pair[0])
    with pytest.raises(FrameError, match=r"l\.png is the same file as right image .*l\.png"):
        ingest(context(left, left))
    with pytest.raises(FrameError, match=r"l\.png has the same pixels as right image .*copy"):
        ingest(context(left, copy))
    # two constant frames (a lens cap) are not a catalog mistake: noted, not failed
    cap_l = write(tmp_path / "cap_l.png", np.zeros((60, 80), np.uint8))
    cap_r = write(tmp_path / "cap_r.tif", np.zeros((60, 80), np.uint8))
    assert "constant frame" in " ".join(ingest(context(cap_l, cap_r)).notes)


def test_regression_rectification_fill_became_an_obstacle_without_a_note(
    tmp_path: Path, pair: tuple[np.ndarray, np.ndarray]
) -> None:
    # rectified frames with black wedges along the border: segmentation returned the fill
    # as one large 'obstacle' per frame, and nothing said why
    left, right = (np.maximum(image, 1) for image in pair)  # no natural zeros
    plain = ingest(context(write(tmp_path / "l.png", left), write(tmp_path / "r.png", right)))
    assert plain.notes == []
    ys, xs = np.indices(left.shape)
    wedge = xs < 6 + ys // 10  # about 10 % of the frame along the left border
    left[wedge], right[wedge] = 0, 0
    left[20:40, 30:50] = 0  # black inside the frame is content, not fill
    result = ingest(context(write(tmp_path / "l2.png", left), write(tmp_path / "r2.png", right)))
    (note,) = result.notes
    assert note.startswith(f"left and right: {wedge.mean():.1%} of the frame is black (0) fill")
    assert "segmentation leaves it out" in note
