"""The CLI maps outcomes to exit codes and prints what a user needs."""

from __future__ import annotations

import shlex

import cv2
import numpy as np
import pytest

from conftest import write_archive
from pipeline.cli import main
from pipeline.lock import RunLock


@pytest.fixture(autouse=True)
def _fake_stages(monkeypatch):
    monkeypatch.setenv("ARROYO_STAGE_PACKAGE", "arroyo_fake_stages")


def test_run_status_graph_and_dry_run(archive, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 0
    assert "4 done, 0 failed" in capsys.readouterr().out
    assert main(["status", str(out)]) == 0
    text = capsys.readouterr().out
    assert "blend" in text and "finished" in text
    assert (
        main(["run", str(archive), "--out", str(out), "--dry-run", "--set", "blend.weight=0.1"])
        == 0
    )
    plan = capsys.readouterr().out
    assert "0 frame(s) would run" not in plan and "changed" in plan
    assert main(["graph"]) == 0
    assert "1. ingest" in capsys.readouterr().out
    assert main(["graph", "--format", "dot"]) == 0
    assert capsys.readouterr().out.startswith("digraph")


def test_failed_frames_exit_1_and_catalog_error_exit_2(archive, tmp_path, capsys):
    (archive.parent / "images" / "f000_right.png").write_bytes(b"")
    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 1
    assert "failed f000" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text("[archive]\nname = 'x'\n[camera]\nfocal_px = -1\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "r2")]) == 2
    assert "bad.toml" in capsys.readouterr().err


def test_bad_set_exits_2_and_locked_exits_3(archive, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--set", "blend.weight=9"]) == 2
    assert "<= 1.0" in capsys.readouterr().err
    out.mkdir()
    with RunLock(out):
        code = main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"])
    assert code == 3
    assert "in use" in capsys.readouterr().err


def test_status_of_missing_rundir_exits_2(tmp_path, capsys):
    assert main(["status", str(tmp_path / "nothing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_disk_full_exits_4_with_a_message(archive, tmp_path, capsys, monkeypatch):
    import errno
    import os

    import pipeline.worker

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(pipeline.worker, "write_frame_array", full)
    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 4
    assert "No space left" in capsys.readouterr().err


def test_products_option_places_products_and_a_bad_url_exits_2(archive, tmp_path, capsys):
    out, shared = tmp_path / "run", tmp_path / "shared"
    argv = ["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]
    assert main([*argv, "--products", str(shared)]) == 0
    assert (shared / "products.zarr").is_dir()
    assert main([*argv, "--dry-run"]) == 0
    assert f"products at {shared}" in capsys.readouterr().out
    assert main([*argv, "--products", "nosuch://bucket/x"]) == 2
    assert "unknown storage protocol 'nosuch'" in capsys.readouterr().err


def test_out_that_is_a_file_exits_2_without_traceback(archive, tmp_path, capsys):
    """Bug: `arroyo run CATALOG --out FILE` died with FileExistsError's traceback (exit 1)."""
    afile = tmp_path / "afile"
    afile.write_text("not a run")
    for extra in ([], ["--dry-run"]):
        argv = ["run", str(archive), "--out", str(afile), "--scheduler", "synchronous"]
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err
        assert "is a file, not a directory" in err and "Traceback" not in err
    assert afile.read_text() == "not a run"
    below = afile / "run"  # a parent that is a file: mkdir fails with ENOTDIR
    assert main(["run", str(archive), "--out", str(below), "--scheduler", "synchronous"]) == 2
    assert "cannot create the run directory" in capsys.readouterr().err


def test_status_of_a_run_killed_before_its_first_frame(archive, tmp_path, capsys, monkeypatch):
    """Bug: a run SIGKILLed before its first frame left run.json without frames.parquet, and
    `arroyo status` printed only 'arroyo: error: RUNDIR/frames.parquet'."""
    import pipeline.runner
    from pipeline.status import status

    out = tmp_path / "run"
    seen = {}

    def killed_here(**kwargs):  # the state a SIGKILL at executor start leaves on disk
        seen["pending"] = status(out).per_stage["tally"]["pending"]
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline.runner, "open_executor", killed_here)
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 130
    assert seen == {"pending": 4}
    (out / "frames.parquet").unlink()  # a run directory of the code before the fix
    assert main(["status", str(out)]) == 2
    assert "has no frames.parquet" in capsys.readouterr().err
    (tmp_path / "afile").write_text("")
    assert main(["status", str(tmp_path / "afile")]) == 2
    assert "is a file, not a run directory" in capsys.readouterr().err


def test_status_of_a_run_killed_while_planning(archive, tmp_path, capsys):
    """A SIGKILL while planning leaves state.sqlite without run.json: status says so."""
    from pipeline.state import RunState

    out = tmp_path / "run"
    out.mkdir()
    RunState(out).close()
    assert main(["status", str(out)]) == 2
    assert "stopped while planning" in capsys.readouterr().err
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 0


def test_param_errors_say_whether_the_catalog_or_set_is_wrong(tmp_path, capsys):
    """Bug: an unknown or bad parameter in the catalog's [params] gave the same message as
    one from --set, naming neither the catalog nor the option."""
    bad = write_archive(tmp_path / "a", extra_toml="\n[params]\nblend = { nosuch = 1 }\n")
    argv = ["run", str(bad), "--out", str(tmp_path / "r"), "--scheduler", "synchronous"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{bad}: [params]: stage 'blend' has no parameter 'nosuch'" in err
    good = write_archive(tmp_path / "b")
    argv = ["run", str(good), "--out", str(tmp_path / "r"), "--scheduler", "synchronous"]
    assert main([*argv, "--set", "blend.weight=abc"]) == 2
    assert "--set blend.weight=abc: parameter 'weight' expects float" in capsys.readouterr().err


def test_status_at_the_end_of_a_run_is_not_interrupted(archive, tmp_path, capsys, monkeypatch):
    """Bug: `arroyo status` that read run.json ('running') just before the run wrote its
    final state, and checked the lock just after the run released it, said 'interrupted'."""
    import json

    import pipeline.lock
    import pipeline.status

    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 0
    meta = json.loads((out / "run.json").read_text())
    final = dict(meta)
    real_holder = pipeline.lock.lock_holder

    def run_ends_now(rundir):  # the run writes its final run.json, then releases the lock
        (out / "run.json").write_text(json.dumps(final))
        return real_holder(rundir)

    (out / "run.json").write_text(json.dumps({**meta, "status": "running"}))
    monkeypatch.setattr(pipeline.lock, "lock_holder", run_ends_now)
    assert pipeline.status.status(out).run_state == "finished"


def test_damaged_run_json_says_how_to_recover(archive, tmp_path, capsys):
    """A damaged run.json stopped every command with the JSON error alone; the message now
    says to remove it and rerun, which resumes from the journal."""
    out = tmp_path / "run"
    argv = ["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]
    assert main(argv) == 0
    (out / "run.json").write_text("{bad")
    assert main(["status", str(out)]) == 2
    assert "remove the file and rerun" in capsys.readouterr().err
    (out / "run.json").unlink()
    assert main(argv) == 0
    assert "4 done" in capsys.readouterr().out


def test_status_verify_exits_1_on_damage(archive, tmp_path, capsys):
    """Regression: `status --verify` exited 0 after finding a deleted chunk, so a script
    checking an archive could not tell damage from a clean run without parsing the text."""
    out = tmp_path / "run"
    assert main(["run", str(archive), "--out", str(out), "--scheduler", "synchronous"]) == 0
    assert main(["status", str(out), "--verify"]) == 0
    chunks = (out / "products.zarr" / "blend").rglob("*")
    chunk = next(p for p in chunks if p.is_file() and p.name != "zarr.json")
    chunk.unlink()
    assert main(["status", str(out), "--verify"]) == 1
    assert "problem(s)" in capsys.readouterr().out
    assert main(["status", str(out)]) == 0  # without --verify: counts only


def test_regression_run_and_status_showed_no_frame_notes(tmp_path, capsys, monkeypatch):
    """Bug (user audit): a run of 12-bit images in 16-bit files "succeeded" (with no rocks);
    the notes saying the frames came out dark and naming ingest.sample_bits were only in
    frames.parquet. The run's summary and `arroyo status` now count the frames with notes,
    show the most common kinds and the `arroyo query` command that lists them all."""
    monkeypatch.setenv("ARROYO_STAGE_PACKAGE", "arroyo_ingest_stages")
    root = tmp_path / "my archive"  # a space: the printed command must quote the path
    catalog = write_archive(root, frames=3, shape=(16, 24))
    for k in (0, 2):  # two frames from a 12-bit camera, written as 16-bit PNGs
        for side in ("left", "right"):
            path = root / "images" / f"f{k:03d}_{side}.png"
            gray = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.uint16)
            assert cv2.imwrite(str(path), gray << 4)
    out = tmp_path / "run dir"
    assert main(["run", str(catalog), "--out", str(out), "--scheduler", "synchronous"]) == 0
    printed = capsys.readouterr().out
    assert "3 done, 0 failed" in printed
    assert "notes: 2 of 3 frames carry notes" in printed
    dark = [line for line in printed.splitlines() if "comes out dark" in line]
    assert len(dark) == 1 and dark[0].lstrip().startswith("2 frames  ingest: ")
    assert "set ingest.sample_bits = 12" in dark[0]
    assert main(["status", str(out)]) == 0
    status_text = capsys.readouterr().out
    assert "notes: 2 of 3 frames carry notes" in status_text and dark[0] in status_text
    command = next(line for line in printed.splitlines() if "every note: " in line)
    argv = shlex.split(command.split("every note: ", 1)[1])
    assert argv[:2] == ["arroyo", "query"]
    assert main([*argv[1:], "--format", "csv"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert [line.split(",")[0] for line in listed[1:]] == ['"f000"', '"f002"']
    assert all("comes out dark" in line for line in listed[1:])


def test_bad_wait_for_workers_exits_2_before_any_work(archive, tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", str(archive), "--out", str(out), "--wait-for-workers", "-5"])
    assert code == 2
    assert "--wait-for-workers must be a finite number of seconds > 0" in capsys.readouterr().err
    assert not out.exists()


def test_regression_stage_package_option_missing(archive, tmp_path, monkeypatch, capsys):
    # the README's own-stages workflow had no --stage-package: only an undocumented
    # environment variable chose the package
    monkeypatch.delenv("ARROYO_STAGE_PACKAGE")
    assert main(["graph", "--stage-package", "arroyo_fake_stages"]) == 0
    assert "tally" in capsys.readouterr().out
    out = tmp_path / "run"
    argv = ["run", str(archive), "--out", str(out), "--stage-package", "arroyo_fake_stages"]
    assert main([*argv, "--scheduler", "synchronous", "--quiet"]) == 0
    assert (out / "tallies.parquet").exists()


@pytest.mark.parametrize(
    ("package", "expected"),
    [
        ("arroyo_no_such_stages", "cannot be imported"),
        ("arroyo_fake_stages.tally", "is a module"),
        ("json", "declares no stage"),
    ],
)
def test_regression_bad_stage_package_traceback(package, expected, capsys):
    # an unknown package printed a ModuleNotFoundError traceback; a package without stages
    # gave an empty graph
    assert main(["graph", "--stage-package", package]) == 2
    assert expected in capsys.readouterr().err


def test_regression_closed_pipe_printed_a_traceback(tmp_path):
    # `arroyo ... | head` ended in "BrokenPipeError: [Errno 32] Broken pipe" and a traceback
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    env.pop("ARROYO_STAGE_PACKAGE")  # the shipped stages: the fake ones are not on the path
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "graph", "--format", "dot"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp_path,
    )
    proc.stdout.close()  # the reader is gone before the first line is written
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait() == 141
    assert "Traceback" not in err
