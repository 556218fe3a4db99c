"""Tests of pipeline.executor: the in-process and local-cluster executors."""

from __future__ import annotations

import logging
import os

import dask
import pytest

from pipeline.errors import ParamError
from pipeline.executor import (
    _ShutdownHeartbeatFilter,
    _worker_environ,
    check_scheduler,
    open_executor,
)


def _record(msg: str) -> logging.LogRecord:
    return logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, msg, None, None)


def test_shutdown_heartbeat_filter_drops_only_the_heartbeat_record():
    # regression: a local cluster's worker printed a "Failed to communicate with scheduler
    # during heartbeat" traceback after a finished run's summary (scheduler closed first)
    keep = _ShutdownHeartbeatFilter()
    assert not keep.filter(_record("Failed to communicate with scheduler during heartbeat."))
    assert keep.filter(_record("Compute Failed"))
    assert keep.filter(_record("Worker stream died during communication"))


def test_threads_executor_runs_items_and_closes_with_the_filter_installed():
    executor = open_executor(scheduler="threads", workers=2)
    try:
        results = dict(executor.map_unordered(lambda x: x * x, range(5)))
    finally:
        executor.close()
    assert results == {i: i * i for i in range(5)}
    worker_log = logging.getLogger("distributed.worker")
    assert any(isinstance(f, _ShutdownHeartbeatFilter) for f in worker_log.filters)


def _malloc_and_threads() -> tuple[str | None, str | None]:
    return os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OMP_NUM_THREADS")


def _housekeeping(dask_worker) -> tuple[bool, float]:
    callbacks = dask_worker.periodic_callbacks
    return "profile" in callbacks, callbacks["memory_monitor"].callback_time


def test_local_threads_worker_runs_without_the_profiler_and_with_slower_monitors():
    # the profiler sampled the running frame's stack every 10 ms (~3 % of a frame's CPU);
    # the 100 ms memory monitor was most of an idle cluster's CPU
    executor = open_executor(scheduler="threads", workers=1)
    try:
        seen = executor.client.run(_housekeeping)  # type: ignore[attr-defined]
    finally:
        executor.close()
    assert list(seen.values()) == [(False, 500)]
    assert dask.config.get("distributed.worker.profile.enabled")  # only its own workers


