"""The report as a person sees it: headless Chromium opens report.html from disk, renders
every image, runs the page's script without console errors, and takes a screenshot.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it when missing); without a
Chromium binary the test is skipped and says why.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import cv2
import numpy as np
import pytest
from test_query import make_run

from pipeline.report import build_report

_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def _chromium() -> str | None:
    override = os.environ.get("ARROYO_CHROMIUM")
    if override:
        return override
    for name in _CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


def test_report_renders_in_headless_chromium(tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip(
            "no Chromium binary on PATH (tried chromium, chromium-browser, google-chrome); "
            "install Debian's `chromium` package (`.ci/run` does) or set ARROYO_CHROMIUM"
        )
    run = make_run(tmp_path / "lab", frames=3, failed=(1,), rocks=5, evaluation=True)
    report = build_report(run)
    n_images = report.read_text().count("<img ")
    shot = tmp_path / "report.png"
    proc = subprocess.run(
        [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
            # lets the load event fire before the DOM is dumped
            "--virtual-time-budget=5000",
            f"--user-data-dir={tmp_path / 'profile'}",
            f"--screenshot={shot}",
            "--window-size=1280,2000",
            "--dump-dom",
            report.resolve().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    dom = proc.stdout
    # the page's own script ran to the end after every image had loaded
    root = re.search(r"<html[^>]*>", dom)
    assert root is not None, dom[:500]
    attrs = dict(re.findall(r'([\w-]+)="([^"]*)"', root.group(0)))
    assert attrs.get("data-report-ready") == "1", root.group(0)
    assert attrs.get("data-images") == str(n_images) and n_images >= 3 + 3 + 1 + 3
    assert attrs.get("data-broken-images") == "0"
    assert "3 of 3 frames shown" in dom  # the frame filter initialised
    # Chromium prints every console message (log, warning, error, uncaught exception) as
    # INFO:CONSOLE on stderr; the report logs nothing, so any such line is a failure
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    assert console == []
    image = cv2.imread(str(shot), cv2.IMREAD_COLOR)
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and image is not None
    assert image.shape[:2] == (2000, 1280)
    # something was drawn: not a blank page
    assert float(np.std(image)) > 10
