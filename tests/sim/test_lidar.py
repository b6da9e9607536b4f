"""The spinning 3-D lidar (``terrain sim --lidar``): ouster-ros's cloud layout, the sweep's
timing, points on the ground where the truth says, determinism, and a log without it as it
was.

Clouds are decoded as any ROS 2 tool would (``mcap_ros2``'s decoder) and viewed through a
numpy dtype built from the message's own ``fields``; the truth comes from the log
(``/truth/odom``, the ``terrain_sim`` record) and the world rebuilt from it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from toolkit.cli.group import main
from toolkit.sim.lidar import LidarParams
from toolkit.sim.simulate import simulate
from toolkit.sim.world import make_world

from .logdata import world_params_from_json

TOPIC = "/ouster/points"
SEED = 5
P = LidarParams()
# ouster-ros's point: (name, offset, PointField datatype).
OUSTER_LAYOUT = [
    ("x", 0, 7),
    ("y", 4, 7),
    ("z", 8, 7),
    ("intensity", 16, 7),
    ("t", 20, 6),
    ("reflectivity", 24, 4),
    ("ring", 26, 4),
    ("ambient", 28, 4),
    ("range", 32, 6),
]
_NUMPY_TYPE = {4: "<u2", 6: "<u4", 7: "<f4"}


@pytest.fixture(scope="module")
def flat_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The calibration profile's straight, smooth road, lidar only, through the CLI."""
    out = tmp_path_factory.mktemp("lidar") / "flat.mcap"
    args = ["sim", str(out), "--profile", "calibration", "--distance-m", "120", "--no-lasers"]
    result = CliRunner().invoke(main, ["-q", *args, "--lidar", "--seed", str(SEED)])
    assert result.exit_code == 0, result.output
    return out


def _read(path: Path, topics: list[str]) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str]]:
    """Decoded messages (log time, message) by topic, and the ``terrain_sim`` record."""
    out: dict[str, list[tuple[int, Any]]] = {t: [] for t in topics}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
            out[channel.topic].append((message.log_time, decoded))
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return out, meta["terrain_sim"]


def _points(cloud: Any) -> NDArray[np.void]:
    """The cloud's points (height, width), viewed through a dtype made from its fields."""
    dt = np.dtype(
        {
            "names": [f.name for f in cloud.fields],
            "formats": [_NUMPY_TYPE[f.datatype] for f in cloud.fields],
            "offsets": [f.offset for f in cloud.fields],
            "itemsize": cloud.point_step,
        }
    )
    return np.frombuffer(bytes(cloud.data), dtype=dt).reshape(cloud.height, cloud.width)


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def test_clouds_have_ouster_ros_layout(flat_log: Path) -> None:
    msgs, meta = _read(flat_log, [TOPIC])
    clouds = [m for _, m in msgs[TOPIC]]
    assert len(clouds) > 20
    for cloud in clouds:
        assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == [
            (*f, 1) for f in OUSTER_LAYOUT
        ]
        assert (cloud.height, cloud.width) == (P.beams, P.columns) == (32, 512)
        assert cloud.point_step == 48 and cloud.row_step == 512 * 48
        assert not cloud.is_dense and not cloud.is_bigendian
        assert cloud.header.frame_id == "os_sensor"
    raw = np.frombuffer(bytes(clouds[5].data), dtype=np.uint8).reshape(-1, 48)
    pad = np.r_[12:16, 30:32, 36:48]
    assert not raw[:, pad].any(), "padding bytes must be zero"
    pts = _points(clouds[5])
    # Rows are rings, every point of a row has its ring; no return: range 0 and xyz 0.
    np.testing.assert_array_equal(pts["ring"], np.arange(32)[:, None] * np.ones((1, 512)))
    miss = pts["range"] == 0
    assert miss.any() and (~miss).any()
    for axis in "xyz":
        assert not pts[axis][miss].any()
    assert not pts["intensity"][miss].any() and not pts["reflectivity"][miss].any()
    # Range (mm) and the point agree: the point is range along its beam from the lidar's
    # origin, 36.18 mm above the sensor frame's.
    hit = ~miss
    xyz = np.stack([pts[a][hit] for a in "xyz"], axis=1).astype(np.float64)
    xyz[:, 2] -= P.lidar_origin_z_m
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), pts["range"][hit] * 1e-3, atol=2e-5)
    # A level lidar 1.9 m up sees ground below the horizon only: the top rings see nothing.
    assert not hit[:15].any() and hit[17:].mean() > 0.95
    # The record holds the lidar's truth.
    truth = json.loads(meta["lidar_truth"])
    assert len(truth["range_bias_m"]) == 32
    assert json.loads(meta["lidar"])["columns"] == 512


