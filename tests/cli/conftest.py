"""Fixtures of the command line's tests: a runner; logging and quiet restored after each."""

from __future__ import annotations

import logging
from typing import Any

import pytest
from click.testing import CliRunner

from toolkit import progress as progress_mod


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture(autouse=True)
def _restore_logging_and_quiet() -> Any:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
    progress_mod.set_quiet(False)
