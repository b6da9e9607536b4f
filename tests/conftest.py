"""Fixtures shared by every test folder.

Everything a test reads lives under ``tests/data/`` (see its README), so the suite runs on a
fresh clone with nothing beside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from tests.stages.test_learn import Pipeline

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


#: The simulated log bundled with the repository (61 s, five lasers).
SAMPLE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"


@pytest.fixture(scope="session")
def sample_projected(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The sample log ingested, posed and projected once for the whole session: (workspace
    root, log id). Read-only: a test that changes it copies it first
    (``shutil.copytree(root, dst, symlinks=True)``)."""
    from toolkit.config import default_config
    from toolkit.stages.ingest import ingest_log
    from toolkit.stages.pose import SPEC as POSE
    from toolkit.stages.project import SPEC as PROJECT
    from toolkit.stages.runner import run_stage
    from toolkit.workspace import Workspace

    ws = Workspace(tmp_path_factory.mktemp("sample_projected") / "ws")
    log_id = ingest_log(SAMPLE_LOG, ws, default_config()).log_id
    run_stage(POSE, ws, default_config(), log_id=log_id)
    run_stage(PROJECT, ws, default_config(), log_id=log_id)
    return ws.root, log_id


@pytest.fixture(scope="module")
def pipeline(
    sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory
) -> Pipeline:
    """The sample labelled, tabled, learned and evaluated, built once a session
    (:func:`tests.stages.test_learn.build_pipeline`). Read-only: copy it to change it."""
    from tests.stages.test_learn import build_pipeline

    return build_pipeline(sample_projected, tmp_path_factory)


#: The slow test files, longest first (seconds on one worker of two, with their fixtures, by
#: `pytest -m slow -n 2 --durations=40`, 2026-11-29 05:34): handed out in this order when
#: several workers share the tests, so that none starts a long file while the other has
#: nothing left to do (collected last, the killed-and-rerun pipeline test alone once kept one
#: core busy for the last three minutes; test_sensors.py, missing here, once simulated the
#: race for 84 s at the very end).
LONGEST_FIRST = (
    "test_pipeline.py",  # 260 s
    "test_race_log.py",  # 137 s (every test of the race log)
    "test_laser_truth.py",  # 101 s
    "test_pose.py",  # 100 s
    "test_kill_anywhere.py",  # 92 s
    "test_croissant.py",  # 65 s
    "test_label.py",  # 42 s
    "test_truth_terrain.py",  # 36 s
    "test_evaluate.py",  # 31 s
    "test_pools.py",  # 29 s
    "test_sample_log.py",  # 27 s
    "test_curved_earth.py",  # 27 s
    "test_project_lidar.py",  # 15 s
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """With several workers (``-n auto --dist loadfile --no-loadscope-reorder``), the files
    of the longest tests first (:data:`LONGEST_FIRST`). The order is the same on every
    worker, as xdist requires; alone, tests run in their usual order."""
    if not getattr(config.option, "numprocesses", None):
        return
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(Path(str(item.fspath)).name, len(rank)))
