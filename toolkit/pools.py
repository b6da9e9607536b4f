"""Process pools that stop when the command stops: no worker outlives an interrupt.

A worker busy in C code (a numpy loop, zstd, a KD-tree) does not see Python's signal handling
until it returns to the interpreter, which may be minutes away; ``ProcessPoolExecutor``'s own
shutdown waits for it. So the workers ignore Ctrl-C (it reaches the whole process group) and
the parent decides: on any exception leaving the pool (KeyboardInterrupt, the SystemExit the
command line raises on SIGTERM, an error) it cancels what has not started and terminates
the workers it started (SIGTERM, whose default action ends a process wherever it is; SIGKILL
after :data:`TERMINATE_GRACE_S`), then lets the exception go on. A command that stopped a pool
so ends without waiting on the pool's own threads (:func:`exit_without_waiting`). A parent
killed outright (SIGKILL, which nothing can catch) is noticed by each worker's watcher thread within
:data:`PARENT_CHECK_S` once the worker's interpreter runs again.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.util
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.context import BaseContext
from typing import Any

from tqdm import tqdm

#: How often a pool worker checks that its parent is still alive (s).
PARENT_CHECK_S = 1.0
#: How long a terminated worker may take to end before it is killed (s).
TERMINATE_GRACE_S = 5.0

#: Set once a pool's workers were ended mid-task (:func:`stop_now`): the pool's own threads
#: may then wait for ever on what a killed worker half-wrote (:func:`exit_without_waiting`).
_STOPPED_MID_TASK = threading.Event()


def _exit_when_orphaned(parent_pid: int) -> None:
    """Watch the parent from a daemon thread; if it dies (kill -9 included, which no handler
    of the parent sees) the worker is re-parented, and exits at once rather than live on."""

    def watch() -> None:
        while True:
            time.sleep(PARENT_CHECK_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="terrain-parent-watch", daemon=True).start()


def _init_worker(
    parent_pid: int, initializer: Callable[..., None] | None, initargs: tuple[Any, ...]
) -> None:
    """Every worker: Ctrl-C ignored (the parent stops the workers), exit with the parent,
    then the pool user's own initializer."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # A forked worker inherits the parent's SIGTERM handler (toolkit.stopping); the parent's
    # terminate must end it wherever it is, as SIGTERM's default action does.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _exit_when_orphaned(parent_pid)
    # tqdm's first bar (a disabled one too) makes a multiprocessing lock, a named semaphore
    # that a terminated worker never unlinks: multiprocessing's resource tracker would warn
    # of it after the command's last line. A worker draws no bar, so a thread lock will do.
    tqdm.set_lock(threading.RLock())
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def process_pool(
    workers: int,
    *,
    mp_context: BaseContext | None = None,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` processes, shut down normally (waiting for
    its tasks) when the block ends, and stopped at once (:func:`stop_now`) when an exception
    of any kind leaves it."""
    before = {p.pid for p in multiprocessing.active_children()}
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=mp_context,
        initializer=_init_worker,
        initargs=(os.getpid(), initializer, initargs),
    )
    try:
        yield pool
    except BaseException:
        stop_now(pool, before)
        raise
    pool.shutdown(wait=True)


def stop_now(pool: ProcessPoolExecutor, before: set[int | None]) -> None:
    """Cancel the pool's pending tasks and end its workers now: those of this process's
    children whose pids are not in ``before`` (the children there were before the pool)."""
    pool.shutdown(wait=False, cancel_futures=True)
    _STOPPED_MID_TASK.set()
    workers = [p for p in multiprocessing.active_children() if p.pid not in before]
    for p in workers:
        p.terminate()
    deadline = time.monotonic() + TERMINATE_GRACE_S
    for p in workers:
        p.join(max(deadline - time.monotonic(), 0.0))
        if p.is_alive():
            p.kill()
            p.join()


def exit_without_waiting(code: int) -> None:
    """End the process now with ``code`` if a pool was stopped mid-task, else return.

    A worker terminated while it wrote a result leaves the pool's manager thread reading
    that message for ever, and the interpreter joins that thread before it exits: the
    command, every ``with`` already unwound, would hang (or print a traceback from the
    exit's thread shutdown) instead of ending. So the output streams and the logs are
    flushed and the process ends without that join. Call it only where nothing is left to
    clean up: the command line's last step."""
    if not _STOPPED_MID_TASK.is_set():
        return
    # The pools' queues hold named semaphores that multiprocessing unlinks in its exit
    # finalizers, which os._exit skips: its resource tracker then warns of "leaked semaphore
    # objects" after the command's own last line. Those finalizers (exit priority 0 and
    # above: the semaphores' unlinking, the queues' closing; never the joins of threads,
    # which are below 0) run here first. multiprocessing's atexit hook runs the same.
    multiprocessing.util._run_finalizers(0)  # type: ignore[attr-defined]
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)
