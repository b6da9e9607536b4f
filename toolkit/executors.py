"""Where batch tasks run: in this process, on a local process pool, or on a Dask cluster.

:func:`make_executor` opens a :class:`concurrent.futures.Executor` of the kind asked for;
:mod:`toolkit.batch` submits one task per log to it, so the same code runs on one laptop or
a cluster. Pool workers log through this process (their records printed by its handlers).
"""

from __future__ import annotations

import contextlib
import logging
import logging.handlers
import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future
from typing import Any

from toolkit.errors import ConfigError
from toolkit.pools import process_pool

_log = logging.getLogger(__name__)

#: The executors :func:`make_executor` knows.
EXECUTOR_KINDS: tuple[str, ...] = ("local", "dask")

#: What a user installs to get the Dask executor.
DISTRIBUTED_HINT = "pip install 'terrain[distributed]'"


class InlineExecutor(Executor):
    """Runs each task in this process at ``submit`` time (``workers=0``: for debugging).

    Breakpoints, profilers and ``--debug`` tracebacks work as in a plain loop; there is no
    isolation and no parallelism.
    """

    def __init__(self) -> None:
        self._shutdown = False

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        """Run ``fn(*args, **kwargs)`` now; return a finished future holding its outcome."""
        if self._shutdown:
            raise RuntimeError("cannot schedule new futures after shutdown")
        future: Future[Any] = Future()
        try:
            result = fn(*args, **kwargs)
        except BaseException as exc:  # the future carries it, as a pool's would
            future.set_exception(exc)
        else:
            future.set_result(result)
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Refuse further tasks (nothing is ever pending)."""
        self._shutdown = True


class _Relay(logging.Handler):
    """Hands a record from a pool worker to this process's logger of the same name, so it
    is filtered and printed by this process's own configuration (the command line's)."""

    def emit(self, record: logging.LogRecord) -> None:
        logging.getLogger(record.name).handle(record)


def _init_pool_worker(log_queue: Any, level: int) -> None:
    """Set up a pool process: no progress bars (the parent shows one over the batch), and
    log records sent to the parent, which prints them with its own handlers and format."""
    from toolkit.progress import set_quiet

    set_quiet(True)
    root = logging.getLogger()
    root.handlers[:] = [logging.handlers.QueueHandler(log_queue)]
    root.setLevel(level)
    logging.captureWarnings(True)


@contextlib.contextmanager
def _local_pool(workers: int) -> Iterator[Executor]:
    """A spawn-started process pool whose workers log through this process.

    ``spawn`` (not ``fork``) starts each worker as a fresh interpreter, as a Dask worker
    would be: a task that runs here also runs on a cluster, and no lock or thread of the
    parent (progress bar, logging, workspace lock) is inherited half-held. An interrupt or
    error stops the workers at once (:func:`toolkit.pools.process_pool`).
    """
    ctx = multiprocessing.get_context("spawn")
    log_queue = ctx.Queue()
    listener = logging.handlers.QueueListener(log_queue, _Relay())
    listener.start()
    try:
        with process_pool(
            workers,
            mp_context=ctx,
            initializer=_init_pool_worker,
            initargs=(log_queue, logging.getLogger().getEffectiveLevel()),
        ) as pool:
            yield pool
    except BaseException:
        # The workers were terminated, perhaps while writing a record: the queue's lock
        # may be held for ever, so nothing here waits on it (the listener's thread is a
        # daemon, and records not relayed by now are lost with the workers).
        log_queue.cancel_join_thread()
        log_queue.close()
        raise
    listener.stop()
    log_queue.close()
    log_queue.join_thread()


def _import_distributed() -> Any:
    """The ``distributed`` package, or a one-line ConfigError saying how to install it."""
    try:
        import distributed
    except ImportError as exc:
        raise ConfigError(
            f"the dask executor needs the 'distributed' package ({exc}): {DISTRIBUTED_HINT}"
        ) from None
    return distributed


@contextlib.contextmanager
def _dask_executor(scheduler: str | None, cluster: Any) -> Iterator[Executor]:
    """A Dask client's executor; the client is closed on exit (a passed cluster is not)."""
    distributed = _import_distributed()
    target = cluster if cluster is not None else scheduler
    try:
        client = distributed.Client(target, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f"cannot connect to the Dask scheduler at {target}: {exc}") from None
    try:
        # pure=False: a task has side effects (files in the workspace), so Dask must run
        # it every time it is submitted, never reuse an earlier result with the same key.
        executor = client.get_executor(pure=False)
        try:
            yield executor
        finally:
            executor.shutdown(wait=False)
    finally:
        client.close()


@contextlib.contextmanager
def make_executor(
    kind: str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    cluster: Any = None,
) -> Iterator[Executor]:
    """Open the executor a batch runs on; closing the ``with`` block shuts it down.

    ``"local"``: a process pool of ``workers`` processes (default ``os.cpu_count()``).
    ``workers=0`` runs every task in this process, one after another (:class:`InlineExecutor`,
    for debugging), as ``terrain sim --workers 0`` does; ``workers=1`` is one worker process,
    so a crash or a leak in a task still cannot take this process down.

    ``"dask"``: ``distributed.Client(scheduler).get_executor()``; ``scheduler`` is the
    scheduler's address (``tcp://host:8786``). Tests pass ``cluster`` instead (e.g. an
    in-process ``distributed.LocalCluster(processes=False)``), which is not closed here.
    The cluster decides how many tasks run at once, so ``workers`` is ignored.

    Raises ConfigError for an unknown kind, a negative worker count, a Dask executor without
    a scheduler, a missing ``distributed`` package or an unreachable scheduler.
    """
    if kind not in EXECUTOR_KINDS:
        choices = ", ".join(repr(k) for k in EXECUTOR_KINDS)
        raise ConfigError(f"executor: expected one of {choices} (got {kind!r})")
    if workers is not None and (isinstance(workers, bool) or workers < 0):
        raise ConfigError(f"workers: expected a count of 0 or more (got {workers!r})")
    if kind == "local":
        if scheduler is not None or cluster is not None:
            raise ConfigError(f"a scheduler applies to the dask executor only (got {scheduler!r})")
        count = (os.cpu_count() or 1) if workers is None else workers
        if count == 0:
            inline = InlineExecutor()
            try:
                yield inline
            finally:
                inline.shutdown()
        else:
            with _local_pool(count) as pool:
                yield pool
        return
    if scheduler is None and cluster is None:
        raise ConfigError("the dask executor needs a scheduler address (--scheduler ADDR)")
    if workers is not None:
        _log.warning("--workers %d ignored: the Dask cluster decides how many tasks run", workers)
    with _dask_executor(scheduler, cluster) as executor:
        yield executor


__all__ = ["DISTRIBUTED_HINT", "EXECUTOR_KINDS", "InlineExecutor", "make_executor"]