def test_each_column_has_its_own_time_across_the_sweep(flat_log: Path) -> None:
    msgs, meta = _read(flat_log, [TOPIC])
    stamps = np.array([_stamp(m) for _, m in msgs[TOPIC]])
    np.testing.assert_array_equal(np.diff(stamps), 100_000_000)  # 10 Hz, no host jitter
    pts = _points(msgs[TOPIC][3][1])
    t = pts["t"].astype(np.int64)
    assert (t == t[:1]).all(), "one time per column"
    assert t[0, 0] == 0 and 99_000_000 < t[0, -1] < 100_000_000
    np.testing.assert_allclose(np.diff(t[0]), 1e9 / 10 / 512, atol=1)
    # Logged once the sweep is complete; stamped by the sensor's clock (offset in the record).
    logged = np.array([lt for lt, _ in msgs[TOPIC]])
    assert (logged - stamps > 99_000_000 - 5_000_000).all()
    truth = json.loads(meta["lidar_truth"])
    start = int(meta["start_time_ns"])
    first = stamps - truth["clock_offset_ns"] - start - truth["phase_ns"]
    np.testing.assert_array_equal(first % 100_000_000, 0)  # whole ns: no float rounding


def test_points_lie_on_flat_ground_at_the_true_height(flat_log: Path) -> None:
    """Every return within 20 m, taken to the world by the true mount and the true pose at
    its column's time, lies on the rebuilt terrain within the lidar's stated errors: 1 cm
    precision, per-ring bias up to 3 cm, footprint averaging over a smooth road."""
    msgs, meta = _read(flat_log, [TOPIC, "/truth/odom"])
    odom = [m for _, m in msgs["/truth/odom"]]
    t_odom = np.array([_stamp(m) for m in odom])
    pos = np.array(
        [[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for m in odom]
    )
    quat = np.array([[getattr(m.pose.pose.orientation, a) for a in "xyzw"] for m in odom])
    slerp = Slerp((t_odom - t_odom[0]) * 1e-9, Rotation.from_quat(quat))
    truth = json.loads(meta["lidar_truth"])
    r_mount = Rotation.from_euler("ZYX", truth["mount"]["rpy_rad"][::-1])
    world = make_world(world_params_from_json(meta["world"]), int(meta["seed"]))
    dz_all = []
    for _, cloud in msgs[TOPIC][5:-5]:
        pts = _points(cloud)
        hit = (pts["range"] > 0) & (pts["range"] < 20_000)
        t = _stamp(cloud) - truth["clock_offset_ns"] + pts["t"][hit].astype(np.int64)
        xyz = np.stack([pts[a][hit] for a in "xyz"], axis=1).astype(np.float64)
        base = r_mount.apply(xyz) + np.asarray(truth["mount"]["xyz_m"])
        rel = (t - t_odom[0]) * 1e-9
        p = np.stack([np.interp(t, t_odom, pos[:, j]) for j in range(3)], axis=1)
        enu = slerp(rel).apply(base) + p
        near = np.argmin(np.hypot(world.route.x_m - p[0, 0], world.route.y_m - p[0, 1]))
        s_car = float(world.route.s_m[near])
        s, d = world.route.to_route(enu[:, 0], enu[:, 1], np.full(len(enu), s_car), 5)
        on_road = np.abs(d) < 3.0
        dz_all.append(enu[on_road, 2] - world.terrain.height(s[on_road], d[on_road]))
    dz = np.concatenate(dz_all)
    assert dz.size > 50_000
    assert abs(float(np.median(dz))) < 0.02
    assert float(np.percentile(np.abs(dz), 95)) < 0.05


def _topics(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def test_same_seed_same_log_whatever_the_workers(tmp_path: Path) -> None:
    kw: dict[str, Any] = {"profile": "sample", "distance_m": 100.0, "seed": 2, "lasers": False}
    a = simulate(tmp_path / "a.mcap", lidar=True, workers=0, **kw).path
    b = simulate(tmp_path / "b.mcap", lidar=True, workers=2, **kw).path
    assert a.read_bytes() == b.read_bytes()
    c = simulate(tmp_path / "c.mcap", lidar=True, workers=0, **{**kw, "seed": 3}).path
    assert _topics(c)[TOPIC] != _topics(a)[TOPIC]


def test_the_lidar_leaves_every_other_topic_as_it_was(tmp_path: Path) -> None:
    """The lidar draws only from generators of its own: with it, every other topic is
    the same message for message but ``/tf_static``, which gains its mount."""
    kw: dict[str, Any] = {"profile": "sample", "distance_m": 100.0, "seed": 2, "workers": 0}
    with_lidar = _topics(simulate(tmp_path / "l.mcap", lidar=True, **kw).path)
    without = _topics(simulate(tmp_path / "n.mcap", **kw).path)
    assert set(with_lidar) - set(without) == {TOPIC}
    for topic, rows in without.items():
        if topic != "/tf_static":
            assert rows == with_lidar[topic], topic
    msgs, _ = _read(tmp_path / "l.mcap", ["/tf_static"])
    frames = {t.child_frame_id: t for t in msgs["/tf_static"][0][1].transforms}
    tr = frames["os_sensor"].transform.translation
    assert (tr.x, tr.y, tr.z) == P.mount.xyz_m
