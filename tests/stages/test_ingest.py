"""Ingest: MCAP logs to the contract's tables, with faithful accounting.

Small logs are built here with the toolkit's writer, one problem at a time; the committed
sample log checks the real thing, and damaged copies of it the salvage path.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from toolkit.config import PipelineConfig, default_config, load_config, parse_config
from toolkit.errors import ConfigError, LogReadError, StageError, ToolkitError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import move_between_frames
from toolkit.geometry.mounts import sensor_mounts
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.manifest import file_sha256
from toolkit.mcapio.cdr_encode import encode_batch, encode_message
from toolkit.mcapio.info import scan_log
from toolkit.mcapio.writer import Batch, LogWriter, Record, merge_by_time
from toolkit.sim.record import sim_origin
from toolkit.stages import ingest as ingest_mod
from toolkit.stages.ingest import IngestResult, ingest_log
from toolkit.tableio import read_table, read_table_metadata
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"
NS = 1_000_000_000
T0 = 1_128_783_600 * NS
CONTRACT_TABLES = ("imu", "gps", "heading", "wheels", "laser")


# --------------------------------------------------------------------------------------
# Building small logs
# --------------------------------------------------------------------------------------


@dataclasses.dataclass
class Msgs:
    """One topic's messages: type, log times (ns) and CDR payloads."""

    topic: str
    type_name: str
    log_t: np.ndarray
    payloads: list[bytes]

    def records(self) -> list[Record]:
        return [
            Record(self.topic, int(t), p, int(t))
            for t, p in zip(self.log_t.tolist(), self.payloads, strict=True)
        ]


def header(stamps: np.ndarray, frame: str = "base_link") -> dict[str, Any]:
    stamps = np.asarray(stamps, dtype=np.int64)
    return {
        "header.stamp.sec": (stamps // NS).astype(np.int32),
        "header.stamp.nanosec": (stamps % NS).astype(np.uint32),
        "header.frame_id": frame,
    }


def times(n: int, rate_hz: float, t0: int = T0) -> np.ndarray:
    return t0 + np.round(np.arange(n) * NS / rate_hz).astype(np.int64)


def msgs(topic: str, type_name: str, stamps: np.ndarray, cols: dict[str, Any]) -> Msgs:
    payloads = encode_batch(type_name, {**header(stamps), **cols}, n=len(stamps))
    return Msgs(topic, type_name, np.asarray(stamps, dtype=np.int64), payloads)


def imu(topic: str = "/imu", n: int = 200, overrides: dict[str, Any] | None = None) -> Msgs:
    t = times(n, 100.0)
    cols = {
        "linear_acceleration.x": np.linspace(-1, 1, n),
        "linear_acceleration.z": np.full(n, 9.81),
        "angular_velocity.z": np.linspace(0, 0.1, n),
        **(overrides or {}),
    }
    return msgs(topic, "sensor_msgs/msg/Imu", t, cols)


def gps(topic: str = "/gps", n: int = 20, no_fix: Sequence[int] = ()) -> Msgs:
    t = times(n, 10.0, T0 + 3_000_000)
    status = np.full(n, 2, dtype=np.int8)
    lat = 37.0 + np.arange(n) * 1e-6
    status[list(no_fix)] = -1
    lat[list(no_fix)] = np.nan
    cols = {
        "status.status": status,
        "latitude": lat,
        "longitude": np.where(np.isnan(lat), np.nan, -116.0),
        "altitude": np.where(np.isnan(lat), np.nan, 900.0),
        "position_covariance": np.array([0.25, 0, 0, 0, 0.25, 0, 0, 0, 1.0]),
        "position_covariance_type": np.uint8(2),
    }
    return msgs(topic, "sensor_msgs/msg/NavSatFix", t, cols)


def gps_heading(topic: str = "/heading", n: int = 20) -> Msgs:
    t = times(n, 10.0, T0 + 4_000_000)
    cols = {"yaw": np.linspace(0, 1, n), "yaw_std": np.full(n, 0.01)}
    return msgs(topic, "terrain_msgs/msg/GpsHeading", t, cols)


def wheel_speeds(topic: str = "/wheels", n: int = 200, speed: float = 5.0) -> Msgs:
    t = times(n, 100.0, T0 + 1_000_000)
    cols = {k: np.full(n, speed) for k in ("front_left", "front_right", "rear_left", "rear_right")}
    return msgs(topic, "terrain_msgs/msg/WheelSpeeds", t, cols)


def scans(
    topic: str, n: int = 30, beams: int = 31, fov_rad: float = 1.0, rate_hz: float = 15.0, **kw: Any
) -> Msgs:
    t = times(n, rate_hz, T0 + 2_000_000)
    ranges = np.linspace(2.0, 20.0, n * beams, dtype=np.float32).reshape(n, beams)
    cols = {
        "angle_min": -fov_rad / 2,
        "angle_max": fov_rad / 2,
        "angle_increment": fov_rad / (beams - 1),
        "time_increment": 1e-5,
        "range_min": 0.5,
        "range_max": 60.0,
        "ranges": ranges,
        **kw,
    }
    return msgs(topic, "sensor_msgs/msg/LaserScan", t, cols)


def write_log(
    path: Path,
    topics: Iterable[Msgs],
    *,
    records: Iterable[Record] | None = None,
    chunk_size: int = 64 * 1024,
) -> Path:
    """Write the topics merged by log time, or ``records`` in the order given."""
    topics = list(topics)
    with LogWriter(path, chunk_size=chunk_size) as log:
        for m in topics:
            log.register(m.topic, m.type_name)
        if records is None:
            records = merge_by_time(Batch(m.topic, m.log_t, m.payloads) for m in topics)
        log.write_interleaved(records)
    return path


def basic_topics() -> list[Msgs]:
    return [
        scans("/laser/a"),
        scans("/laser/b"),
        imu(),
        gps(),
        gps_heading(),
        wheel_speeds(),
    ]


def make_config(**topics: str | list[str]) -> PipelineConfig:
    """The default configuration with these [topics] (unnamed optional roles absent)."""
    values: dict[str, Any] = {
        "lasers": ["/laser/a", "/laser/b"],
        "imu": "/imu",
        "gps": "/gps",
        "heading": "/heading",
        "wheels": "/wheels",
        "tf_static": "",
        "truth_pose": "",
        "truth_features": "",
    }
    values.update(topics)
    lines = ["[topics]"]
    for key, value in values.items():
        if isinstance(value, list):
            lines.append(f"{key} = [{', '.join(repr(v).replace(chr(39), chr(34)) for v in value)}]")
        else:
            lines.append(f'{key} = "{value}"')
    return parse_config("\n".join(lines) + "\n")


def log_dir(ws: Workspace, result: IngestResult) -> Path:
    return ws.log_dir(result.log_id)


def detail(ws: Workspace, result: IngestResult) -> dict[str, Any]:
    return dict(ws.manifest(result.log_id).read()["ingest"])


def assert_accounting(ws: Workspace, result: IngestResult) -> None:
    """For every topic: read = written + sum of rejects; rows = written for per-message roles."""
    for topic, acc in detail(ws, result)["topics"].items():
        assert acc["read"] == acc["written"] + sum(acc["rejects"].values()), topic
        if acc["role"] not in ("tf_static", "truth_features"):
            assert acc["rows"] == acc["written"], topic


def read(ws: Workspace, result: IngestResult, table: str) -> Any:
    return pq.read_table(ws.log_table(result.log_id, table))


def assert_sorted(table: Any) -> None:
    t = table.column("t_ns").to_numpy()
    assert np.all(np.diff(t) >= 0)


def partial_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith((".partial", ".sorted", ".tmp"))]


