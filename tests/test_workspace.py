"""Tests of toolkit.workspace: log ids, manifests, the lock, freshness."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from toolkit.atomic import atomic_write_bytes
from toolkit.config import default_config
from toolkit.errors import ConfigError, WorkspaceError
from toolkit.manifest import Manifest, StageRecord, check_up_to_date, digest_files, file_sha256
from toolkit.workspace import Workspace, log_id_for, make_log_id

# -- hashing and log ids ------------------------------------------------------------------


def test_file_sha256_streams_large_files(tmp_path: Path) -> None:
    data = os.urandom(2_500_000)  # more than two 1 MiB chunks
    path = tmp_path / "big.bin"
    path.write_bytes(data)
    assert file_sha256(path) == hashlib.sha256(data).hexdigest()


def test_file_sha256_missing_file(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="cannot read"):
        file_sha256(tmp_path / "absent.mcap")


def test_log_id_is_stable_and_content_derived(tmp_path: Path) -> None:
    a = tmp_path / "race day.mcap"
    a.write_bytes(b"one")
    sha = hashlib.sha256(b"one").hexdigest()
    assert log_id_for(a) == f"race_day-{sha[:12]}"
    assert log_id_for(a) == log_id_for(a)
    copy = tmp_path / "sub" / "race day.mcap"
    copy.parent.mkdir()
    copy.write_bytes(b"one")
    assert log_id_for(copy) == log_id_for(a)  # where it lives does not matter
    b = tmp_path / "other" / "race day.mcap"
    b.parent.mkdir()
    b.write_bytes(b"two")
    assert log_id_for(b) != log_id_for(a)  # same name, different content


def test_make_log_id_sanitises_stem() -> None:
    sha = "ABCDEF0123456789" * 4
    assert make_log_id("../../etc/passwd", sha) == "etc_passwd-abcdef012345"
    assert make_log_id("///", sha) == "log-abcdef012345"
    assert "/" not in make_log_id("a/b", sha)


# -- atomic writes ------------------------------------------------------------------------


# -- manifest -----------------------------------------------------------------------------


def _record(**overrides: object) -> StageRecord:
    fields: dict[str, object] = {
        "inputs": {"log": "aa" * 32},
        "config_hash": "cc" * 32,
        "outputs": ("imu.parquet",),
        "row_counts": {"imu": 10},
        "rejects": {"clock_skew": 2},
        "timings_s": {"total": 1.25},
        "warnings": ("gps gap of 3 s",),
    }
    fields.update(overrides)
    return StageRecord(**fields)  # type: ignore[arg-type]


def test_manifest_missing_is_empty(tmp_path: Path) -> None:
    m = Manifest(tmp_path / "manifest.json")
    assert m.stages() == {}
    assert m.stage("ingest") is None


def test_manifest_records_and_reads_back(tmp_path: Path) -> None:
    m = Manifest(tmp_path / "logs" / "x" / "manifest.json")
    m.record_stage("ingest", _record())
    m.record_stage("pose", _record(row_counts={"pose": 5}))
    m.set_header(source={"path": "a.mcap", "sha256": "aa" * 32})
    got = m.stage("ingest")
    assert got is not None
    assert got.rejects == {"clock_skew": 2}
    assert got.warnings == ("gps gap of 3 s",)
    assert got.toolkit_version  # stamped
    assert got.finished_utc.endswith("+00:00")
    assert set(m.stages()) == {"ingest", "pose"}
    raw = json.loads(m.path.read_text())
    assert raw["format"] == 1
    assert raw["source"]["path"] == "a.mcap"
    m.remove_stage("pose")
    assert set(m.stages()) == {"ingest"}
    with pytest.raises(ValueError):
        m.set_header(stages={})


def test_manifest_corrupt_is_a_workspace_error(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    path.write_text("{not json")
    with pytest.raises(WorkspaceError, match="not valid JSON"):
        Manifest(path).stages()
    path.write_text(json.dumps({"format": 1, "stages": {"ingest": {"inputs": 3}}}))
    with pytest.raises(WorkspaceError, match="malformed record for stage 'ingest'"):
        Manifest(path).stage("ingest")
    path.write_text(json.dumps({"format": 99, "stages": {}}))
    with pytest.raises(WorkspaceError, match="format"):
        Manifest(path).stages()
    path.write_bytes(b'{"format": 1, "stages": {"\xff": {}}}')  # not UTF-8
    with pytest.raises(WorkspaceError, match="not UTF-8 text") as err:
        Manifest(path).stages()
    assert str(path) in str(err.value)


def _record_in_child(path: str, name: str) -> None:
    Manifest(path).record_stage(name, _record())


def test_manifest_concurrent_updates_lose_nothing(tmp_path: Path) -> None:
    path = tmp_path / "manifest.json"
    names = [f"stage{i}" for i in range(12)]
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_record_in_child, args=(str(path), n)) for n in names]
    for p in procs:
        p.start()
    for p in procs:
        p.join(30)
        assert p.exitcode == 0
    assert set(Manifest(path).stages()) == set(names)
    assert [p.name for p in tmp_path.iterdir()] == ["manifest.json"]


# -- freshness ----------------------------------------------------------------------------


def test_check_up_to_date(tmp_path: Path) -> None:
    out = tmp_path / "imu.parquet"
    inputs = {"log": "aa" * 32}
    rec = _record()
    assert not check_up_to_date(None, inputs=inputs, config_hash="cc" * 32, outputs=[out])
    missing = check_up_to_date(rec, inputs=inputs, config_hash="cc" * 32, outputs=[out])
    assert not missing and "missing" in missing.reason
    out.write_bytes(b"x")
    unverified = check_up_to_date(rec, inputs=inputs, config_hash="cc" * 32, outputs=[out])
    assert not unverified and "no record of what was written" in unverified.reason
    rec = _record(output_files=digest_files(tmp_path, ["imu.parquet"]))
    assert check_up_to_date(rec, inputs=inputs, config_hash="cc" * 32, outputs=[out])
    changed = check_up_to_date(rec, inputs={"log": "bb" * 32}, config_hash="cc" * 32, outputs=[out])
    assert not changed and "log" in changed.reason
    extra = {**inputs, "pose": "dd" * 32}
    assert not check_up_to_date(rec, inputs=extra, config_hash="cc" * 32, outputs=[out])
    cfg = check_up_to_date(rec, inputs=inputs, config_hash="ee" * 32, outputs=[out])
    assert not cfg and "configuration" in cfg.reason
    out.write_bytes(b"y")  # same size, other bytes: not what the stage wrote
    changed_output = check_up_to_date(rec, inputs=inputs, config_hash="cc" * 32, outputs=[out])
    assert not changed_output and "output changed" in changed_output.reason
    out.write_bytes(b"")  # truncated
    assert not check_up_to_date(rec, inputs=inputs, config_hash="cc" * 32, outputs=[out])


def test_stage_record_keeps_output_digests_through_json(tmp_path: Path) -> None:
    (tmp_path / "imu.parquet").write_bytes(b"abc")
    rec = _record(output_files=digest_files(tmp_path, ["imu.parquet"]))
    back = StageRecord.from_json(rec.to_json())
    assert back.output_files == rec.output_files
    assert back.output_files["imu.parquet"].size_bytes == 3


def test_workspace_is_up_to_date_uses_log_manifest(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    out = ws.log_table("L1", "imu")
    kwargs = {"inputs": {"log": "aa" * 32}, "config_hash": "cc" * 32, "outputs": [out]}
    assert not ws.is_up_to_date("ingest", log_id="L1", **kwargs)  # type: ignore[arg-type]
    atomic_write_bytes(out, b"parquet")
    ws.manifest("L1").record_stage(
        "ingest", _record(output_files=digest_files(out.parent, ["imu.parquet"]))
    )
    assert ws.is_up_to_date("ingest", log_id="L1", **kwargs)  # type: ignore[arg-type]
    assert not ws.is_up_to_date("ingest", log_id=None, **kwargs)  # type: ignore[arg-type]


# -- workspace paths, config, lock ------------------------------------------------------


def test_workspace_paths_follow_the_contract(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    assert ws.config_path == tmp_path / "config.toml"
    assert ws.log_manifest_path("L") == tmp_path / "logs" / "L" / "manifest.json"
    assert ws.log_table("L", "points") == tmp_path / "logs" / "L" / "points.parquet"
    assert ws.events_table == tmp_path / "tables" / "events.parquet"
    assert ws.event_points_table == tmp_path / "tables" / "event_points.parquet"
    assert ws.model_path == tmp_path / "model.json"
    assert ws.scores_table == tmp_path / "report" / "scores.parquet"
    assert ws.summary_path == tmp_path / "report" / "summary.json"
    assert ws.manifest().path == tmp_path / "manifest.json"
    for bad in ("", "..", "a/b", ".a.lock", ".a.host-1-abc.gen", "a\\b"):
        with pytest.raises(WorkspaceError, match="invalid log id"):
            ws.log_dir(bad)


def test_workspace_config_round_trip_and_require(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    with pytest.raises(WorkspaceError, match="no such workspace"):
        ws.require()
    ws.create()
    with pytest.raises(WorkspaceError, match="not a workspace"):
        ws.read_config()
    ws.write_config(default_config())
    assert ws.read_config() == default_config()
    ws.config_path.write_text("[label]\nfir_tap = 3\n")
    with pytest.raises(ConfigError, match="label.fir_tap"):
        ws.read_config()


def test_log_ids_lists_directories(tmp_path: Path) -> None:
    ws = Workspace(tmp_path).create()
    assert ws.log_ids() == []
    (ws.logs_dir / "b-1").mkdir()
    (ws.logs_dir / "a-2").mkdir()
    (ws.logs_dir / "stray.txt").write_text("")
    assert ws.log_ids() == ["a-2", "b-1"]


def test_lock_is_exclusive_within_a_process(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    with ws.lock(), pytest.raises(WorkspaceError, match=rf"in use .*pid {os.getpid()}"):
        ws.lock().acquire()
    with ws.lock():  # released: can be taken again
        pass


def test_lock_held_by_another_process(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    holder = textwrap.dedent(
        f"""
        import sys, time
        from toolkit.workspace import Workspace
        with Workspace({str(tmp_path)!r}).lock():
            print("locked", flush=True)
            sys.stdin.readline()
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", holder], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        with pytest.raises(WorkspaceError, match=f"pid {proc.pid}") as info:
            ws.lock().acquire()
        assert info.value.path == tmp_path
    finally:
        assert proc.stdin is not None
        proc.stdin.write("\n")
        proc.stdin.close()
        proc.wait(30)
    with ws.lock():
        pass


