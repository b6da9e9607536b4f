"""The 3-D lidar role on real clouds: ingest reads what the vendors' decoders read.

The logs are derived from real recordings by ``tests/data/real-lidar/derive.py`` (provenance
in that folder's README): an Ouster OS-1-128 on a moving vehicle in ouster-ros's layout, with
what ouster-sdk decoded from its packets beside it, and one Velodyne VLP-16 cloud in nebula's
layout, re-packed in velodyne_pointcloud's and livox_ros_driver2's.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from toolkit.config import PipelineConfig, default_config, parse_config
from toolkit.config_init import init_config
from toolkit.errors import StageError
from toolkit.mcapio.info import scan_log
from toolkit.stages.ingest import ingest_log
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

REAL = Path(__file__).resolve().parents[1] / "data" / "real-lidar"
LASER_FREE_TOPICS = {
    "lasers": (),
    "gps": None,
    "heading": None,
    "wheels": None,
    "truth_pose": None,
    "truth_features": None,
}


def _config(lidar_topic: str, imu: str | None = None, **lidar: object) -> PipelineConfig:
    cfg = default_config()
    topics = dataclasses.replace(cfg.topics, **LASER_FREE_TOPICS, imu=imu, lidars=(lidar_topic,))
    return dataclasses.replace(cfg, topics=topics, lidar=dataclasses.replace(cfg.lidar, **lidar))


def _ingest(tmp_path: Path, log: Path, cfg: PipelineConfig) -> tuple[pa.Table, dict[str, Any]]:
    """The log's lidar table and the ingest's manifest record."""
    result = ingest_log(log, Workspace(tmp_path / "ws"), cfg)
    log_dir = tmp_path / "ws" / "logs" / result.log_id
    manifest = json.loads((log_dir / "manifest.json").read_text())
    return read_table(log_dir / "lidar.parquet", "lidar"), manifest["ingest"]


def test_an_ouster_cloud_lands_where_the_vendors_decoder_puts_it(tmp_path: Path) -> None:
    """Every valid return of ouster-ros's layout, at ouster-sdk's position (1 mm) and its
    column's time (exactly), its beam as the ring; the no-returns dropped and counted."""
    ref = np.load(REAL / "ouster-os1-128.reference.npz")
    valid = ref["range_mm"] > 0
    table, detail = _ingest(
        tmp_path, REAL / "ouster-os1-128.mcap", _config("/ouster/points", "/ouster/imu")
    )
    assert table.num_rows == int(valid.sum())
    got = np.stack([table.column(a).to_numpy() for a in "xyz"], axis=1).astype(np.float64)
    t_ns = table.column("t_ns").to_numpy()
    ring = table.column("ring").to_numpy()
    # The table is sorted by time; the reference is in cloud order: match by (time, ring).
    order_got = np.lexsort((ring, t_ns))
    order_ref = np.lexsort((ref["beam"][valid], ref["time_ns"][valid]))
    np.testing.assert_array_equal(t_ns[order_got], ref["time_ns"][valid][order_ref])
    np.testing.assert_array_equal(ring[order_got], ref["beam"][valid][order_ref])
    np.testing.assert_allclose(got[order_got], ref["xyz"][valid][order_ref], atol=1e-3, rtol=0)
    counts = detail["topics"]["/ouster/points"]["counts"]
    assert counts["lidar_zero_range"] == int((~valid).sum())
    assert counts["lidar_no_point_time"] == 0
    assert table.schema.metadata[b"lidar_time_presets"] == b"ouster"


@pytest.mark.parametrize(
    ("log", "tolerance_ns"),
    [
        ("vlp16-nebula.mcap", 0),
        ("vlp16-velodyne-derived.mcap", 1_000),  # float32 seconds after the header: ~7 ns
        ("vlp16-livox-derived.mcap", 256),  # float64 absolute ns near 1.7e18: a 256 ns grid
    ],
)
def test_one_velodyne_cloud_in_three_drivers_layouts_decodes_alike(
    tmp_path: Path, log: str, tolerance_ns: int
) -> None:
    """The same VLP-16 returns in nebula's, velodyne's and livox's layouts: the same points
    (exactly: float32 in each) and the same times, each driver's preset found by 'auto'."""
    ref = np.load(REAL / "vlp16.reference.npz")
    table, _ = _ingest(tmp_path, REAL / log, _config("/velodyne_points"))
    assert table.num_rows == len(ref["xyz"])
    got = np.stack([table.column(a).to_numpy() for a in "xyz"], axis=1).astype(np.float64)
    t_ns = table.column("t_ns").to_numpy()
    # Match by position (the points are distinct), then compare the times.
    key_got = np.lexsort(got.T[::-1])
    key_ref = np.lexsort(ref["xyz"].T[::-1])
    np.testing.assert_allclose(got[key_got], ref["xyz"][key_ref], atol=1e-6, rtol=0)
    diff = np.abs(t_ns[key_got] - ref["time_ns"][key_ref])
    assert int(diff.max()) <= tolerance_ns
    np.testing.assert_array_equal(table.column("ring").to_numpy()[key_got], ref["channel"][key_ref])


