"""``terrain config init``: a configuration written from a log loads, and its guesses are the
log's sensors, on the vendored Husky log, on the simulator's log under other topic names, and
on tiny logs built here (two IMUs, fused odometry, /tf_static)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from toolkit.cli import main
from toolkit.config import load_config, parse_config
from toolkit.config_init import Setting, apply_settings, init_config
from toolkit.mcapio.cdr_encode import encode_batch, encode_message
from toolkit.mcapio.reader import LogReader
from toolkit.mcapio.writer import Batch, LogWriter, merge_by_time
from toolkit.stages.ingest import ingest_log
from toolkit.workspace import Workspace

REPO = Path(__file__).resolve().parents[1]
HUSKY_LOG = REPO / "tests" / "data" / "real-logs" / "husky-gps-imu-odom.mcap"
SAMPLE_LOG = REPO / "sample_logs" / "sample.mcap"
NS = 1_000_000_000
T0 = 1_700_000_000 * NS

#: The simulator's topics under the names another robot might give them.
RENAMES = {
    "/imu/data": "/sensors/imu0",
    "/gps/fix": "/gnss/fix",
    "/gps/heading": "/gnss/heading",
    "/vehicle/wheel_speeds": "/vehicle/wheel_speed",
    "/truth/odom": "/sim/ground_truth/odom",
    "/truth/features": "/sim/features",
    **{f"/laser/front_{k}": f"/lidar/scan_{k}" for k in range(1, 6)},
}


def _comments_of(text: str, key: str) -> str:
    """The comment lines right above ``key = ...`` (the first such key in the text), as
    one line of text (the wrapping undone)."""
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(f"{key} = "))
    above = []
    for line in reversed(lines[:at]):
        if not line.startswith("#"):
            break
        above.append(line)
    return " ".join(" ".join(line.lstrip("#").split()) for line in reversed(above))


# -- the Husky ------------------------------------------------------------------------------


def test_husky_config_names_its_sensors_and_what_it_lacks(tmp_path: Path) -> None:
    text = init_config(HUSKY_LOG)
    cfg = parse_config(text)
    assert cfg.topics.imu == "/imu/data"
    assert cfg.topics.gps == "/fix"
    assert cfg.topics.wheels == "/husky_velocity_controller/odom"
    assert cfg.topics.lasers == ()
    assert cfg.topics.heading is None and cfg.topics.tf_static is None
    assert cfg.topics.truth_pose is None and cfg.topics.truth_features is None
    head = text.split("\nname = ")[0]
    assert "project: NO: no laser" in head
    assert "label: NO: the IMU samples at 30.0 Hz, too slow for the shock band" in head
    assert "pose: yes" in head
    assert "no GPS compass found" in _comments_of(text, "heading")
    assert "no /tf_static in the log" in _comments_of(text, "imu_position_m")
    # The Husky's IMU is turned (roll 90 deg, robot_localization's transform): gravity says so.
    roll, pitch, yaw = cfg.vehicle.imu_orientation_rad
    assert abs(roll - math.pi / 2) < 0.05 and abs(pitch) < 0.05 and yaw == 0.0
    assert "mounted turned" in _comments_of(text, "imu_orientation_rad")
    assert cfg.vehicle.imu_frame == "imu_link"
    # GPS present: dead reckoning is left to the user, with the choice explained.
    assert cfg.pose.dead_reckoning == "inertial"
    assert "CHECK" in _comments_of(text, "dead_reckoning")


def test_the_bundled_husky_configuration_names_the_logs_own_frames() -> None:
    """``pipelines/husky.toml`` names the sensor frames the Husky log's messages carry
    (ROS 1's leading "/" dropped, as tf2 does): its GPS frame is ``gps``, not a guess."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    cfg = load_config(REPO / "pipelines" / "husky.toml")
    frames: dict[str, str] = {}
    with HUSKY_LOG.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=["/fix", "/imu/data"]):
            frames.setdefault(channel.topic, msg.header.frame_id.lstrip("/"))
            if len(frames) == 2:
                break
    assert cfg.vehicle.gps_frame == frames["/fix"] == "gps"
    assert cfg.vehicle.imu_frame == frames["/imu/data"]
    assert parse_config(init_config(HUSKY_LOG)).vehicle.gps_frame == "gps"


