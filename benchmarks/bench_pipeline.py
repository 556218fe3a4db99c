"""End-to-end benchmarks of the engine: throughput, overhead, memory, task granularity.

Usage (from the repository root; numbers go to BENCHMARKS.md)::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_pipeline.py throughput --frames 200
    PYTHONPATH=. .venv/bin/python benchmarks/bench_pipeline.py overhead --frames 40
    PYTHONPATH=. .venv/bin/python benchmarks/bench_pipeline.py memory --frames 200 2000
    PYTHONPATH=. .venv/bin/python benchmarks/bench_pipeline.py cpu --frames 40
    PYTHONPATH=. .venv/bin/python benchmarks/bench_pipeline.py machine

``throughput`` runs a rendered ``mojave`` archive (``--size`` px square, default 500) with the
default methods through ``arroyo run`` (``pipeline.runner.run``) on a local cluster of 1 and
2 worker processes (and ``--threads``: one process, 2 threads), reports pairs/s (whole run and
steady state after the first frame), parallel efficiency, mean seconds per stage from
``frames.parquet``, the peak RSS of driver + workers and their CPU seconds (sampled every
0.2 s with psutil).

``overhead`` times, in this process, the same stages called directly on numpy arrays in a loop
(``STAGE.run`` in graph order, same effective params, nothing written), the engine on one core
(``scheduler='synchronous'``: zarr, Parquet, SQLite journal, provenance) and OpenCV StereoSGBM
alone (``pipeline._baselines.sgbm_disparity``) on the same frames.

``cpu`` runs the archive once synchronously in this process and reports CPU seconds per frame
(``time.process_time``) of each stage's ``run`` and of the engine around them, with the
worker's zarr and file writes and the driver's journal flushes named: the figure to compare
code versions by on a machine shared with other jobs, where wall time is not.

``memory`` runs archives of each ``--frames`` count on 2 worker processes and compares peak
RSS. Rendering thousands of frames takes long, so ``--unique`` frames are rendered once and
the frame index repeats them under new frame ids (the engine neither knows nor cares).

Archives are rendered once into ``--workdir`` (default /tmp/arroyo-bench) and reused.
``--catalog PATH --stage-package NAME`` benchmark any catalog / stage package instead
(e.g. the fake stages of the engine tests, to measure pure engine cost).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import threading
import time
import tomllib
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.catalog import load_catalog
from pipeline.graph import build_graph, discover_stages, resolve_stage_params
from pipeline.runner import run
from pipeline.stage import FrameContext

__all__ = [
    "PeakRSS",
    "ensure_archive",
    "repeat_catalog",
    "timed_run",
    "pure_compute",
    "sgbm_alone",
    "machine",
]

_MB = 1024 * 1024


# -- measuring -------------------------------------------------------------------------------
class PeakRSS:
    """Peak resident memory and CPU time of this process and its descendants, sampled in a
    thread.

    ``total`` sums RSS over the tree (shared pages counted once per process, so it
    overestimates); ``driver`` is this process alone; ``worker`` the largest descendant.
    ``cpu_driver`` / ``cpu_workers`` are user + system CPU seconds spent inside the block
    (a descendant's last sample before it exits: at most one interval is missed per
    process). CPU seconds do not count time the run waited for a core another job held, so
    they compare runs on a shared machine better than wall time.
    """

    # every 50 ms the sampler itself took ~3 % of a core in the driver (psutil walks /proc
    # for the process tree); 0.2 s keeps it under 1 % and still sees the compaction peaks,
    # which last seconds
    def __init__(self, interval: float = 0.2) -> None:
        self.interval = interval
        self.total = self.driver = self.worker = 0
        self._cpu: dict[int, float] = {}
        self._cpu_start = 0.0
        self.cpu_driver = self.cpu_workers = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def __enter__(self) -> PeakRSS:
        self._cpu_start = _cpu_seconds(psutil.Process())
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        me = psutil.Process()
        self.cpu_driver = _cpu_seconds(me) - self._cpu_start
        self.cpu_workers = sum(v for pid, v in self._cpu.items() if pid != me.pid)

    def _sample(self) -> None:
        me = psutil.Process()
        while not self._stop.is_set():
            rss = {}
            for proc in [me, *me.children(recursive=True)]:
                try:
                    rss[proc.pid] = proc.memory_info().rss
                    self._cpu[proc.pid] = _cpu_seconds(proc)
                except psutil.Error:  # a worker exiting between listing and reading
                    continue
            self.total = max(self.total, sum(rss.values()))
            self.driver = max(self.driver, rss.get(me.pid, 0))
            others = [v for k, v in rss.items() if k != me.pid]
            self.worker = max(self.worker, max(others, default=0))
            self._stop.wait(self.interval)

    def as_dict(self) -> dict[str, float]:
        return {
            "peak_rss_total_mb": round(self.total / _MB, 1),
            "peak_rss_driver_mb": round(self.driver / _MB, 1),
            "peak_rss_worker_mb": round(self.worker / _MB, 1),
            "cpu_driver_s": round(self.cpu_driver, 2),
            "cpu_workers_s": round(self.cpu_workers, 2),
        }


def _cpu_seconds(proc: psutil.Process) -> float:
    times = proc.cpu_times()
    return times.user + times.system


def machine() -> dict[str, Any]:
    """Where the numbers come from: cores, CPU model, load, versions, date."""
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = {}
    for dist in (
        "dask",
        "distributed",
        "numpy",
        "numba",
        "opencv-python-headless",
        "zarr",
        "pyarrow",
        "scipy",
    ):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "stages", "pipeline"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        commit = head + (" + uncommitted changes in stages/ or pipeline/" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "commit": commit,
        "nproc": os.cpu_count(),
        "cpu": model,
        "memory_gb": round(psutil.virtual_memory().total / 1024**3, 1),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
        "python": platform.python_version(),
        "versions": versions,
    }


# -- archives --------------------------------------------------------------------------------
def ensure_archive(workdir: Path, archetype: str, frames: int, size: int, seed: int) -> Path:
    """Render (once) a built-in archive; return its catalog.toml.

    Uses ``pipeline.synth.synthesize_archive`` when it exists, else writes the same layout
    (images, frames.csv, catalog.toml; no truth) from ``pipeline.synth.render_pair``.
    """
    out = workdir / f"{archetype}-{frames}f-{size}px-s{seed}"
    catalog = out / "catalog.toml"
    if not (out / ".complete").is_file():
        shutil.rmtree(out, ignore_errors=True)
        start = time.perf_counter()
        try:
            from pipeline.synth import synthesize_archive
        except ImportError:
            _render_archive(out, archetype, frames, size, seed)
        else:
            synthesize_archive(archetype, out, frames=frames, seed=seed, size=size)
        print(f"rendered {frames} frames of {archetype} in {time.perf_counter() - start:.0f} s")
        (out / ".complete").write_text("ok\n")
    return catalog


def _render_archive(out: Path, archetype: str, frames: int, size: int, seed: int) -> None:
    import cv2

    from pipeline.synth import render_pair

    (out / "images").mkdir(parents=True)
    rows = ["frame_id,left,right,archetype,seed"]
    camera: dict[str, Any] = {}
    for k in range(frames):
        left, right, _truth, _rocks, camera = render_pair(archetype, seed=seed + k, size=size)
        fid = f"{archetype}-{seed + k:05d}"
        cv2.imwrite(str(out / "images" / f"{fid}_left.png"), left)
        cv2.imwrite(str(out / "images" / f"{fid}_right.png"), right)
        rows.append(f"{fid},images/{fid}_left.png,images/{fid}_right.png,{archetype},{seed + k}")
    (out / "frames.csv").write_text("\n".join(rows) + "\n")
    lines = ["[archive]", f'name = "{archetype}"', "", "[camera]"]
    lines += [f"{key} = {_toml_value(value)}" for key, value in camera.items()]
    lines += ["", "[frames]", 'index = "frames.csv"', f"shape = [{size}, {size}]", ""]
    (out / "catalog.toml").write_text("\n".join(lines))


def repeat_catalog(catalog: Path, frames: int) -> Path:
    """A catalog of ``frames`` frames cycling through ``catalog``'s pairs under new ids.

    Only ``[archive]``, ``[camera]``, ``[frames]`` and ``[params]`` are kept: the truth no
    longer matches the frame ids.
    """
    doc = tomllib.loads(catalog.read_text())
    index = catalog.parent / doc["frames"]["index"]
    with open(index, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out_index = catalog.parent / f"frames-x{frames}.csv"
    with open(out_index, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for k in range(frames):
            row = dict(rows[k % len(rows)])
            row["frame_id"] = f"{row['frame_id']}-r{k // len(rows):04d}"
            writer.writerow(row)
    lines = []
    for section in ("archive", "camera", "frames", "params"):
        if section not in doc:
            continue
        table = dict(doc[section])
        if section == "frames":
            table["index"] = out_index.name
        if section == "archive":
            table["name"] = f"{table['name']}-x{frames}"
        lines.append(f"[{section}]")
        lines += [f"{key} = {_toml_value(value)}" for key, value in table.items()]
        lines.append("")
    out = catalog.parent / f"catalog-x{frames}.toml"
    out.write_text("\n".join(lines))
    return out


def _toml_value(value: Any) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)  # strings, numbers, booleans and lists read back as TOML


# -- runs ------------------------------------------------------------------------------------
def timed_run(
    catalog: Path,
    rundir: Path,
    *,
    scheduler: str | None,
    workers: int | None,
    stage_package: str,
) -> dict[str, Any]:
    """One fresh ``run`` with wall time, steady-state rate, per-stage seconds and peak RSS.

    ``rundir`` is removed first when it exists; benchmarks that time the engine's own cost
    give a new directory instead (:func:`_fresh_rundir`).
    """
    shutil.rmtree(rundir, ignore_errors=True)
    finished: list[float] = []
    times0 = os.times()

    def progress(done: int, total: int, frame_id: str) -> None:
        finished.append(time.perf_counter())

    with PeakRSS() as memory:
        start = time.perf_counter()
        summary = run(
            catalog,
            rundir,
            scheduler=scheduler,
            workers=workers,
            stage_package=stage_package,
            progress=progress,
        )
        wall = time.perf_counter() - start
    sys_s = os.times().system - times0.system  # this process: the engine of synchronous runs
    frames = pq.read_table(rundir / "frames.parquet").to_pylist()
    stages = [k[: -len("_seconds")] for k in frames[0] if k.endswith("_seconds")]
    per_stage = {
        s: statistics.fmean(f[f"{s}_seconds"] for f in frames if f[f"{s}_seconds"] is not None)
        for s in stages
    }
    n = summary.done + summary.failed
    steady = (len(finished) - 1) / (finished[-1] - finished[0]) if len(finished) > 2 else None
    cpu = memory.cpu_driver + memory.cpu_workers
    return {
        "scheduler": scheduler or "local processes",
        "workers": workers,
        "frames": n,
        "done": summary.done,
        "failed": summary.failed,
        "wall_s": round(wall, 2),
        "pairs_per_s": round(n / wall, 3),
        "steady_pairs_per_s": round(steady, 3) if steady else None,
        "time_to_first_frame_s": round(finished[0] - start, 2) if finished else None,
        "cpu_s": round(cpu, 2),
        "cpu_s_per_frame": round(cpu / n, 4) if n else None,
        "driver_sys_cpu_s_per_frame": round(sys_s / n, 4) if n else None,
        "stage_seconds_mean": {s: round(v, 4) for s, v in per_stage.items()},
        "task_seconds_mean": round(sum(per_stage.values()), 4),
        "tasks_per_frame": 1,  # process_frame: one task runs every pending stage of a frame
        **memory.as_dict(),
    }


def _load_frames(catalog: Path, stage_package: str, limit: int):
    cat = load_catalog(catalog)
    graph = build_graph(discover_stages(stage_package))
    params = resolve_stage_params(graph, cat.params)
    shape = cat.shape
    contexts = []
    for frame in cat.frames[:limit]:
        contexts.append(
            FrameContext(
                frame_id=frame.frame_id,
                archive=cat.name,
                camera=frame.camera,
                metadata=dict(frame.metadata),
                left_path=frame.left,
                right_path=frame.right,
                image_shape=shape,
            )
        )
    return graph, params, contexts


def pure_compute(catalog: Path, stage_package: str, limit: int) -> dict[str, Any]:
    """Every stage's ``run`` in graph order on numpy arrays, in this process, nothing stored.

    One warm-up frame first (numba compilation, imports), then the timed loop. OpenCV runs
    on one thread, as in the engine's workers.
    """
    import cv2

    cv2.setNumThreads(1)  # as pipeline.worker does in every task: one worker, one core
    graph, params, contexts = _load_frames(catalog, stage_package, limit)
    per_stage = {s.name: 0.0 for s in graph.stages}

    def one(ctx: FrameContext) -> None:
        produced: dict[str, Any] = {}
        for stage in graph.stages:
            inputs = {n: produced[n] for n in stage.inputs + stage.optional_inputs if n in produced}
            t = time.perf_counter()
            result = stage.run(inputs, frame=ctx, params=dict(params[stage.name]))
            per_stage[stage.name] += time.perf_counter() - t
            produced.update(result.arrays)

    one(contexts[0])
    per_stage = dict.fromkeys(per_stage, 0.0)
    # sampled like the engine's runs (timed_run), so that the sampler's own CPU cancels
    with PeakRSS():
        start, cpu_start, times0 = time.perf_counter(), time.process_time(), os.times()
        for ctx in contexts:
            one(ctx)
        wall = time.perf_counter() - start
        cpu = time.process_time() - cpu_start
        sys_s = os.times().system - times0.system
    n = len(contexts)
    return {
        "frames": n,
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "cpu_s_per_frame": round(cpu / n, 4),
        "sys_cpu_s_per_frame": round(sys_s / n, 4),
        "pairs_per_s": round(n / wall, 3),
        "stage_seconds_mean": {s: round(v / n, 4) for s, v in per_stage.items()},
    }


def sgbm_alone(catalog: Path, stage_package: str, limit: int) -> dict[str, Any] | None:
    """OpenCV StereoSGBM (the evaluation baseline) on the same frames, images preloaded."""
    import cv2

    from pipeline._baselines import sgbm_disparity

    _graph, params, contexts = _load_frames(catalog, stage_package, limit)
    cv2.setNumThreads(1)  # the engine's workers run OpenCV on one thread each
    jobs = []
    for ctx in contexts:
        left = cv2.imread(str(ctx.left_path), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(ctx.right_path), cv2.IMREAD_GRAYSCALE)
        jobs.append((left, right, _disparity_range(ctx, left.shape, params.get("depth", {}))))
    sgbm_disparity(jobs[0][0], jobs[0][1], min_disparity=jobs[0][2][0], max_disparity=jobs[0][2][1])
    start = time.perf_counter()
    for left, right, (lo, hi) in jobs:
        sgbm_disparity(left, right, min_disparity=lo, max_disparity=hi)
    wall = time.perf_counter() - start
    pairs = jobs
    kwargs = {"disparity_range_first_frame": jobs[0][2]}
    return {
        "frames": len(pairs),
        "wall_s": round(wall, 3),
        "pairs_per_s": round(len(pairs) / wall, 2),
        "sgbm_kwargs": kwargs,
    }


def _disparity_range(ctx: FrameContext, shape: tuple[int, ...], depth: dict) -> tuple[int, int]:
    """The range the depth stage searches for this frame (SGBM needs min >= 0)."""
    if "min_disparity" not in depth:  # a stage package without the real depth stage
        return 0, 64
    from stages.depth import resolve_disparity_range

    lo, hi = resolve_disparity_range(ctx.camera, tuple(shape), dict(depth))
    return max(lo, 0), hi


# -- commands --------------------------------------------------------------------------------
def _catalog(args: argparse.Namespace, frames: int) -> Path:
    if args.catalog:
        base = Path(args.catalog)
        n = len(load_catalog(base).frames)
        return base if n == frames else repeat_catalog(base, frames)
    unique = min(args.unique or frames, frames)
    base = ensure_archive(args.workdir, args.archetype, unique, args.size, args.seed)
    return base if unique == frames else repeat_catalog(base, frames)


def _fresh_run(
    catalog: Path, rundir: Path, scheduler: str | None, workers: int, args: argparse.Namespace
) -> dict[str, Any]:
    """``timed_run`` in a new interpreter, so that the peak RSS of one run is not the
    high-water mark left by the previous one."""
    command = [
        sys.executable,
        __file__,
        "single",
        "--catalog",
        str(catalog),
        "--rundir",
        str(rundir),
        "--workers",
        str(workers),
        "--stage-package",
        args.stage_package,
    ]
    if scheduler:
        command += ["--scheduler", scheduler]
    done = subprocess.run(command, check=True, capture_output=True, text=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    print(json.dumps(result), flush=True)
    return result


def cmd_single(args: argparse.Namespace) -> dict[str, Any]:
    return timed_run(
        Path(args.catalog),
        args.rundir,
        scheduler=args.scheduler,
        workers=args.workers,
        stage_package=args.stage_package,
    )


def cmd_throughput(args: argparse.Namespace) -> dict[str, Any]:
    catalog = _catalog(args, args.frames[0])
    runs = []
    setups: list[tuple[str | None, int]] = [(None, 1), (None, 2)]
    if args.threads:
        setups.append(("threads", 2))
    for scheduler, workers in setups:
        label = f"{scheduler or 'processes'}-{workers}"
        result = _fresh_run(catalog, _fresh_rundir(args, label), scheduler, workers, args)
        runs.append(result)
    _remove_rundirs(args)  # after the last run: a deletion slows the next run's file creation
    one, two = runs[0], runs[1]
    efficiency = {
        "whole_run": round(two["pairs_per_s"] / (2 * one["pairs_per_s"]), 3),
        "steady_state": round(two["steady_pairs_per_s"] / (2 * one["steady_pairs_per_s"]), 3)
        if one["steady_pairs_per_s"] and two["steady_pairs_per_s"]
        else None,
    }
    return {"catalog": str(catalog), "runs": runs, "parallel_efficiency": efficiency}


def _without_fsync() -> Any:
    """Context in which the engine skips its fsyncs: attributes their cost, never a setting."""
    import contextlib
    from unittest import mock

    import pipeline.journal
    import pipeline.store

    stack = contextlib.ExitStack()
    stack.enter_context(mock.patch.object(pipeline.journal, "sync_filesystem", lambda path: None))
    stack.enter_context(mock.patch.object(pipeline.store.os, "fsync", lambda fd: None))
    return stack


def _stage_cpu_meter(stage_package: str) -> Any:
    """Context in which every stage's ``run`` adds its CPU seconds (``time.process_time``)
    to the yielded dict under ``'stages'`` and under its own name, for in-process
    (synchronous) engine runs: the engine's own CPU is then the run's CPU minus that,
    without the pure loop's noise."""
    import contextlib
    import dataclasses

    import pipeline.worker

    @contextlib.contextmanager
    def meter() -> Any:
        stages = pipeline.worker._stages(stage_package)  # the worker's cached stage objects
        original = dict(stages)
        spent = {"stages": 0.0}

        def wrap(name: str, run_: Any) -> Any:
            def timed(*a: Any, **k: Any) -> Any:
                start = time.process_time()
                try:
                    return run_(*a, **k)
                finally:
                    seconds = time.process_time() - start
                    spent["stages"] += seconds
                    spent[name] = spent.get(name, 0.0) + seconds

            return timed

        for name, stage in original.items():
            stages[name] = dataclasses.replace(stage, run=wrap(name, stage.run))
        try:
            yield spent
        finally:
            stages.update(original)

    return meter()


