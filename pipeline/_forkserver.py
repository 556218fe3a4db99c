"""A warm fork server for local worker processes.

dask starts each local worker process with ``spawn``: a fresh interpreter that imports
dask.distributed and the run's main module, then, at its first task, the stage package
(numba, scipy, OpenCV, zarr...). Every worker pays that alone, after the driver has planned
the run. With a fork server the imports are paid once, in one process that the runner
starts before it validates the catalog, so that they run beside the driver's own start-up;
the workers are forked from it with the stage package imported.

The server is multiprocessing's (one per driver process). :func:`stop_forkserver` ends it
after each run: a server kept for the next run would hand its workers the stage code it
imported when it started, not the code on disk (stages edited in a notebook session).
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import multiprocessing.forkserver
import os
import signal
import sys
import threading
from collections.abc import Iterator, Mapping
from typing import Any

__all__ = ["forkserver_supported", "start_forkserver", "stop_forkserver", "warm_stage_package"]

# what dask.distributed preloads in its own fork servers (distributed.utils.get_mp_context)
_DISTRIBUTED = ["distributed", "dask", "msgpack", "cloudpickle", "tornado", "toolz", "numpy"]
# names the stage package to warm; set only in the server's environment
_WARM_VAR = "ARROYO_FORKSERVER_STAGES"
_PATH_VAR = "ARROYO_FORKSERVER_PATH"
# what start/stop_forkserver use of multiprocessing.forkserver's private server object
_SERVER_API = ("set_forkserver_preload", "ensure_running", "_forkserver_pid", "_stop")
_lock = threading.Lock()
_users = 0  # start_forkserver calls not yet undone by stop_forkserver


def forkserver_supported() -> bool:
    """Whether this platform has multiprocessing's fork server (not Windows) and this
    Python the server object :func:`start_forkserver` and :func:`stop_forkserver` reach
    (private to multiprocessing: a Python that moved it keeps dask's ``spawn``)."""
    server = getattr(multiprocessing.forkserver, "_forkserver", None)
    return (
        "forkserver" in multiprocessing.get_all_start_methods()
        and all(hasattr(server, name) for name in _SERVER_API)
    )


def start_forkserver(stage_package: str, *, environ: Mapping[str, Any]) -> None:
    """Start the fork server (unless one runs) importing dask.distributed and
    ``stage_package``, with ``environ`` added to its environment.

    Returns as soon as the server process exists; it imports in the background and the
    first worker fork waits for it. Warming never fails the server: what it could not
    import, a worker imports (and reports) at its first task.

    Parameters
    ----------
    stage_package : str
        The run's stage package (see :func:`pipeline.graph.stage_package_name`).
    environ : mapping of str to object
        Environment of the server and so of every worker forked from it (dask's
        ``distributed.nanny.pre-spawn-environ``: thread limits that must be set before
        numpy is imported); values are converted with ``str``.
    """
    global _users
    server = multiprocessing.forkserver._forkserver  # the one 'forkserver' contexts use
    # this module first: it shields the server (and so its workers) from ^C before the rest
    server.set_forkserver_preload([__name__, *_DISTRIBUTED])
    extra = {k: str(v) for k, v in environ.items()}
    # the server sets the driver's sys.path only in the processes it forks (CPython 3.11
    # ignores it while preloading); the stage package may be on it alone (tests, notebooks)
    path = json.dumps(sys.path)
    with _lock, _environ({**extra, _WARM_VAR: stage_package, _PATH_VAR: path}):
        server.ensure_running()
        _users += 1


def stop_forkserver() -> None:
    """Undo one :func:`start_forkserver`: the last one stops the server, at once.

    Call it when no worker forked for that start is alive (after its cluster closed): their
    exit codes reach their nanny through the server. Counting the starts keeps the server
    for another run in the same process (a thread) until that one ends too. A server still
    warming reads no request (the run failed before its cluster, or had nothing to do) and
    is terminated rather than waited for.
    """
    global _users
    server: Any = multiprocessing.forkserver._forkserver
    with _lock:
        _users = max(_users - 1, 0)
        pid = server._forkserver_pid
        if _users or pid is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
        server._stop()  # private, but what CPython's own tests stop the server with: reaps it


def warm_stage_package(package: str) -> None:
    """Import ``package``'s stages into the worker's cache of stage objects.

    The stages' numba kernels are left to load from their on-disk cache at their first call
    in each worker: the cache index lists every signature ever compiled (tests, other
    dtypes), 91 entries in a checkout after a test-suite run against the ~30 a run calls,
    and loading them all took 0.7-0.8 s of the server's warm-up, on the run's critical path.
    """
    from .worker import _stages

    _stages(package)


@contextlib.contextmanager
def _environ(extra: Mapping[str, str]) -> Iterator[None]:
    saved = {k: os.environ.get(k) for k in extra}
    os.environ.update(extra)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _warm_in_server() -> None:
    package = os.environ.pop(_WARM_VAR, None)  # popped: forked workers must not see it
    path = os.environ.pop(_PATH_VAR, None)
    if not package:
        return  # imported by a driver or a worker, not by the fork server
    # The terminal's ^C reaches every process of the run's group. The driver stops the run
    # and closes its cluster; a warming server printed the traceback of the import it was
    # in, and each forked worker one of dask's interrupted shutdown. Ignored here, SIGINT
    # stays ignored in the workers: multiprocessing's server hands them the handler it
    # found at its start (CPython's forkserver.main/_serve_one).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if path:
        sys.path[:] = json.loads(path)
    try:
        warm_stage_package(package)
    except Exception:  # a worker imports the package again and reports what fails
        pass


_warm_in_server()
