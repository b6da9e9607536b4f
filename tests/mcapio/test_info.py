"""scan_log / render_table: right figures, problems found, and no crash on damaged files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, IndexType, Writer

from toolkit.errors import LogReadError
from toolkit.mcapio.cdr_encode import encode_batch
from toolkit.mcapio.info import LogInfo, render_table, scan_log
from toolkit.mcapio.msgdefs import load_msgdef
from toolkit.mcapio.writer import LogWriter, merge_by_time

T0 = 1_700_000_000_000_000_000


def _good_log(path: Path, compression: CompressionType = CompressionType.ZSTD) -> Path:
    """IMU at 100 Hz for 10 s (one 0.5 s dropout), wheels at 20 Hz, one registered silent topic."""
    t_imu = T0 + np.arange(1000, dtype=np.int64) * 10_000_000
    t_imu = np.concatenate([t_imu[:500], t_imu[550:]])  # a 0.51 s gap
    t_wheels = T0 + np.arange(200, dtype=np.int64) * 50_000_000
    imu = encode_batch(
        "sensor_msgs/msg/Imu",
        {
            "header.stamp.sec": t_imu // 10**9,
            "header.stamp.nanosec": t_imu % 10**9,
            "linear_acceleration.z": np.linspace(9.0, 10.0, len(t_imu)),
        },
    )
    wheels = encode_batch("terrain_msgs/msg/WheelSpeeds", {"front_left": np.arange(200.0)})
    with LogWriter(path, compression=compression, chunk_size=64 * 1024) as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.register("/wheels", "terrain_msgs/msg/WheelSpeeds")
        log.register("/gps/heading", "terrain_msgs/msg/GpsHeading")
        log.add_metadata("terrain", {"seed": "1"})
        log.add_attachment("truth.json", b"{}", "application/json")
        log.write_interleaved(merge_by_time([("/imu", t_imu, imu), ("/wheels", t_wheels, wheels)]))
    return path


def _check_good(info: LogInfo) -> None:
    topics = {t.topic: t for t in info.topics}
    assert list(topics) == ["/imu", "/wheels", "/gps/heading"]
    imu = topics["/imu"]
    assert imu.message_type == "sensor_msgs/msg/Imu"
    assert imu.message_count == 950
    assert imu.first_time_ns == T0 and imu.last_time_ns == T0 + 999 * 10_000_000
    assert imu.max_gap_s == pytest.approx(0.51)
    assert imu.long_gaps == 1
    assert imu.mean_rate_hz == pytest.approx(949 / 9.99)
    wheels = topics["/wheels"]
    assert wheels.message_count == 200 and wheels.long_gaps == 0
    assert wheels.mean_rate_hz == pytest.approx(20.0)
    assert topics["/gps/heading"].message_count == 0
    assert info.message_count == 1150
    assert info.start_time_ns == T0 and info.duration_s == pytest.approx(9.99)
    assert info.profile == "ros2" and info.library.startswith("terrain-toolkit/")
    assert info.metadata_names == ("terrain",)
    assert info.attachment_names == ("truth.json",)
    assert info.chunk_count >= 2
    assert info.problem_kinds() == {"empty_topic"}


def test_good_log_from_its_summary(tmp_path: Path) -> None:
    info = scan_log(_good_log(tmp_path / "good.mcap"))
    assert info.scan == "index" and info.has_summary
    _check_good(info)
    assert info.compression == ("zstd",)
    json.dumps(info.to_dict())
    table = render_table(info)
    assert "/imu" in table and "sensor_msgs/msg/Imu" in table and "950" in table
    assert "[empty_topic] topic /gps/heading has no messages" in table


def test_full_scan_agrees_with_the_summary(tmp_path: Path) -> None:
    path = _good_log(tmp_path / "good.mcap")
    full = scan_log(path, full=True)
    assert full.scan == "full"
    _check_good(full)
    assert full.topics == scan_log(path).topics


def test_truncated_log_reports_problems_and_keeps_what_it_read(tmp_path: Path) -> None:
    path = _good_log(tmp_path / "good.mcap")
    data = path.read_bytes()
    half = tmp_path / "half.mcap"
    half.write_bytes(data[: len(data) // 2])
    info = scan_log(half)
    assert {"no_summary", "truncated"} <= info.problem_kinds()
    assert not info.has_summary and info.scan == "full"
    assert 0 < info.message_count < 1150
    assert info.profile == "ros2"
    json.dumps(info.to_dict())
    assert "[truncated]" in render_table(info)


def test_corrupt_chunk_fails_its_crc(tmp_path: Path) -> None:
    path = _good_log(tmp_path / "plain.mcap", compression=CompressionType.NONE)
    data = bytearray(path.read_bytes())
    at = data.index(np.float64(np.linspace(9.0, 10.0, 950)[100]).tobytes())
    data[at] ^= 0xFF  # one bit pattern inside one IMU message of an uncompressed chunk
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    info = scan_log(bad, full=True)
    assert info.problem_kinds() == {"chunk_crc", "empty_topic"}
    (crc,) = [p.message for p in info.problems if p.kind == "chunk_crc"]
    assert crc.startswith("chunk at offset") and "CRC" in crc
    # The chunk is lost as ingest loses it, and every one of its messages is counted.
    topics = {t.topic: t for t in info.topics}
    assert 0 < info.messages_lost < 1150
    assert info.message_count + info.messages_lost == 1150
    assert topics["/imu"].messages_lost > 0
    assert info.damage_summary is not None
    assert f"lost {info.messages_lost} messages (" in info.damage_summary
    assert info.damage_summary in render_table(info)
    # The index pass reads no chunk, so it cannot see the bad CRC: it says so in its mode.
    assert scan_log(bad).scan == "index"


def test_disorder_duplicates_and_foreign_schemas_are_reported(tmp_path: Path) -> None:
    path = tmp_path / "messy.mcap"
    payloads = encode_batch("terrain_msgs/msg/WheelSpeeds", {"front_left": np.arange(5.0)})
    times = np.array([10, 20, 15, 30, 40], dtype=np.int64)
    with LogWriter(path) as log:
        log.register("/wheels", "terrain_msgs/msg/WheelSpeeds")
        log.write_batch("/wheels", times, payloads)
        log.write_batch("/wheels", [40], [payloads[4]])  # an exact duplicate
        log.write_batch("/wheels", [40], [payloads[3]])  # same time, other bytes: not one
    for full in (False, True):
        info = scan_log(path, full=full)
        kinds = info.problem_kinds()
        assert kinds == {"out_of_order", "duplicates"}, (full, info.problems)
        messages = {p.kind: p.message for p in info.problems}
        assert messages["duplicates"].startswith("1 duplicate")
        assert messages["out_of_order"].startswith("1 messages")


def test_log_without_summary_is_streamed(tmp_path: Path) -> None:
    path = tmp_path / "nosummary.mcap"
    with open(path, "wb") as f:
        w = Writer(
            f,
            index_types=IndexType.NONE,
            repeat_channels=False,
            repeat_schemas=False,
            use_statistics=False,
            use_summary_offsets=False,
        )
        w.start(profile="ros2", library="test")
        sid = w.register_schema(
            "terrain_msgs/msg/GpsHeading",
            "ros2msg",
            load_msgdef("terrain_msgs/msg/GpsHeading").encode(),
        )
        ros = w.register_channel("/heading", "cdr", sid)
        js = w.register_channel("/json", "json", w.register_schema("Thing", "jsonschema", b"{}"))
        for i, payload in enumerate(encode_batch("terrain_msgs/msg/GpsHeading", {}, n=30)):
            w.add_message(ros, log_time=i * 100, data=payload, publish_time=i * 100, sequence=i)
        w.add_message(js, log_time=2950, data=b"{}", publish_time=2950, sequence=0)
        w.finish()
    info = scan_log(path)
    assert not info.has_summary and info.scan == "full"
    assert [(t.topic, t.message_count) for t in info.topics] == [("/heading", 30), ("/json", 1)]
    assert info.problem_kinds() == {"no_summary", "unknown_schema"}
    assert "jsonschema" in {p.kind: p.message for p in info.problems}["unknown_schema"]


def test_files_that_are_not_mcap_raise_log_read_error(tmp_path: Path) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("hello, not a log\n")
    with pytest.raises(LogReadError, match="notes.mcap: not an MCAP file"):
        scan_log(text)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(LogReadError, match="not an MCAP file"):
        scan_log(empty)
    with pytest.raises(LogReadError, match="missing.mcap: no such file"):
        scan_log(tmp_path / "missing.mcap")
    with pytest.raises(LogReadError, match="not a regular file"):
        scan_log(tmp_path)
    magic_only = tmp_path / "magic.mcap"
    magic_only.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(LogReadError, match="magic.mcap"):
        scan_log(magic_only)


def _expected_messages(mcap: Path) -> int:
    records = json.loads(mcap.with_suffix(".json").read_text())["records"]
    return sum(r["type"] == "Message" for r in records)


def test_conformance_corpus_never_crashes(conformance_files: list[Path]) -> None:
    outcomes = {"info": 0, "refused": 0}
    for path in conformance_files:
        for full in (False, True):
            try:
                info = scan_log(path, full=full)
            except LogReadError:
                outcomes["refused"] += 1
                continue
            outcomes["info"] += 1
            json.dumps(info.to_dict())
            render_table(info)
            assert info.message_count == _expected_messages(path), (path.name, full)
    assert outcomes["info"] > 0
