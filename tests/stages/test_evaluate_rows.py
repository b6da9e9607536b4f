"""Evaluate's rows as jobs: run in other processes, back in their order (the report they
make on two cores against one: ``tests/stages/test_evaluate.py``)."""

from __future__ import annotations

from toolkit.stages.evaluate_rows import Job, PerProcess, run_jobs


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