def test_a_cloud_read_without_its_time_field_is_said_and_counted(tmp_path: Path) -> None:
    """With time = "none" every return takes its cloud's stamp: counted per cloud."""
    table, detail = _ingest(
        tmp_path, REAL / "ouster-os1-128.mcap", _config("/ouster/points", time="none")
    )
    assert np.array_equal(table.column("t_ns").to_numpy(), table.column("scan_t_ns").to_numpy())
    assert detail["topics"]["/ouster/points"]["counts"]["lidar_no_point_time"] == 3


def test_rings_and_ranges_select_returns_and_count_the_rest(tmp_path: Path) -> None:
    ref = np.load(REAL / "ouster-os1-128.reference.npz")
    valid = ref["range_mm"] > 0
    rings = tuple(int(b) for b in ref["beams_kept"][:2])
    table, detail = _ingest(
        tmp_path,
        REAL / "ouster-os1-128.mcap",
        _config("/ouster/points", rings=rings, min_range_m=2.0, max_range_m=20.0),
    )
    r = np.linalg.norm(ref["xyz"], axis=1)
    want = valid & np.isin(ref["beam"], rings) & (r >= 2.0) & (r <= 20.0)
    assert table.num_rows == int(want.sum())
    counts = detail["topics"]["/ouster/points"]["counts"]
    assert counts["lidar_ring_not_kept"] == int((valid & ~np.isin(ref["beam"], rings)).sum())
    assert counts["lidar_out_of_range"] == int(
        (valid & np.isin(ref["beam"], rings) & ~((r >= 2.0) & (r <= 20.0))).sum()
    )


def test_clouds_without_point_times_are_said_on_the_terminal(tmp_path: Path) -> None:
    result = ingest_log(
        REAL / "ouster-os1-128.mcap",
        Workspace(tmp_path / "ws"),
        _config("/ouster/points", time="none"),
    )
    said = [w for w in result.warnings if "no per-point time" in w]
    assert said == [
        "/ouster/points: 3 of 3 clouds have no per-point time: each return is at its cloud's "
        "stamp (motion correction off); set [lidar] time if the driver writes one"
    ]


def test_a_log_of_lidar_packets_is_said_to_need_its_driver(tmp_path: Path) -> None:
    """info, config init and ingest each say the lidar is packets, never a silent 'no laser'."""
    log = REAL / "ouster-packets-only.mcap"
    info = scan_log(log)
    assert any(
        p.kind == "lidar_packets" and "/os_node0/lidar_packets" in p.message for p in info.problems
    )
    comments = re.sub(r"\s*\n#\s*", " ", init_config(log))  # the wrapped comments, as read
    assert "/os_node0/lidar_packets holds a lidar driver's raw packets" in comments
    with pytest.raises(StageError, match="raw packets .*PointCloud2 first"):
        ingest_log(log, Workspace(tmp_path / "ws"), default_config())
    with pytest.raises(StageError, match="lidar_packets holds a lidar driver's raw packets"):
        ingest_log(log, Workspace(tmp_path / "ws2"), _config("/os_node0/lidar_packets"))


def test_config_init_finds_the_lidar_its_preset_and_keeps_the_cloud_near_the_path() -> None:
    """The Ouster log's configuration names its cloud topic, the ouster preset from the
    fields, the mount from /tf_static, and a near-path cloud; it loads and says project can
    run once there is a pose."""
    text = init_config(REAL / "ouster-os1-128.mcap")
    cfg = parse_config(text)
    assert cfg.topics.lidars == ("/ouster/points",)
    assert cfg.lidar.time == "ouster"
    assert cfg.project.keep == "near_path"
    assert "project: yes: 1 3-D lidar(s)" in text
    assert (
        "/ouster/points: sensor_msgs/msg/PointCloud2 at 10.0 Hz, frame os_sensor; mount in" in text
    )


