"""Tests of pipeline.executor: the in-process and local-cluster executors."""

from __future__ import annotations

import logging

from pipeline.executor import _ShutdownHeartbeatFilter, open_executor


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
