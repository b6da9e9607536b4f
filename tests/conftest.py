"""Fixtures shared by every test folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture
def conformance_files() -> list[Path]:
    """The MCAP project's conformance corpus: ``shared/`` beside the repository (as in CI),
    or wherever ``TERRAIN_MCAP_CONFORMANCE`` points. Its absence is a failure, not a skip."""
    default = Path(__file__).resolve().parents[2] / "shared" / "mcap-conformance"
    root = Path(os.environ.get("TERRAIN_MCAP_CONFORMANCE", default))
    files = sorted(root.glob("*/*.mcap"))
    if not files:
        pytest.fail(f"MCAP conformance corpus not found under {root}")
    return files