def test_a_lidar_on_its_own_clock_is_re_anchored_at_the_log_time_and_said(
    tmp_path: Path,
) -> None:
    """The real Ouster's stamps are its boot clock (991 s: a 1970 date); recorded by a host
    whose log times are 2023's, each cloud is placed at its log time, its points keeping their
    offsets within the sweep, counted per cloud and said on the terminal."""
    shift_ns = 1_700_000_000 * 10**9
    log = tmp_path / "host_clock.mcap"
    with (REAL / "ouster-os1-128.mcap").open("rb") as f, log.open("wb") as g:
        writer = Writer(g)
        writer.start("ros2", "test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id]
                )
            t = message.log_time + shift_ns
            writer.add_message(channels[channel.id], t, message.data, t)
        writer.finish()
    result = ingest_log(log, Workspace(tmp_path / "ws"), _config("/ouster/points"))
    log_dir = tmp_path / "ws" / "logs" / result.log_id
    table = read_table(log_dir / "lidar.parquet", "lidar")
    counts = json.loads((log_dir / "manifest.json").read_text())["ingest"]["topics"][
        "/ouster/points"
    ]["counts"]
    assert counts["lidar_sensor_clock"] == 3
    ref = np.load(REAL / "ouster-os1-128.reference.npz")
    scan_t = np.unique(table.column("scan_t_ns").to_numpy())
    np.testing.assert_array_equal(scan_t, ref["stamp_ns"] + shift_ns)
    offsets = table.column("t_ns").to_numpy() - table.column("scan_t_ns").to_numpy()
    assert offsets.min() >= 0 and offsets.max() < 100_000_000  # within the 10 Hz sweep
    assert any("3 clouds stamped on the sensor's own clock" in w for w in result.warnings)


@pytest.mark.parametrize(
    ("time_settings", "what"),
    [
        # A field that is no time at all: the beam number read as ns spans 127 ns.
        ({"time": "custom", "time_field": "ring", "time_unit": "ns"}, "short"),
        # The right field in a unit 1000 times too large: the kept part spans 0.5 s.
        ({"time": "custom", "time_field": "t", "time_unit": "us"}, "long"),
    ],
)
def test_a_sweep_whose_times_do_not_span_its_period_is_counted_and_said(
    tmp_path: Path, time_settings: dict[str, str], what: str
) -> None:
    """The real Ouster's clouds come every 100 ms and each spans ~100 ms of point times; read
    with the wrong field or unit, each cloud's span is off its period, counted and said."""
    cfg = _config("/ouster/points", **time_settings)
    result = ingest_log(REAL / "ouster-os1-128.mcap", Workspace(tmp_path / "ws"), cfg)
    manifest = json.loads((tmp_path / "ws" / "logs" / result.log_id / "manifest.json").read_text())
    counts = manifest["ingest"]["topics"]["/ouster/points"]["counts"]
    assert counts["lidar_span_off_period"] == 3, what
    said = [w for w in result.warnings if "span more than 1.5 or less than 0.1" in w]
    assert said and "(100.0 ms)" in said[0] and "3 of 3 clouds" in said[0]


def test_the_real_sweeps_span_their_period(tmp_path: Path) -> None:
    """Read as ouster-ros writes them, the three clouds each span ~1 period: none flagged."""
    table, manifest = _ingest(tmp_path, REAL / "ouster-os1-128.mcap", _config("/ouster/points"))
    assert manifest["topics"]["/ouster/points"]["counts"]["lidar_span_off_period"] == 0
    t = table.column("t_ns").to_numpy() - table.column("scan_t_ns").to_numpy()
    assert 0.9e8 < t.max() - t.min() < 1.0e8


def test_the_lidar_table_is_written_as_a_bulk_table(tmp_path: Path) -> None:
    """A row per return: written as the point cloud is, floats byte-stream-split and times
    delta-encoded (12 % smaller on a simulated lidar log), the values unchanged."""
    import pyarrow.parquet as pq

    _ingest(tmp_path, REAL / "ouster-os1-128.mcap", _config("/ouster/points"))
    (path,) = (p for p in (tmp_path / "ws" / "logs").glob("*/lidar.parquet") if "/." not in str(p))
    meta = pq.ParquetFile(path).metadata.row_group(0)
    encodings = {
        meta.column(j).path_in_schema: set(meta.column(j).encodings)
        for j in range(meta.num_columns)
    }
    assert "BYTE_STREAM_SPLIT" in encodings["x"]
    assert "DELTA_BINARY_PACKED" in encodings["t_ns"]
