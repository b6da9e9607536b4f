"""How a stage changes one log: inside a new generation of its directory, published whole.

Every per-log stage after ingest (pose, project, label) reads the log's current files and
writes its outputs and the manifest into a new generation (:mod:`toolkit.generations`),
committed in one atomic switch only when it computed something: killed at any moment, the
log is as before or as after, never between. Its warnings are said on the terminal, not
only written into the manifest.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol, TypeVar

from toolkit.workspace import Workspace


class StageOutcome(Protocol):
    """What a per-log stage returns: whether it computed anything, and what to say."""

    @property
    def status(self) -> str: ...  # "up_to_date" when it found nothing to do

    @property
    def warnings(self) -> Sequence[str]: ...


R = TypeVar("R", bound=StageOutcome)


def run_on_log(
    workspace: Workspace,
    log_id: str,
    body: Callable[[Path, float], R],
    logger: logging.Logger,
) -> R:
    """Run ``body(log_dir, start)`` on a new generation of the log and commit it unless the
    stage was up to date; a log the workspace does not have is one StageError line."""
    start = time.perf_counter()
    workspace.require_log(log_id)
    with workspace.change_log(log_id) as gen:
        result = body(gen.path, start)
        if result.status != "up_to_date":
            gen.commit()
    for warning in result.warnings:
        logger.warning("%s: %s", log_id, warning)
    return result


__all__ = ["StageOutcome", "run_on_log"]
