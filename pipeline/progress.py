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
        start = time.monotonic()

        def update(done: int, total: int, frame_id: str) -> None:
            if not task:
                bar.start()
                task["id"] = bar.add_task("run", total=total, rate="")
            rate = done / max(time.monotonic() - start, 1e-9)
            bar.update(task["id"], completed=done, rate=f"{rate:.2f} frames/s")

        return update, bar.stop
    state = {"last": 0.0, "start": time.monotonic()}

    def log(done: int, total: int, frame_id: str) -> None:
        now = time.monotonic()
        if done == total or now - state["last"] >= 5.0:
            elapsed = now - state["start"]
            rate = done / max(elapsed, 1e-9)
            eta = (total - done) / rate if rate else float("nan")
            print(
                f"arroyo: {done}/{total} frames, {rate:.2f} frames/s, ETA {eta:.0f} s "
                f"(last {frame_id})",
                file=sys.stderr,
                flush=True,
            )
            state["last"] = now

    return log, (lambda: None)
