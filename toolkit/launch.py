"""The process's entry point (``terrain``, ``python -m toolkit``).

The stop on Ctrl-C and SIGTERM (:mod:`toolkit.stopping`) is set up before anything else is
imported: importing the command line takes a few tenths of a second, and a signal there
would otherwise end the process with a traceback (Ctrl-C) or without a word (SIGTERM).
"""

from __future__ import annotations

import signal
import sys

from toolkit.stopping import Stopped, stop_on_signals


def entry() -> None:
    """Run the command line (:func:`toolkit.cli.group.entry`) with the stop on signals; a
    stop it did not report itself (one during start-up) is one line here."""
    try:
        with stop_on_signals():
            from toolkit.cli.group import entry as command_line

            command_line()
    except Stopped as exc:
        if not exc.said:
            sys.stderr.write(f"terrain: error: {exc.line}\n")
            sys.stderr.flush()
        raise SystemExit(exc.code) from None
    finally:
        # The command is over, its outputs written or removed and its exit code decided;
        # what is left is the interpreter's own shutdown (a few tenths of a second). A signal
        # there would end the process by its default action, without a line and with a code
        # that is not the command's: it changes nothing now, so it is ignored.
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_IGN)


__all__ = ["entry"]