@pytest.fixture
def ws(tmp_path: Path) -> Workspace:
    return Workspace(tmp_path / "ws")


# --------------------------------------------------------------------------------------
# The sample log
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sample_ingest(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, IngestResult]:
    ws = Workspace(tmp_path_factory.mktemp("sample") / "ws")
    return ws, ingest_log(SAMPLE_LOG, ws, default_config())


def test_sample_log_row_counts_match_the_log(sample_ingest: tuple[Workspace, IngestResult]) -> None:
    ws, result = sample_ingest
    counts = {t.topic: t.message_count for t in scan_log(SAMPLE_LOG).topics}
    lasers = [f"/laser/front_{i}" for i in range(1, 6)]
    assert result.status == "ingested"
    assert result.row_counts["imu"] == 6710  # 67.1 s at 100 Hz (sample_logs/README.md)
    assert result.row_counts["imu"] == counts["/imu/data"]
    assert result.row_counts["gps"] == counts["/gps/fix"]
    assert result.row_counts["heading"] == counts["/gps/heading"]
    assert result.row_counts["wheels"] == counts["/vehicle/wheel_speeds"]
    assert result.row_counts["laser"] == sum(counts[t] for t in lasers)
    assert result.row_counts["truth_pose"] == counts["/truth/odom"]
    assert result.row_counts["tf_static"] == 7  # base_link to imu, gps and five lasers
    assert result.row_counts["truth_features"] > 0
    assert result.rejects == {} and result.lost == {} and result.warnings == ()
    assert_accounting(ws, result)
    for topic, acc in detail(ws, result)["topics"].items():
        assert acc["read"] == counts[topic]


def test_sample_log_tables_follow_the_contract(
    sample_ingest: tuple[Workspace, IngestResult],
) -> None:
    ws, result = sample_ingest
    sha = file_sha256(SAMPLE_LOG)
    record = ws.manifest(result.log_id).stage("ingest")
    assert record is not None
    for name in (*CONTRACT_TABLES, "truth_pose"):
        table = read_table(ws.log_table(result.log_id, name), name)
        assert_sorted(table)
        meta = read_table_metadata(ws.log_table(result.log_id, name))
        assert meta["source_sha256"] == sha
        assert meta["config_hash"] == record.config_hash
        assert meta["schema_name"] == name
    assert record.inputs == {"log": sha}
    assert set(record.outputs) >= {f"{n}.parquet" for n in CONTRACT_TABLES}
    laser = read(ws, result, "laser")
    assert set(laser.column("laser").to_pylist()) == {f"/laser/front_{i}" for i in range(1, 6)}
    tf = json.loads((log_dir(ws, result) / "tf_static.json").read_text())
    children = {t["child_frame"] for t in tf["transforms"]}
    assert set(laser.column("frame_id").to_pylist()) <= children  # every laser's mount is known
    assert "tf_static.json" in record.outputs
    for name in CONTRACT_TABLES:  # every column chunk of every row group: zstd
        meta = pq.ParquetFile(ws.log_table(result.log_id, name)).metadata
        codecs = {
            meta.row_group(g).column(c).compression
            for g in range(meta.num_row_groups)
            for c in range(meta.num_columns)
        }
        assert codecs == {"ZSTD"}, (name, codecs)


def test_sample_log_counts_no_returns_and_gps_dropouts(
    sample_ingest: tuple[Workspace, IngestResult],
) -> None:
    ws, result = sample_ingest
    totals = detail(ws, result)["counts"]
    laser = read(ws, result, "laser")
    ranges = laser.column("ranges").combine_chunks()
    flat = ranges.values.to_numpy()
    row = np.repeat(np.arange(len(laser)), np.diff(ranges.offsets.to_numpy()))
    lo = laser.column("range_min").to_numpy()[row]
    hi = laser.column("range_max").to_numpy()[row]
    no_return = ~np.isfinite(flat) | (flat < lo) | (flat > hi)
    assert totals["laser_no_return"] == int(no_return.sum()) > 0
    gps_table = read(ws, result, "gps")
    status = gps_table.column("status").to_numpy()
    assert totals["gps_no_fix"] == int((status == -1).sum()) > 0  # the sim's dropout
    lat = gps_table.column("latitude").to_numpy()
    assert np.isnan(lat[status == -1]).all() and np.isfinite(lat[status >= 0]).all()


def test_sample_log_truth_pose_agrees_with_wheels(
    sample_ingest: tuple[Workspace, IngestResult],
) -> None:
    ws, result = sample_ingest
    truth = read(ws, result, "truth_pose")
    wheels = read(ws, result, "wheels")
    speed = np.interp(
        wheels.column("t_ns").to_numpy(),
        truth.column("t_ns").to_numpy(),
        truth.column("speed").to_numpy(),
    )
    # The wheel encoders carry a few percent of scale error and noise.
    np.testing.assert_allclose(wheels.column("speed").to_numpy(), speed, rtol=0.1, atol=0.3)
    meta = read_table_metadata(ws.log_table(result.log_id, "truth_pose"))
    assert meta["frame_id"] == "enu_agreeing_fix"  # the pose's frame (see test_pose_mounts)


# --------------------------------------------------------------------------------------
# Other vehicles: renamed topics, other laser counts, other message types
# --------------------------------------------------------------------------------------