def _fresh_rundir(args: argparse.Namespace, label: str) -> Path:
    """A run directory of a new name, to be removed by :func:`_remove_rundirs` after the
    last measurement.

    The engine creates ~65 files and directories per frame. On ext4 without a journal (this
    machine's root filesystem) allocating an inode skips, one by one, the inodes deleted in
    the last 60 s (6 min while their inode table block is dirty; ``find_inode_bit`` /
    ``recently_deleted``): removing the previous run's directory (~2,000 inodes) just before
    a run raised the engine's system CPU from 2-3 to 17-25 ms per frame, growing with every
    round (measured with the stages replayed, 30 frames), which the pure loop, creating no
    files, never paid.
    """
    rundir = args.workdir / "runs" / f"{label}-{os.getpid()}-{time.monotonic_ns():x}"
    args.rundirs.append(rundir)
    return rundir


def _remove_rundirs(args: argparse.Namespace) -> None:
    for rundir in args.rundirs:
        shutil.rmtree(rundir, ignore_errors=True)
    args.rundirs.clear()


def cmd_overhead(args: argparse.Namespace) -> dict[str, Any]:
    """Pure compute and the engine alternately (``--repeats`` rounds) so that load drift on a
    shared machine hits both; the engine's own time is also measured inside each run as
    wall time minus the stage time it recorded, and as CPU seconds of the engine run minus
    those of the pure loop (``engine_own_cpu_s_per_frame``; both run in this process, so
    the CPU of zarr's and blosc's threads is counted)."""
    frames = args.frames[0]
    catalog = _catalog(args, frames)
    pures, engines, bare = [], [], []
    for round_ in range(args.repeats):
        pures.append(pure_compute(catalog, args.stage_package, frames))
        print("pure", json.dumps(pures[-1]), flush=True)
        with _stage_cpu_meter(args.stage_package) as spent:
            engine = timed_run(
                catalog,
                _fresh_rundir(args, "overhead-sync"),
                scheduler="synchronous",
                workers=None,
                stage_package=args.stage_package,
            )
        engine["stage_cpu_s"] = round(spent["stages"], 2)
        engine["own_cpu_s_per_frame"] = round(
            (engine["cpu_s"] - spent["stages"]) / engine["frames"], 4
        )
        engines.append(engine)
        print("engine", json.dumps(engines[-1]), flush=True)
        if round_ == 0:
            with _without_fsync():
                bare.append(
                    timed_run(
                        catalog,
                        _fresh_rundir(args, "overhead-sync"),
                        scheduler="synchronous",
                        workers=None,
                        stage_package=args.stage_package,
                    )
                )
            print("engine without fsync", json.dumps(bare[-1]), flush=True)
    sgbm = sgbm_alone(catalog, args.stage_package, frames)
    print("sgbm", json.dumps(sgbm), flush=True)
    _remove_rundirs(args)

    def own(run_: dict[str, Any]) -> float:
        return run_["wall_s"] / run_["frames"] - run_["task_seconds_mean"]

    pure_s = statistics.median(r["wall_s"] for r in pures)
    engine_s = statistics.median(r["wall_s"] for r in engines)
    own_s = statistics.median(own(r) for r in engines)
    compute_s = statistics.median(r["task_seconds_mean"] for r in engines)
    # each round's pure loop and engine run are minutes apart at most: their ratio is less
    # exposed to load drift than the ratio of medians over rounds
    rounds = [
        {
            "wall": round(e["wall_s"] / p["wall_s"], 3),
            "cpu": round(e["cpu_s"] / p["cpu_s"], 3),
            "own_cpu_s_per_frame": round(e["cpu_s_per_frame"] - p["cpu_s_per_frame"], 4),
        }
        for p, e in zip(pures, engines, strict=True)
    ]
    return {
        "catalog": str(catalog),
        "pure_compute": pures,
        "engine_synchronous": engines,
        "engine_without_fsync": bare,
        "rounds": rounds,
        "engine_over_pure_cpu": statistics.median(r["cpu"] for r in rounds),
        "engine_own_cpu_s_per_frame": statistics.median(r["own_cpu_s_per_frame"] for r in rounds),
        # system CPU (the kernel's, os.times): the engine's file creation and writes show
        # as the engine's excess over the pure loop's (page faults of the stages' arrays)
        "engine_sys_cpu_s_per_frame": statistics.median(
            e["driver_sys_cpu_s_per_frame"] for e in engines
        ),
        "pure_sys_cpu_s_per_frame": statistics.median(p["sys_cpu_s_per_frame"] for p in pures),
        # measured inside each engine run: its CPU minus the CPU spent in the stages' run()
        "engine_own_cpu_in_run_s_per_frame": statistics.median(
            e["own_cpu_s_per_frame"] for e in engines
        ),
        "engine_own_cpu_over_stage_cpu": statistics.median(
            e["own_cpu_s_per_frame"] * e["frames"] / e["stage_cpu_s"] for e in engines
        ),
        "engine_over_pure_wall": round(engine_s / pure_s, 3),
        "engine_own_seconds_per_frame": round(own_s, 4),
        "engine_own_over_stage_compute": round(own_s / compute_s, 3),
        "fsync_seconds_per_frame": round(own_s - own(bare[0]), 4) if bare else None,
        "sgbm_alone": sgbm,
        "engine_over_sgbm": round(engine_s / sgbm["wall_s"], 2),
    }


