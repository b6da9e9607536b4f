"""Evaluate's rows trained two at a time give the report one at a time gives, to the bit."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.stages.test_learn import Pipeline, copy_workspace
from toolkit.config import default_config
from toolkit.stages import evaluate_rows
from toolkit.stages.evaluate import SPEC as EVALUATE
from toolkit.stages.evaluate_rows import Job, PerProcess, run_jobs
from toolkit.stages.runner import run_stage


def _report_bytes(root: Path) -> dict[str, bytes]:
    report = root / "report"
    return {p.name: p.read_bytes() for p in sorted(report.iterdir()) if p.is_file()}


@pytest.mark.slow  # an evaluation of the sample after its pipeline (~70 s); run by .ci/run
def test_rows_trained_on_two_cores_make_the_same_report_as_on_one(
    pipeline: Pipeline, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The shared pipeline's report was made with the default two workers; made again one
    row at a time, it is the same, file for file."""
    assert evaluate_rows.ROW_WORKERS == 2
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    monkeypatch.setattr(evaluate_rows, "ROW_WORKERS", 1)
    run_stage(EVALUATE, ws, default_config(), overwrite=True)
    alone, both = _report_bytes(ws.root), _report_bytes(pipeline.ws.root)
    assert {"summary.json", "scores.parquet", "index.html", "roc.png"} <= set(both)
    assert alone == both


def _pid_and(value: int) -> tuple[int, int]:
    import os

    return os.getpid(), value


def test_jobs_run_in_other_processes_and_come_back_in_their_order() -> None:
    import os

    told: list[str | None] = []
    jobs = [Job(f"row{i}", f"step {i}", lambda i=i: _pid_and(i), {}) for i in range(5)]
    got = run_jobs(jobs, told.append, workers=2)
    assert [v for _, v in got] == list(range(5))
    assert all(pid != os.getpid() for pid, _ in got)
    assert told == [f"step {i}" for i in range(5)]
    alone = run_jobs(jobs, told.append, workers=1)
    assert [pid for pid, _ in alone] == [os.getpid()] * 5


def test_a_per_process_value_is_made_once_per_process() -> None:
    made: list[int] = []
    value = PerProcess(lambda: made.append(1) or len(made))
    assert value.get() == value.get() == 1
    assert made == [1]
