"""A command stops on the first Ctrl-C or SIGTERM, even where the exception its handler
raises is swallowed (issue "Truth far from home", point 4)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from toolkit.progress import progress
from toolkit.stopping import Interrupted, Terminated, stop_on_signals, stop_requested

ROOT = Path(__file__).resolve().parents[1]


def _swallowing_code(signum: int) -> None:
    """What pyarrow's lazy import of pandas did: a blanket ``except`` around the spot where
    the signal's exception landed."""
    with contextlib.suppress(BaseException):  # the point of the test
        os.kill(os.getpid(), signum)


@pytest.mark.parametrize(
    ("signum", "kind", "code"),
    [(signal.SIGTERM, Terminated, 143), (signal.SIGINT, Interrupted, 130)],
)
def test_a_swallowed_stop_is_raised_when_the_block_ends(
    signum: int, kind: type[SystemExit], code: int
) -> None:
    with pytest.raises(kind) as stopped, stop_on_signals():
        _swallowing_code(signum)
        assert stop_requested() == signum
    assert stopped.value.code == code
    assert stop_requested() is None  # the block is over: nothing carried to the next


def test_a_swallowed_stop_is_raised_at_the_next_progress_step() -> None:
    seen = []
    with pytest.raises(Terminated), stop_on_signals():
        for i in progress(range(5), desc="steps"):
            seen.append(i)
            if i == 1:
                _swallowing_code(signal.SIGTERM)
    assert seen == [0, 1]


def test_a_command_exit_after_a_stop_is_the_stop() -> None:
    """A command that, stop swallowed, ran on to its own exit 0 is reported stopped."""
    with pytest.raises(Terminated), stop_on_signals():
        _swallowing_code(signal.SIGTERM)
        sys.exit(0)


def test_a_second_signal_while_the_first_unwinds_does_not_cut_the_cleanup() -> None:
    cleaned = []
    with pytest.raises(Terminated), stop_on_signals():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
        finally:
            os.kill(os.getpid(), signal.SIGTERM)  # returns: the cleanup goes on
            cleaned.append(True)
    assert cleaned == [True]


def test_handlers_are_restored_after_the_block() -> None:
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with stop_on_signals(), stop_on_signals():  # nested: the launcher's and the command's
        pass
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_during_start_up_is_one_line(signum: int, code: int) -> None:
    """Sent while the command line is still being imported (the launcher has set up the
    stop first): the shell's code and one line, no traceback."""
    script = (
        "import os, signal, sys\n"
        "sys.argv = ['terrain', '--help']\n"
        "import toolkit.launch as launch\n"
        "import builtins\n"
        "real_import = builtins.__import__\n"
        "def slow(name, *a, **k):\n"
        "    if name == 'toolkit.cli.group':\n"
        f"        os.kill(os.getpid(), {int(signum)})\n"
        "    return real_import(name, *a, **k)\n"
        "builtins.__import__ = slow\n"
        "launch.entry()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == code, done.stderr
    assert done.stderr.count("terrain: error: stopped (") == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stdout == ""


class _Thing:
    """Something a weak reference can point at."""


def test_a_stop_landing_where_python_can_only_print_it_is_not_printed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A Ctrl-C landing in a weakref callback (importlib's module-lock callback took one):
    Python hands such an exception to ``sys.unraisablehook``, which prints it ("Exception
    ignored in ...", a traceback), and goes on. Inside the block a stop there reaches no
    hook (it is raised again when the block ends); any other exception there still does."""
    import weakref

    seen: list[object] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))

    def stop_here(_ref: object) -> None:
        os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(Interrupted), stop_on_signals():
        thing = _Thing()
        ref = weakref.ref(thing, stop_here)
        del thing  # the callback runs, and the stop lands in it
        assert ref() is None
    assert seen == []

    def fail_here(_ref: object) -> None:
        raise ValueError("not a stop")

    with stop_on_signals():
        thing = _Thing()
        ref = weakref.ref(thing, fail_here)
        del thing
    assert [type(e) for e in seen] == [ValueError]
