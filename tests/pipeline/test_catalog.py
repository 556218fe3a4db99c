"""Survey catalog loading: valid catalogs, every validation error, and fuzzing."""

from __future__ import annotations

import hashlib
import os
import sys
import types
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.camera import Camera
from pipeline.catalog import Catalog, load_catalog
from pipeline.errors import CatalogError

VALID_TOML = """\
[archive]
name = "mojave"
description = "Mojave desert rock field"

[camera]
focal_px = 430.0
baseline_m = 0.10
height_m = 1.0
pitch_deg = 38.0
reference = "right"

[frames]
index = "frames.csv"
"""

VALID_CSV = "frame_id,left,right\nf001,images/f001_l.png,images/f001_r.png\n"


def write_catalog(
    directory: Path, toml: str = VALID_TOML, csv: str | None = VALID_CSV, name: str = "cat.toml"
) -> Path:
    path = directory / name
    path.write_text(toml, encoding="utf-8")
    if csv is not None:
        (directory / "frames.csv").write_text(csv, encoding="utf-8")
    return path


def assert_error(path: Path, *fragments: str) -> str:
    with pytest.raises(CatalogError) as info:
        load_catalog(path)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


# --- valid catalogs ---------------------------------------------------------------------


def test_valid_catalog_with_metadata_overrides_and_paths(tmp_path: Path) -> None:
    images = tmp_path / "elsewhere"
    toml = VALID_TOML.replace('index = "frames.csv"', 'index = "idx/frames.csv"\nshape = [48, 64]')
    toml += '\n[truth]\ndir = "truth"\n\n[params]\ndepth = { max_disparity = 64 }\n'
    toml += '[params.segment]\nmethod = "adaptive"\nsmooth = true\n'
    (tmp_path / "idx").mkdir()
    csv = (
        "frame_id,left,right,site,count,sun_deg,baseline_m,pitch_deg\n"
        f"a.1,l1.png,r1.png,north,3,12,0.2,\n"
        f"b_2,{images}/l2.png,../r2.png,south,4,12.5,,10\n"
        f"c-3,l3.png,r3.png,,,,,\n"
    )
    (tmp_path / "idx" / "frames.csv").write_text(csv)
    path = write_catalog(tmp_path, toml, csv=None)

    catalog = load_catalog(os.path.relpath(path))  # a relative catalog path works too
    assert isinstance(catalog, Catalog)
    assert catalog.path == path and catalog.source == path
    assert catalog.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert catalog.name == "mojave"
    assert catalog.description == "Mojave desert rock field"
    assert catalog.camera == Camera(430.0, 0.10, height_m=1.0, pitch_deg=38.0)
    assert catalog.shape == (48, 64)
    assert catalog.truth_dir == tmp_path / "truth"
    assert catalog.index_path == tmp_path / "idx" / "frames.csv"
    assert catalog.params == {
        "depth": {"max_disparity": 64},
        "segment": {"method": "adaptive", "smooth": True},
    }
    a, b, c = catalog.frames
    assert [f.frame_id for f in catalog.frames] == ["a.1", "b_2", "c-3"]
    # paths relative to the CSV's directory, or absolute
    assert a.left == tmp_path / "idx" / "l1.png" and a.left.is_absolute()
    assert b.left == images / "l2.png"
    assert b.right == tmp_path / "r2.png"
    # metadata typed per column; empty cells are None
    assert a.metadata == {"site": "north", "count": 3, "sun_deg": 12.0}
    assert isinstance(a.metadata["sun_deg"], float)
    assert b.metadata == {"site": "south", "count": 4, "sun_deg": 12.5}
    assert c.metadata == {"site": None, "count": None, "sun_deg": None}
    # per-frame overrides; an empty cell keeps the catalog's value
    assert a.overrides == {"baseline_m": 0.2}
    assert a.camera.baseline_m == 0.2 and a.camera.pitch_deg == 38.0
    assert b.overrides == {"pitch_deg": 10.0}
    assert b.camera.baseline_m == 0.10 and b.camera.pitch_deg == 10.0
    assert c.overrides == {} and c.camera == catalog.camera


