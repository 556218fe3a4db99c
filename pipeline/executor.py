"""Where frame tasks run: in-process, a local dask.distributed cluster, or a remote one."""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

from ._forkserver import forkserver_supported, start_forkserver, stop_forkserver
from .errors import ParamError
from .graph import stage_package_name

__all__ = [
    "Executor",
    "open_executor",
    "local_processes",
    "prestart_local_workers",
    "describe_scheduler",
    "check_scheduler",
    "check_workers",
    "check_worker_wait",
    "terminate_as_interrupt",
]

_SCHEDULER_EXPECTED = (
    "expected 'threads', 'synchronous' or the address of a running dask scheduler such as "
    "tcp://host:8786 (leave --scheduler out for local worker processes)"
)


class Executor:
    """Run ``fn(item)`` for each item, at most ``window`` in flight, yielding results as they
    finish. A task whose worker died repeatedly yields ``(item, exception)``."""

    name = "synchronous"
    workers = 1

    def map_unordered(
        self, fn: Callable[[Any], Any], items: Iterable[Any]
    ) -> Iterator[tuple[Any, Any]]:
        for item in items:
            yield item, fn(item)

    def close(self) -> None:
        pass


class _DistributedExecutor(Executor):
    def __init__(self, client: Any, cluster: Any | None, name: str) -> None:
        self.client = client
        self.cluster = cluster
        self.name = name
        self.forkserver = False  # whether closing stops this process's fork server
        info = client.scheduler_info()
        self.workers = max(1, sum(w.get("nthreads", 1) for w in info["workers"].values()))

    def map_unordered(
        self, fn: Callable[[Any], Any], items: Iterable[Any]
    ) -> Iterator[tuple[Any, Any]]:
        from distributed import as_completed

        pending = iter(items)
        window = 2 * self.workers + 2  # keeps every worker busy, bounds driver memory
        owner: dict[Any, Any] = {}
        done = as_completed()
        for item in pending:
            future = self.client.submit(fn, item, pure=False)
            owner[future.key] = item
            done.add(future)
            if len(owner) >= window:
                break
        for future in done:
            item = owner.pop(future.key)
            try:
                result = future.result()
            except Exception as exc:  # KilledWorker, lost connection... reported per item
                result = exc
            future.release()
            yield item, result
            nxt = next(pending, None)
            if nxt is not None:
                new = self.client.submit(fn, nxt, pure=False)
                owner[new.key] = nxt
                done.add(new)

    def close(self) -> None:
        if self.cluster is not None:
            # a local cluster's scheduler may close while a worker is mid-heartbeat; the
            # worker then logs a harmless traceback after the run's summary (dask/distributed
            # #9032): filter exactly that record on the workers before closing
            try:
                self.client.run(_install_heartbeat_filter)
            except Exception:  # a dead worker must not turn a finished run into a failure
                pass
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        if self.forkserver:
            stop_forkserver()


