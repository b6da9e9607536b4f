"""Progress: bars on a terminal, log lines and a heartbeat off it, nothing with ``--quiet``.

Long work (simulation, ingest, learning) wraps its loops in :func:`progress`. Bars go to
stderr, so stdout stays clean for results; they are shown when stderr is a terminal and the
``CI`` environment variable is unset (or ``""``, ``0``, ``false``). Off a terminal (a pipe, a
CI log) the same call gives a :class:`Heartbeat`: every :data:`HEARTBEAT_S` seconds at most
one line on stderr saying what runs, how far it is and for how long, so a long job is never
silent for a minute; :func:`note` prints a line there as each stage or log finishes. After
:func:`set_quiet` (the command line's ``-q``) neither shows.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Sized
from typing import Any

from tqdm import tqdm

from toolkit.stopping import checked

_quiet = False


def set_quiet(quiet: bool) -> None:
    """Silence (or re-allow) every progress bar in this process."""
    global _quiet
    _quiet = quiet


def _ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def progress_enabled() -> bool:
    """Whether progress bars would be shown now."""
    if _quiet or _ci():
        return False
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False


#: Longest silence off a terminal while work goes on, s (``TERRAIN_HEARTBEAT_S`` overrides).
HEARTBEAT_S = 60.0
PROG = "terrain"


def _heartbeat_s() -> float:
    try:
        return max(0.01, float(os.environ.get("TERRAIN_HEARTBEAT_S", HEARTBEAT_S)))
    except ValueError:
        return HEARTBEAT_S


def logging_progress() -> bool:
    """Whether progress is logged as lines (off a terminal, not quiet)."""
    return not _quiet and not progress_enabled()


def note(line: str) -> None:
    """One progress line on stderr off a terminal (a stage or a log finished); nothing on a
    terminal, where the bars say it, or when quiet."""
    if logging_progress():
        print(f"{PROG}: {line}", file=sys.stderr, flush=True)


def say(line: str) -> None:
    """One result line on stdout as it comes (a stage of ``terrain run`` finished): above
    the bars on a terminal (``tqdm.write``, so no bar is cut), a plain line off it. Unlike
    :func:`note`, printed with ``-q`` too: it is a result, not progress."""
    if progress_enabled():
        tqdm.write(line, file=sys.stdout)
        sys.stdout.flush()
    else:
        print(line, flush=True)


def write_above_bars(text: str) -> None:
    """``text`` on stderr without cutting a bar on a terminal (log records, warnings)."""
    if progress_enabled():
        tqdm.write(text, file=sys.stderr)
    else:
        print(text, file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes} min {secs:02d} s" if minutes else f"{secs} s"


class Heartbeat:
    """Progress off a terminal, with the part of tqdm's interface the toolkit uses
    (iteration, ``update``, ``set_postfix_str``, ``close``, a context manager): a daemon
    thread prints ``terrain: DESC: N/TOTAL UNIT (P %), POSTFIX, after T`` every
    ``interval_s`` while the work runs, and nothing once it is closed."""

    def __init__(
        self,
        iterable: Iterable[Any] | None,
        total: float | None,
        desc: str,
        unit: str,
        interval_s: float,
    ) -> None:
        self.iterable = iterable
        self.total = total
        self.desc = desc
        self.unit = unit
        self.n = 0.0
        self.postfix = ""
        self._start = time.monotonic()
        self._stop = threading.Event()
        self._interval_s = interval_s
        self._thread = threading.Thread(target=self._beat, name=f"heartbeat {desc}", daemon=True)
        self._thread.start()

    def line(self) -> str:
        """What the next heartbeat says."""
        n = f"{self.n:g}"
        done = f"{n}/{self.total:g} {self.unit}" if self.total else f"{n} {self.unit}"
        if self.total:
            done += f" ({100.0 * self.n / self.total:.0f} %)"
        postfix = f", {self.postfix}" if self.postfix else ""
        elapsed = _duration(time.monotonic() - self._start)
        return f"{PROG}: {self.desc or 'working'}: {done}{postfix}, after {elapsed}"

    def _beat(self) -> None:
        while not self._stop.wait(self._interval_s):
            print(self.line(), file=sys.stderr, flush=True)

    def update(self, n: float = 1) -> None:
        self.n += n

    def set_postfix_str(self, text: str = "", refresh: bool = True) -> None:
        self.postfix = text

    def set_description(self, desc: str | None = None, refresh: bool = True) -> None:
        self.desc = desc or ""

    def close(self) -> None:
        self._stop.set()

    def __iter__(self) -> Iterator[Any]:
        if self.iterable is None:
            raise TypeError("a heartbeat without an iterable is updated, not iterated")
        try:
            for item in self.iterable:
                yield item
                self.n += 1
        finally:
            self.close()

    def __enter__(self) -> Heartbeat:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress(
    iterable: Iterable[Any] | None = None,
    *,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    unit_scale: bool = False,
) -> Any:
    """A tqdm bar over ``iterable`` (or a manual one to ``.update(n)`` when it is None).

    Use as ``for x in progress(xs, desc="ingest")`` or
    ``with progress(total=n_bytes, unit="B", unit_scale=True) as bar: bar.update(k)``.
    Off a terminal it is a :class:`Heartbeat` with the same interface; when quiet, a
    disabled bar (a pass-through).
    """
    sized_total = len(iterable) if isinstance(iterable, Sized) else None  # as tqdm would take
    if iterable is not None:
        # Each step is a checkpoint: a stop whose exception was swallowed where the signal
        # landed is raised here (toolkit.stopping).
        iterable = checked(iterable)
    if logging_progress():
        return Heartbeat(iterable, total, desc, unit, _heartbeat_s())
    return tqdm(
        iterable,
        total=total if total is not None else sized_total,
        desc=desc,
        unit=unit,
        unit_scale=unit_scale,
        disable=not progress_enabled(),
        file=sys.stderr,
        leave=False,
        dynamic_ncols=True,
    )