def test_minimal_catalog_defaults(tmp_path: Path) -> None:
    toml = '[archive]\nname = "x"\n[camera]\nfocal_px = 100\nbaseline_m = 1\n'
    toml += '[frames]\nindex = "frames.csv"\n'
    catalog = load_catalog(write_catalog(tmp_path, toml))
    assert catalog.description == ""
    assert catalog.camera == Camera(100.0, 1.0)
    assert catalog.params == {} and catalog.truth_dir is None and catalog.shape is None
    assert len(catalog.frames) == 1 and catalog.frames[0].metadata == {}


def test_does_not_check_that_images_exist(tmp_path: Path) -> None:
    catalog = load_catalog(write_catalog(tmp_path))
    assert not catalog.frames[0].left.exists()


def test_csv_with_bom_crlf_quotes_and_blank_lines(tmp_path: Path) -> None:
    csv = '\ufeffframe_id,left,right,note\r\n\r\nf1,"a b.png",r.png,"x, y"\r\n\r\n'
    catalog = load_catalog(write_catalog(tmp_path, csv=csv))
    assert catalog.frames[0].left == tmp_path / "a b.png"
    assert catalog.frames[0].metadata == {"note": "x, y"}


# --- [synth] catalogs ---------------------------------------------------------------------


@pytest.fixture
def fake_synth(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[tuple]:
    calls: list[tuple] = []
    rendered = tmp_path / "cache" / "lab"
    rendered.mkdir(parents=True)
    toml = VALID_TOML.replace('"mojave"', '"lab_rendered"') + "[params]\ndepth = { a = 1, b = 2 }\n"
    write_catalog(rendered, toml, name="catalog.toml")

    def ensure_archive(archetype, *, frames, seed, variant=None):
        calls.append((archetype, frames, seed, variant))
        if archetype == "nope":
            raise ValueError("unknown archetype 'nope'")
        return rendered / "catalog.toml"

    module = types.ModuleType("pipeline.synth")
    module.ensure_archive = ensure_archive  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "pipeline.synth", module)
    return calls


def test_synth_catalog_loads_the_rendered_archive(tmp_path: Path, fake_synth: list) -> None:
    toml = '[archive]\nname = "lab"\n[synth]\narchetype = "lab"\nframes = 4\nseed = 7\n'
    toml += "[params]\ndepth = { b = 3 }\n"
    path = write_catalog(tmp_path, toml, csv=None, name="lab.toml")
    catalog = load_catalog(path)
    assert fake_synth == [("lab", 4, 7, None)]
    assert catalog.source == path
    assert catalog.path == tmp_path / "cache" / "lab" / "catalog.toml"
    assert catalog.sha256 == hashlib.sha256(catalog.path.read_bytes()).hexdigest()
    assert catalog.name == "lab"
    assert catalog.description == "Mojave desert rock field"  # the rendered one's
    assert catalog.params == {"depth": {"a": 1, "b": 3}}
    assert catalog.frames[0].left == tmp_path / "cache" / "lab" / "images" / "f001_l.png"


def test_synth_catalog_errors(tmp_path: Path, fake_synth: list) -> None:
    base = '[archive]\nname = "lab"\n[synth]\narchetype = "nope"\nframes = 4\nseed = 7\n'
    path = write_catalog(tmp_path, base, csv=None, name="lab.toml")
    assert_error(path, "lab.toml", "line 3", "[synth]", "unknown archetype 'nope'")
    write_catalog(tmp_path, base.replace("frames = 4", "frames = 0"), csv=None, name="lab.toml")
    assert_error(path, "lab.toml", "line 5", "[synth] frames", ">= 1")
    write_catalog(tmp_path, base.replace("seed = 7", 'seed = "7"'), csv=None, name="lab.toml")
    assert_error(path, "line 6", "[synth] seed", "expected an integer")
    write_catalog(tmp_path, base + "[camera]\nfocal_px = 1\n", csv=None, name="lab.toml")
    assert_error(path, "line 7", "[camera]", "remove [camera]")


