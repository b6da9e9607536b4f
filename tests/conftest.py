"""Fixtures shared by every test folder.

Everything a test reads lives under ``tests/data/`` (see its README), so the suite runs on a
fresh clone with nothing beside it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

#: Files the tests read: the MCAP conformance corpus, real robots' logs.
DATA_DIR = Path(__file__).resolve().parent / "data"

#: How many logs the MCAP conformance corpus holds (its SHA256SUMS lists them).
CONFORMANCE_LOG_COUNT = 416


@pytest.fixture(scope="session")
def conformance_files() -> list[Path]:
    """The MCAP project's conformance corpus, vendored in ``tests/data/mcap-conformance``.

    A corpus that is missing or incomplete is a failure, not a skip: a test that silently
    reads fewer files proves less than it claims.
    """
    root = DATA_DIR / "mcap-conformance"
    files = sorted(root.glob("*/*.mcap"))
    if len(files) != CONFORMANCE_LOG_COUNT:
        pytest.fail(
            f"MCAP conformance corpus under {root}: {len(files)} logs, "
            f"expected {CONFORMANCE_LOG_COUNT}"
        )
    return files