def _engine_cpu_meter(spent: dict[str, float]) -> Any:
    """Context in which the worker's product writes and the driver's journal flushes add
    their CPU seconds to ``spent`` (``engine:...`` keys), for synchronous runs."""
    import contextlib
    from unittest import mock

    import pipeline.journal
    import pipeline.worker

    def wrap(label: str, fn: Any) -> Any:
        def timed(*a: Any, **k: Any) -> Any:
            start = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                spent[label] = spent.get(label, 0.0) + time.process_time() - start

        return timed

    stack = contextlib.ExitStack()
    for owner, name, label in (
        (pipeline.worker, "write_frame_array", "engine:zarr_write"),
        (pipeline.worker, "read_frame_array", "engine:zarr_read"),
        (pipeline.worker, "write_product_file", "engine:file_write"),
        (pipeline.journal.Journal, "flush", "engine:journal_flush"),
    ):
        stack.enter_context(mock.patch.object(owner, name, wrap(label, getattr(owner, name))))
    return stack


def cmd_cpu(args: argparse.Namespace) -> dict[str, Any]:
    """CPU seconds per frame of each stage and of the engine, one synchronous run in this
    process (``time.process_time``: what a shared machine's other jobs do not inflate).
    Imports and the numba cache load happen before the timed run; ``engine`` is the run's
    CPU minus its stages' (zarr writes, PNG files, journal, Parquet, run set-up), with the
    named parts of it under ``engine:...``."""
    frames = args.frames[0]
    catalog = _catalog(args, frames)
    rundir = _fresh_rundir(args, "cpu-sync")
    import pipeline.worker

    pipeline.worker._stages(args.stage_package)  # import the stages outside the timing
    # pyarrow imports pandas at its first conversion of a numpy array (the journal's first
    # flush): a one-off import, as the stages', not a per-frame cost
    pa.array(np.zeros(1))
    with _stage_cpu_meter(args.stage_package) as spent, _engine_cpu_meter(spent):
        start = time.process_time()
        summary = run(catalog, rundir, scheduler="synchronous", stage_package=args.stage_package)
        total = time.process_time() - start
    _remove_rundirs(args)
    n = summary.done + summary.failed
    per_frame = {k: round(v / n, 4) for k, v in spent.items() if k != "stages"}
    return {
        "catalog": str(catalog),
        "frames": n,
        "failed": summary.failed,
        "cpu_s_per_frame": round(total / n, 4),
        "stage_cpu_s_per_frame": round(spent["stages"] / n, 4),
        "engine_cpu_s_per_frame": round((total - spent["stages"]) / n, 4),
        "per_frame": per_frame,
    }