# --- catalog (TOML) errors ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "fragments"),
    [
        ("focal_px = 430.0", "focal_px = 430.0 ]", ("cat.toml: line 6: malformed TOML", "column")),
        ("focal_px = 430.0", "focal_px = -430.0", ("line 6", "[camera] focal_px", "> 0")),
        ("focal_px = 430.0", "focal_px = 0", ("line 6", "[camera] focal_px", "> 0")),
        ("baseline_m = 0.10", "baseline_m = -0.1", ("line 7", "[camera] baseline_m", "> 0")),
        ("baseline_m = 0.10", "baseline_m = nan", ("line 7", "baseline_m", "finite number")),
        ("focal_px = 430.0", 'focal_px = "430"', ("line 6", "focal_px", "finite number")),
        ("focal_px = 430.0", "focal_px = true", ("line 6", "focal_px", "finite number")),
        ("focal_px = 430.0\n", "", ("line 5", "[camera]", "missing required key 'focal_px'")),
        ("pitch_deg = 38.0", "pitch_deg = 95", ("line 9", "pitch_deg", "[0, 90)")),
        ("height_m = 1.0", "height_m = -1.0", ("line 8", "height_m", "> 0")),
        ('reference = "right"', 'reference = "up"', ("line 10", "reference", "'right' or 'left'")),
        ('reference = "right"', 'refrence = "right"', ("line 10", "[camera] refrence", "unknown")),
        ('"mojave"', '"Mojave Desert"', ("line 2", "[archive] name", "[a-z0-9_-]+")),
        ('name = "mojave"\n', "", ("line 1", "[archive]", "missing required key 'name'")),
        ('name = "mojave"', "name = 3", ("line 2", "[archive] name", "expected a string")),
        ('description = "Mojave desert rock field"', "description = 1", ("line 3", "description")),
        ('index = "frames.csv"', "index = 1", ("line 13", "[frames] index", "expected a string")),
        ('index = "frames.csv"\n', "", ("line 12", "[frames]", "missing required key 'index'")),
        ('index = "frames.csv"', 'index = "frames.csv"\nshape = [0, 2]', ("line 14", "shape")),
        ('index = "frames.csv"', 'index = "f.csv"\nshape = [2]', ("line 14", "[H, W]")),
        ("[camera]", "[camra]", ("line 5", "unknown table or key 'camra'")),
        ("[frames]", "[frame]", ("line 12", "'frame'")),
    ],
)
def test_toml_errors_name_file_field_and_line(
    tmp_path: Path, old: str, new: str, fragments: tuple[str, ...]
) -> None:
    assert old in VALID_TOML
    path = write_catalog(tmp_path, VALID_TOML.replace(old, new, 1))
    assert_error(path, "cat.toml", *fragments)


@pytest.mark.parametrize(
    ("extra", "fragments"),
    [
        ("[truth]\n", ("line 15", "[truth]", "missing required key 'dir'")),
        ("[truth]\ndir = 5\n", ("line 16", "[truth] dir", "expected a string")),
        ("[params]\ndepth = 3\n", ("line 16", "[params] depth", "table of parameters")),
        ("[params]\ndepth = { a = [1, 2] }\n", ("line 16", "depth.a", "number, string")),
        ("[params]\ndepth = { a = inf }\n", ("line 16", "depth.a", "finite")),
        ("[params.depth]\na = {b = 1}\n", ("line 15", "depth.a", "number, string")),
        ("top = 1\n", ("line 15", "[frames] top", "unknown key", "index, shape")),
    ],
)
def test_optional_table_errors(tmp_path: Path, extra: str, fragments: tuple[str, ...]) -> None:
    path = write_catalog(tmp_path, VALID_TOML + "\n" + extra)
    assert_error(path, "cat.toml", *fragments)


def test_missing_tables(tmp_path: Path) -> None:
    path = write_catalog(tmp_path, '[archive]\nname = "x"\n')
    assert_error(path, "cat.toml", "missing required table [camera]")
    path = write_catalog(tmp_path, VALID_TOML.split("[frames]")[0])
    assert_error(path, "cat.toml", "missing required table [frames]")
    path = write_catalog(tmp_path, "[camera]" + VALID_TOML.split("[camera]")[1])
    assert_error(path, "cat.toml", "missing required table [archive]")


