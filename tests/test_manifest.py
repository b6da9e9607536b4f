"""Manifests: records, concurrent updates, the up-to-date check, finished inputs."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
from pathlib import Path

import pytest

from toolkit.errors import WorkspaceError
from toolkit.manifest import Manifest, StageRecord, check_up_to_date, digest_files, file_sha256


def _record(**overrides: object) -> StageRecord:
    """A stage record with plausible fields, ``overrides`` replacing some (also used by
    test_workspace)."""
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


def _record_in_child(path: str, name: str) -> None:
    Manifest(path).record_stage(name, _record())


def test_file_sha256_streams_large_files(tmp_path: Path) -> None:
    data = os.urandom(2_500_000)  # more than two 1 MiB chunks
    path = tmp_path / "big.bin"
    path.write_bytes(data)
    assert file_sha256(path) == hashlib.sha256(data).hexdigest()


def test_file_sha256_missing_file(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="cannot read"):
        file_sha256(tmp_path / "absent.mcap")


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


@pytest.mark.parametrize(
    ("token", "field"),
    [
        ("Infinity", "stages.pose.row_counts.pose"),
        ("NaN", "stages.pose.row_counts.pose"),
        ("-Infinity", "stages.pose.row_counts.pose"),
        ("1e999", "stages.pose.row_counts.pose"),  # read as an infinity
    ],
)
def test_a_non_finite_number_is_a_corrupt_manifest_naming_the_field(
    tmp_path: Path, token: str, field: str
) -> None:
    """The toolkit writes strict JSON: a NaN or infinity read back is a tampered manifest,
    refused with the file and the field named (not an OverflowError later on)."""
    path = tmp_path / "manifest.json"
    m = Manifest(path)
    m.record_stage("pose", _record(row_counts={"pose": 5}))
    path.write_text(path.read_text().replace('"pose": 5', f'"pose": {token}'))
    for read in (m.stages, m.read, lambda: m.stage("pose")):
        with pytest.raises(WorkspaceError, match=f"manifest field {field} is not a finite") as err:
            read()
        assert str(path) in str(err.value)


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("row_counts", {"imu": 6.5}, "row_counts.imu is 6.5, not a whole number"),
        ("rejects", {"clock_skew": -1}, "rejects.clock_skew is -1, not a whole number"),
        ("row_counts", {"imu": True}, "row_counts.imu is True, not a whole number"),
        ("timings_s", {"total": "fast"}, "timings_s.total is 'fast', not a finite number"),
        (
            "output_files",
            {"imu.parquet": {"bytes": 1.5, "sha256": "ab"}},
            r"output_files.imu.parquet.bytes is 1.5",
        ),
    ],
)
def test_a_count_that_is_no_count_is_a_malformed_record_naming_the_field(
    tmp_path: Path, key: str, value: object, said: str
) -> None:
    path = tmp_path / "manifest.json"
    record = _record().to_json()
    record[key] = value
    path.write_text(json.dumps({"format": 1, "stages": {"ingest": record}}))
    with pytest.raises(WorkspaceError, match=f"malformed record for stage 'ingest': {said}"):
        Manifest(path).stage("ingest")