def test_husky_config_ingests_and_poses(tmp_path: Path) -> None:
    """The stranger's path of the README: config init, ingest, pose, through the CLI."""
    runner = CliRunner()
    config = tmp_path / "my_robot.toml"
    result = runner.invoke(main, ["config", "init", str(HUSKY_LOG), "--out", str(config)])
    assert result.exit_code == 0, result.output
    load_config(config)
    ws = str(tmp_path / "ws")
    result = runner.invoke(main, ["ingest", str(HUSKY_LOG), "-w", ws, "-c", str(config)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["pose", "-w", ws])
    assert result.exit_code == 0, result.output
    assert "pose estimated" in result.stdout
    (log_id,) = Workspace(ws).log_ids()
    assert Workspace(ws).log_table(log_id, "pose").is_file()


# -- the simulator's log under other names ----------------------------------------------------


def _renamed_copy(src: Path, dst: Path, renames: dict[str, str]) -> Path:
    """``src`` with its topics renamed, through the toolkit's reader and writer."""
    with LogReader(src) as reader:
        channels = reader.channels()
        batches = [
            Batch(renames.get(b.channel.topic, b.channel.topic), b.log_time_ns, b.payloads)
            for b in reader.batches()
        ]
        metadata = reader.report.metadata
    with LogWriter(dst) as log:
        for topic, channel in channels.items():
            log.register(renames.get(topic, topic), channel.schema_name)
        log.write_interleaved(merge_by_time(batches))
        for name, data in metadata.items():
            log.add_metadata(name, data)
    return dst


@pytest.fixture(scope="module")
def renamed_sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _renamed_copy(
        SAMPLE_LOG, tmp_path_factory.mktemp("renamed") / "other_names.mcap", RENAMES
    )


def test_renamed_sim_log_is_found_by_type(renamed_sample: Path) -> None:
    text = init_config(renamed_sample)
    cfg = parse_config(text)
    assert cfg.topics.imu == "/sensors/imu0"
    assert cfg.topics.gps == "/gnss/fix"
    assert cfg.topics.heading == "/gnss/heading"
    assert cfg.topics.wheels == "/vehicle/wheel_speed"
    assert cfg.topics.truth_pose == "/sim/ground_truth/odom"
    assert cfg.topics.truth_features == "/sim/features"
    assert cfg.topics.lasers == tuple(f"/lidar/scan_{k}" for k in range(1, 6))
    assert cfg.topics.tf_static == "/tf_static"
    # The truth is Odometry too, yet never the wheels: its name says what it is.
    assert "ground truth" in _comments_of(text, "wheels")
    # The sim's 100 Hz IMU carries the shock band; its mounts come from /tf_static.
    head = text.split("\nname = ")[0]
    for stage in ("pose", "project", "label"):
        assert f"  {stage}: yes" in head, head
    assert "from /tf_static: base_link -> " in _comments_of(text, "imu_position_m")
    default = load_config(REPO / "pipelines" / "stanley2005.toml")
    assert cfg.vehicle.imu_position_m == pytest.approx(default.vehicle.imu_position_m)


def test_renamed_sim_log_ingests_like_the_original(renamed_sample: Path, tmp_path: Path) -> None:
    config = tmp_path / "generated.toml"
    config.write_text(init_config(renamed_sample))
    ours = ingest_log(renamed_sample, Workspace(tmp_path / "a"), load_config(config))
    theirs = ingest_log(
        SAMPLE_LOG, Workspace(tmp_path / "b"), load_config(REPO / "pipelines" / "stanley2005.toml")
    )
    assert ours.row_counts == theirs.row_counts
    assert all(n > 0 for n in ours.row_counts.values()), ours.row_counts
    assert set(ours.row_counts) >= {"imu", "gps", "heading", "wheels", "laser", "truth_pose"}


# -- tiny logs ------------------------------------------------------------------------------


def _header(stamps: np.ndarray, frame: str) -> dict[str, Any]:
    return {
        "header.stamp.sec": (stamps // NS).astype(np.int32),
        "header.stamp.nanosec": (stamps % NS).astype(np.uint32),
        "header.frame_id": frame,
    }


def _stamps(n: int, rate_hz: float) -> np.ndarray:
    return T0 + np.round(np.arange(n) * NS / rate_hz).astype(np.int64)


def _write(path: Path, topics: dict[str, tuple[str, np.ndarray, list[bytes]]]) -> Path:
    with LogWriter(path) as log:
        for topic, (type_name, _, _) in topics.items():
            log.register(topic, type_name)
        log.write_interleaved(
            merge_by_time(Batch(topic, t, p) for topic, (_, t, p) in topics.items())
        )
    return path


def _sensor(type_name: str, n: int, rate_hz: float, frame: str, cols: dict[str, Any]):
    t = _stamps(n, rate_hz)
    return type_name, t, encode_batch(type_name, {**_header(t, frame), **cols}, n=n)


def _imu(frame: str, rate_hz: float = 100.0, n: int = 100):
    return _sensor(
        "sensor_msgs/msg/Imu", n, rate_hz, frame, {"linear_acceleration.z": np.full(n, 9.81)}
    )


def _fix(frame: str = "gps_link", n: int = 20):
    cols = {"latitude": np.full(n, 37.4), "longitude": np.full(n, -122.1), "altitude": 10.0}
    return _sensor("sensor_msgs/msg/NavSatFix", n, 10.0, frame, cols)


def _odom(n: int = 50):
    return _sensor("nav_msgs/msg/Odometry", n, 50.0, "odom", {"twist.twist.linear.x": 1.0})


def test_two_imus_pick_by_name_and_fused_odometry_is_refused(tmp_path: Path) -> None:
    log = _write(
        tmp_path / "two_imus.mcap",
        {
            "/imu/data_raw": _imu("imu_link", rate_hz=200.0),  # faster, but raw
            "/imu/data": _imu("imu_link"),
            "/odometry/filtered": _odom(),
            "/wheel/odom": _odom(),
            "/gps/fix": _fix(),
        },
    )
    text = init_config(log)
    cfg = parse_config(text)
    assert cfg.topics.imu == "/imu/data"
    imu_notes = _comments_of(text, "imu")
    assert "also /imu/data_raw" in imu_notes and "'raw'" in imu_notes
    assert cfg.topics.wheels == "/wheel/odom"
    assert "also /odometry/filtered" in _comments_of(text, "wheels")
    assert "fusion's output" in _comments_of(text, "wheels")
    assert cfg.topics.gps == "/gps/fix"


def _empty(type_name: str):
    """A topic registered in the log without any message."""
    return type_name, np.array([], dtype=np.int64), []


def test_a_topic_without_messages_never_wins(tmp_path: Path) -> None:
    """An empty /imu/data won over a 100 Hz /imu/data_raw by its name, and the head said
    "pose: yes": ingest then found no IMU message. A topic with no messages is now passed
    over, said on the terminal with what was chosen instead; one of a single message (no
    rate) ranks below one with a rate."""
    log = _write(
        tmp_path / "empty_imu.mcap",
        {
            "/imu/data": _empty("sensor_msgs/msg/Imu"),
            "/imu/data_raw": _imu("imu_link"),
            "/gps/fix": _fix(),
        },
    )
    result = CliRunner().invoke(main, ["config", "init", str(log)])
    assert result.exit_code == 0, result.output
    cfg = parse_config(result.stdout)
    assert cfg.topics.imu == "/imu/data_raw"
    notes = _comments_of(result.stdout, "imu")
    assert (
        "also /imu/data: sensor_msgs/msg/Imu, 0 message(s): not used, it has no messages" in notes
    )
    assert (
        "[topics] imu: '/imu/data' (sensor_msgs/msg/Imu) not used, it has no messages in the "
        "log; '/imu/data_raw' chosen"
    ) in result.stderr
    assert "pose: yes" in result.stdout
    # The only IMU empty: no IMU, and the head says pose cannot run.
    log = _write(
        tmp_path / "no_imu.mcap",
        {"/imu/data": _empty("sensor_msgs/msg/Imu"), "/gps/fix": _fix()},
    )
    result = CliRunner().invoke(main, ["config", "init", str(log)])
    assert result.exit_code == 0, result.output
    assert parse_config(result.stdout).topics.imu is None
    assert "pose: NO: no IMU" in result.stdout
    assert "'/imu/data' (sensor_msgs/msg/Imu) not used" in result.stderr
    assert "no IMU topic left" in result.stderr
    # One message has no rate: a 100 Hz topic wins over it whatever the names.
    log = _write(
        tmp_path / "one_message.mcap",
        {"/imu/data": _imu("imu_link", n=1), "/imu/data_raw": _imu("imu_link")},
    )
    assert parse_config(init_config(log)).topics.imu == "/imu/data_raw"


def test_a_topic_named_empty_plays_no_role_and_is_said(tmp_path: Path) -> None:
    """An IMU on a topic named "" was written ``imu = ""``, which means no IMU, under a head
    saying "pose: yes". A configuration cannot name it: it is passed over, said on the
    terminal and in the comments, and the head says what the written file means."""
    log = _write(tmp_path / "blank.mcap", {"": _imu("imu_link"), "/gps/fix": _fix()})
    result = CliRunner().invoke(main, ["config", "init", str(log)])
    assert result.exit_code == 0, result.output
    cfg = parse_config(result.stdout)
    assert cfg.topics.imu is None
    assert "pose: NO: no IMU" in result.stdout
    assert 'also "": sensor_msgs/msg/Imu at 100.0 Hz' in _comments_of(result.stdout, "imu")
    assert (
        "[topics] imu: '' (sensor_msgs/msg/Imu) not used, its name is empty, and a "
        'configuration cannot name it ("" is no topic); no IMU topic left'
    ) in result.stderr
    log = _write(
        tmp_path / "blank_and_named.mcap", {"": _imu("imu_link"), "/imu": _imu("imu_link")}
    )
    assert parse_config(init_config(log)).topics.imu == "/imu"


def test_fused_odometry_alone_is_no_wheels_and_no_gps_dead_reckons_on_odometry(
    tmp_path: Path,
) -> None:
    log = _write(
        tmp_path / "fused.mcap",
        {"/imu/data": _imu("imu_link"), "/odometry/filtered": _odom()},
    )
    text = init_config(log)
    cfg = parse_config(text)
    assert cfg.topics.wheels is None and cfg.topics.gps is None
    assert "pose: NO: no GPS nor wheel speeds" in text
    log = _write(tmp_path / "wheels.mcap", {"/imu/data": _imu("imu_link"), "/odom": _odom()})
    cfg = parse_config(init_config(log))
    assert cfg.topics.wheels == "/odom"
    assert cfg.pose.dead_reckoning == "odometry"


def _tf_static(transforms: list[tuple[str, str, tuple[float, ...], tuple[float, ...]]]):
    """One TFMessage: (parent, child, xyz, rpy) each."""
    return _tf_message(
        [
            (parent, child, xyz, tuple(Rotation.from_euler("ZYX", [y, p, r]).as_quat()))
            for parent, child, xyz, (r, p, y) in transforms
        ]
    )


def _tf_message(transforms: list[tuple[str, str, tuple[float, ...], tuple[float, ...]]]):
    """One TFMessage: (parent, child, xyz, quaternion xyzw) each, as given."""
    out = []
    for parent, child, xyz, (qx, qy, qz, qw) in transforms:
        out.append(
            {
                "header": {"stamp": {"sec": T0 // NS, "nanosec": 0}, "frame_id": parent},
                "child_frame_id": child,
                "transform": {
                    "translation": {"x": xyz[0], "y": xyz[1], "z": xyz[2]},
                    "rotation": {"x": qx, "y": qy, "z": qz, "w": qw},
                },
            }
        )
    payload = encode_message("tf2_msgs/msg/TFMessage", {"transforms": out})
    return "tf2_msgs/msg/TFMessage", np.array([T0], dtype=np.int64), [payload]


def test_tf_static_gives_the_mounts(tmp_path: Path) -> None:
    log = _write(
        tmp_path / "tf.mcap",
        {
            "/tf_static": _tf_static(
                [
                    ("base_link", "chassis", (0.5, 0.0, 0.3), (0.0, 0.0, 0.0)),
                    ("chassis", "imu_link", (0.1, -0.2, 0.4), (0.0, 0.0, math.pi / 2)),
                    ("base_link", "gps_link", (-0.3, 0.0, 1.2), (0.0, 0.0, 0.0)),
                    ("base_link", "laser_front", (1.0, 0.0, 1.5), (0.0, 0.3, 0.0)),
                ]
            ),
            "/imu/data": _imu("imu_link"),
            "/gps/fix": _fix("gps_link"),
            "/scan": _sensor("sensor_msgs/msg/LaserScan", 10, 10.0, "laser_front", {}),
            "/scan_rear": _sensor("sensor_msgs/msg/LaserScan", 10, 10.0, "laser_rear", {}),
        },
    )
    text = init_config(log)
    cfg = parse_config(text)
    assert cfg.topics.tf_static == "/tf_static"
    assert cfg.vehicle.imu_frame == "imu_link" and cfg.vehicle.gps_frame == "gps_link"
    assert cfg.vehicle.imu_position_m == pytest.approx((0.6, -0.2, 0.7))
    assert cfg.vehicle.imu_orientation_rad == pytest.approx((0.0, 0.0, math.pi / 2))
    assert cfg.vehicle.gps_antenna_position_m == pytest.approx((-0.3, 0.0, 1.2))
    assert "from /tf_static: base_link -> imu_link" in _comments_of(text, "imu_position_m")
    lasers = _comments_of(text, "lasers")
    assert "/scan: " in lasers and "mount in /tf_static" in lasers
    assert "/scan_rear: " in lasers and "project drops its scans without a mount" in lasers
    assert cfg.topics.lasers == ("/scan", "/scan_rear")


def test_unusable_static_transforms_are_dropped_by_the_rule_ingest_keeps(tmp_path: Path) -> None:
    """A NaN in /tf_static: config init said "pose: yes" and ingest then died writing
    tf_static.json; a zero quaternion was dropped here but kept by ingest and refused by
    pose. Now config init, ingest and pose keep the same transforms, by one rule, and say
    the same lines; the whole path runs (exit 0)."""
    identity = (0.0, 0.0, 0.0, 1.0)
    log = _write(
        tmp_path / "bad_tf.mcap",
        {
            "/tf_static": _tf_message(
                [
                    ("base_link", "imu_link", (math.nan, 0.0, 0.4), identity),
                    ("base_link", "gps_link", (-0.3, 0.0, 1.2), (0.0, 0.0, 0.0, 0.0)),
                    ("base_link", "laser_front", (1.0, 0.0, 1.5), identity),
                    ("base_link", "laser_front", (1.0, 0.0, 1.6), identity),
                ]
            ),
            "/imu/data": _imu("imu_link"),
            "/gps/fix": _fix("gps_link"),
            "/wheel/odom": _odom(),
        },
    )
    runner = CliRunner()
    config = tmp_path / "robot.toml"
    result = runner.invoke(main, ["config", "init", str(log), "--out", str(config)])
    assert result.exit_code == 0, result.output
    said = [ln for ln in result.stderr.splitlines() if "/tf_static: " in ln]
    assert len(said) == 2
    assert "2 unusable static transform(s) dropped" in said[0]
    assert "'imu_link' (NaN or inf in its translation)" in said[0]
    assert "'gps_link' (a rotation quaternion of zero norm)" in said[0]
    assert "child frame 'laser_front' has conflicting static transforms" in said[1]
    text = config.read_text()
    assert "pose: yes" in text and "CHECK: /tf_static: 2 unusable" in text
    cfg = load_config(config)
    assert cfg.vehicle.imu_position_m == (0.0, 0.0, 0.0)  # not from the dropped transform
    assert "'imu_link' is not below 'base_link'" in _comments_of(text, "imu_position_m")
    ws = tmp_path / "ws"
    result = runner.invoke(main, ["ingest", str(log), "-w", str(ws), "-c", str(config)])
    assert result.exit_code == 0, result.output
    for line in said:  # ingest says what config init said, word for word
        assert line.split("] ", 1)[1].split(": ", 1)[1] in result.stderr
    (log_id,) = Workspace(ws).log_ids()
    kept = json.loads(Workspace(ws).log_dir(log_id).joinpath("tf_static.json").read_text())
    assert [t["child_frame"] for t in kept["transforms"]] == ["laser_front"]
    assert kept["transforms"][0]["translation_m"] == [1.0, 0.0, 1.6]
    result = runner.invoke(main, ["pose", "-w", str(ws)])
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.stderr


#: Topic names a log may hold that TOML must escape, or that break a comment or a line.
ODD_NAMES = {
    "imu": '/imu\x01"quoted"\\back',
    "gps": "/gps\nfix\r\t€ü",
    "wheels": "/wheel/odom\x7f\x85",
    "lasers": ("/scan\u2028a", "/scan\x1fb\u2029"),
}


def test_odd_topic_and_frame_names_round_trip(tmp_path: Path) -> None:
    """A control character in a topic name made a configuration that does not load. Every
    string is now written as a TOML string escape and every comment with such characters
    escaped: the file config init writes loads with the project's loader and names the
    log's own topics and frames."""
    lasers = ODD_NAMES["lasers"]
    log = _write(
        tmp_path / "odd\x01name\n.mcap",
        {
            ODD_NAMES["imu"]: _imu("imu\x02\nlink"),
            ODD_NAMES["gps"]: _fix('gps"link\\'),
            ODD_NAMES["wheels"]: _odom(),
            lasers[0]: _sensor("sensor_msgs/msg/LaserScan", 10, 10.0, "laser", {}),
            lasers[1]: _sensor("sensor_msgs/msg/LaserScan", 10, 10.0, "laser", {}),
        },
    )
    config = tmp_path / "odd.toml"
    result = CliRunner().invoke(main, ["config", "init", str(log), "--out", str(config)])
    assert result.exit_code == 0, result.output
    cfg = load_config(config)
    assert cfg.topics.imu == ODD_NAMES["imu"]
    assert cfg.topics.gps == ODD_NAMES["gps"]
    assert cfg.topics.wheels == ODD_NAMES["wheels"]
    assert cfg.topics.lasers == tuple(sorted(lasers))
    assert cfg.vehicle.imu_frame == "imu\x02\nlink" and cfg.vehicle.gps_frame == 'gps"link\\'
    text = config.read_text(encoding="utf-8")
    assert text.splitlines() == text.split("\n")[:-1]  # no line break but the file's own
    comments = "\n".join(ln for ln in text.splitlines() if ln.lstrip().startswith("#"))
    assert "/imu\\u0001" in comments and "/gps\\u000afix" in comments  # said, escaped


def test_apply_settings_adds_a_key_its_section_lacks_and_refuses_a_section() -> None:
    """A role declared since the default was written has no line there: its key goes at the
    end of its section; a section the default lacks, or a new key without a value, is a
    programming error."""
    default = 'name = "x"\n\n[topics]\nimu = "/imu"\n\n[time]\nskew = 1\n'
    text = apply_settings(default, [], {("topics", "barometer"): Setting('"/baro"', ("why",))})
    assert text.endswith('[topics]\nimu = "/imu"\n# why\nbarometer = "/baro"\n\n[time]\nskew = 1\n')
    with pytest.raises(ValueError, match="bogus"):
        apply_settings(default, [], {("bogus", "key"): Setting("1")})
    with pytest.raises(ValueError, match="without a value"):
        apply_settings(default, [], {("topics", "barometer"): Setting(None)})


# -- the command line -----------------------------------------------------------------------


def test_config_init_cli_errors_are_one_line(tmp_path: Path) -> None:
    runner = CliRunner()
    garbage = tmp_path / "g.mcap"
    garbage.write_bytes(b"not an mcap at all")
    for path in (garbage, tmp_path / "absent.mcap"):
        result = runner.invoke(main, ["config", "init", str(path)])
        assert result.exit_code == 1
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"terrain: error: {path}: "), lines
        assert result.stdout == ""
    out = tmp_path / "mine.toml"
    out.write_text("# edited by hand\n")
    result = runner.invoke(main, ["config", "init", str(HUSKY_LOG), "--out", str(out)])
    assert result.exit_code == 1 and "--overwrite" in result.stderr
    assert out.read_text() == "# edited by hand\n"
    result = runner.invoke(
        main, ["config", "init", str(HUSKY_LOG), "--out", str(out), "--overwrite"]
    )
    assert result.exit_code == 0, result.output
    assert load_config(out).topics.imu == "/imu/data"
    result = runner.invoke(main, ["config", "init", str(HUSKY_LOG)])
    assert result.exit_code == 0
    assert result.stdout == out.read_text()


def test_a_truncated_log_gives_a_configuration_and_a_warning_on_the_terminal(
    tmp_path: Path,
) -> None:
    """Salvageable input: the first chunk of the sample log alone still yields a loadable
    configuration (exit 0), and the damage is said on the terminal, not only in comments."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(SAMPLE_LOG.read_bytes()[:300_000])
    result = CliRunner().invoke(main, ["config", "init", str(cut)])
    assert result.exit_code == 0
    parse_config(result.stdout, source="stdout")
    warnings = [ln for ln in result.stderr.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and "cut.mcap" in warnings[0] and "problem(s)" in warnings[0]
    assert "Traceback" not in result.stderr