def test_unknown_top_level_key(tmp_path: Path) -> None:
    path = write_catalog(tmp_path, "version = 2\n" + VALID_TOML)
    assert_error(path, "cat.toml", "line 1", "unknown table or key 'version'", "[archive]")


def test_duplicate_key_is_malformed_toml_with_line(tmp_path: Path) -> None:
    path = write_catalog(tmp_path, VALID_TOML.replace("height_m = 1.0", "focal_px = 1.0"))
    assert_error(path, "cat.toml", "line 8", "malformed TOML")


def test_missing_unreadable_and_binary_catalog_files(tmp_path: Path) -> None:
    assert_error(tmp_path / "absent.toml", "absent.toml", "does not exist")
    assert_error(tmp_path, str(tmp_path), "is a directory")
    garbage = tmp_path / "garbage.toml"
    garbage.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe" + bytes(range(256)))
    assert_error(garbage, "garbage.toml", "line 1", "not valid UTF-8")
    garbage.write_bytes(b"\x00\x01\x02 = \x03\n")
    assert_error(garbage, "garbage.toml", "malformed TOML")
    with pytest.raises(TypeError, match="str or os.PathLike"):
        load_catalog(3)  # type: ignore[arg-type]


# --- frame index (CSV) errors -------------------------------------------------------------


@pytest.mark.parametrize(
    ("csv", "fragments"),
    [
        ("", ("frames.csv", "empty")),
        ("frame_id,left,right\n", ("frames.csv", "no frames")),
        ("frame_id,left\nf1,a.png\n", ("frames.csv", "line 1", "right")),
        ("id,left,right\nf1,a,b\n", ("frames.csv", "line 1", "frame_id")),
        ("frame_id,left,right\nf1,a,b\n,c,d\n", ("line 3", "empty cell", "'frame_id'")),
        ("frame_id,left,right\nf1,,b\n", ("line 2", "empty cell", "'left'")),
        ("frame_id,left,right\nf1,a, \n", ("line 2", "empty cell", "'right'")),
        ("frame_id,left,right\nf1,a,b\nf2,c,d\nf1,e,f\n", ("line 4", "duplicate", "line 2")),
        ("frame_id,left,right\nf 1,a,b\n", ("line 2", "frame_id 'f 1'", "safe in file names")),
        (
            "frame_id,left,right\n../x,a,b\n",
            (
                "line 2",
                "frame_id '../x'",
            ),
        ),
        ("frame_id,left,right\n..,a,b\n", ("line 2", "frame_id '..'")),
        ("frame_id,left,right\nf1,a,b,c\n", ("line 2", "expected 3 cells", "got 4")),
        ("frame_id,left,right\nf1,a\n", ("line 2", "expected 3 cells", "got 2")),
        ("frame_id,left,right,left\nf1,a,b,c\n", ("line 1", "'left' appears twice")),
        ("frame_id,left,right,\nf1,a,b,c\n", ("line 1", "header cell 4 is empty")),
        ("frame_id,left,right,focal_px\nf1,a,b,wide\n", ("line 2", "'focal_px'", "finite")),
        ("frame_id,left,right,baseline_m\nf1,a,b,1\nf2,c,d,-2\n", ("line 3", "> 0")),
        ("frame_id,left,right,pitch_deg\nf1,a,b,90\n", ("line 2", "[0, 90)")),
        ("frame_id,left,right,cx\nf1,a,b,inf\n", ("line 2", "'cx'", "finite")),
        ('frame_id,left,right\nf1,"a,b\n', ("frames.csv", "line")),
    ],
)
def test_index_errors_name_file_and_line(
    tmp_path: Path, csv: str, fragments: tuple[str, ...]
) -> None:
    assert_error(write_catalog(tmp_path, csv=csv), *fragments)


