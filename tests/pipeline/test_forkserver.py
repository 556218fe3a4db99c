"""Tests of pipeline._forkserver: local worker processes forked from a warm server."""

from __future__ import annotations

import multiprocessing.forkserver
import os
import signal
import sys
import time

import pytest

import pipeline.worker
from pipeline._forkserver import (
    forkserver_supported,
    start_forkserver,
    stop_forkserver,
    warm_stage_package,
)
from pipeline.executor import open_executor

FAKE = "arroyo_fake_stages"


def test_warm_stage_package_fills_the_workers_stage_cache():
    pipeline.worker._stages.cache_clear()
    warm_stage_package(FAKE)
    assert pipeline.worker._stages.cache_info().currsize == 1
    assert set(pipeline.worker._stages(FAKE)) == {"ingest", "blend", "tally"}
    assert pipeline.worker._stages.cache_info().hits == 1


def _warm_worker() -> tuple[bool, bool, int, bool]:
    stages = pipeline.worker._stages.cache_info().currsize  # set before any task ran
    ignores_sigint = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    return FAKE in sys.modules, "ARROYO_FORKSERVER_STAGES" in os.environ, stages, ignores_sigint


@pytest.mark.slow
@pytest.mark.skipif(not forkserver_supported(), reason="no fork server on this platform")
def test_local_workers_start_with_the_stage_package_imported_and_the_server_stops():
    executor = open_executor(scheduler=None, workers=2, stage_package=FAKE)
    try:
        seen = executor.client.run(_warm_worker)  # type: ignore[attr-defined]
        server = multiprocessing.forkserver._forkserver._forkserver_pid
        assert server is not None
        parents = executor.client.run(os.getppid)  # type: ignore[attr-defined]
        results = dict(executor.map_unordered(abs, [-1, -2]))
    finally:
        executor.close()
    # SIGINT ignored: a terminal's ^C (sent to the run's whole process group) printed a
    # traceback from the warming server and from each worker's interrupted shutdown
    assert list(seen.values()) == [(True, False, 1, True)] * 2
    assert set(parents.values()) == {server}  # forked by the server, not spawned
    assert results == {-1: 1, -2: 2}
    assert multiprocessing.forkserver._forkserver._forkserver_pid is None


@pytest.mark.skipif(not forkserver_supported(), reason="no fork server on this platform")
def test_stopping_a_warming_server_does_not_wait_for_its_imports():
    # a run that fails validation (or has nothing to do) stops the server it started
    start_forkserver("stages", environ={})  # imports for a second or more
    start = time.perf_counter()
    stop_forkserver()
    assert time.perf_counter() - start < 0.5
    assert multiprocessing.forkserver._forkserver._forkserver_pid is None


@pytest.mark.skipif(not forkserver_supported(), reason="no fork server on this platform")
def test_server_stops_when_every_start_was_undone():
    # two runs in one process (threads) share the server: the first to end must not stop
    # it under the other's workers
    start_forkserver("stages", environ={})
    start_forkserver("stages", environ={})
    pid = multiprocessing.forkserver._forkserver._forkserver_pid
    stop_forkserver()
    assert multiprocessing.forkserver._forkserver._forkserver_pid == pid
    stop_forkserver()
    assert multiprocessing.forkserver._forkserver._forkserver_pid is None
    stop_forkserver()  # one too many: nothing to do


def test_a_python_without_the_private_server_object_keeps_spawn(monkeypatch):
    # the server object and its _stop are multiprocessing's private API: if a Python moves
    # them, local workers must start as dask starts them, not fail
    monkeypatch.setattr(multiprocessing.forkserver, "_forkserver", object())
    assert not forkserver_supported()
