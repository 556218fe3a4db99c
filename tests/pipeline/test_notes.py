"""Summaries of the frames' notes (pipeline.notes)."""

from __future__ import annotations

import shlex

from pipeline.notes import format_notes, notes_query, summarize_notes

STAGES = ("ingest", "depth", "segment", "describe")


def _segment_routine(k: int) -> list[tuple[str, str]]:
    return [
        ("segment", f"{100 + k} px of weak halves joined to their objects"),
        ("segment", f"{20 + k} px of faint rims dropped"),
        ("segment", f"height noise 1.{k} cm: heights unusable, intensity rules only"),
    ]


def test_kinds_group_notes_differing_in_numbers_files_and_side():
    frames = [
        [("ingest", "left: 12 samples of /data/a 1_left.png are above 4095 (max 5000)")],
        [("ingest", "right: 3 samples of /data/b_right.tif are above 4095 (max 4100)")],
        [("ingest", "left and right: colour (3 channels) converted to gray")],
        [],
    ]
    summary = summarize_notes(frames, stages=STAGES, files=["/data/a 1_left.png"])
    assert (summary.frames, summary.noted) == (4, 3)
    clipped, colour = summary.kinds
    assert (clipped.frames, clipped.varies, colour.frames, colour.varies) == (2, True, 1, False)
    assert clipped.example.startswith("left: 12 samples of /data/a 1_left.png")


def test_a_kind_counts_frames_not_notes():
    frame = [("segment", "2 px of faint rims dropped"), ("segment", "9 px of faint rims dropped")]
    (kind,) = summarize_notes([frame], stages=STAGES).kinds
    assert kind.frames == 1 and kind.varies


def test_input_notes_come_before_routine_notes_of_later_stages():
    """Segment's notes, on every frame, must not push out an ingest note on a few."""
    frames = [_segment_routine(k) for k in range(9)]
    frames[4] = [("ingest", "left: alpha channel ignored"), *frames[4]]
    frames[5] = [("depth", "no ground plane fitted: height is NaN"), *frames[5]]
    summary = summarize_notes(frames, stages=STAGES)
    assert [k.stage for k in summary.kinds] == ["ingest", "depth", *["segment"] * 3]
    text = format_notes(summary, "runs/lab")
    lines = [line.strip() for line in text.splitlines()]
    assert lines[0].startswith("notes: 9 of 9 frames carry notes, 3 kinds; earliest stage first")
    assert lines[1] == "1 frame  ingest: left: alpha channel ignored"
    assert lines[2] == "1 frame  depth: no ground plane fitted: height is NaN"
    assert lines[3] == (
        "9 frames  segment: e.g. height noise 1.0 cm: heights unusable, intensity rules only"
    )
    assert lines[-2] == "and 2 kinds of rule report (segment, up to 9 frames)"
    assert lines[-1].startswith("every note: arroyo query runs/lab ")


def test_regression_routine_rule_reports_filled_every_run_summary():
    """Regression: a normal lab run ended with four lines of segment's rule reports ("171 px
    of weak halves joined to their objects" ...), on every frame of every run; notes that
    start with a count are now only counted, in one line."""
    frames = [_segment_routine(k)[:2] for k in range(3)] + [[]]
    text = format_notes(summarize_notes(frames, stages=STAGES), "runs/lab")
    assert text.count("\n") == 1
    assert text.startswith(
        "notes: 3 of 4 frames carry notes: 2 kinds of rule report (segment, up to 3 frames); "
        "every note: arroyo query runs/lab "
    )


def test_at_most_five_kinds_are_shown():
    frames = [[(stage, f"{stage} note {k}") for stage in STAGES for k in "ab"]]
    text = format_notes(summarize_notes(frames, stages=STAGES), "r")
    assert len([line for line in text.splitlines() if " frame  " in line]) == 5
    assert "  and 3 other kinds" in text


def test_no_notes_no_lines():
    assert format_notes(summarize_notes([[], []], stages=STAGES), "r") == ""
    assert format_notes(summarize_notes([], stages=STAGES), "r") == ""


def test_query_command_is_quoted_and_says_allow_running():
    argv = shlex.split(notes_query("/tmp/my runs/lab", running=True))
    assert argv[:3] == ["arroyo", "query", "--allow-running"]
    assert argv[3] == "/tmp/my runs/lab" and argv[4].startswith("SELECT frame_id, notes FROM")
    assert "--allow-running" not in notes_query("runs/lab")


def test_regression_note_naming_the_setting_was_hidden_behind_commoner_conversions():
    # a user's run: 16-bit frames, colour frames and one 12-bit-in-16-bit pair; the summary
    # showed the two plain ingest conversions and put the note that says what to set into
    # "and 1 other kind"
    dark = (
        "left and right: 16-bit samples scaled to 8 bits by >> 8 (max 4080 -> 15); the data "
        "uses only 12 bits, so it comes out dark: if the camera writes 12-bit samples, set "
        "ingest.sample_bits = 12 (catalog [params] or --set)"
    )
    frames = [
        [("ingest", "left and right: 16-bit samples scaled to 8 bits by >> 8 (max 65535 -> 255)")],
        [("ingest", "left and right: 16-bit samples scaled to 8 bits by >> 8 (max 65280 -> 255)")],
        [("ingest", "left and right: 3 identical colour channels reduced to one")],
        [("ingest", "left and right: 3 identical colour channels reduced to one")],
        [("ingest", dark)],
    ]
    summary = summarize_notes(frames, stages=STAGES)
    assert summary.kinds[0].example == dark
    text = format_notes(summary, "runs/x")
    assert "set ingest.sample_bits = 12" in text
    assert "in a stage those naming a setting, then the most common:" in text.splitlines()[0]
    assert "and 1 other kind" in text  # the colour note, the less telling, is the one left out
    assert "colour" not in text