def test_index_unreadable(tmp_path: Path) -> None:
    path = write_catalog(tmp_path, csv=None)
    assert_error(path, "frames.csv", "does not exist", "[frames] index")
    (tmp_path / "frames.csv").mkdir()
    assert_error(path, "frames.csv", "is a directory")
    (tmp_path / "frames.csv").rmdir()
    (tmp_path / "frames.csv").write_bytes(b"frame_id,left,right\nf1,\xff\xfe,b\n")
    assert_error(path, "frames.csv", "line 2", "UTF-8")


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() == 0,
    reason="running as root: root reads files whatever their permissions",
)
def test_index_without_read_permission(tmp_path: Path) -> None:
    path = write_catalog(tmp_path)
    (tmp_path / "frames.csv").chmod(0)
    assert_error(path, "frames.csv", "permission denied")


# --- fuzzing: nothing but CatalogError ------------------------------------------------------

FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

_KEYS = st.sampled_from(
    ["name", "description", "focal_px", "baseline_m", "height_m", "pitch_deg", "reference",
     "cx", "cy", "index", "shape", "dir", "archetype", "frames", "seed", "variant", "depth",
     "max_disparity", "bogus", "a.b", '"quoted"']
)  # fmt: skip
_VALUES = st.sampled_from(
    ['"mojave"', '"Bad Name"', '"frames.csv"', '"right"', '"left"', '""', "430.0", "0", "-1",
     "1e400", "nan", "inf", "-inf", "99999999999999999999999999", "true", "[1, 2]", "[48, 64]",
     "[]", "[[1]]", "{}", "{ a = 1 }", "{ a = { b = 1 } }", "1979-05-27", '"\\u0000"', "[",
     '"a', "'x'", "0x10", "1_000"]
)  # fmt: skip
_HEADERS = st.sampled_from(
    ["[archive]", "[camera]", "[frames]", "[truth]", "[params]", "[params.depth]", "[synth]",
     "[bogus]", "[[frames]]", "[camera.x]", "[archive"]
)  # fmt: skip
_TOML_LINES = st.one_of(_HEADERS, st.builds(lambda k, v: f"{k} = {v}", _KEYS, _VALUES))


def _assert_only_catalog_error(path: Path) -> None:
    try:
        load_catalog(path)
    except CatalogError:
        pass


@FUZZ
@given(text=st.text(max_size=300))
def test_fuzz_arbitrary_text(tmp_path: Path, text: str) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    (tmp_path / "frames.csv").write_text(VALID_CSV)
    _assert_only_catalog_error(path)