def test_shared_locks_coexist_and_exclude_an_exclusive_one(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    with (
        ws.lock(shared=True),  # two ingests side by side...
        ws.lock(shared=True),
        pytest.raises(WorkspaceError, match="in use by another terrain process"),
    ):
        ws.lock().acquire()  # ...and a pose is refused while they run
    with ws.lock(), pytest.raises(WorkspaceError, match=rf"pid {os.getpid()}"):
        ws.lock(shared=True).acquire()  # an ingest is refused while a pose runs


def test_ingest_honours_the_lock_a_pose_holds(tmp_path: Path) -> None:
    from toolkit.batch import run_ingest_batch

    ws = Workspace(tmp_path / "ws")
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"
    with ws.lock(), pytest.raises(WorkspaceError, match="in use"):
        run_ingest_batch([sample], ws.root, None, overwrite=False, workers=1)
    assert not ws.log_ids()


def test_require_finished_refuses_what_the_producer_did_not_write(tmp_path: Path) -> None:
    from toolkit.manifest import file_sha256, require_finished

    (tmp_path / "imu.parquet").write_bytes(b"written")
    rec = _record(output_files=digest_files(tmp_path, ["imu.parquet"]))
    now = {"imu.parquet": file_sha256(tmp_path / "imu.parquet")}
    require_finished(rec, "ingest", now, tmp_path)  # the file it wrote: accepted
    with pytest.raises(WorkspaceError, match="no finished ingest"):
        require_finished(None, "ingest", now, tmp_path)
    (tmp_path / "imu.parquet").write_bytes(b"edited")
    changed = {"imu.parquet": file_sha256(tmp_path / "imu.parquet")}
    with pytest.raises(WorkspaceError, match="imu.parquet: not the file the last finished"):
        require_finished(rec, "ingest", changed, tmp_path)


def test_an_output_of_an_older_table_schema_is_not_up_to_date(tmp_path: Path) -> None:
    """A table written for an older version of its schema (which every reader refuses) makes
    its stage run again, even with inputs, config and bytes unchanged."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from toolkit.manifest import FileDigest, StageRecord, check_up_to_date
    from toolkit.tableio import load_table_schema, write_table

    path = tmp_path / "heading.parquet"
    write_table(
        path,
        pa.table({"t_ns": [1, 2], "yaw": [0.0, 0.1], "yaw_std": [0.01, 0.01]}),
        "heading",
        source_sha256="0" * 64,
        config_hash="c",
    )
    record = StageRecord(
        inputs={},
        config_hash="c",
        outputs=(path.name,),
        output_files={path.name: FileDigest.of(path)},
    )
    assert check_up_to_date(record, inputs={}, config_hash="c", outputs=[path])
    table = pq.read_table(path)
    meta = dict(table.schema.metadata)
    meta[b"schema_version"] = str(load_table_schema("heading").version - 1).encode()
    pq.write_table(table.replace_schema_metadata(meta), path)
    record = StageRecord(
        inputs={},
        config_hash="c",
        outputs=(path.name,),
        output_files={path.name: FileDigest.of(path)},
    )
    fresh = check_up_to_date(record, inputs={}, config_hash="c", outputs=[path])
    assert not fresh and "written for schema heading v0" in fresh.reason


def test_created_takes_away_only_an_unused_fresh_workspace(tmp_path: Path) -> None:
    """Fresh and left without a log: removed. Fresh but holding a file the toolkit did not
    write, or a lock another process holds: kept."""
    import fcntl
    import os

    ws = Workspace(tmp_path / "a")
    with ws.created():
        (ws.logs_dir / ".x-1.lock").touch()  # a failed ingest's log lock
    assert not ws.root.exists()

    ws = Workspace(tmp_path / "b")
    with ws.created():
        (ws.root / "theirs.txt").write_text("x")
    assert (ws.root / "theirs.txt").is_file()

    ws = Workspace(tmp_path / "c")
    with ws.created():
        held = ws.logs_dir / ".y-2.lock"
        held.touch()
        fd = os.open(held, os.O_RDONLY)
        fcntl.flock(fd, fcntl.LOCK_EX)  # another shard's ingest is still at work
    try:
        assert held.is_file()
    finally:
        os.close(fd)


def test_an_unknown_log_is_refused_naming_the_logs_there(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    with pytest.raises(WorkspaceError, match="has no log yet"):
        ws.require_log("a-1")
    for name in ("b-2", "a-1"):
        (ws.logs_dir / name).mkdir()
    assert ws.require_log("a-1") == ws.log_dir("a-1")
    with pytest.raises(WorkspaceError, match="no log 'c-3' in the workspace; its logs: a-1, b-2"):
        ws.require_log("c-3")