def cmd_memory(args: argparse.Namespace) -> dict[str, Any]:
    runs = []
    for frames in args.frames:
        catalog = _catalog(args, frames)
        result = _fresh_run(catalog, _fresh_rundir(args, f"memory-{frames}"), None, 2, args)
        runs.append(result)
    _remove_rundirs(args)
    first, last = runs[0], runs[-1]
    growth = {
        key: round(last[key] / first[key] - 1, 3)
        for key in ("peak_rss_total_mb", "peak_rss_driver_mb", "peak_rss_worker_mb")
    }
    return {"runs": runs, "growth_first_to_last": growth}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "command", choices=("throughput", "overhead", "memory", "machine", "single", "cpu")
    )
    parser.add_argument("--frames", type=int, nargs="+", default=[200])
    parser.add_argument("--unique", type=int, default=None, help="render only this many")
    parser.add_argument("--size", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--archetype", default="mojave")
    parser.add_argument("--threads", action="store_true", help="also 1 process x 2 threads")
    parser.add_argument("--catalog", default=None, help="benchmark this catalog instead")
    parser.add_argument("--stage-package", default="stages")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/arroyo-bench"))
    parser.add_argument("--repeats", type=int, default=2, help="overhead: rounds")
    parser.add_argument("--rundir", type=Path, help="single: the run directory")
    parser.add_argument("--scheduler", default=None, help="single: scheduler")
    parser.add_argument("--workers", type=int, default=None, help="single: workers")
    parser.add_argument("--json", type=Path, default=None, help="append results here")
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    args.rundirs = []  # run directories to remove after the measurements
    command = {
        "throughput": cmd_throughput,
        "overhead": cmd_overhead,
        "memory": cmd_memory,
        "machine": lambda _a: {},
        "single": cmd_single,
        "cpu": cmd_cpu,
    }[args.command]
    if args.command == "single":  # one JSON line for the parent process
        print(json.dumps(cmd_single(args)))
        return
    result = {
        "command": args.command,
        "argv": argv if argv is not None else sys.argv[1:],
        "machine": machine(),
        **command(args),
    }
    text = json.dumps(result, indent=2, default=str)
    print(text)
    if args.json:
        with open(args.json, "a") as fh:
            fh.write(json.dumps(result, default=str) + "\n")


if __name__ == "__main__":
    main()
