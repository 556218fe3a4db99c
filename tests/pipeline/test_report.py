"""arroyo report: one self-contained HTML page per run, for runs with failed frames, without
rocks, with many frames, and while a run is writing."""

from __future__ import annotations

import base64
import json
import re
import statistics
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import zarr
from test_query import make_run

from pipeline._report_figures import relation_counts, scene_graph_caption, scene_graph_image
from pipeline._report_html import esc
from pipeline.cli import main
from pipeline.errors import ParamError, RunDirError
from pipeline.lock import RunLock
from pipeline.report import build_report
from stages.quicklook import objects_image


class _Page(HTMLParser):
    """Collects the elements the assertions look at."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[dict[str, str]] = []
        self.frames: list[dict[str, str]] = []
        self.external: list[str] = []
        self.tags: list[str] = []
        self.rows_in_frame: dict[str, int] = {}
        self._frame: str | None = None
        self._in_rocks = False

    def handle_starttag(self, tag, attrs):
        a = {k: v or "" for k, v in attrs}
        self.tags.append(tag)
        if tag == "img":
            self.images.append({**a, "frame": self._frame or ""})
        if tag == "details" and "frame" in a.get("class", ""):
            self.frames.append(a)
            self._frame = a["data-id"]
            self.rows_in_frame[self._frame] = 0
        for key in ("src", "href"):
            value = a.get(key, "")
            if value and not value.startswith(("data:", "#")):
                self.external.append(value)
        if tag == "tbody" and self._frame is not None:
            self._in_rocks = True
        if tag == "tr" and self._in_rocks and self._frame is not None:
            self.rows_in_frame[self._frame] += 1

    def handle_endtag(self, tag):
        if tag == "tbody":
            self._in_rocks = False
        if tag == "details":
            self._frame = None


def _parse(path: Path) -> tuple[str, _Page]:
    text = path.read_text()
    page = _Page()
    page.feed(text)
    return text, page


def _decode_png(src: str) -> np.ndarray:
    assert src.startswith("data:image/png;base64,")
    data = base64.b64decode(src.split(",", 1)[1])
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.size > 0
    return image


def test_report_of_a_run_with_failed_frames(tmp_path):
    run = make_run(tmp_path / "lab", frames=4, failed=(1,), rocks=5, evaluation=True)
    path = build_report(run)
    assert path == run / "report.html"
    text, page = _parse(path)
    frames = pq.read_table(run / "frames.parquet").to_pylist()
    # summary: counts, the failure with its error, stage versions, time per stage
    assert re.search(r'<div class="value">3</div><div class="label">done</div>', text)
    assert re.search(r'<div class="value">1</div><div class="label">failed</div>', text)
    assert "depth: no valid disparity in frame lab_001" in text
    depth_times = [f["depth_seconds"] for f in frames if f["depth_seconds"] is not None]
    assert f"{statistics.fmean(depth_times):.3f}" in text
    assert "<code>{&quot;step&quot;: 0.25}</code>" in text
    # evaluation pivot: one column per method
    assert '<th class="num">opencv-sgbm</th>' in text
    # every frame listed, the failed one flagged, rock tables match the descriptors
    assert [f["data-id"] for f in page.frames] == [f["frame_id"] for f in frames]
    assert [f["data-status"] for f in page.frames] == [f["status"] for f in frames]
    desc = pq.read_table(run / "descriptors.parquet", partitioning=None).to_pylist()
    for f in frames:
        want = sum(1 for d in desc if d["frame_id"] == f["frame_id"])
        assert page.rows_in_frame[f["frame_id"]] == want
    # images: all decodable PNG data URIs; nothing fetched from the network
    assert page.external == [] and "<link" not in text and "<script src" not in text
    for img in page.images:
        _decode_png(img["src"])
    per_frame = {
        f["frame_id"]: [i for i in page.images if i["frame"] == f["frame_id"]] for f in frames
    }
    assert len(per_frame["lab_000"]) == 4  # quicklook files embedded, and the scene graph
    assert len(per_frame["lab_003"]) == 4  # no files: drawn from products.zarr
    assert len(per_frame["lab_001"]) == 1  # failed in depth: only the reference image
    residual = _decode_png(per_frame["lab_003"][2]["src"])
    assert residual.shape[1] == 2 * 64 + 4  # left - right beside left - pseudo-left
    per_archive = [i for i in page.images if not i["frame"]]
    assert len(per_archive) == 3  # size-frequency, top view, histograms


def test_quicklook_file_is_embedded_byte_for_byte(tmp_path):
    run = make_run(tmp_path / "lab", frames=1)
    _, page = _parse(build_report(run))
    stored = (run / "quicklooks" / "lab_000" / "objects.png").read_bytes()
    first = next(i for i in page.images if i["frame"] == "lab_000")
    assert base64.b64decode(first["src"].split(",", 1)[1]) == stored


def test_report_of_a_run_without_rocks(tmp_path):
    run = make_run(tmp_path / "bare", frames=2, rocks=0)
    text, page = _parse(build_report(run))
    assert "No rocks were described in this run." in text
    assert text.count("No rocks in this frame.") == 2
    assert text.count("Scene graph: no objects, so no relations.") == 2
    assert "No evaluation" in text
    assert all(i["frame"] for i in page.images)  # no per-archive plots without rocks


def test_report_of_a_run_where_every_frame_failed(tmp_path):
    run = make_run(tmp_path / "broken", frames=2, failed=(0, 1))
    text, page = _parse(build_report(run))
    assert re.search(r'<div class="value">2</div><div class="label">failed</div>', text)
    assert [f["data-status"] for f in page.frames] == ["failed", "failed"]


def test_frames_beyond_the_cap_are_summarised(tmp_path):
    run = make_run(tmp_path / "many", frames=3, rocks=1)
    text, page = _parse(build_report(run, max_frames=1))
    assert len(page.frames) == 1 and "Showing the first 1 of 3 frames" in text
    with pytest.raises(ValueError, match="max_frames"):
        build_report(run, max_frames=-1)


def test_regression_cli_report_could_not_set_max_frames(tmp_path, capsys):
    # build_report takes max_frames but `arroyo report` had no option for it: a survey run's
    # page always embedded 50 frames' images, and could never show more
    run = make_run(tmp_path / "many", frames=3, rocks=1)
    assert main(["report", str(run), "--max-frames", "2"]) == 0
    text, page = _parse(run / "report.html")
    assert len(page.frames) == 2 and "Showing the first 2 of 3 frames" in text
    assert main(["report", str(run), "--max-frames", "-1"]) == 2
    assert "max_frames must be an int >= 0" in capsys.readouterr().err


def test_output_locations(tmp_path):
    run = make_run(tmp_path / "lab", frames=1, rocks=2)
    assert build_report(run, tmp_path / "r.html") == tmp_path / "r.html"
    (tmp_path / "out").mkdir()
    assert build_report(run, tmp_path / "out") == tmp_path / "out" / "report.html"
    with pytest.raises(ParamError, match="does not exist"):
        build_report(run, tmp_path / "nope" / "r.html")
    assert [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name] == []


def test_cli_report_and_its_errors(tmp_path, capsys):
    run = make_run(tmp_path / "lab", frames=1, rocks=2)
    assert main(["report", str(run)]) == 0
    assert capsys.readouterr().out.strip() == f"arroyo: wrote {run / 'report.html'}"
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_run_in_progress_needs_allow_running_and_says_so(tmp_path):
    run = make_run(tmp_path / "live", frames=2, rocks=2, status="running")
    with RunLock(run):
        with pytest.raises(RunDirError, match="still in progress"):
            build_report(run)
        assert not (run / "report.html").exists()
        text = build_report(run, allow_running=True).read_text()
    assert "still in progress" in text


def test_large_quicklooks_are_embedded_with_a_palette():
    from pipeline._report_figures import compact_png
    from stages.quicklook import encode_png

    rng = np.random.default_rng(0)
    gray = rng.normal(128, 20, size=(300, 300)).clip(0, 255).astype(np.uint8)
    image = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    cv2.circle(image, (150, 150), 40, (0, 0, 255), 2)
    data = encode_png(image)
    small = compact_png(data, max_bytes=1000)
    assert len(small) < len(data)
    decoded = cv2.imdecode(np.frombuffer(small, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == image.shape
    assert np.abs(decoded.astype(int) - image.astype(int)).mean() < 8
    assert compact_png(data, max_bytes=len(data)) is data


def _rewrite_frames(run: Path, frame_id: str, **changes) -> None:
    rows = pq.read_table(run / "frames.parquet").to_pylist()
    for row in rows:
        if row["frame_id"] == frame_id:
            row.update(changes)
    pq.write_table(pa.Table.from_pylist(rows), run / "frames.parquet")


def test_frame_failed_on_rerun_shows_no_earlier_run_images(tmp_path):
    """Regression: a frame done once, then failed at ingest on a rerun (its file cut
    short), showed the earlier run's quicklook files and slabs in the report: outlined
    objects under a 'failed' badge with '0 rocks'."""
    run = make_run(tmp_path / "lab", frames=2)
    assert (run / "quicklooks" / "lab_000" / "objects.png").is_file()
    stages = ("ingest", "depth", "segment", "describe", "quicklook")
    _rewrite_frames(
        run, "lab_000", status="failed", failed_stage="ingest", error="ingest: cut short",
        **{f"{s}_seconds": None for s in stages},
    )
    _rewrite_frames(run, "lab_001", depth_seconds=None, segment_seconds=None,
                    describe_seconds=None, quicklook_seconds=None)
    text, page = _parse(build_report(run))
    per_frame = {f: [i for i in page.images if i["frame"] == f] for f in ("lab_000", "lab_001")}
    assert per_frame["lab_000"] == [] and "No images for this frame." in text
    # ingest current, the rest not: the bare reference image, no outlines of old labels
    (only,) = per_frame["lab_001"]
    right = np.asarray(zarr.open_group(run / "products.zarr", mode="r")["right"][1])
    bare = objects_image(right, np.zeros(right.shape, np.int32))
    np.testing.assert_array_equal(_decode_png(only["src"])[..., :3], bare[..., :3])


def test_report_draws_over_the_reference_image(tmp_path):
    """Regression: the report drew a frame's outlines and range contours over the right
    image even when the run's reference was the left one (the labels' geometry); and its
    residual caption said "left − pseudo-left" (the residual is right minus pseudo-right)."""
    run = make_run(tmp_path / "lab", frames=2, quicklooks=False)
    meta = json.loads((run / "run.json").read_text())
    meta["camera"]["reference"] = "left"
    (run / "run.json").write_text(json.dumps(meta))
    text, page = _parse(build_report(run))
    assert "<figcaption>right − left | right − pseudo-right</figcaption>" in text
    assert "pseudo-left" not in text
    first = next(i for i in page.images if i["frame"] == "lab_000")
    group = zarr.open_group(run / "products.zarr", mode="r")
    want = objects_image(np.asarray(group["left"][0]), np.asarray(group["labels"][0]))
    np.testing.assert_array_equal(_decode_png(first["src"])[..., :3], want[..., :3])


def test_report_of_a_read_only_run_directory(tmp_path, readonly_view):
    """Regression: `arroyo report` of an archived run on a read-only mount rendered the
    whole page, then ended in an EROFS traceback; --output elsewhere works."""
    view = readonly_view(make_run(tmp_path / "lab", frames=1, rocks=2))
    with pytest.raises(ParamError, match="is not writable .*pass --output FILE"):
        build_report(view)
    assert build_report(view, tmp_path / "r.html").is_file()


def _frame_tables(run: Path, frame_id: str) -> tuple[pa.Table, pa.Table]:
    tables = []
    for name in ("descriptors", "relations"):
        table = pq.read_table(run / f"{name}.parquet", partitioning=None)
        tables.append(table.filter(pa.compute.equal(table["frame_id"], frame_id)))
    return tables[0], tables[1]


def test_each_frame_shows_its_scene_graph_with_the_relation_counts(tmp_path):
    run = make_run(tmp_path / "lab", frames=2, rocks=5, quicklooks=False)
    text, page = _parse(build_report(run))
    group = zarr.open_group(run / "products.zarr", mode="r")
    for index, fid in enumerate(("lab_000", "lab_001")):
        nodes, edges = _frame_tables(run, fid)
        assert edges.num_rows > 0  # the fixture's frames have relations
        (graph,) = [i for i in page.images if i["frame"] == fid and "scene graph" in i["alt"]]
        # the figure is the function's picture of this frame's descriptors and relations
        want = scene_graph_image(np.asarray(group["right"][index]), nodes, edges)
        np.testing.assert_array_equal(_decode_png(graph["src"])[..., :3], want)
        caption = scene_graph_caption(relation_counts(edges["relation"].to_pylist()))
        assert f"<figcaption>{esc(caption)}</figcaption>" in text
        for name, n in relation_counts(edges["relation"].to_pylist()).items():
            assert f"{name} {n}" in caption


def test_scene_graph_of_a_frame_without_relations(tmp_path):
    # one object: no pair, so no relations; the figure shows it and says so
    run = make_run(tmp_path / "lab", frames=1, rocks=1, quicklooks=False)
    nodes, edges = _frame_tables(run, "lab_000")
    assert nodes.num_rows == 1 and edges.num_rows == 0
    text, page = _parse(build_report(run))
    assert [i["alt"] for i in page.images if i["frame"]][-1] == "lab_000: scene graph"
    assert "This frame has no relations." in text


def test_regression_report_output_dash_and_output_under_a_file(tmp_path, monkeypatch):
    # `-o -` wrote a file named '-' into the working directory; `-o FILE/r.html` said
    # "directory FILE does not exist"
    run = make_run(tmp_path / "lab", frames=1)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ParamError, match="not stdout; pass a file name"):
        build_report(run, "-", max_frames=0)
    assert not (tmp_path / "-").exists()
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    with pytest.raises(ParamError, match=f"{plain} is a file, not a directory"):
        build_report(run, plain / "r.html", max_frames=0)


def test_regression_report_of_a_run_without_its_frames_table_was_written(tmp_path):
    # frames.parquet deleted: the report was written with no frame at all
    run = make_run(tmp_path / "lab", frames=2)
    (run / "frames.parquet").unlink()
    with pytest.raises(RunDirError, match="no frames.parquet"):
        build_report(run, tmp_path / "r.html", max_frames=0)
    assert not (tmp_path / "r.html").exists()
