"""Tests of batches: shards, a task per log on a local pool and on Dask, the ingest verb.

Most tests run fake tasks (module-level, so they pickle into pool processes and Dask
workers); the last ones ingest two simulated logs, one of them broken, with the real stage.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import random
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from toolkit import batch
from toolkit.batch import (
    BatchSummary,
    Executors,
    ItemOutcome,
    run_batch,
    run_ingest_batch,
    shard,
)
from toolkit.cli import main
from toolkit.config import PipelineConfig, default_config, load_config
from toolkit.errors import ConfigError, LogReadError
from toolkit.executors import InlineExecutor, make_executor

# -- fake tasks -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FakeResult:
    log_id: str
    status: str
    warnings: tuple[str, ...] = ()


def fake_task(item: str) -> Any:
    """Fails on 'bad' (a ToolkitError) and 'boom' (a bug); 'old' is already up to date."""
    if item == "bad":
        raise LogReadError("truncated:\nnothing usable", path=item)
    if item == "boom":
        raise ValueError("kaboom")
    if item == "old":
        return FakeResult(log_id=f"{item}-id", status="up_to_date")
    return FakeResult(log_id=f"{item}-id", status="ingested", warnings=("a gap",))


def warning_task(item: str) -> str:
    logging.getLogger("toolkit.fake").warning("warned about %s in pid %d", item, os.getpid())
    return item


def dying_task(item: str) -> str:
    os._exit(3)


ITEMS = ["a", "bad", "b", "boom", "old", "c"]


def check_fake_summary(summary: BatchSummary) -> None:
    assert [o.item for o in summary.outcomes] == ITEMS  # input order, whatever finished first
    assert summary.done == ["a", "b", "c"]
    assert summary.up_to_date == ["old"]
    assert summary.failed == {"bad": "truncated: nothing usable", "boom": "ValueError: kaboom"}
    assert not summary.ok
    assert summary.results["a"] == FakeResult("a-id", "ingested", ("a gap",))
    boom = next(o for o in summary.outcomes if o.item == "boom")
    assert "Traceback" in boom.detail and "kaboom" in boom.detail


# -- shards ---------------------------------------------------------------------------------


def test_shards_are_disjoint_complete_and_balanced() -> None:
    logs = [Path(f"/data/run{i:03d}.mcap") for i in range(23)]
    parts = [shard(logs, i, 5) for i in range(5)]
    flat = [p for part in parts for p in part]
    assert sorted(flat) == sorted(logs)
    assert len(set(flat)) == len(flat)
    assert {len(part) for part in parts} <= {4, 5}


def test_shards_do_not_depend_on_input_order_or_mount_point() -> None:
    names = [f"log_{i}.mcap" for i in range(17)]
    here = [Path("/mnt/a/logs", n) for n in names]
    there = [Path("/scratch/x", n) for n in names]
    random.Random(3).shuffle(there)
    for i in range(4):
        assert [p.name for p in shard(here, i, 4)] == [p.name for p in shard(there, i, 4)]
    assert shard(here, 0, 1) == sorted(here)


def test_shard_keeps_repeated_items_once_and_keeps_their_type() -> None:
    items = ["b.mcap", "a.mcap", "b.mcap"]
    assert shard(items, 0, 1) == ["a.mcap", "b.mcap"]
    assert shard(items, 1, 2) == ["b.mcap"]
    assert shard([], 0, 3) == []


@pytest.mark.parametrize(
    ("index", "count", "names"),
    [
        (3, 3, ["shard_index=3", "num_shards=3"]),
        (-1, 2, ["shard_index=-1"]),
        (0, 0, ["num_shards", "got 0"]),
        (True, 2, ["shard_index", "True"]),
    ],
)
def test_bad_shard_indices_name_the_values(index: Any, count: Any, names: list[str]) -> None:
    with pytest.raises(ConfigError) as err:
        shard(["a.mcap"], index, count)
    for name in names:
        assert name in str(err.value)


# -- executors ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dask_cluster() -> Iterator[Any]:
    import distributed  # the [distributed] extra: installed by the README's test command

    cluster = distributed.LocalCluster(
        processes=False, n_workers=1, threads_per_worker=2, dashboard_address=None
    )
    try:
        yield cluster
    finally:
        cluster.close()


def test_run_batch_inline_keeps_going_past_failures() -> None:
    with make_executor("local", workers=0) as executor:
        assert isinstance(executor, InlineExecutor)
        summary = run_batch(fake_task, ITEMS, executor, desc="fake")
    check_fake_summary(summary)


def test_run_batch_on_local_pool_keeps_going_past_failures() -> None:
    with make_executor("local", workers=2) as executor:
        summary = run_batch(fake_task, ITEMS + ["a"], executor, desc="fake")
    check_fake_summary(summary)


def test_run_batch_on_in_process_dask_cluster(dask_cluster: Any) -> None:
    with make_executor("dask", cluster=dask_cluster) as executor:
        summary = run_batch(fake_task, ITEMS, executor, desc="fake")
    check_fake_summary(summary)


def test_dask_executor_from_an_existing_client(dask_cluster: Any) -> None:
    import distributed  # the [distributed] extra: installed by the README's test command

    with distributed.Client(dask_cluster, set_as_default=False) as client:
        summary = run_batch(fake_task, ["a", "bad"], client.get_executor(), desc="fake")
    assert summary.done == ["a"]
    assert summary.failed == {"bad": "truncated: nothing usable"}


def test_pool_worker_logs_reach_this_process(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    with make_executor("local", workers=1) as executor:
        summary = run_batch(warning_task, ["x"], executor, desc="fake")
    assert summary.done == ["x"]
    records = [r for r in caplog.records if r.name == "toolkit.fake"]
    assert len(records) == 1
    assert "warned about x" in records[0].getMessage()
    assert f"pid {os.getpid()}" not in records[0].getMessage()  # it ran in another process


def test_a_dead_worker_process_is_a_failed_item_not_a_crash() -> None:
    with make_executor("local", workers=1) as executor:
        summary = run_batch(dying_task, ["x"], executor, desc="fake")
    assert list(summary.failed) == ["x"]
    assert summary.failed["x"].startswith("BrokenProcessPool")


# -- the summary ----------------------------------------------------------------------------


def test_render_lists_items_counts_and_reasons() -> None:
    summary = BatchSummary(
        "ingest",
        (
            ItemOutcome("a.mcap", "done", FakeResult("a-1", "ingested", ("w1", "w2"))),
            ItemOutcome("b.mcap", "failed", reason="truncated"),
            ItemOutcome("c.mcap", "up_to_date", FakeResult("c-1", "up_to_date")),
        ),
        1.25,
        unit="log",
    )
    text = summary.render()
    assert "ingested    a.mcap  [a-1]  (2 warnings)" in text
    assert "failed      b.mcap: truncated" in text
    assert "up to date  c.mcap  [c-1]" in text
    assert text.splitlines()[-1] == "ingest: 3 logs: 1 ingested, 1 up to date, 1 failed in 1.2 s"
    assert "truncated" not in summary.render(with_reasons=False)


# -- run_ingest_batch with a fake ingest ----------------------------------------------------


def fake_stage_task(
    log_path: str,
    *,
    stage: str,
    workspace_root: str,
    config: PipelineConfig,
    overwrite: bool,
    cwd: str,
) -> FakeResult:
    """Stands in for stage_task: records what it was given in the workspace."""
    Path(workspace_root, f"{Path(log_path).name}.seen").write_text(
        f"{Path(cwd, log_path).is_file()} {overwrite} {stage} {config.name}"
    )
    return FakeResult(Path(log_path).stem, "ingested")


def test_run_ingest_batch_records_the_config_and_shards(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(batch, "stage_task", fake_stage_task)
    for name in ("a", "b", "c"):
        Path(f"{name}.mcap").write_bytes(b"x")
    ws = tmp_path / "ws"
    logs = [Path("c.mcap"), Path("a.mcap"), Path("./a.mcap"), Path("b.mcap")]
    summary = run_ingest_batch(
        logs,
        ws,
        None,
        overwrite=True,
        executors=Executors(shard_index=1, num_shards=2),
        executor=InlineExecutor(),
    )
    assert summary.done == [Path("b.mcap")]
    assert (ws / "b.mcap.seen").read_text() == f"True True ingest {default_config().name}"
    assert load_config(ws / "config.toml") == default_config()
    assert "shard 1 of 2: 1 of 3 logs" in summary.render()

    everything = run_ingest_batch(logs, ws, None, overwrite=False, executor=InlineExecutor())
    assert everything.done == [Path("c.mcap"), Path("a.mcap"), Path("b.mcap")]  # given order

    custom = tmp_path / "custom.toml"
    custom.write_text('name = "custom"\n')
    # Another configuration than the workspace's is refused once, before any log runs...
    before = sorted(p.name for p in ws.iterdir())
    with pytest.raises(ConfigError, match="another configuration"):
        run_ingest_batch([Path("a.mcap")], ws, custom, overwrite=False, executor=InlineExecutor())
    assert sorted(p.name for p in ws.iterdir()) == before
    # ...and replaces it with --overwrite.
    run_ingest_batch([Path("a.mcap")], ws, custom, overwrite=True, executor=InlineExecutor())
    assert load_config(ws / "config.toml").name == "custom"
    # Without -c, the workspace's recorded configuration stays in force.
    run_ingest_batch([Path("a.mcap")], ws, None, overwrite=False, executor=InlineExecutor())
    assert load_config(ws / "config.toml").name == "custom"


def test_run_ingest_batch_bad_config_fails_once_before_any_work(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[topics]\nimu = 3\n")
    with pytest.raises(ConfigError, match="topics.imu"):
        run_ingest_batch([tmp_path / "a.mcap"], tmp_path / "ws", bad, overwrite=False)
    assert not (tmp_path / "ws" / "config.toml").exists()


def test_missing_log_is_a_failed_item(tmp_path: Path) -> None:
    summary = run_ingest_batch(
        [tmp_path / "nope.mcap"], tmp_path / "ws", None, overwrite=False, executor=InlineExecutor()
    )
    assert list(summary.failed) == [tmp_path / "nope.mcap"]
    reason = summary.failed[tmp_path / "nope.mcap"]
    assert reason.startswith("no such") and "nope.mcap" not in reason  # the item names the file


# -- the command line -----------------------------------------------------------------------


class RecordingBatch:
    """A stand-in for run_ingest_batch that records its arguments."""

    def __init__(self, failed: dict[Path, str]) -> None:
        self.failed = failed
        self.calls: list[tuple[tuple[Any, ...], dict[str, Any]]] = []

    def __call__(self, *args: Any, **kwargs: Any) -> BatchSummary:
        self.calls.append((args, kwargs))
        outcomes = tuple(
            ItemOutcome(log, "failed", reason=self.failed[log])
            if log in self.failed
            else ItemOutcome(log, "done", FakeResult(log.stem, "ingested"))
            for log in args[0]
        )
        return BatchSummary("ingest", outcomes, 0.5, unit="log")


def invoke(args: list[str], fake: RecordingBatch, monkeypatch: pytest.MonkeyPatch) -> Any:
    """The command line with ``fake`` for the batch, in an empty folder holding the
    ``.mcap`` files named (empty: the verb refuses a log argument that is no file)."""
    monkeypatch.setattr(batch, "run_ingest_batch", fake)
    with tempfile.TemporaryDirectory() as folder, monkeypatch.context() as here:
        here.chdir(folder)
        for arg in args:
            if arg.endswith(".mcap"):
                Path(arg).touch()
        return CliRunner().invoke(main, args)


def test_cli_ingest_help() -> None:
    result = CliRunner().invoke(main, ["ingest", "--help"])
    assert result.exit_code == 0
    for option in ("--workspace", "--config", "--overwrite", "--executor", "--scheduler"):
        assert option in result.output
    for option in ("--workers", "--shard-index", "--num-shards"):
        assert option in result.output


def test_cli_ingest_passes_its_options(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = RecordingBatch({})
    args = ["ingest", "a.mcap", "b.mcap", "-w", "ws", "-c", "cfg.toml", "--overwrite"]
    args += ["--executor", "dask", "--scheduler", "tcp://h:8786", "--workers", "3"]
    args += ["--shard-index", "1", "--num-shards", "4"]
    result = invoke(args, fake, monkeypatch)
    assert result.exit_code == 0, result.output
    (call_args, kwargs) = fake.calls[0]
    assert call_args == ([Path("a.mcap"), Path("b.mcap")], Path("ws"), Path("cfg.toml"))
    assert kwargs == {
        "overwrite": True,
        "executors": Executors("dask", "tcp://h:8786", workers=3, shard_index=1, num_shards=4),
    }
    assert "ingest: 2 logs: 2 ingested, 0 failed" in result.output


def test_cli_ingest_defaults(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = RecordingBatch({})
    result = invoke(["ingest", "a.mcap", "-w", "ws"], fake, monkeypatch)
    assert result.exit_code == 0, result.output
    (call_args, kwargs) = fake.calls[0]
    assert call_args == ([Path("a.mcap")], Path("ws"), None)
    assert kwargs == {"overwrite": False, "executors": Executors()}


def test_cli_ingest_failure_lines_and_exit_1(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = RecordingBatch({Path("b.mcap"): "truncated: no usable message"})
    result = invoke(["ingest", "a.mcap", "b.mcap", "-w", "ws"], fake, monkeypatch)
    assert result.exit_code == 1
    assert result.stderr.splitlines() == ["terrain: error: b.mcap: truncated: no usable message"]
    assert "1 ingested, 1 failed" in result.stdout
    assert "truncated" not in result.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["ingest", "a.mcap", "-w", "ws", "--executor", "dask"], "--scheduler"),
        (["ingest", "a.mcap", "-w", "ws", "--scheduler", "tcp://h:1"], "--executor dask"),
        (["ingest", "a.mcap", "-w", "ws", "--shard-index", "2", "--num-shards", "2"], "shard"),
        (["ingest", "a.mcap", "-w", "ws", "--num-shards", "0"], "num-shards"),
        (["ingest", "a.mcap", "-w", "ws", "--workers", "-1"], "workers"),
        (["ingest", "a.mcap", "-w", "ws", "--executor", "slurm"], "executor"),
        (["ingest", "a.mcap"], "-w"),
        (["ingest", "-w", "ws"], "LOG.mcap"),
    ],
)
def test_cli_ingest_usage_errors_exit_2(
    args: list[str], message: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake = RecordingBatch({})
    result = invoke(args, fake, monkeypatch)
    assert result.exit_code == 2, result.output
    assert message in result.stderr
    assert not fake.calls


# -- two real logs, one broken --------------------------------------------------------------


@pytest.fixture(scope="module")
def two_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A good simulated log and a broken one (truncated to a few hundred bytes)."""
    from toolkit.sim.simulate import simulate

    folder = tmp_path_factory.mktemp("logs")
    good, broken = folder / "good.mcap", folder / "broken.mcap"
    simulate(good, profile="sample", distance_m=150, seed=21, workers=0)
    simulate(broken, profile="sample", distance_m=150, seed=22, workers=0)
    with broken.open("r+b") as fh:
        fh.truncate(300)
    return good, broken


