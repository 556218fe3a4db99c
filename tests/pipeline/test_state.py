"""The completion journal's readers: what planning, publishing and the frames table need."""

from __future__ import annotations

import pytest

from pipeline.errors import RunDirError
from pipeline.state import STATE_NAME, PartRecord, RunState, StageRecord


def _record(frame: str, stage: str, key: str, parts: dict[str, str]) -> StageRecord:
    return StageRecord(
        frame, stage, key, "run1", 0.5, {"n": 3}, ["a note"], {"labels": "ab" * 32}, parts
    )


def test_light_readers_agree_with_the_full_records(tmp_path):
    state = RunState(tmp_path)
    try:
        records = [
            _record("f0", "segment", "k0", {}),
            _record("f0", "describe", "k1", {"descriptors": "p1", "relations": "p2"}),
            _record("f1", "describe", "k2", {"descriptors": "p3"}),
        ]
        parts = [PartRecord(p, "descriptors", f".staging/{p}", "0" * 64, 1) for p in ("p1", "p3")]
        state.commit_batch(records, {}, parts)
        full = state.done()
        assert full[("f0", "describe")] == records[1]
        assert state.done_keys() == {key: r.key for key, r in full.items()}
        assert state.live_parts("descriptors") == {"f0": "p1", "f1": "p3"}
        assert state.live_parts("relations") == {"f0": "p2"}
        assert state.live_part_ids() == {"p1", "p2", "p3"}
        light = list(state.iter_done(integrity=False))
        assert [(r.frame_id, r.stage) for r in light] == [(r.frame_id, r.stage) for r in records]
        assert all(r.checksums == {} and r.part_ids == {} for r in light)
        assert [r.figures for r in light] == [r.figures for r in records]
    finally:
        state.close()


@pytest.mark.parametrize("readonly", [False, True])
def test_damaged_journal_is_a_run_dir_error(tmp_path, readonly):
    """Bug: a damaged state.sqlite ended `arroyo status` and `arroyo run` in sqlite3's
    DatabaseError traceback."""
    (tmp_path / STATE_NAME).write_bytes(bytes(range(256)) * 12)
    with pytest.raises(RunDirError, match="damaged .file is not a database.; move it away"):
        RunState(tmp_path, readonly=readonly)
