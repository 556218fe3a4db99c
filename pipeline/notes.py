"""The frames' notes in short, for the end of ``arroyo run`` and for ``arroyo status``.

Stages record notes per frame (ingest: colour converted to gray, 16-bit data that comes out
dark, clipped samples; depth: no ground plane; segment: what its rules dropped or joined).
They are in ``frames.parquet`` only, so a run whose 12-bit images came out dark looked like
a success with no rocks. The summary counts the frames with notes and shows the most common
kinds of note: notes are grouped by their text without file names, numbers and ingest's
``left:``/``right:``, each kind shown by its first note ("e.g." when the kind's notes
differ). Kinds are listed in stage order (an input problem explains what the later stages
found, and segment's routine notes, on nearly every frame, must not push it out), within a
stage those that name a parameter to set (``set ingest.sample_bits = 12``) first, at most
two per stage and five in all, with the ``arroyo query`` command that lists every note: a
run of 16-bit, colour and 12-bit-in-16-bit frames showed the two plain conversions and hid
the one note that said what to do as "and 1 other kind".
A note that starts with a count ("171 px of weak halves joined to their objects", "2 streak(s)
... dropped") reports what a rule did, routine on nearly every frame: such kinds are only
counted, in one line, so a normal run's summary is that line and the command.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .plan import RunPlan
    from .state import RunState

__all__ = [
    "NoteKind",
    "NotesSummary",
    "summarize_notes",
    "run_notes",
    "format_notes",
    "notes_query",
]

_PER_STAGE = 2
_SHOWN = 5
_IMAGE_FILE = re.compile(r"\S+\.(?:png|jpe?g|tiff?|pgm|ppm|pnm|bmp|dib)\b", re.IGNORECASE)
_NUMBER = re.compile(r"\d+(?:\.\d+)?")
_SIDE = re.compile(r"^(?:left and right|left|right): ")


@dataclass(frozen=True)
class NoteKind:
    """Notes that differ only in file names and numbers.

    Attributes
    ----------
    stage : str
        The stage that wrote them.
    example : str
        The first of them, as recorded.
    frames : int
        Frames carrying one, >= 1.
    varies : bool
        Whether they differ (in numbers or file names) from ``example``.
    """

    stage: str
    example: str
    frames: int
    varies: bool


@dataclass(frozen=True)
class NotesSummary:
    """How many frames carry notes and the kinds of note, most telling first.

    Attributes
    ----------
    frames : int
        Frames summarised.
    noted : int
        Of those, frames with at least one note.
    kinds : tuple of NoteKind
        Every kind, in stage order, then those naming a ``stage.param`` first, then most
        frames first, then first seen.
    """

    frames: int
    noted: int
    kinds: tuple[NoteKind, ...]


def summarize_notes(
    frame_notes: Iterable[Sequence[tuple[str, str]]],
    *,
    stages: Sequence[str],
    files: Iterable[str] = (),
) -> NotesSummary:
    """Group the notes of frames into kinds.

    Parameters
    ----------
    frame_notes : iterable of sequence of (str, str)
        Per frame, its notes as ``(stage, note)`` pairs; an empty sequence for a frame
        without notes (it counts in ``frames``).
    stages : sequence of str
        The stages in graph order; a note of another stage sorts last.
    files : iterable of str
        File paths the notes may name (the frames' images), left out when grouping, as is
        any word ending in an image extension.

    Returns
    -------
    NotesSummary
    """
    order = {name: k for k, name in enumerate(stages)}
    # longest first: a path that contains another is removed whole
    paths = sorted({p for p in files if p}, key=len, reverse=True)
    kinds: dict[tuple[str, str], list] = {}  # key -> [stage, example, frames, varies]
    n_frames = n_noted = 0
    for notes in frame_notes:
        n_frames += 1
        n_noted += bool(notes)
        seen = set()
        for stage, note in notes:
            key = (stage, _pattern(note, paths))
            entry = kinds.setdefault(key, [stage, note, 0, False])
            entry[3] = entry[3] or note != entry[1]
            if key not in seen:
                seen.add(key)
                entry[2] += 1
    names = "|".join(re.escape(name) for name in stages)
    advice = re.compile(rf"\b(?:{names})\.[a-z_]+") if names else None

    def rank(item: tuple[int, list]) -> tuple[int, bool, int, int]:
        first_seen, (stage, example, frames, _varies) = item
        says_what_to_set = advice is not None and advice.search(example) is not None
        return (order.get(stage, len(order)), not says_what_to_set, -frames, first_seen)

    ranked = sorted(enumerate(kinds.values()), key=rank)
    return NotesSummary(
        frames=n_frames,
        noted=n_noted,
        kinds=tuple(NoteKind(s, example, n, varies) for _i, (s, example, n, varies) in ranked),
    )


def run_notes(plan: RunPlan, state: RunState) -> NotesSummary:
    """The notes of the frames a run selected, from their current records (those of the
    keys the plan wants, as ``frames.parquet`` has them): a frame failed in depth keeps its
    ingest notes."""
    selected: dict[str, list[tuple[str, str]]] = {f.frame_id: [] for f in plan.frames}
    for record in state.iter_done(integrity=False):
        notes = selected.get(record.frame_id)
        if notes is None or not record.notes:
            continue
        if plan.keys.get(record.frame_id, {}).get(record.stage) != record.key:
            continue  # a record of other inputs or params: not what this run made
        notes.extend((record.stage, note) for note in record.notes)
    return summarize_notes(
        selected.values(),
        stages=[s.name for s in plan.graph.stages],
        files=[str(p) for f in plan.frames for p in (f.left, f.right)],
    )


def notes_query(rundir: str | Path, *, running: bool = False) -> str:
    """The ``arroyo query`` command that lists every frame's notes (``running``: of a run
    still in progress, which needs ``--allow-running``)."""
    sql = "SELECT frame_id, notes FROM frames WHERE notes IS NOT NULL ORDER BY index"
    flag = " --allow-running" if running else ""
    return f"arroyo query{flag} {shlex.quote(str(rundir))} {shlex.quote(sql)}"


def format_notes(summary: NotesSummary, rundir: str | Path, *, running: bool = False) -> str:
    """A few lines for people: the frames with notes, the most common kinds of note (stage
    order, at most two a stage, five in all) and the command that lists them all; empty
    when no frame has a note.

    Parameters
    ----------
    summary : NotesSummary
    rundir : str or Path
        The run directory, for the command.
    running : bool
        The run is still in progress (the command needs ``--allow-running``).

    Returns
    -------
    str
        Lines ending in a newline, or ``""``.
    """
    if not summary.noted:
        return ""
    reports = [kind for kind in summary.kinds if _is_rule_report(kind.example)]
    telling = [kind for kind in summary.kinds if not _is_rule_report(kind.example)]
    command = f"every note: {notes_query(rundir, running=running)}"
    header = f"notes: {summary.noted} of {_count(summary.frames, 'frame')} carry notes"
    if not telling:
        return f"{header}: {_reports_line(reports)}; {command}\n"
    shown: list[NoteKind] = []
    per_stage: dict[str, int] = {}
    for kind in telling:
        if len(shown) == _SHOWN:
            break
        if per_stage.get(kind.stage, 0) < _PER_STAGE:
            per_stage[kind.stage] = per_stage.get(kind.stage, 0) + 1
            shown.append(kind)
    lines = [
        f"{header}, {_count(len(telling), 'kind')}; earliest stage first, in a stage those "
        "naming a setting, then the most common:"
    ]
    width = len(_count(max(kind.frames for kind in shown), "frame"))
    for kind in shown:
        example = f"e.g. {kind.example}" if kind.varies else kind.example
        lines.append(f"  {_count(kind.frames, 'frame'):>{width}}  {kind.stage}: {example}")
    if len(telling) > len(shown):
        lines.append(f"  and {_count(len(telling) - len(shown), 'other kind')}")
    if reports:
        lines.append(f"  and {_reports_line(reports)}")
    lines.append(f"  {command}")
    return "\n".join(lines) + "\n"


def _is_rule_report(note: str) -> bool:
    """A note that starts with a count says what a rule did (see the module docstring)."""
    return note[:1].isdigit()


def _reports_line(reports: Sequence[NoteKind]) -> str:
    stages = ", ".join(dict.fromkeys(kind.stage for kind in reports))
    frames = max(kind.frames for kind in reports)
    kinds = _count(len(reports), "kind")
    return f"{kinds} of rule report ({stages}, up to {_count(frames, 'frame')})"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _pattern(note: str, paths: Sequence[str]) -> str:
    """The note without file names and numbers: notes differing only there group."""
    for path in paths:
        note = note.replace(path, "<file>")
    note = _IMAGE_FILE.sub("<file>", note)
    # ingest names the side: a dark left and a dark right image are one kind of note
    note = _SIDE.sub("", note)
    return _NUMBER.sub("#", note)
