"""How a command stops: on the first Ctrl-C or SIGTERM, wherever it lands.

Within :func:`stop_on_signals` (the command line's whole run), SIGINT and SIGTERM raise
:class:`Interrupted` or :class:`Terminated` where the main thread is, so every ``with``
unwinds: pools stop their workers, partial files go, locks are released. Both are
``SystemExit`` with the shell's code for the signal (128 + its number: 130, 143), which the
command line turns into one line (``terrain: error: stopped (SIGTERM)``).

An exception raised from a signal handler can be lost: it lands wherever the interpreter is,
and code there may swallow it (pyarrow imports pandas lazily under a blanket ``except``; a
C extension's callback prints "Exception ignored" and goes on). So the request is also
remembered, and honoured again:

- at every checkpoint (:func:`check_stop`): each step of a progress bar, each stage the
  runner starts;
- when the block ends normally: a command asked to stop never exits 0 as if it had not been.

Only the first signal raises. A second one while the first unwinds returns at once, so it
cannot cut a cleanup short (a partial file half-removed); SIGKILL still ends everything.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")

#: What each signal is called in the one line a stopped command prints.
SIGNAL_NAMES: dict[int, str] = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


class Stopped(SystemExit):
    """A command stopped by a signal; its code is 128 + the signal's number."""

    def __init__(self, signum: int) -> None:
        super().__init__(128 + signum)
        self.signum = signum
        #: Set once the command line has printed :attr:`line`.
        self.said = False

    @property
    def line(self) -> str:
        """What the command line says of it."""
        return f"stopped ({SIGNAL_NAMES.get(self.signum, f'signal {self.signum}')})"


class Terminated(Stopped):
    """Stopped by SIGTERM (``kill``, a CI's timeout, a scheduler): exit 143."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)


class Interrupted(Stopped):
    """Stopped by Ctrl-C (SIGINT): exit 130."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signum)


#: The first signal received within :func:`stop_on_signals`, until the block ends.
_requested: int | None = None


def _stopped(signum: int) -> Stopped:
    return Interrupted(signum) if signum == signal.SIGINT else Terminated(signum)


def _handle(signum: int, _frame: object) -> None:
    global _requested
    if _requested is not None:
        return  # the stop is under way (or will be raised at the next checkpoint)
    _requested = signum
    raise _stopped(signum)


def stop_requested() -> int | None:
    """The signal a stop was asked by, or None."""
    return _requested


def check_stop() -> None:
    """A checkpoint: raise the stop asked for (if any) here, where normal work goes on, in
    case the handler's exception was swallowed where it landed."""
    if _requested is not None:
        raise _stopped(_requested)


def checked(iterable: Iterable[T]) -> Iterator[T]:
    """``iterable``'s items, with :func:`check_stop` before each."""
    for item in iterable:
        check_stop()
        yield item
    check_stop()


#: How many :func:`stop_on_signals` blocks are open (the launcher's and the command's).
_depth = 0


def _quiet_about_stops(previous: Callable[[Any], object]) -> Callable[[Any], None]:
    """An ``sys.unraisablehook`` that says nothing of a stop raised where Python can only
    print it and carry on (a weakref callback, a ``__del__``: importlib's module-lock
    callback took a Ctrl-C once and printed its traceback): the stop is remembered and
    raised again at the next checkpoint, so nothing is lost by not printing it. Any other
    unraisable exception goes to ``previous``."""

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, Stopped):
            return
        previous(unraisable)

    return hook


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, Ctrl-C and SIGTERM stop the command (module docstring). Blocks
    nest: the outermost installs the handlers and restores the previous ones after. A block
    left by any other exit (a command's exit 0 or 1) while a stop was asked for raises the
    stop instead: the command was stopped, whatever it did after. In a thread other than the
    main one (where Python delivers signals) it does nothing."""
    global _requested, _depth
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Any] = {}
    unraisable = sys.unraisablehook
    if _depth == 0:
        previous = {s: signal.signal(s, _handle) for s in SIGNAL_NAMES}
        sys.unraisablehook = _quiet_about_stops(unraisable)
    _depth += 1
    try:
        yield
    except SystemExit as exc:
        if _requested is not None and not isinstance(exc, Stopped):
            raise _stopped(_requested) from None
        raise
    else:
        check_stop()
    finally:
        _depth -= 1
        if _depth == 0:
            for s, handler in previous.items():
                signal.signal(s, handler)
            sys.unraisablehook = unraisable
            _requested = None


__all__ = [
    "Interrupted",
    "Stopped",
    "Terminated",
    "check_stop",
    "checked",
    "stop_on_signals",
    "stop_requested",
]