def test_worker_environ_keeps_dask_thread_limits_without_the_malloc_trim_threshold():
    environ = _worker_environ()
    assert "MALLOC_TRIM_THRESHOLD_" not in environ
    assert {environ[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")} == {1}


@pytest.mark.slow
def test_local_worker_processes_run_without_the_malloc_trim_threshold(monkeypatch):
    # regression: dask's MALLOC_TRIM_THRESHOLD_=65536 turned every temporary array above
    # 128 KiB into a fresh mmap; a 500x500 frame spent ~0.09 s more CPU in the kernel
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    executor = open_executor(scheduler=None, workers=2)
    try:
        seen = executor.client.run(_malloc_and_threads)  # type: ignore[attr-defined]
        housekeeping = executor.client.run(_housekeeping)  # type: ignore[attr-defined]
        results = dict(executor.map_unordered(abs, [-1, -2, -3]))
    finally:
        executor.close()
    assert len(seen) == 2 and set(seen.values()) == {(None, "1")}
    assert list(housekeeping.values()) == [(False, 500)] * 2  # the nannies passed it on
    assert results == {-1: 1, -2: 2, -3: 3}


@pytest.mark.parametrize("address", ["bogus", "thread", "tcp://host"])
def test_scheduler_that_is_no_address_is_a_param_error(address):
    """Bug: `--scheduler bogus` said only "missing port number in address 'bogus'", after
    the run directory was made."""
    with pytest.raises(ParamError, match="expected 'threads', 'synchronous' or the address"):
        check_scheduler(address)
    for fine in (None, "threads", "synchronous", "tcp://10.0.0.5:8786", "10.0.0.5:8786"):
        check_scheduler(fine)


def test_unreachable_scheduler_is_a_param_error(monkeypatch):
    """Bug: an unreachable --scheduler address ended in OSError's traceback (exit 1)."""
    import distributed

    def unreachable(address, timeout):
        raise OSError(f"Timed out trying to connect to {address} after {timeout}")

    monkeypatch.setattr(distributed, "Client", unreachable)
    with pytest.raises(ParamError, match="cannot reach the dask scheduler .Timed out"):
        open_executor(scheduler="tcp://127.0.0.1:9", workers=None)


def test_a_run_whose_scheduler_is_unreachable_is_recorded_stopped(archive, tmp_path, monkeypatch):
    """run.json said 'running' (status: 'interrupted') for a run whose cluster never came."""
    import json

    import distributed

    from pipeline.runner import run
    from pipeline.status import status

    def unreachable(address, timeout):
        raise OSError("Timed out")

    monkeypatch.setattr(distributed, "Client", unreachable)
    out = tmp_path / "run"
    with pytest.raises(ParamError):
        run(archive, out, scheduler="tcp://127.0.0.1:9", stage_package="arroyo_fake_stages")
    assert json.loads((out / "run.json").read_text())["status"] == "stopped"
    assert status(out).run_state == "stopped"


def test_ctrl_c_while_a_local_cluster_starts_waits_for_it_then_closes_it(monkeypatch):
    """Bug: a ^C while the local cluster started stopped the fork server under nannies still
    forking workers, and dask logged a traceback per nanny; the ^C now waits for the
    cluster, which is closed before the KeyboardInterrupt goes on."""
    import signal

    import distributed

    real = distributed.LocalCluster
    made = []

    def interrupted_start(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # the terminal's ^C, in the middle of the start
        made.append(real(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(distributed, "LocalCluster", interrupted_start)
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        open_executor(scheduler="threads", workers=1)
    assert made and made[0].status.name == "closed"
    assert signal.getsignal(signal.SIGINT) is handler


def test_sigterm_while_a_local_cluster_starts_is_held_like_ctrl_c(monkeypatch):
    """A SIGTERM (now a stop like ^C, see test_runner) during the cluster's start waits for
    it, closes it, then stops: not a dask traceback per nanny."""
    import signal

    import distributed

    from pipeline.executor import terminate_as_interrupt

    real = distributed.LocalCluster
    made = []

    def terminated_start(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        made.append(real(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(distributed, "LocalCluster", terminated_start)
    handler = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), terminate_as_interrupt():
        open_executor(scheduler="threads", workers=1)
    assert made and made[0].status.name == "closed"
    assert signal.getsignal(signal.SIGTERM) is handler


def test_scheduler_without_workers_is_a_param_error(monkeypatch):
    """Regression: a reachable `dask scheduler` with no worker took the frames and the run
    waited forever without a word; it now stops (exit 2) once no worker joined in time."""
    import distributed

    import pipeline.executor

    monkeypatch.setattr(pipeline.executor, "WORKER_WAIT_SECONDS", 0.5)
    with distributed.LocalCluster(
        n_workers=0, processes=False, dashboard_address=":0"
    ) as cluster:
        with pytest.raises(ParamError, match="has no worker .*start workers with `dask worker"):
            open_executor(scheduler=cluster.scheduler_address, workers=None)


def test_regression_workers_from_a_batch_queue_got_only_60_s(monkeypatch):
    """Regression: a run on a remote scheduler stopped after a fixed 60 s without a worker,
    too short for workers submitted to a batch queue; ``worker_wait`` sets the wait."""
    import distributed

    import pipeline.executor

    monkeypatch.setattr(pipeline.executor, "WORKER_WAIT_SECONDS", 3600.0)  # never reached
    with distributed.LocalCluster(
        n_workers=0, processes=False, dashboard_address=":0"
    ) as cluster:
        with pytest.raises(ParamError, match=r"none joined within 0.3 s.*--wait-for-workers"):
            open_executor(scheduler=cluster.scheduler_address, workers=None, worker_wait=0.3)
    for bad in (0, -1.0, float("nan"), float("inf"), True, "60"):
        with pytest.raises(ParamError, match="--wait-for-workers"):
            open_executor(scheduler="tcp://127.0.0.1:1", workers=None, worker_wait=bad)
