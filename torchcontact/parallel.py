"""Run independent jobs in parallel: in this process, in local processes, or on a Ray cluster.

``parallel_map(function, items, workers=2, backend="local")`` yields ``(index, result)`` as each
job finishes, in any order. Every backend calls the same ``function`` on the same item, so
results do not depend on the backend. Trials and data collection run through it; their
results are saved by the caller as they arrive, so a job that is lost costs only itself.

``backend="ray"`` submits each item as a Ray task (``ray.init(address)``: a running cluster, or
with no address a local instance of ``workers`` CPUs). A task whose worker process dies is
submitted once more and reported through ``on_retry``; a second death raises. Ray reuses its
worker processes from task to task, so a worker keeps what it built and compiled (the trial
runner's per-process cache) for every later task it runs.
"""

from __future__ import annotations

import functools
import multiprocessing
import signal
import socket
from collections.abc import Callable, Iterator, Sequence
from typing import Any

BACKENDS = ("local", "ray")
"""``local``: this process (one worker) or a pool of spawned processes; ``ray``: Ray tasks."""

RAY_EXTRA = "pip install 'torchcontact[ray]'"
"""How to install the optional Ray backend."""


def parallel_map(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    on_retry: Callable[[int, BaseException], None] | None = None,
) -> Iterator[tuple[int, Any]]:
    """``(index, function(items[index]))`` for every item, as each finishes.

    Args:
        function: a picklable module-level function of one item.
        items: the jobs' inputs (picklable).
        workers: processes (``local``) or CPUs of a local Ray instance (``ray`` without an
            address); a running cluster decides its own parallelism.
        backend: one of :data:`BACKENDS`.
        address: a Ray cluster's address (``ray`` only); None starts a local instance.
        on_retry: ``(index, error)`` when a Ray task's worker died and the job is resubmitted.
    """
    check_backend(workers, backend, address)
    if backend == "ray":
        return _ray_map(function, items, workers, address, on_retry)
    return _local_map(function, items, workers)


def check_backend(workers: int, backend: str, address: str | None) -> None:
    """Refuse arguments :func:`parallel_map` cannot use (before anything runs): ``ValueError``
    naming the argument, or ``ImportError`` naming the extra when Ray is asked for and missing."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if address is not None and backend != "ray":
        raise ValueError(f"address is for backend='ray', got backend={backend!r}")
    if backend == "ray":
        import_ray()
        if address is not None:
            check_address(address)


RAY_CONNECT_TIMEOUT = 10.0
"""[s] How long :func:`check_address` waits for a Ray cluster to answer (``ray.init`` itself
waits minutes on an address where nothing listens)."""


def check_address(address: str) -> None:
    """Refuse a Ray ``address`` (``HOST:PORT``, ``ray://HOST:PORT`` or ``auto``) where no
    server accepts a connection within :data:`RAY_CONNECT_TIMEOUT`: ``ValueError`` naming it."""
    if address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"address must be HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), RAY_CONNECT_TIMEOUT).close()
    except OSError as error:
        reason = error.strerror or f"no answer within {RAY_CONNECT_TIMEOUT:g} s"
        raise ValueError(f"address {address!r}: no Ray cluster answers there ({reason})") from None


def _local_map(function, items, workers: int) -> Iterator[tuple[int, Any]]:
    if workers == 1 or len(items) <= 1:
        for index, item in enumerate(items):
            yield index, function(item)
        return
    pool = multiprocessing.get_context("spawn").Pool(min(workers, len(items)), _ignore_sigint)
    try:
        yield from pool.imap_unordered(functools.partial(_indexed, function), enumerate(items))
    except (KeyboardInterrupt, GeneratorExit):  # Ctrl-C, or the caller stopped: stop them now
        pool.terminate()
        raise
    finally:
        pool.close()
        pool.join()


def _ignore_sigint() -> None:
    """A pool worker leaves Ctrl-C to the process that started it (which stops the pool),
    instead of each printing its own traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _indexed(function, pair):
    index, item = pair
    return index, function(item)


def import_ray():
    """The ``ray`` module, or an ``ImportError`` that names the extra to install."""
    try:
        import ray
    except ImportError:
        raise ImportError(f"backend='ray' needs Ray, which is not installed: {RAY_EXTRA}") from None
    return ray


def _ray_map(function, items, workers: int, address: str | None, on_retry):
    ray = import_ray()
    if not ray.is_initialized():
        options = {"address": address} if address else {"num_cpus": workers}
        ray.init(**options, include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=1, max_retries=0)(function)
    pending = {task.remote(item): index for index, item in enumerate(items)}
    retried: set[int] = set()
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        index = pending.pop(done[0])
        try:
            result = ray.get(done[0])
        except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as error:
            if index in retried:
                raise
            retried.add(index)
            if on_retry is not None:
                on_retry(index, error)
            pending[task.remote(items[index])] = index
            continue
        yield index, result