def test_renamed_topics_and_three_lasers_of_361_beams(tmp_path: Path, ws: Workspace) -> None:
    fov = math.radians(270.0)
    yaw = np.linspace(-3.0, 3.0, 25)
    quat = Rotation.from_euler("ZYX", np.stack([yaw, yaw * 0, yaw * 0 + 0.05], axis=1)).as_quat()
    t_heading = times(25, 10.0, T0 + 5_000_000)
    heading = msgs(
        "/vehicle/heading",
        "geometry_msgs/msg/QuaternionStamped",
        t_heading,
        {f"quaternion.{a}": quat[:, i] for i, a in enumerate("xyzw")},
    )
    t_twist = times(250, 50.0, T0 + 6_000_000)
    twist = msgs(
        "/vehicle/twist",
        "geometry_msgs/msg/TwistStamped",
        t_twist,
        {"twist.linear.x": np.linspace(0.0, 12.0, 250)},
    )
    lasers = [scans(f"/scan/{s}", n=40, beams=361, fov_rad=fov, rate_hz=40.0) for s in "lmr"]
    log = write_log(
        tmp_path / "other_vehicle.mcap",
        [*lasers, imu("/vehicle/imu"), gps("/vehicle/fix"), heading, twist],
    )
    config_file = tmp_path / "other.toml"
    config_file.write_text(
        'name = "other"\n[topics]\n'
        'lasers = ["/scan/l", "/scan/m", "/scan/r"]\n'
        'imu = "/vehicle/imu"\ngps = "/vehicle/fix"\nheading = "/vehicle/heading"\n'
        'wheels = "/vehicle/twist"\ntf_static = ""\ntruth_pose = ""\ntruth_features = ""\n'
        '[evaluate]\nbaseline_closest_laser = ""\n'
        "[pose]\nheading_noise_rad = 0.03\n"
    )
    config = load_config(config_file)
    result = ingest_log(log, ws, config)
    assert result.row_counts == {
        "imu": 200, "gps": 20, "heading": 25, "wheels": 250, "laser": 120,
    }  # fmt: skip
    laser = read_table(ws.log_table(result.log_id, "laser"), "laser")
    assert_sorted(laser)
    assert sorted(set(laser.column("laser").to_pylist())) == ["/scan/l", "/scan/m", "/scan/r"]
    assert {len(r) for r in laser.column("ranges").to_pylist()} == {361}
    np.testing.assert_allclose(laser.column("angle_increment").to_numpy(), fov / 360, rtol=1e-6)
    np.testing.assert_allclose(laser.column("angle_min").to_numpy(), -fov / 2, rtol=1e-6)
    head = read_table(ws.log_table(result.log_id, "heading"), "heading")
    np.testing.assert_allclose(head.column("yaw").to_numpy(), yaw, atol=1e-9)
    # QuaternionStamped carries no uncertainty: null, and pose applies [pose] heading_noise_rad.
    assert head.column("yaw_std").to_pylist() == [None] * 25
    wheels = read_table(ws.log_table(result.log_id, "wheels"), "wheels")
    np.testing.assert_allclose(wheels.column("speed").to_numpy(), np.linspace(0.0, 12.0, 250))
    assert wheels.column("rear_left").null_count == 250
    assert ws.read_config() == config
    assert_accounting(ws, result)


def test_wheels_from_odometry_twist(tmp_path: Path, ws: Workspace) -> None:
    t = times(100, 50.0, T0 + 1_000_000)
    odom = msgs(
        "/odom",
        "nav_msgs/msg/Odometry",
        t,
        {"twist.twist.linear.x": np.full(100, 7.5), "pose.pose.orientation.w": 1.0},
    )
    topics = [m for m in basic_topics() if m.topic != "/wheels"] + [odom]
    log = write_log(tmp_path / "odom.mcap", topics)
    result = ingest_log(log, ws, make_config(wheels="/odom"))
    wheels = read(ws, result, "wheels")
    assert wheels.column("speed").to_pylist() == [7.5] * 100
    assert wheels.column("front_right").null_count == 100


def test_message_type_a_role_does_not_accept(tmp_path: Path, ws: Workspace) -> None:
    topics = basic_topics()
    twist = msgs("/twist", "geometry_msgs/msg/TwistStamped", times(5, 10.0), {})
    log = write_log(tmp_path / "wrong.mcap", [*topics, twist])
    with pytest.raises(StageError) as err:
        ingest_log(log, ws, make_config(imu="/twist"))
    text = str(err.value)
    assert "/twist" in text and "geometry_msgs/msg/TwistStamped" in text
    assert "sensor_msgs/msg/Imu" in text and str(log) in text


# --------------------------------------------------------------------------------------
# Missing roles
# --------------------------------------------------------------------------------------