class _ShutdownHeartbeatFilter(logging.Filter):
    """Drop the worker's "failed heartbeat" record, which only a closing scheduler causes."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(_HEARTBEAT_FAILURE)


_HEARTBEAT_FAILURE = "Failed to communicate with scheduler during heartbeat"


def _install_heartbeat_filter() -> None:
    worker_log = logging.getLogger("distributed.worker")
    if not any(isinstance(f, _ShutdownHeartbeatFilter) for f in worker_log.filters):
        worker_log.addFilter(_ShutdownHeartbeatFilter())


def local_processes(scheduler: str | None, workers: int | None) -> bool:
    """Whether ``open_executor`` starts local worker processes (else threads, in-process
    or remote workers): a local cluster of more than one worker."""
    return scheduler is None and (workers or os.cpu_count() or 1) > 1


def prestart_local_workers(
    scheduler: str | None, workers: int | None, stage_package: str | None
) -> bool:
    """Start warming the worker processes that ``open_executor`` will start, if it starts
    local ones, so that their imports overlap the caller's planning; return whether it
    did (the caller then calls :func:`pipeline._forkserver.stop_forkserver` when done)."""
    if not (local_processes(scheduler, workers) and forkserver_supported()):
        return False
    start_forkserver(stage_package_name(stage_package), environ=_worker_environ())
    return True


def open_executor(
    *,
    scheduler: str | None,
    workers: int | None,
    stage_package: str | None = None,
    worker_wait: float | None = None,
) -> Executor:
    """The executor for ``--scheduler`` / ``--workers``.

    Parameters
    ----------
    scheduler : str, optional
        ``None`` (a local dask.distributed cluster of ``workers`` processes), ``'threads'``
        (a local in-process cluster with ``workers`` threads), ``'synchronous'`` (no dask,
        one frame after another; for debugging), or the address of a running scheduler
        (``tcp://host:8786``).
    workers : int, optional
        Local worker count; default: the machine's cores.
    stage_package : str, optional
        The stage package local worker processes import before their first task (see
        :mod:`pipeline._forkserver`); default: :func:`pipeline.graph.stage_package_name`.
    worker_wait : float, optional
        Seconds (> 0) a remote ``scheduler`` may take to get its first worker before
        ParamError; default :data:`WORKER_WAIT_SECONDS`.
    """
    check_workers(workers)
    wait = WORKER_WAIT_SECONDS if worker_wait is None else worker_wait
    check_worker_wait(wait)
    if scheduler == "synchronous":
        return Executor()
    from distributed import Client, LocalCluster

    if scheduler is None or scheduler == "threads":
        import dask

        n = workers or os.cpu_count() or 1
        processes = local_processes(scheduler, workers)
        # read by each nanny (or in-process worker) when it is created; a nanny passes it
        # on to its worker process, also when it restarts one
        config = {**_LOCAL_CLUSTER_CONFIG, "distributed.nanny.pre-spawn-environ": _worker_environ()}
        forked = processes and forkserver_supported()
        if forked:
            # workers forked from a warm server (pipeline._forkserver); the runner started it
            # before planning, else it starts here. A worker the nanny restarts after this
            # block is spawned as by default.
            config["distributed.worker.multiprocessing-method"] = "forkserver"
            start_forkserver(stage_package_name(stage_package), environ=_worker_environ())
        interrupt = _DeferredInterrupt()
        try:
            with interrupt, dask.config.set(config):
                cluster = LocalCluster(
                    n_workers=n if processes else 1,
                    threads_per_worker=1 if processes else n,
                    processes=processes,
                    dashboard_address=":0",  # a free port: never collide with another cluster
                    silence_logs=logging.ERROR,
                )
                kind = "processes" if processes else "threads"
                executor = _DistributedExecutor(
                    Client(cluster), cluster, f"local dask cluster, {n} {kind}"
                )
        except BaseException:
            if forked:
                stop_forkserver()
            raise
        executor.forkserver = forked
        if interrupt.caught:
            executor.close()
            raise KeyboardInterrupt
        return executor
    check_scheduler(scheduler)
    try:
        client = Client(scheduler, timeout="20s")
    except (OSError, ValueError, TypeError) as exc:
        # an unreachable address raised OSError's traceback (exit 1) after 20 s
        raise ParamError(
            f"--scheduler {scheduler}: cannot reach the dask scheduler ({exc}); check that "
            "`dask scheduler` runs there and its port is open, or leave --scheduler out for "
            "local worker processes"
        ) from None
    try:
        # a scheduler without workers took the frames and the run waited without a word
        client.wait_for_workers(1, timeout=wait)
    except (TimeoutError, OSError) as exc:
        client.close()
        raise ParamError(
            f"--scheduler {scheduler}: the dask scheduler has no worker (none joined within "
            f"{wait:g} s: {type(exc).__name__}); start workers with `dask worker {scheduler}` "
            "(give them longer with --wait-for-workers SECONDS, e.g. from a batch queue), or "
            "leave --scheduler out for local worker processes"
        ) from None
    return _DistributedExecutor(client, None, f"dask.distributed at {scheduler}")


WORKER_WAIT_SECONDS = 60.0
"""How long a run waits for a remote scheduler's first worker before it stops (exit 2), by
default (``--wait-for-workers``)."""


def check_worker_wait(seconds: float) -> None:
    """Raise ParamError unless ``seconds`` is a finite number > 0."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
        raise ParamError(
            f"--wait-for-workers expects seconds (a number > 0), got {seconds!r} "
            f"({type(seconds).__name__})"
        )
    if not (0 < seconds < float("inf")):
        raise ParamError(
            f"--wait-for-workers must be a finite number of seconds > 0, got {seconds!r}; "
            f"leave it out for {WORKER_WAIT_SECONDS:g} s"
        )


class _DeferredInterrupt:
    """Hold a ^C (SIGINT in the main thread) or a SIGTERM until the block ends; ``caught``
    says whether one came. A ^C while a local cluster started stopped the fork server under
    nannies still forking their workers, and dask logged a traceback for each."""

    def __init__(self) -> None:
        self.caught = False
        self._saved: dict[int, Any] = {}

    def _hold(self, signum: int, frame: Any) -> None:
        self.caught = True

    def __enter__(self) -> _DeferredInterrupt:
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._saved[signum] = signal.signal(signum, self._hold)
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._saved.items():
            signal.signal(signum, handler)
        self._saved.clear()


@contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block, a SIGTERM stops the main thread as a ^C does (KeyboardInterrupt).

    A batch system's time limit (SLURM, PBS), ``timeout`` and ``docker stop`` send SIGTERM:
    it killed the driver outright, so the frames of the journal's last batch were lost and
    the finished frames' rows stayed unpublished until a rerun. Further SIGTERMs are ignored
    while the run stops, so the publication finishes; the previous handler comes back after.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _stop(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt

    saved = signal.signal(signal.SIGTERM, _stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, saved)


def check_workers(workers: int | None) -> None:
    """Raise ParamError unless ``workers`` is None (the machine's cores) or an int >= 1."""
    if workers is None:
        return
    if isinstance(workers, bool) or not isinstance(workers, int):
        raise ParamError(
            f"--workers expects a whole number of local workers, got {workers!r} "
            f"({type(workers).__name__}); leave it out for one per core"
        )
    if workers < 1:
        raise ParamError(
            f"--workers must be >= 1, got {workers}; leave it out for one per core"
        )


def check_scheduler(scheduler: str | None) -> None:
    """Raise ParamError unless ``scheduler`` is None, 'threads', 'synchronous' or an
    address dask.distributed can parse (a bare word such as 'thread' is not)."""
    if scheduler is None or scheduler in ("threads", "synchronous"):
        return
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler)
        if scheme in ("tcp", "tls"):
            parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise ParamError(f"--scheduler {scheduler!r}: {exc}; {_SCHEDULER_EXPECTED}") from None


_LOCAL_CLUSTER_CONFIG: dict[str, Any] = {
    # Local clusters are the engine's own; a scheduler at an address keeps its owner's
    # settings. The worker's statistical profiler (the dashboard's Profile page) walks the
    # running task's stack every 10 ms on the worker's event loop, taking the GIL from the
    # task each time: measured on 40 mojave frames, one worker, three alternating rounds,
    # 0.321 s of CPU per frame with it, 0.311 without (3 %).
    "distributed.worker.profile.enabled": False,
    # Periodic housekeeping of every server, by default every 20 ms (event-loop tick),
    # 100 ms (worker memory monitor) and 500 ms (system monitor): an idle 2-worker local
    # cluster used 0.049 core-seconds per second with them, 0.0145 with these (~5 ms of
    # CPU per frame at 2 workers). Memory is still checked twice a second against the
    # spill / pause / terminate limits; a frame takes ~0.25 s and allocates ~100 MB.
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "500ms",
    "distributed.admin.system-monitor.interval": "2s",
}


def _worker_environ() -> dict[str, Any]:
    """Environment of local worker processes: dask's, without ``MALLOC_TRIM_THRESHOLD_``.

    dask sets that variable to 64 KiB so that idle workers hand memory back to the OS; it
    also switches off glibc's adaptive mmap threshold, so every temporary array above
    128 KiB (a frame's stages make hundreds of 1 MB ones) is a fresh mmap whose pages fault
    in and are zeroed by the kernel. Measured on 60 mojave frames, one worker process:
    system CPU 7.8-8.1 -> 2.1-3.0 s, worker CPU 0.49-0.51 -> 0.43 s per frame. A value the
    user exported is inherited by the workers unchanged.
    """
    import dask

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    return environ


def describe_scheduler(scheduler: str | None, workers: int | None) -> str:
    """How ``run.json`` and the progress line name the scheduler before it starts."""
    return scheduler or f"local ({workers or os.cpu_count()} workers)"