def check_two_log_batch(logs: tuple[Path, Path], ws: Path, executor: Any) -> None:
    good, broken = logs
    first = run_ingest_batch([good, broken], ws, None, overwrite=False, executor=executor)
    assert first.done == [good]
    assert list(first.failed) == [broken]
    reason = first.failed[broken]
    assert reason and "\n" not in reason and "Traceback" not in reason
    assert not reason.startswith(str(broken))  # the summary names the file, not the reason
    result = first.results[good]
    assert result.status == "ingested"
    for table in ("imu", "gps", "laser"):
        assert (ws / "logs" / result.log_id / f"{table}.parquet").is_file()
    # The broken log left no tables behind.
    assert [p.name for p in ws.glob("logs/broken-*/*.parquet")] == []

    again = run_ingest_batch([broken, good], ws, None, overwrite=False, executor=executor)
    assert again.up_to_date == [good]
    assert again.failed == {broken: reason}
    assert "1 up to date, 1 failed" in again.render()


def test_two_log_batch_on_local_pool(two_logs: tuple[Path, Path], tmp_path: Path) -> None:
    with make_executor("local", workers=2) as executor:
        check_two_log_batch(two_logs, tmp_path / "ws", executor)


def test_two_log_batch_on_in_process_dask_cluster(
    two_logs: tuple[Path, Path], tmp_path: Path, dask_cluster: Any
) -> None:
    with make_executor("dask", cluster=dask_cluster) as executor:
        check_two_log_batch(two_logs, tmp_path / "ws", executor)


def test_cli_ingest_two_logs_end_to_end(two_logs: tuple[Path, Path], tmp_path: Path) -> None:
    good, broken = two_logs
    args = ["ingest", str(good), str(broken), "-w", str(tmp_path / "ws"), "--workers", "2"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    # One error line; the other stderr lines are progress (each log as it finishes).
    lines = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(lines) == 1 and lines[0].startswith(f"terrain: error: {broken}: "), result.stderr
    assert "1 ingested, 1 failed" in result.stdout