def test_a_topic_typo_is_said_with_the_topic_it_meant(
    tmp_path: Path, ws: Workspace, caplog: pytest.LogCaptureFixture
) -> None:
    """``imu = "/imu/dta"`` where the log's only Imu topic is ``/imu``-something: the
    terminal names the topic it most likely meant (a close name, or the log's only topic of
    an accepted type no role reads); none is offered for a topic no such topic resembles."""
    log = write_log(tmp_path / "log.mcap", basic_topics())
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        ingest_log(log, ws, make_config(imu="/imu/dta"))
    hints = [r.getMessage() for r in caplog.records if "did you mean" in r.getMessage()]
    assert len(hints) == 1
    assert (
        "role imu: topic /imu/dta not in the log; did you mean /imu (sensor_msgs/msg/Imu"
        in (hints[0])
    )
    assert str(log) in hints[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        ingest_log(log, ws, make_config(gps="/gps/fixx"), overwrite=True)
    hints = [r.getMessage() for r in caplog.records if "did you mean" in r.getMessage()]
    assert len(hints) == 1 and "did you mean /gps (sensor_msgs/msg/NavSatFix" in hints[0]


def test_missing_roles_are_one_warning_naming_topics_and_accepted_types(
    tmp_path: Path, ws: Workspace, caplog: pytest.LogCaptureFixture
) -> None:
    """A log without lasers or compass (a robot's, say): ingested, the two roles listed at
    once in one terminal line with the message types each accepts, their tables empty."""
    topics = [m for m in basic_topics() if m.topic not in ("/heading", "/laser/a", "/laser/b")]
    log = write_log(tmp_path / "log.mcap", topics)
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        result = ingest_log(log, ws, make_config())
    lines = [r.getMessage() for r in caplog.records if "roles missing" in r.getMessage()]
    assert len(lines) == 1
    line = lines[0]
    assert str(log) in line
    assert "lasers (/laser/a, /laser/b; accepts sensor_msgs/msg/LaserScan)" in line
    assert "heading (/heading; accepts geometry_msgs/msg/QuaternionStamped" in line
    assert "terrain_msgs/msg/GpsHeading" in line
    info = detail(ws, result)
    assert info["missing_roles"] == ["heading", "lasers"]
    assert info["missing_topics"] == {"lasers": ["/laser/a", "/laser/b"], "heading": ["/heading"]}
    assert result.row_counts["laser"] == 0 and result.row_counts["heading"] == 0
    assert result.row_counts["imu"] == 200
    assert read_table(ws.log_table(result.log_id, "heading"), "heading").num_rows == 0


def test_roles_absent_on_purpose_are_recorded_not_warned(tmp_path: Path, ws: Workspace) -> None:
    topics = [m for m in basic_topics() if m.topic not in ("/laser/a", "/laser/b")]
    log = write_log(tmp_path / "log.mcap", topics)
    result = ingest_log(log, ws, make_config(lasers=[]))
    assert not any("missing" in w for w in result.warnings)
    info = detail(ws, result)
    assert info["missing_roles"] == [] and "lasers" in info["absent_roles"]
    assert result.row_counts["laser"] == 0


def test_log_without_any_configured_topic_names_what_it_has(tmp_path: Path, ws: Workspace) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    config = make_config(
        lasers=["/scan"], imu="/imu/nowhere", gps="/fix", heading="", wheels="/odom"
    )
    with pytest.raises(StageError) as err:
        ingest_log(log, ws, config)
    text = str(err.value)
    assert "none of the configured topics is in the log" in text and "/imu/nowhere" in text
    assert "accepts sensor_msgs/msg/Imu" in text
    for found in ("/imu", "/gps", "/laser/a", "/wheels"):
        assert found in text
    assert "\n" not in text
    assert not list(ws.logs_dir.rglob("*.parquet"))
    assert not partial_files(ws.root)


def test_one_of_several_lasers_missing_is_a_warning(tmp_path: Path, ws: Workspace) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    result = ingest_log(log, ws, make_config(lasers=["/laser/a", "/laser/b", "/laser/c"]))
    assert result.row_counts["laser"] == 60
    assert any("/laser/c" in w for w in result.warnings)


# --------------------------------------------------------------------------------------
# Order, duplicates, non-finite values, clock skew
# --------------------------------------------------------------------------------------


def test_out_of_order_messages_are_sorted_beyond_the_buffer(tmp_path: Path, ws: Workspace) -> None:
    topics = basic_topics()
    imu_msgs = next(m for m in topics if m.topic == "/imu")
    others = [m for m in topics if m.topic != "/imu"]
    records = list(merge_by_time(Batch(m.topic, m.log_t, m.payloads) for m in others))
    imu_records = imu_msgs.records()
    # The first 50 IMU messages arrive at the very end, long after later ones were written.
    records += imu_records[50:] + imu_records[:50]
    log = write_log(tmp_path / "late.mcap", topics, records=records, chunk_size=2048)
    result = ingest_log(log, ws, make_config(), reorder_buffer_bytes=2048)
    table = read_table(ws.log_table(result.log_id, "imu"), "imu")
    assert table.num_rows == 200
    np.testing.assert_array_equal(table.column("t_ns").to_numpy(), imu_msgs.log_t)
    info = detail(ws, result)
    assert info["topics"]["/imu"]["counts"]["out_of_order"] == 50
    assert info["resorted_tables"] == ["imu"]
    meta = read_table_metadata(ws.log_table(result.log_id, "imu"))
    assert meta["schema_name"] == "imu" and meta["source_sha256"] == file_sha256(log)
    assert not partial_files(ws.root)
    assert_accounting(ws, result)


def test_slightly_out_of_order_messages_are_sorted_in_the_buffer(
    tmp_path: Path, ws: Workspace
) -> None:
    topics = basic_topics()
    imu_msgs = next(m for m in topics if m.topic == "/imu")
    order = np.arange(200)
    order[10:20] = order[10:20][::-1]  # ten swapped neighbours
    shuffled = Msgs("/imu", imu_msgs.type_name, imu_msgs.log_t[order],
                    [imu_msgs.payloads[i] for i in order])  # fmt: skip
    topics = [shuffled if m.topic == "/imu" else m for m in topics]
    records = [r for m in topics for r in m.records()]
    log = write_log(tmp_path / "swap.mcap", topics, records=records)
    result = ingest_log(log, ws, make_config())
    table = read(ws, result, "imu")
    np.testing.assert_array_equal(table.column("t_ns").to_numpy(), imu_msgs.log_t)
    info = detail(ws, result)
    assert info["topics"]["/imu"]["counts"]["out_of_order"] == 9
    assert info["resorted_tables"] == []


def test_exact_duplicates_are_dropped_and_counted(tmp_path: Path, ws: Workspace) -> None:
    topics = basic_topics()
    records = list(merge_by_time(Batch(m.topic, m.log_t, m.payloads) for m in topics))
    imu_records = [r for r in records if r.topic == "/imu"]
    dupes = imu_records[100:110]
    # Same log time, other bytes: not a duplicate.
    other = imu(n=200, overrides={"linear_acceleration.y": np.full(200, 0.5)}).records()[120]
    records += dupes + [other] + dupes[:3]
    log = write_log(tmp_path / "dup.mcap", topics, records=records)
    result = ingest_log(log, ws, make_config())
    acc = detail(ws, result)["topics"]["/imu"]
    assert acc["read"] == 214
    assert acc["rejects"]["duplicate"] == 13
    assert result.rejects["/imu"] == {"duplicate": 13}
    assert result.row_counts["imu"] == 201
    again = ingest_log(log, ws, make_config())
    assert again.status == "up_to_date" and again.rejects == {"/imu": {"duplicate": 13}}
    assert ws.manifest(result.log_id).stage("ingest").rejects == {"duplicate": 13}  # type: ignore[union-attr]
    assert_accounting(ws, result)


def tf_static(*messages: list[tuple[str, str, tuple[float, ...], tuple[float, ...]]]) -> Msgs:
    """``/tf_static``: one TFMessage per list of (parent, child, xyz, quaternion xyzw)."""
    payloads = [
        encode_message(
            "tf2_msgs/msg/TFMessage",
            {
                "transforms": [
                    {
                        "header": {"stamp": {"sec": T0 // NS, "nanosec": k}, "frame_id": parent},
                        "child_frame_id": child,
                        "transform": {
                            "translation": dict(zip("xyz", xyz, strict=True)),
                            "rotation": dict(zip("xyzw", q, strict=True)),
                        },
                    }
                    for parent, child, xyz, q in transforms
                ]
            },
        )
        for k, transforms in enumerate(messages)
    ]
    log_t = T0 + np.arange(len(messages), dtype=np.int64) * 1000
    return Msgs("/tf_static", "tf2_msgs/msg/TFMessage", log_t, payloads)


def test_unusable_and_conflicting_static_transforms_are_dropped_said_and_counted(
    tmp_path: Path, ws: Workspace
) -> None:
    """NaN or inf in a transform made ingest die writing tf_static.json (the log lost); a
    zero quaternion was written and then refused by pose; a child frame given two transforms
    kept the last unsaid. Now: dropped or replaced by one rule, said, counted, JSON finite."""
    nan, inf = math.nan, math.inf
    identity = (0.0, 0.0, 0.0, 1.0)
    log = write_log(
        tmp_path / "tf.mcap",
        [
            *basic_topics(),
            tf_static(
                [
                    ("base_link", "imu_link", (0.1, 0.0, 0.5), (0.0, 0.0, 0.0, 2.0)),
                    ("base_link", "gps_link", (nan, 0.0, 1.0), identity),
                    ("base_link", "laser_a", (1.0, 0.0, 1.0), (inf, 0.0, 0.0, 1.0)),
                    ("base_link", "laser_b", (1.0, 0.0, 1.0), (0.0, 0.0, 0.0, 0.0)),
                    ("base_link", "chassis", (0.0, 0.0, 0.2), identity),
                ],
                [
                    ("base_link", "imu_link", (0.1, 0.0, 0.5), (0.0, 0.0, 0.0, -1.0)),  # same
                    ("base_link", "chassis", (0.0, 0.0, 0.3), identity),  # conflicting
                ],
            ),
        ],
    )
    result = ingest_log(log, ws, make_config(tf_static="/tf_static"))
    assert result.status == "ingested"
    path = log_dir(ws, result) / "tf_static.json"

    def refuse(constant: str) -> None:
        raise AssertionError(f"{constant} in tf_static.json")

    written = json.loads(path.read_text(), parse_constant=refuse)["transforms"]
    assert [(t["child_frame"], t["translation_m"]) for t in written] == [
        ("imu_link", [0.1, 0.0, 0.5]),
        ("chassis", [0.0, 0.0, 0.3]),
    ]
    assert written[0]["rotation_xyzw"] == [0.0, 0.0, 0.0, 1.0]  # normalised
    assert result.row_counts["tf_static"] == 2
    assert detail(ws, result)["tf_static"] == {
        "read": 7,
        "written": 2,
        "repeats": 1,
        "dropped": {
            "non_finite_translation": 1,
            "non_finite_rotation": 1,
            "zero_rotation": 1,
            "conflicting": 1,
        },
    }
    dropped = next(w for w in result.warnings if "unusable static transform" in w)
    assert dropped.startswith("/tf_static: 3 unusable")
    assert all(f"'{f}'" in dropped for f in ("gps_link", "laser_a", "laser_b"))
    conflict = next(w for w in result.warnings if "conflicting" in w)
    assert "child frame 'chassis'" in conflict and "(0, 0, 0.2)" in conflict
    assert "(0, 0, 0.3)" in conflict
    assert ws.manifest(result.log_id).stage("ingest").warnings == result.warnings  # type: ignore[union-attr]
    # The stages read it by the same rule: the IMU's mount from it, the antenna's not.
    mounts = sensor_mounts(
        path, dataclasses.replace(default_config().vehicle, gps_frame="gps_link")
    )
    assert mounts.imu.source == "tf_static" and mounts.gps.source == "config"
    assert_accounting(ws, result)


def test_screening_nan_skew_no_fix_and_zero_speed(tmp_path: Path, ws: Workspace) -> None:
    accel_z = np.full(200, 9.81)
    accel_z[[5, 6, 7]] = np.nan
    gyro_x = np.zeros(200)
    gyro_x[8] = np.inf
    # Message 50's stamp is 5 s after its log time: beyond time.max_header_skew_ns (1 s).
    stamps = times(200, 100.0)
    stamps[50] += 5 * NS
    skewed = msgs(
        "/imu",
        "sensor_msgs/msg/Imu",
        stamps,
        {"linear_acceleration.z": accel_z, "angular_velocity.x": gyro_x},
    )
    imu_msgs = Msgs("/imu", skewed.type_name, times(200, 100.0), skewed.payloads)
    ranges = np.full((30, 31), 10.0, dtype=np.float32)
    ranges[0, :5] = np.nan
    ranges[1, 0] = np.inf
    ranges[2, 0] = 100.0  # beyond range_max
    laser = scans("/laser/a", ranges=ranges)
    topics = [
        laser,
        scans("/laser/b"),
        imu_msgs,
        gps(no_fix=[3, 4, 5]),
        gps_heading(),
        wheel_speeds(speed=0.0),
    ]
    log = write_log(tmp_path / "screen.mcap", topics)
    result = ingest_log(log, ws, make_config())
    info = detail(ws, result)["topics"]
    assert info["/imu"]["rejects"] == {
        "bad_payload": 0, "bad_time": 0, "clock_skew": 1, "duplicate": 0, "non_finite": 4,
        "time_outlier": 0, "imu_beyond_range": 0, "imu_spike": 0,
    }  # fmt: skip
    assert result.row_counts["imu"] == 195
    # 5 of 200 (2.5 %) rejected: above 1 %, so said on the terminal with the reasons.
    assert "topic /imu: 5 of 200 messages rejected (clock_skew 1, non_finite 4)" in result.warnings
    assert not any("topic /gps:" in w for w in result.warnings)  # no fix is kept, not rejected
    assert info["/laser/a"]["counts"]["laser_no_return"] == 7
    assert sum(info["/laser/a"]["rejects"].values()) == 0
    laser_table = read(ws, result, "laser")
    first = laser_table.filter(
        laser_table.column("laser").to_numpy(zero_copy_only=False) == "/laser/a"
    )
    assert np.isnan(first.column("ranges")[0].values.to_numpy()[:5]).all()
    assert info["/gps"]["counts"]["gps_no_fix"] == 3
    gps_table = read(ws, result, "gps")
    assert gps_table.num_rows == 20
    assert gps_table.column("status").to_pylist()[3:6] == [-1, -1, -1]
    wheels = read(ws, result, "wheels")
    assert wheels.num_rows == 200 and set(wheels.column("speed").to_pylist()) == {0.0}
    assert_accounting(ws, result)


def test_a_negative_range_min_is_said_once_and_its_negative_ranges_counted(
    tmp_path: Path, ws: Workspace
) -> None:
    """A laser claiming range_min = -1 m: its negative ranges are no returns, counted by
    reason in the manifest (kept in the table as read), and the claim is said on the
    terminal once for the topic, not once per scan."""
    ranges = np.full((30, 31), 10.0, dtype=np.float32)
    ranges[:, 0] = -0.5
    ranges[3, 1] = -2.0
    ranges[4, 2] = np.nan
    topics = [t for t in basic_topics() if t.topic != "/laser/a"]
    topics.append(scans("/laser/a", ranges=ranges, range_min=-1.0))
    log = write_log(tmp_path / "negative.mcap", topics)
    result = ingest_log(log, ws, make_config())
    info = detail(ws, result)["topics"]
    counts = info["/laser/a"]["counts"]
    assert counts["laser_negative_range"] == 31
    assert counts["laser_negative_range_min"] == 30
    assert counts["laser_no_return"] == 1
    assert info["/laser/b"]["counts"]["laser_negative_range"] == 0
    said = [w for w in result.warnings if "range_min" in w]
    assert len(said) == 1 and said[0].startswith("/laser/a: 30 of 30 scans give a negative")
    assert ws.manifest(result.log_id).stage("ingest").warnings == result.warnings  # type: ignore[union-attr]
    laser = read(ws, result, "laser")
    first = laser.filter(laser.column("laser").to_numpy(zero_copy_only=False) == "/laser/a")
    assert first.column("ranges")[0].values.to_numpy()[0] == np.float32(-0.5)
    assert_accounting(ws, result)


def test_undecodable_payload_is_rejected(tmp_path: Path, ws: Workspace) -> None:
    topics = basic_topics()
    imu_msgs = next(m for m in topics if m.topic == "/imu")
    imu_msgs.payloads[17] = imu_msgs.payloads[17][:40]
    log = write_log(tmp_path / "bad.mcap", topics)
    result = ingest_log(log, ws, make_config())
    assert result.rejects["/imu"] == {"bad_payload": 1}
    assert result.row_counts["imu"] == 199
    assert_accounting(ws, result)


def test_a_role_with_no_usable_message_is_a_warning(
    tmp_path: Path, ws: Workspace, caplog: pytest.LogCaptureFixture
) -> None:
    topics = [m for m in basic_topics() if m.topic != "/imu"]
    topics.append(imu(overrides={"linear_acceleration.x": np.full(200, np.nan)}))
    log = write_log(tmp_path / "nan.mcap", topics)
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        result = ingest_log(log, ws, make_config())
    said = [r.getMessage() for r in caplog.records]
    assert any("no usable message" in m and "200 rejected (non_finite)" in m for m in said)
    assert result.row_counts["imu"] == 0 and result.row_counts["gps"] == 20


def test_nothing_usable_at_all_is_a_stage_error(tmp_path: Path, ws: Workspace) -> None:
    topics = [imu(overrides={"linear_acceleration.x": np.full(200, np.nan)})]
    log = write_log(tmp_path / "nan.mcap", topics)
    with pytest.raises(StageError, match=r"nothing usable.*imu.*200 rejected \(non_finite\)"):
        ingest_log(log, ws, make_config())
    assert not list(ws.logs_dir.rglob("*.parquet"))
    assert not partial_files(ws.root)


# --------------------------------------------------------------------------------------
# Idempotence, overwrite, failures, configuration
# --------------------------------------------------------------------------------------


def _mtimes(directory: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in directory.iterdir()}


def test_rerun_is_up_to_date_and_overwrite_redoes(tmp_path: Path, ws: Workspace) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    config = make_config()
    first = ingest_log(log, ws, config)
    before = _mtimes(log_dir(ws, first))
    again = ingest_log(log, ws, config)
    assert again.status == "up_to_date"
    assert again.log_id == first.log_id and again.row_counts == first.row_counts
    assert _mtimes(log_dir(ws, first)) == before
    redo = ingest_log(log, ws, config, overwrite=True)
    assert redo.status == "ingested"
    after = _mtimes(log_dir(ws, first))
    assert all(after[name] != before[name] for name in before)


def test_pose_tuning_leaves_ingest_up_to_date(tmp_path: Path, ws: Workspace) -> None:
    """Ingest's identity covers what it reads ([topics], [time]), not the pose stage's
    tuning: retuning the filter must not make every ingested log stale."""
    log = write_log(tmp_path / "log.mcap", basic_topics())
    config = make_config()
    first = ingest_log(log, ws, config)
    retuned = dataclasses.replace(
        config, pose=dataclasses.replace(config.pose, heading_noise_rad=0.2, gate_chi2_gps=30.0)
    )
    ws.use_config(retuned, overwrite=True)
    assert ingest_log(log, ws, retuned).status == "up_to_date"
    other_time = dataclasses.replace(
        retuned, time=dataclasses.replace(retuned.time, max_header_skew_ns=123_000_000)
    )
    ws.use_config(other_time, overwrite=True)
    assert ingest_log(log, ws, other_time).status == "ingested"
    assert first.status == "ingested"


@pytest.mark.parametrize("damage", ["truncate", "same_size_other_bytes"])
def test_a_changed_output_makes_the_log_not_up_to_date(
    tmp_path: Path, ws: Workspace, damage: str
) -> None:
    """ "Up to date" means the outputs are what the last ingest wrote, not that they exist."""
    log = write_log(tmp_path / "log.mcap", basic_topics())
    first = ingest_log(log, ws, make_config())
    imu = ws.log_table(first.log_id, "imu")
    data = imu.read_bytes()
    if damage == "truncate":
        imu.write_bytes(data[:1000])
    else:
        imu.write_bytes(data[:-9] + bytes(b ^ 0xFF for b in data[-9:-8]) + data[-8:])
    again = ingest_log(log, ws, make_config())
    assert again.status == "ingested"
    assert imu.read_bytes() == data


def test_missing_output_makes_the_log_not_up_to_date(tmp_path: Path, ws: Workspace) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    first = ingest_log(log, ws, make_config())
    ws.log_table(first.log_id, "gps").unlink()
    assert ingest_log(log, ws, make_config()).status == "ingested"
    assert ws.log_table(first.log_id, "gps").is_file()


def _failing_after(calls: int, real: Callable[..., Any]) -> Callable[..., Any]:
    count = {"n": 0}

    def convert(*args: Any) -> Any:
        count["n"] += 1
        if count["n"] > calls:
            raise RuntimeError("converter broke midway")
        return real(*args)

    return convert


def test_failure_midway_leaves_no_partial_file(
    tmp_path: Path, ws: Workspace, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics(), chunk_size=2048)
    converters = ROLE_SPECS["imu"].converters
    real = converters["sensor_msgs/msg/Imu"]
    monkeypatch.setitem(converters, "sensor_msgs/msg/Imu", _failing_after(3, real))
    with pytest.raises(RuntimeError, match="midway"):
        ingest_log(log, ws, make_config(), reorder_buffer_bytes=1024)
    assert not partial_files(ws.root)
    assert ws.log_ids() == []  # a first ingest that fails leaves no trace
    # A failed re-run after a good one leaves the log exactly as it was: the old files
    # byte for byte and their record (a new generation is discarded, never half-published).
    monkeypatch.setitem(converters, "sensor_msgs/msg/Imu", real)
    good = ingest_log(log, ws, make_config())
    before = {p.name: p.read_bytes() for p in ws.log_dir(good.log_id).iterdir()}
    monkeypatch.setitem(converters, "sensor_msgs/msg/Imu", _failing_after(3, real))
    with pytest.raises(RuntimeError):
        ingest_log(log, ws, make_config(), overwrite=True, reorder_buffer_bytes=1024)
    assert not partial_files(ws.root)
    assert {p.name: p.read_bytes() for p in ws.log_dir(good.log_id).iterdir()} == before
    assert read_table(ws.log_table(good.log_id, "imu"), "imu").num_rows == 200
    assert [p.name for p in ws.logs_dir.iterdir() if p.name.endswith(".gen")] == [
        ws.log_dir(good.log_id).resolve().name
    ]


def test_config_in_force_is_recorded_and_a_different_one_refused(
    tmp_path: Path, ws: Workspace
) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    config = make_config()
    ingest_log(log, ws, config)
    assert ws.read_config() == config
    other = dataclasses.replace(config, name="other")
    with pytest.raises(ConfigError, match="another configuration"):
        ingest_log(log, ws, other)
    result = ingest_log(log, ws, other, overwrite=True)
    assert result.status == "ingested"
    assert ws.read_config() == other


# --------------------------------------------------------------------------------------
# Damaged logs
# --------------------------------------------------------------------------------------


def test_truncated_sim_log_is_salvaged_with_losses_counted(
    tmp_path: Path, ws: Workspace, caplog: pytest.LogCaptureFixture
) -> None:
    data = SAMPLE_LOG.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        result = ingest_log(cut, ws, default_config())
    assert result.status == "ingested"
    assert any("damaged log" in w for w in result.warnings)
    lines = [r.getMessage() for r in caplog.records if "damaged log" in r.getMessage()]
    assert len(lines) == 1 and str(cut) in lines[0] and "truncated" in lines[0]
    info = detail(ws, result)
    assert "truncated" in {d["reason"] for d in info["damage"]}
    assert info["unknown_lost_bytes"]["truncated"] > 0
    assert 0 < result.row_counts["imu"] < 6150
    assert_accounting(ws, result)
    for name in CONTRACT_TABLES:
        assert_sorted(read_table(ws.log_table(result.log_id, name), name))


def _flip_byte_in_chunk(src: Path, dst: Path, chunk_number: int) -> None:
    data = bytearray(src.read_bytes())
    with src.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    index = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[chunk_number]
    middle = index.chunk_start_offset + index.chunk_length // 2
    data[middle] ^= 0xFF
    dst.write_bytes(bytes(data))


def test_corrupt_chunk_is_skipped_and_its_messages_counted_lost(
    tmp_path: Path, ws: Workspace
) -> None:
    bad = tmp_path / "bad_chunk.mcap"
    _flip_byte_in_chunk(SAMPLE_LOG, bad, 5)
    result = ingest_log(bad, ws, default_config())
    assert result.status == "ingested" and result.warnings
    reasons = {r for by_reason in result.lost.values() for r in by_reason}
    assert reasons and reasons <= {"chunk_crc", "chunk_decompress"}
    info = detail(ws, result)
    counts = {t.topic: t.message_count for t in scan_log(SAMPLE_LOG).topics}
    for topic, acc in info["topics"].items():
        assert acc["read"] + sum(acc["lost"].values()) == counts[topic], topic
    assert_accounting(ws, result)


def test_log_without_summary_ingests(tmp_path: Path, ws: Workspace) -> None:
    log = write_log(tmp_path / "log.mcap", basic_topics())
    with log.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    footer_start = log.stat().st_size - 8 - 29  # cut the summary, footer and closing magic
    data_end = max(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    shutil.copy(log, tmp_path / "nosummary.mcap")
    raw = (tmp_path / "nosummary.mcap").read_bytes()
    assert data_end < footer_start
    (tmp_path / "nosummary.mcap").write_bytes(raw[:data_end])
    result = ingest_log(tmp_path / "nosummary.mcap", ws, make_config())
    assert result.row_counts["imu"] == 200 and result.row_counts["laser"] == 60
    assert "no_summary" in {d["reason"] for d in detail(ws, result)["damage"]}
    assert_accounting(ws, result)


# --------------------------------------------------------------------------------------
# The MCAP conformance corpus
# --------------------------------------------------------------------------------------


#: Why a corpus file is refused: it has none of the configured topics, or no usable message.
CORPUS_REFUSALS = ("none of the configured topics", "not an MCAP file", "nothing usable")


def test_conformance_corpus_is_ingested_or_refused_clearly(
    tmp_path: Path, conformance_files: list[Path]
) -> None:
    """Every corpus file: ingested, or refused with one line naming the file. None holds ROS 2
    sensor data, so each is refused (none of the configured topics, or no readable file)."""
    ws = Workspace(tmp_path / "ws")
    outcomes: dict[str, str] = {}
    for path in conformance_files:
        try:
            result = ingest_log(path, ws, default_config())
        except ToolkitError as exc:
            message = str(exc)
            assert "\n" not in message and str(path) in message, path.name
            outcomes[path.name] = f"refused: {message[len(str(path)) + 2 :]}"
        else:
            outcomes[path.name] = f"ingested: {result.row_counts}"
    reasons = Counter(o.split(":")[0] + ":" + o.split(":")[1][:30] for o in outcomes.values())
    print("\n".join(f"{name}: {outcome}" for name, outcome in sorted(outcomes.items())))
    ingested = [name for name, o in outcomes.items() if o.startswith("ingested")]
    assert ingested == [], (ingested, reasons)
    unexplained = [
        (name, o) for name, o in outcomes.items() if not any(why in o for why in CORPUS_REFUSALS)
    ]
    assert unexplained == [], unexplained[:5]
    assert ws.log_ids() == []  # refused logs leave nothing behind


def test_sample_tables_equal_the_reference_decoder(
    sample_ingest: tuple[Workspace, IngestResult],
) -> None:
    """Every role's table holds, value for value, what mcap-ros2-support's decoder reads."""
    from mcap_ros2.decoder import DecoderFactory

    ws, result = sample_ingest
    ref: dict[str, list[Any]] = {}
    with SAMPLE_LOG.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            ref.setdefault(channel.topic, []).append(msg)

    def stamp(m: Any) -> int:
        return int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)

    def table(name: str) -> dict[str, Any]:
        return pq.read_table(ws.log_table(result.log_id, name)).to_pydict()

    def by_time(msgs: list[Any]) -> list[Any]:
        return sorted(msgs, key=stamp)

    imu, msgs = table("imu"), by_time(ref["/imu/data"])
    assert imu["t_ns"] == [stamp(m) for m in msgs]
    assert imu["accel_z"] == [m.linear_acceleration.z for m in msgs]
    assert imu["gyro_x"] == [m.angular_velocity.x for m in msgs]

    gps, msgs = table("gps"), by_time(ref["/gps/fix"])
    assert gps["t_ns"] == [stamp(m) for m in msgs]
    np.testing.assert_array_equal(gps["latitude"], [m.latitude for m in msgs])
    assert gps["status"] == [m.status.status for m in msgs]

    heading, msgs = table("heading"), by_time(ref["/gps/heading"])
    assert heading["yaw"] == [m.yaw for m in msgs]

    wheels, msgs = table("wheels"), by_time(ref["/vehicle/wheel_speeds"])
    assert wheels["front_left"] == [m.front_left for m in msgs]
    assert wheels["rear_right"] == [m.rear_right for m in msgs]

    laser = table("laser")
    scans = by_time([m for t, ms in ref.items() if t.startswith("/laser/") for m in ms])
    assert sorted(laser["t_ns"]) == [stamp(m) for m in scans]
    got = {
        (t, a): r
        for t, a, r in zip(laser["t_ns"], laser["angle_min"], laser["ranges"], strict=True)
    }
    for m in scans[:: max(len(scans) // 500, 1)]:
        np.testing.assert_array_equal(
            np.asarray(got[(stamp(m), m.angle_min)], dtype=np.float32),
            np.asarray(m.ranges, dtype=np.float32),
        )

    # The truth moves from the simulator's frame into the pose's (stages/truth.py): the
    # decoded positions, moved through geodetic coordinates, to a micrometre.
    truth, msgs = table("truth_pose"), by_time(ref["/truth/odom"])
    sim = sim_origin(json.loads((log_dir(ws, result) / "mcap_metadata.json").read_text()))
    o = json.loads(read_table_metadata(ws.log_table(result.log_id, "truth_pose"))["enu_origin"])
    assert sim is not None
    xyz_sim = np.array([[getattr(m.pose.pose.position, a) for a in "xyz"] for m in msgs])
    q = [m.pose.pose.orientation for m in msgs]
    yaw_sim = Rotation.from_quat([[o.x, o.y, o.z, o.w] for o in q]).as_euler("ZYX")[:, 0]
    moved, yaw = move_between_frames(
        xyz_sim,
        yaw_sim,
        sim,
        GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"]),
    )
    assert yaw is not None
    np.testing.assert_allclose(truth["x"], moved[:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(truth["z"], moved[:, 2], rtol=0, atol=1e-6)
    # The yaw turns by the two maps' difference in convergence, about dlon sin(lat): 1.4e-6
    # rad here, the first agreeing fix ~14 m east or west of the simulator's origin (1e-5
    # rad for 100 m); roll and pitch are the same in both frames.
    np.testing.assert_allclose(truth["yaw"], yaw, rtol=0, atol=1e-9)
    assert 0.0 < np.abs(yaw - yaw_sim).max() < 1e-5


def test_sample_log_mcap_metadata_is_kept(sample_ingest: tuple[Workspace, IngestResult]) -> None:
    ws, result = sample_ingest
    record = ws.manifest(result.log_id).stage("ingest")
    assert record is not None and "mcap_metadata.json" in record.outputs
    meta = json.loads((log_dir(ws, result) / "mcap_metadata.json").read_text())
    sim = meta["terrain_sim"]
    origin = json.loads(sim["origin"])
    assert set(origin) >= {"latitude_deg", "longitude_deg", "altitude_m"}
    assert json.loads(sim["gps_dropouts_ns"])  # the sample's scheduled 5 s dropout


def test_config_becomes_the_workspace_s_only_after_success(tmp_path: Path, ws: Workspace) -> None:
    """A first ingest that fails leaves no config, so a corrected one is not refused."""
    log = write_log(tmp_path / "log.mcap", basic_topics())
    wrong = make_config(lasers=["/scan"], imu="/x", gps="/y", heading="", wheels="")
    with pytest.raises(StageError, match="none of the configured topics"):
        ingest_log(log, ws, wrong)
    assert not ws.config_path.exists()
    right = make_config()
    assert ingest_log(log, ws, right).status == "ingested"
    assert ws.read_config() == right


def test_a_log_time_beyond_int64_never_becomes_a_row(tmp_path: Path, ws: Workspace) -> None:
    """A message logged at 2^64-1 ns with a zero header stamp would be t_ns = -1."""
    topics = basic_topics()
    stray = msgs("/imu", "sensor_msgs/msg/Imu", np.zeros(1, dtype=np.int64), {})
    records = list(merge_by_time(Batch(m.topic, m.log_t, m.payloads) for m in topics))
    records.append(Record("/imu", 2**64 - 1, stray.payloads[0], 2**64 - 1))
    log = write_log(tmp_path / "stray.mcap", topics, records=records)
    result = ingest_log(log, ws, make_config())
    assert result.rejects["/imu"] == {"bad_time": 1}
    imu_t = read(ws, result, "imu").column("t_ns").to_numpy()
    assert imu_t.min() >= 0 and len(imu_t) == 200
    assert_accounting(ws, result)


def test_a_log_rewritten_while_read_is_refused(
    tmp_path: Path, ws: Workspace, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The recorded sha256 must describe the bytes read: a log appended to mid-read is
    refused (and leaves nothing) rather than recorded under its old hash."""
    log = write_log(tmp_path / "log.mcap", basic_topics())
    real = ingest_mod.LogReader.batches

    def batches_then_append(self: Any) -> Any:
        yield from real(self)
        with log.open("ab") as f:
            f.write(b"more")

    monkeypatch.setattr(ingest_mod.LogReader, "batches", batches_then_append)
    with pytest.raises(LogReadError, match="changed while it was read"):
        ingest_log(log, ws, make_config())
    assert not list(ws.logs_dir.rglob("*.parquet"))
    assert not partial_files(ws.root)


@pytest.mark.parametrize("offset_s", [300, 3 * 365 * 86400])
def test_one_message_stamped_far_away_is_a_time_outlier(
    tmp_path: Path, ws: Workspace, offset_s: int
) -> None:
    """One IMU message stamped 5 minutes or 3 years after the log's end (log time alike) is
    rejected as time_outlier, not written as a row past the data."""
    topics = basic_topics()
    imu_msgs = next(m for m in topics if m.topic == "/imu")
    late = int(imu_msgs.log_t[-1]) + offset_s * NS
    stray = msgs("/imu", "sensor_msgs/msg/Imu", np.array([late]), {})
    records = list(merge_by_time(Batch(m.topic, m.log_t, m.payloads) for m in topics))
    records.append(Record("/imu", late, stray.payloads[0], late))
    log = write_log(tmp_path / "late.mcap", topics, records=records)
    result = ingest_log(log, ws, make_config())
    assert result.rejects["/imu"] == {"time_outlier": 1}
    imu_t = read(ws, result, "imu").column("t_ns").to_numpy()
    assert len(imu_t) == 200 and imu_t.max() < late
    assert_accounting(ws, result)


def test_ingest_removes_what_killed_runs_left(
    tmp_path: Path, ws: Workspace, caplog: pytest.LogCaptureFixture
) -> None:
    """A run killed while changing a log leaves a hidden generation (never a file in the
    log's directory); the next change of that log removes it and says so."""
    import subprocess
    import sys

    log = write_log(tmp_path / "log.mcap", basic_topics())
    first = ingest_log(log, ws, make_config())
    before = sorted(p.name for p in ws.log_dir(first.log_id).iterdir())
    code = (
        "import os, sys; from toolkit.workspace import Workspace; "
        "cm = Workspace(sys.argv[1]).change_log(sys.argv[2]); gen = cm.__enter__(); "
        "(gen.path / 'imu.parquet').unlink(); (gen.path / 'half.parquet').write_bytes(b'x'); "
        "print(gen.path, flush=True); os._exit(9)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(ws.root), first.log_id], capture_output=True, text=True
    )
    orphan = Path(out.stdout.strip())
    assert out.returncode == 9 and orphan.is_dir(), out.stderr
    assert sorted(p.name for p in ws.log_dir(first.log_id).iterdir()) == before
    with caplog.at_level(logging.WARNING, logger="toolkit"):
        assert ingest_log(log, ws, make_config()).status == "up_to_date"
    assert not orphan.exists()
    assert any("left by killed runs" in r.getMessage() for r in caplog.records)


def test_a_directory_or_fifo_is_not_a_missing_file(tmp_path: Path, ws: Workspace) -> None:
    import os

    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    for path in (tmp_path, fifo):
        with pytest.raises(LogReadError, match="not a regular file"):
            ingest_log(path, ws, make_config())
    with pytest.raises(LogReadError, match="no such log file"):
        ingest_log(tmp_path / "absent.mcap", ws, make_config())