@FUZZ
@given(data=st.binary(max_size=300))
def test_fuzz_binary(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_bytes(data)
    _assert_only_catalog_error(path)


@FUZZ
@given(lines=st.lists(_TOML_LINES, max_size=25))
def test_fuzz_tomlish_documents(tmp_path: Path, lines: list[str]) -> None:
    (tmp_path / "frames.csv").write_text(VALID_CSV)
    _assert_only_catalog_error(write_catalog(tmp_path, "\n".join(lines), csv=None))


_CELLS = st.one_of(
    st.sampled_from(["f1", "f1", "a.png", "", " ", "1", "-2", "0.5", "1e999", "nan", '"', "x,y"]),
    st.text(max_size=8),
)
_COLUMNS = st.sampled_from(
    ["frame_id", "left", "right", "baseline_m", "focal_px", "pitch_deg", "cx", "site", ""]
)


@FUZZ
@given(
    header=st.lists(_COLUMNS, min_size=0, max_size=6),
    rows=st.lists(st.lists(_CELLS, max_size=7), max_size=6),
    raw=st.text(max_size=200),
    use_raw=st.booleans(),
)
def test_fuzz_index_csv(
    tmp_path: Path, header: list[str], rows: list[list[str]], raw: str, use_raw: bool
) -> None:
    text = raw if use_raw else "\n".join(",".join(r) for r in [header, *rows])
    path = write_catalog(tmp_path, csv=None)
    (tmp_path / "frames.csv").write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        catalog = load_catalog(path)
    except CatalogError:
        return
    ids = [frame.frame_id for frame in catalog.frames]
    assert ids and len(set(ids)) == len(ids)
    assert all(frame.left.is_absolute() and frame.right.is_absolute() for frame in catalog.frames)


@FUZZ
@given(
    replacements=st.lists(st.tuples(st.integers(0, 12), _VALUES), max_size=3),
    extra=st.lists(_TOML_LINES, max_size=4),
)
def test_fuzz_mutated_valid_catalog(
    tmp_path: Path, replacements: list[tuple[int, str]], extra: list[str]
) -> None:
    lines = VALID_TOML.splitlines()
    for number, value in replacements:
        if " = " in lines[number]:
            lines[number] = lines[number].split(" = ")[0] + " = " + value
    path = write_catalog(tmp_path, "\n".join(lines + extra))
    _assert_only_catalog_error(path)


def test_permission_denied_message_even_as_root(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Root reads everything, so the permission branch is also exercised by simulation."""
    path = write_catalog(tmp_path)
    real_read_bytes = Path.read_bytes

    def read_bytes(self: Path) -> bytes:
        if self.name == "frames.csv":
            raise PermissionError(13, "Permission denied", str(self))
        return real_read_bytes(self)

    monkeypatch.setattr(Path, "read_bytes", read_bytes)
    assert_error(path, "frames.csv", "permission denied")


def test_name_of_a_builtin_archive_points_at_its_catalog(tmp_path: Path) -> None:
    """`arroyo run lab` (a built-in archive's name, not a path) said only that the file does
    not exist; the message now gives the shipped catalog's path."""
    shipped = Path(__file__).resolve().parents[2] / "catalogs" / "lab.toml"
    assert_error(tmp_path / "lab", "does not exist", f"catalog is {shipped}")


@pytest.mark.parametrize(
    "column", ["notes", "status", "index", "error", "archive", "run_id", "run"]
)
def test_regression_metadata_column_named_like_a_frames_column_was_lost(
    tmp_path: Path, column: str
) -> None:
    # a user's `notes` column was dropped from frames.parquet without a word, and an
    # `archive` or `run_id` column replaced the real ones in `arroyo query`
    csv = f"frame_id,left,right,sol,{column}\nf1,a.png,b.png,12,x\n"
    assert_error(
        write_catalog(tmp_path, csv=csv), "frames.csv", "line 1", repr(column), f"my_{column}"
    )


def test_regression_missing_index_named_neither_the_catalog_nor_its_line(tmp_path: Path) -> None:
    # a catalog in another directory than its index: the message named only the CSV path
    (tmp_path / "catalogs").mkdir()
    path = write_catalog(tmp_path / "catalogs", csv=None)
    message = assert_error(path, "cat.toml", "line 13", "[frames] index", "does not exist")
    assert str(tmp_path / "catalogs" / "frames.csv") in message
    assert f"catalog's directory {tmp_path / 'catalogs'}" in message


def test_regression_home_relative_paths_were_taken_as_relative_to_the_csv(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `~/data/l.png` in a user's index read '.../catalog dir/~/data/l.png': missing file
    home = tmp_path / "home"
    (home / "survey").mkdir(parents=True)
    monkeypatch.setenv("HOME", str(home))
    (home / "survey" / "frames.csv").write_text("frame_id,left,right\nf1,~/data/l.png,r.png\n")
    toml = VALID_TOML.replace('index = "frames.csv"', 'index = "~/survey/frames.csv"')
    toml += '\n[truth]\ndir = "~/truth"\n'
    catalog = load_catalog(write_catalog(tmp_path, toml, csv=None))
    assert catalog.index_path == home / "survey" / "frames.csv"
    assert catalog.truth_dir == home / "truth"
    (frame,) = catalog.frames
    assert frame.left == home / "data" / "l.png"
    assert frame.right == home / "survey" / "r.png"


@pytest.mark.parametrize("sep", [";", "\t"])
def test_regression_semicolon_index_from_a_spreadsheet_gave_no_hint(
    tmp_path: Path, sep: str
) -> None:
    # a European spreadsheet's CSV export: the header read as one column
    csv = sep.join(["frame_id", "left", "right"]) + "\n" + sep.join(["f1", "a", "b"]) + "\n"
    assert_error(
        write_catalog(tmp_path, csv=csv), "line 1", f"separated by {sep!r}", "with commas"
    )
