"""Progress bars that show on a terminal and stay silent in pipes, CI and ``--quiet`` runs.

Long work (simulation, ingest, learning) wraps its loops in :func:`progress`. Bars go to
stderr, so stdout stays clean for results; they are disabled when stderr is not a terminal,
when the ``CI`` environment variable is set (to anything but ``""``, ``0`` or ``false``), or
after :func:`set_quiet` (the command line's ``-q``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm

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
    When disabled it is a pass-through with the same interface.
    """
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        unit_scale=unit_scale,
        disable=not progress_enabled(),
        file=sys.stderr,
        leave=False,
        dynamic_ncols=True,
    )
