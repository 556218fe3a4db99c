"""Tests of pipeline/progress.py: the plain log lines of a run's progress."""

from __future__ import annotations

import pytest

from pipeline import progress


@pytest.fixture
def clock(monkeypatch):
    now = {"t": 100.0}
    monkeypatch.setattr(progress.time, "monotonic", lambda: now["t"])
    return now


def test_the_eta_leaves_out_the_first_frame(clock, capsys):
    # regression: on a fresh install the first frame took 30 s (numba compiling) and the
    # next ones 1-2 s each; the ETA from the mean rate said 430 s for a run of 20
    now = clock
    log, close = progress.make_progress()
    now["t"] += 30.0
    log(1, 12, "f1")
    for done in range(2, 12):
        now["t"] += 2.0
        log(done, 12, f"f{done}")
    now["t"] += 2.0
    log(12, 12, "f12")
    close()
    lines = capsys.readouterr().err.splitlines()
    assert "rate and ETA from the next frame on" in lines[0] and "f1)" in lines[0]
    # the next line 5 s or more later: frames 2-4 in 6 s, 8 frames to go at 0.5 frames/s
    assert lines[1] == "arroyo: 4/12 frames, 0.50 frames/s, ETA 16 s (last f4)"
    # not "all done" (a run with failed frames said so): done is a frame status
    assert lines[-1] == "arroyo: 12/12 frames, all processed (last f12)"


def test_disabled_progress_prints_nothing(clock, capsys):
    log, close = progress.make_progress(enabled=False)
    log(1, 2, "a")
    close()
    assert capsys.readouterr().err == ""
