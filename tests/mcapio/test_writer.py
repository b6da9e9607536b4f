"""LogWriter: files readable by the reference reader, reproducible, and never half-written."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from toolkit.errors import SchemaError
from toolkit.mcapio.cdr_encode import encode_batch
from toolkit.mcapio.writer import LogWriter, Record, merge_by_time


def _stamp(t: np.ndarray) -> dict[str, np.ndarray]:
    return {"header.stamp.sec": t // 10**9, "header.stamp.nanosec": t % 10**9}


def _write_sample(path: Path, n_imu: int = 400) -> dict[str, object]:
    """A small two-second log: IMU at 200 Hz, laser at 75 Hz, GPS at 10 Hz, one TF message."""
    rng = np.random.default_rng(7)
    t_imu = 1_700_000_000_000_000_000 + np.arange(n_imu, dtype=np.int64) * 5_000_000
    t_laser = t_imu[0] + np.arange(150, dtype=np.int64) * 13_333_333
    t_gps = t_imu[0] + np.arange(20, dtype=np.int64) * 100_000_000
    accel = rng.normal(0, 1, (n_imu, 3))
    ranges = rng.random((150, 181)).astype(np.float32) * 40
    imu = encode_batch(
        "sensor_msgs/msg/Imu",
        {
            **_stamp(t_imu),
            "header.frame_id": "imu",
            "linear_acceleration.x": accel[:, 0],
            "linear_acceleration.y": accel[:, 1],
            "linear_acceleration.z": accel[:, 2],
        },
    )
    laser = encode_batch(
        "sensor_msgs/msg/LaserScan",
        {
            **_stamp(t_laser),
            "header.frame_id": "laser_1",
            "angle_min": -np.pi / 2,
            "angle_max": np.pi / 2,
            "angle_increment": np.pi / 180,
            "ranges": ranges,
        },
    )
    gps = encode_batch(
        "sensor_msgs/msg/NavSatFix",
        {
            **_stamp(t_gps),
            "header.frame_id": "gps",
            "latitude": 36.0 + np.arange(20) * 1e-6,
            "longitude": -117.0,
            "position_covariance_type": 2,
        },
    )
    tf = encode_batch(
        "tf2_msgs/msg/TFMessage",
        {
            "transforms": [
                [
                    {"header": {"frame_id": "base_link"}, "child_frame_id": "imu"},
                ]
            ]
        },
    )
    with LogWriter(path) as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.register("/laser_1", "sensor_msgs/msg/LaserScan")
        log.register("/gps/fix", "sensor_msgs/msg/NavSatFix")
        log.register("/tf_static", "tf2_msgs/msg/TFMessage")
        log.add_metadata("terrain", {"profile": "sample", "seed": "7"})
        log.add_attachment("config.toml", b"[vehicle]\nwheelbase_m = 2.9\n", "application/toml")
        log.write_interleaved(
            merge_by_time(
                [
                    ("/tf_static", t_imu[:1], tf),
                    ("/imu", t_imu, imu),
                    ("/laser_1", t_laser, laser),
                    ("/gps/fix", t_gps, gps),
                ]
            )
        )
    return {"accel": accel, "ranges": ranges, "t_imu": t_imu, "n": n_imu + 150 + 20 + 1}


def test_log_reads_back_with_the_reference_reader(tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    sample = _write_sample(path)
    assert path.exists() and not (tmp_path / "sample.mcap.partial").exists()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == sample["n"]
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert all(c.message_index_offsets for c in summary.chunk_indexes)
        imu_rows, laser_rows, times = [], [], []
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            times.append(message.log_time)
            if channel.topic == "/imu":
                assert schema is not None and schema.name == "sensor_msgs/msg/Imu"
                a = decoded.linear_acceleration
                imu_rows.append((a.x, a.y, a.z))
                stamp = decoded.header.stamp
                assert stamp.sec * 10**9 + stamp.nanosec == message.log_time
            elif channel.topic == "/laser_1":
                laser_rows.append(decoded.ranges)
            elif channel.topic == "/tf_static":
                assert decoded.transforms[0].child_frame_id == "imu"
        assert times == sorted(times) and len(times) == sample["n"]
        np.testing.assert_array_equal(np.array(imu_rows), sample["accel"])
        np.testing.assert_array_equal(np.array(laser_rows, dtype=np.float32), sample["ranges"])
        assert [m.name for m in reader.iter_metadata()] == ["terrain"]
        assert [a.name for a in reader.iter_attachments()] == ["config.toml"]
    with open(path, "rb") as f:  # every CRC (chunks, data section) checks out
        records = list(StreamReader(f, validate_crcs=True).records)
    assert records


def test_identical_input_gives_identical_bytes(tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _write_sample(a)
    _write_sample(b)
    assert hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()


def test_large_logs_are_split_into_chunks(tmp_path: Path) -> None:
    path = tmp_path / "big.mcap"
    n = 3000
    rng = np.random.default_rng(1)
    payloads = encode_batch(
        "sensor_msgs/msg/LaserScan",
        {
            "ranges": rng.random((n, 181)).astype(np.float32),
        },
    )
    with LogWriter(path) as log:
        log.register("/laser", "sensor_msgs/msg/LaserScan")
        log.write_batch("/laser", np.arange(n, dtype=np.int64) * 10**7, payloads)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 2


def test_partial_file_is_removed_on_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.mcap"
    partial = tmp_path / "broken.mcap.partial"
    with pytest.raises(RuntimeError, match="boom"), LogWriter(path) as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.write_batch("/imu", [1, 2], encode_batch("sensor_msgs/msg/Imu", {}, n=2))
        assert partial.exists() and not path.exists()
        raise RuntimeError("boom")
    assert not path.exists() and not partial.exists()
    with pytest.raises(SchemaError, match="not registered"), LogWriter(path) as log:
        log.write_batch("/nowhere", [1], [b"\x00\x01\x00\x00"])
    assert not path.exists() and not partial.exists()


def test_existing_file_is_kept_when_a_rewrite_fails(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write_sample(path)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="non-negative"), LogWriter(path) as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.write_batch("/imu", [-5], encode_batch("sensor_msgs/msg/Imu", {}))
    assert path.read_bytes() == before


def test_topic_type_conflict_is_a_schema_error(tmp_path: Path) -> None:
    with LogWriter(tmp_path / "x.mcap") as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.register("/imu", "sensor_msgs/Imu")  # same type, other spelling: fine
        with pytest.raises(SchemaError, match="already registered"):
            log.register("/imu", "sensor_msgs/msg/LaserScan")


def test_merge_by_time_is_stable_and_global() -> None:
    merged = list(
        merge_by_time(
            [
                ("/a", np.array([3, 1, 5]), [b"a3", b"a1", b"a5"]),
                ("/b", np.array([1, 3]), [b"b1", b"b3"], np.array([10, 30])),
            ]
        )
    )
    assert [r.payload for r in merged] == [b"a1", b"b1", b"a3", b"b3", b"a5"]
    assert merged[1] == Record("/b", 1, b"b1", 10)
    assert merged[0].publish_time_ns == 1
    with pytest.raises(ValueError, match="one time per payload"):
        list(merge_by_time([("/a", np.array([1, 2]), [b"x"])]))
