"""Progress of a run: a rich bar on a terminal, plain log lines otherwise."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

__all__ = ["make_progress"]


def make_progress(*, enabled: bool = True) -> tuple[Callable[[int, int, str], None], Any]:
    """Return ``(callback(done, total, frame_id), closer)``."""
    if not enabled:
        return (lambda done, total, frame_id: None), (lambda: None)
    if sys.stderr.isatty():
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeRemainingColumn,
        )

        bar = Progress(
            TextColumn("[bold]arroyo[/bold] frames"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[rate]}"),
            TimeRemainingColumn(),
            transient=False,
        )
        task: dict[str, Any] = {}
        rate_of = _SteadyRate()

        def update(done: int, total: int, frame_id: str) -> None:
            if not task:
                bar.start()
                task["id"] = bar.add_task("run", total=total, rate="")
            rate = rate_of(done, time.monotonic())
            text = f"{rate:.2f} frames/s" if rate is not None else ""
            bar.update(task["id"], completed=done, rate=text)

        return update, bar.stop
    state = {"last": 0.0}
    rate_of = _SteadyRate()

    def log(done: int, total: int, frame_id: str) -> None:
        now = time.monotonic()
        rate = rate_of(done, now)
        if done == total or now - state["last"] >= 5.0:
            if done == total:
                pace = "all processed"  # not "done": some may have failed
            elif rate is None:
                pace = "rate and ETA from the next frame on (the first carries the start-up)"
            else:
                eta = (total - done) / rate if rate > 0 else float("nan")
                pace = f"{rate:.2f} frames/s, ETA {eta:.0f} s"
            print(
                f"arroyo: {done}/{total} frames, {pace} (last {frame_id})",
                file=sys.stderr,
                flush=True,
            )
            state["last"] = now

    return log, (lambda: None)


class _SteadyRate:
    """Frames per second since the first progress report: the first frame carries the
    run's start-up (workers starting, numba compiling its kernels on a fresh install,
    20-30 s against 1-2 s per frame after), and an ETA from it was 10-20 times too long.
    ``None`` until a second report brings a frame on."""

    def __init__(self) -> None:
        self._first: tuple[int, float] | None = None

    def __call__(self, done: int, now: float) -> float | None:
        if self._first is None:
            self._first = (done, now)
            return None
        first_done, first_at = self._first
        if done <= first_done:
            return None
        return (done - first_done) / max(now - first_at, 1e-9)
