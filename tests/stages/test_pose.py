"""Pose stage on the sample and a race log: accuracy against truth, errors, idempotence."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from toolkit.config import default_config
from toolkit.errors import StageError
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.pose import PoseResult
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table, read_table_metadata
from toolkit.workspace import Workspace

from .crafted import write_table

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"


@pytest.fixture(scope="module")
def sample_pose(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, str, PoseResult]:
    ws = Workspace(tmp_path_factory.mktemp("pose") / "ws")
    ingested = ingest_log(SAMPLE_LOG, ws, default_config())
    return ws, ingested.log_id, run_stage(POSE, ws, default_config(), log_id=ingested.log_id)


def test_sample_pose_meets_the_accuracy_targets(
    sample_pose: tuple[Workspace, str, PoseResult],
) -> None:
    ws, log_id, result = sample_pose
    acc = result.accuracy
    assert acc is not None
    assert acc["horizontal_rmse_m"] <= 0.3
    assert acc["roll_rmse_deg"] <= 0.3
    assert acc["pitch_rmse_deg"] <= 0.3
    assert acc["yaw_rmse_deg"] <= 0.5
    (drop,) = acc["gps_dropouts"]  # the sample's 5 s dropout at 30-35 s
    assert drop["duration_s"] == pytest.approx(5.0)
    assert drop["horizontal_error_at_end_m"] <= 1.0
    assert ws.manifest(log_id).read()["pose_accuracy"] == acc


@pytest.fixture(scope="module")
def race_pose(tmp_path_factory: pytest.TempPathFactory) -> PoseResult:
    """A 3 km race log: realistic roughness and its scheduled 10 s GPS dropout at 60 s."""
    from toolkit.sim.simulate import simulate

    root = tmp_path_factory.mktemp("race_pose")
    log = root / "race.mcap"
    # Pose reads no scans; without lasers the drive and every other sensor are the same
    # (test_determinism), at a fraction of the simulation's time.
    simulate(log, profile="race", distance_m=3000.0, seed=3, lasers=False)
    ws = Workspace(root / "ws")
    ingested = ingest_log(log, ws, default_config())
    return run_stage(POSE, ws, default_config(), log_id=ingested.log_id)


def assert_race_targets(acc: dict[str, Any] | None, dropouts: Callable[[float], bool]) -> None:
    """The pose targets on a race log: horizontal RMSE <= 0.3 m, roll and pitch <= 0.3 deg,
    yaw <= 0.5 deg, and <= 2 m at the end of every GPS dropout whose duration ``dropouts``
    selects (the race profile schedules one of 10 s at 60 s)."""
    assert acc is not None
    assert acc["horizontal_rmse_m"] <= 0.3
    assert acc["roll_rmse_deg"] <= 0.3
    assert acc["pitch_rmse_deg"] <= 0.3
    assert acc["yaw_rmse_deg"] <= 0.5
    drops = [d for d in acc["gps_dropouts"] if dropouts(d["duration_s"])]
    assert drops, "the race profile schedules a 10 s dropout at 60 s"
    assert all(d["horizontal_error_at_end_m"] <= 2.0 for d in drops)


@pytest.mark.slow  # a race simulated and posed (24 s); run by .ci/run
def test_race_pose_meets_the_accuracy_targets(race_pose: PoseResult) -> None:
    """Issue 4's targets on a race log, the 10 s dropout included."""
    assert_race_targets(race_pose.accuracy, lambda duration_s: duration_s >= 10.0)


def test_sample_pose_table_follows_the_contract(
    sample_pose: tuple[Workspace, str, PoseResult],
) -> None:
    ws, log_id, result = sample_pose
    path = ws.log_table(log_id, "pose")
    table = read_table(path, "pose")
    t = table.column("t_ns").to_numpy()
    assert result.rows == table.num_rows > 5900
    np.testing.assert_allclose(np.diff(t), 10_000_000, atol=1)  # 100 Hz
    origin = json.loads(read_table_metadata(path)["enu_origin"])
    gps = read_table(ws.log_table(log_id, "gps"), "gps")
    first = next(r for r in gps.to_pylist() if r["status"] >= 0)
    assert origin["latitude_deg"] == first["latitude"]
    record = ws.manifest(log_id).stage("pose")
    assert record is not None and record.row_counts == {"pose": table.num_rows}
    detail = ws.manifest(log_id).read()["pose"]
    assert detail["imu_gaps"] == {"bridged": 0, "restarted": 0}
    assert detail["heading_source"] == "compass"
    assert set(detail["gated"]) <= {"gps", "heading", "wheels", "nhc"}


def test_pose_rerun_is_up_to_date(sample_pose: tuple[Workspace, str, PoseResult]) -> None:
    ws, log_id, _ = sample_pose
    path = ws.log_table(log_id, "pose")
    before = path.stat().st_mtime_ns
    again = run_stage(POSE, ws, default_config(), log_id=log_id)
    assert again.status == "up_to_date"
    assert path.stat().st_mtime_ns == before


def test_no_gps_fix_dead_reckons_and_without_wheels_is_a_stage_error(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    ws0, log_id, _ = sample_pose
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(ws0.root, ws.root, symlinks=True)
    gps_path = ws.log_table(log_id, "gps")
    gps = read_table(gps_path, "gps")
    n = gps.num_rows
    nan = pa.array(np.full(n, np.nan))
    bad = gps.set_column(
        gps.schema.get_field_index("status"), "status", pa.array(np.full(n, -1, dtype=np.int8))
    )
    for name in ("latitude", "longitude", "altitude"):
        bad = bad.set_column(bad.schema.get_field_index(name), name, nan)
    meta = read_table_metadata(gps_path)
    write_table(
        gps_path, bad, "gps", source_sha256=meta["source_sha256"], config_hash=meta["config_hash"]
    )
    # Without a fix but with wheel speeds the pose dead-reckons in a local frame.
    local = run_stage(POSE, ws, default_config(), log_id=log_id)
    meta_pose = read_table_metadata(ws.log_table(log_id, "pose"))
    assert meta_pose["frame_id"] == "local_first_pose" and "enu_origin" not in meta_pose
    assert json.loads(meta_pose["local_origin"])["t_ns"] > 0
    assert local.heading_source == "local"
    assert any("dead-reckoning" in w for w in local.warnings)
    # ...and the drift against the truth (moved into that frame) is reported.
    assert local.accuracy is not None
    # Inertial dead reckoning drifts with the square of time (the gyro bias turns the
    # heading): over the sample's 67 s and 619 m it ends 35 m off, 5.7 %. A bound on
    # whether it works at all; the 5 % target is the odometry mode's, on the Husky log.
    assert 0.0 < local.accuracy["horizontal_error_at_end_m"] < 0.1 * 619.0
    assert local.accuracy["roll_rmse_deg"] <= 0.5
    wheels = read_table(ws.log_table(log_id, "wheels"), "wheels")
    wmeta = read_table_metadata(ws.log_table(log_id, "wheels"))
    write_table(
        ws.log_table(log_id, "wheels"),
        wheels.slice(0, 0),
        "wheels",
        source_sha256=wmeta["source_sha256"],
        config_hash=wmeta["config_hash"],
    )
    with pytest.raises(StageError, match="pose needs roles the log lacks: gps .* no fix"):
        run_stage(POSE, ws, default_config(), log_id=log_id)
    empty = read_table(ws.log_table(log_id, "imu"), "imu").slice(0, 0)
    meta = read_table_metadata(ws.log_table(log_id, "imu"))
    write_table(
        ws.log_table(log_id, "imu"),
        empty,
        "imu",
        source_sha256=meta["source_sha256"],
        config_hash=meta["config_hash"],
    )
    with pytest.raises(StageError) as err:  # every missing role named at once
        run_stage(POSE, ws, default_config(), log_id=log_id)
    assert "imu (0 usable rows; accepts sensor_msgs/msg/Imu); gps (" in str(err.value)


def test_no_compass_heading_from_gps_track(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    ws0, log_id, _ = sample_pose
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(ws0.root, ws.root, symlinks=True)
    path = ws.log_table(log_id, "heading")
    head = read_table(path, "heading")
    meta = read_table_metadata(path)
    write_table(
        path,
        head.slice(0, 0),
        "heading",
        source_sha256=meta["source_sha256"],
        config_hash=meta["config_hash"],
    )
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    assert ws.manifest(log_id).read()["pose"]["heading_source"] == "gps_track"
    assert result.accuracy is not None
    assert result.accuracy["horizontal_rmse_m"] <= 1.0
    assert result.accuracy["yaw_rmse_deg"] <= 3.0


def _copy_workspace(sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path) -> Workspace:
    ws0, _, _ = sample_pose
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(ws0.root, ws.root, symlinks=True)
    return ws


def _rewrite(ws: Workspace, log_id: str, name: str, table: pa.Table) -> None:
    path = ws.log_table(log_id, name)
    meta = read_table_metadata(path)
    write_table(
        path, table, name, source_sha256=meta["source_sha256"], config_hash=meta["config_hash"]
    )


def _drop_imu_span(ws: Workspace, log_id: str, start_s: float, length_s: float) -> None:
    """Delete the IMU rows in [t0 + start_s, t0 + start_s + length_s)."""
    imu = read_table(ws.log_table(log_id, "imu"), "imu")
    t = imu.column("t_ns").to_numpy()
    lo = t[0] + int(start_s * 1e9)
    keep = (t < lo) | (t >= lo + int(length_s * 1e9))
    _rewrite(ws, log_id, "imu", imu.filter(pa.array(keep)))


def test_short_imu_gap_is_bridged(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    _drop_imu_span(ws, log_id, 20.0, 0.3)
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    assert ws.manifest(log_id).read()["pose"]["imu_gaps"] == {"bridged": 1, "restarted": 0}
    assert result.accuracy is not None
    assert result.accuracy["horizontal_rmse_m"] <= 0.3
    assert result.accuracy["yaw_rmse_deg"] <= 0.5


def test_long_imu_gap_restarts_the_filter(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    _drop_imu_span(ws, log_id, 20.0, 1.0)
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    assert ws.manifest(log_id).read()["pose"]["imu_gaps"] == {"bridged": 0, "restarted": 1}
    assert result.rows > 5900
    assert result.accuracy is not None
    assert result.accuracy["horizontal_rmse_m"] <= 0.5  # the 1 s crossing costs a little


@pytest.mark.parametrize("pause_s", [60.0, 365 * 86400.0])
def test_a_paused_recorder_leaves_a_hole_not_made_up_rows(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path, pause_s: float
) -> None:
    """Every sensor silent for a minute or a year (a recorder paused): no pose row inside the
    pause, memory and time that do not grow with it, and the first fix after it puts the
    filter back on the GPS (said on the terminal, counted)."""
    _, log_id, before = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    t0 = int(read_table(ws.log_table(log_id, "imu"), "imu", columns=["t_ns"])["t_ns"][0].as_py())
    cut = t0 + 20 * 1_000_000_000
    shift = int(pause_s * 1e9)
    for name in ("imu", "gps", "heading", "wheels"):
        table = read_table(ws.log_table(log_id, name), name)
        t = table.column("t_ns").to_numpy()
        moved = pa.array(np.where(t >= cut, t + shift, t), pa.int64())
        _rewrite(ws, log_id, name, table.set_column(0, "t_ns", moved))
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    t = read_table(ws.log_table(log_id, "pose"), "pose", columns=["t_ns"])["t_ns"].to_numpy()
    step_ns = 10_000_000
    assert not np.any((t > cut + step_ns) & (t < cut + shift - step_ns))
    assert abs(result.rows - before.rows) < 100  # the same rows, less the pause
    assert any("no pose for" in w and "IMU gap" in w for w in result.warnings)
    assert any("re-initialised from the GPS" in w for w in result.warnings)
    assert ws.manifest(log_id).read()["pose"]["reinitialised"] >= 1


def test_single_vehicle_speed_meets_the_targets(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    """Wheels with only the vehicle speed (per-wheel columns null)."""
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    wheels = read_table(ws.log_table(log_id, "wheels"), "wheels")
    for name in ("front_left", "front_right", "rear_left", "rear_right"):
        i = wheels.schema.get_field_index(name)
        wheels = wheels.set_column(i, name, pa.nulls(wheels.num_rows, pa.float64()))
    _rewrite(ws, log_id, "wheels", wheels)
    acc = run_stage(POSE, ws, default_config(), log_id=log_id).accuracy
    assert acc is not None
    assert acc["horizontal_rmse_m"] <= 0.3
    assert acc["roll_rmse_deg"] <= 0.3
    assert acc["pitch_rmse_deg"] <= 0.3
    assert acc["yaw_rmse_deg"] <= 0.5


def _decimate(ws: Workspace, log_id: str, name: str, rate_hz: float) -> None:
    table = read_table(ws.log_table(log_id, name), name)
    t = table.column("t_ns").to_numpy()
    step = max(1, round(1e9 / rate_hz / float(np.median(np.diff(t)))))
    _rewrite(ws, log_id, name, table.take(pa.array(np.arange(0, table.num_rows, step))))


def test_other_imu_and_gps_rates(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    """IMU decimated to 50 Hz and GPS to 5 Hz: looser bounds, still a usable pose."""
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    _decimate(ws, log_id, "imu", 50.0)
    _decimate(ws, log_id, "gps", 5.0)
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    assert result.rows > 5900  # still 100 Hz out
    acc = result.accuracy
    assert acc is not None
    assert acc["horizontal_rmse_m"] <= 0.5
    assert acc["roll_rmse_deg"] <= 0.5
    assert acc["pitch_rmse_deg"] <= 0.5
    assert acc["yaw_rmse_deg"] <= 1.0


def test_cli_pose_exit_codes(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    from click.testing import CliRunner

    from toolkit.cli import main

    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    runner = CliRunner()
    ok = runner.invoke(main, ["pose", "-w", str(ws.root), "--log", log_id, "--overwrite"])
    assert ok.exit_code == 0, ok.output
    assert f"{log_id}: pose estimated" in ok.stdout
    bad = runner.invoke(main, ["pose", "-w", str(ws.root), "--log", "no-such-log"])
    assert bad.exit_code == 1
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("terrain: error: ")
    assert "no-such-log" in lines[0]


def test_sample_pose_roll_and_pitch_rates_follow_the_truth(
    sample_pose: tuple[Workspace, str, PoseResult],
) -> None:
    """roll_rate and pitch_rate (the paper's gamma and psi) against the truth's Euler rates.

    The pose's rates are the bias-corrected gyro samples turned into Euler rates. The
    simulated IMU reports each sample as the mean body rate over its period ``T`` (an
    integrating IMU) plus white noise ``sigma_g``, so against the instantaneous truth the
    error is that noise and half a period of lag, ``(T / 2) * d(rate)/dt``:

        rms error ~ sqrt(sigma_g^2 + (T / 2 * rms(d rate / dt))^2)

    On the sample log's rough road that is ~0.008 (roll) and ~0.006 (pitch) rad/s against
    true rates of ~0.07 rad/s RMS; a one-sample lag would double it. The bound allows 25 %
    over that budget. The mean error must also stay within a quarter of the simulated
    initial gyro bias spread, which an uncorrected gyro bias would not.
    """
    ws, log_id, _ = sample_pose
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    truth = read_table(ws.log_table(log_id, "truth_pose"), "truth_pose")
    sim = json.loads((ws.log_dir(log_id) / "mcap_metadata.json").read_text())["terrain_sim"]
    imu = json.loads(sim["sensors"])["imu"]
    sigma_g = float(imu["gyro_noise_radps"])
    period_s = 1.0 / float(imu["rate_hz"])
    t_truth_ns = truth.column("t_ns").to_numpy()
    t_pose_ns = pose.column("t_ns").to_numpy()
    inside = (t_pose_ns >= t_truth_ns[0]) & (t_pose_ns <= t_truth_ns[-1])
    t_truth_s = (t_truth_ns - t_truth_ns[0]) * 1e-9
    t_pose_s = (t_pose_ns[inside] - t_truth_ns[0]) * 1e-9
    assert t_pose_s.size > 5900
    for name in ("roll_rate", "pitch_rate"):
        true_radps = truth.column(name).to_numpy()
        error = pose.column(name).to_numpy()[inside] - np.interp(t_pose_s, t_truth_s, true_radps)
        rms_error = float(np.sqrt(np.mean(error**2)))
        rms_rate_change = float(np.sqrt(np.mean((np.diff(true_radps) / np.diff(t_truth_s)) ** 2)))
        budget = float(np.hypot(sigma_g, 0.5 * period_s * rms_rate_change))
        assert rms_error <= 1.25 * budget, f"{name}: RMS error {rms_error:.5f} rad/s"
        assert abs(float(np.mean(error))) <= 0.25 * float(imu["gyro_bias_initial_radps"])


# -- Issue "Pose that holds on every log" ------------------------------------------------


@pytest.fixture(scope="module", params=[201, 202])
def unseen_race_pose(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> PoseResult:
    """2 km race logs of seeds nobody tuned on (each with its per-wheel scale errors, the
    race profile's 10 s dropout at 60 s and random ones)."""
    from toolkit.sim.simulate import simulate

    seed = int(request.param)
    root = tmp_path_factory.mktemp(f"race_{seed}")
    log = root / "race.mcap"
    simulate(log, profile="race", distance_m=2000.0, seed=seed, lasers=False)  # as above
    ws = Workspace(root / "ws")
    return run_stage(
        POSE, ws, default_config(), log_id=ingest_log(log, ws, default_config()).log_id
    )


@pytest.mark.slow  # two races simulated and posed (32 s); run by .ci/run
def test_unseen_race_seeds_meet_the_targets(unseen_race_pose: PoseResult) -> None:
    """Every dropout up to 10 s, as the issue asks."""
    assert_race_targets(unseen_race_pose.accuracy, lambda duration_s: duration_s <= 10.05)


def _shift_fixes(gps: pa.Table, rows: np.ndarray, east_m: float) -> pa.Table:
    """The fixes ``rows`` moved ``east_m`` metres east (longitude only)."""
    lat = gps.column("latitude").to_numpy(zero_copy_only=False).copy()
    lon = gps.column("longitude").to_numpy(zero_copy_only=False).copy()
    lon[rows] += np.degrees(east_m / (6_378_137.0 * np.cos(np.radians(lat[rows]))))
    return gps.set_column(gps.schema.get_field_index("longitude"), "longitude", pa.array(lon))


def test_a_filter_locked_out_by_its_gate_reinitialises(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """From 40 s on every fix is 300 m east of where the filter is: it gates them, and after
    ``reinit_after_gated_fixes`` in a row takes its position from the GPS again."""
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    gps = read_table(ws.log_table(log_id, "gps"), "gps")
    t = gps.column("t_ns").to_numpy()
    late = np.flatnonzero(t >= t[0] + 40_000_000_000)
    _rewrite(ws, log_id, "gps", _shift_fixes(gps, late, 300.0))
    config = default_config()
    with caplog.at_level("WARNING"):
        result = run_stage(POSE, ws, config, log_id=log_id)
    detail = ws.manifest(log_id).read()["pose"]
    assert detail["reinitialised"] == 1
    assert any("re-initialised from the GPS" in r.getMessage() for r in caplog.records)
    assert result.gated.get("gps", 0) <= config.pose.reinit_after_gated_fixes + 2
    # The pose follows the moved fixes to the end (truth does not: it was not moved).
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    origin = json.loads(read_table_metadata(ws.log_table(log_id, "pose"))["enu_origin"])
    from toolkit.geometry.geodesy import GeodeticOrigin
    from toolkit.geometry.map_frame import geodetic_to_world

    o = GeodeticOrigin(origin["latitude_deg"], origin["longitude_deg"], origin["altitude_m"])
    moved = read_table(ws.log_table(log_id, "gps"), "gps")
    ok = moved.column("status").to_numpy() >= 0
    enu = np.asarray(
        geodetic_to_world(
            moved.column("latitude").to_numpy(zero_copy_only=False)[ok],
            moved.column("longitude").to_numpy(zero_copy_only=False)[ok],
            moved.column("altitude").to_numpy(zero_copy_only=False)[ok],
            o,
        )
    )
    t_fix = moved.column("t_ns").to_numpy()[ok]
    tp = pose.column("t_ns").to_numpy()
    end = t_fix >= tp[-1] - 5_000_000_000
    x = np.interp(t_fix[end], tp, pose.column("x").to_numpy())
    assert np.abs(x - enu[end, 0]).max() < 3.0


def test_reinitialisation_off_leaves_the_filter_locked_out(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    """The same jump with ``reinit_after_gated_fixes = 0``: every later fix is gated (what
    the re-initialisation is for)."""
    import dataclasses

    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    gps = read_table(ws.log_table(log_id, "gps"), "gps")
    t = gps.column("t_ns").to_numpy()
    late = np.flatnonzero(t >= t[0] + 40_000_000_000)
    _rewrite(ws, log_id, "gps", _shift_fixes(gps, late, 300.0))
    config = default_config()
    config = dataclasses.replace(
        config, pose=dataclasses.replace(config.pose, reinit_after_gated_fixes=0)
    )
    result = run_stage(POSE, ws, config, log_id=log_id)
    assert ws.manifest(log_id).read()["pose"]["reinitialised"] == 0
    assert result.gated.get("gps", 0) > 100


def test_a_wild_first_fix_does_not_move_the_map(
    sample_pose: tuple[Workspace, str, PoseResult], tmp_path: Path
) -> None:
    """The first valid fix 2 km off: the origin is the next fix (the first the later ones
    agree with), the wild one is ignored, and the pose meets its targets."""
    _, log_id, _ = sample_pose
    ws = _copy_workspace(sample_pose, tmp_path)
    gps = read_table(ws.log_table(log_id, "gps"), "gps")
    valid = np.flatnonzero(gps.column("status").to_numpy() >= 0)
    _rewrite(ws, log_id, "gps", _shift_fixes(gps, valid[:1], 2000.0))
    result = run_stage(POSE, ws, default_config(), log_id=log_id)
    origin = json.loads(read_table_metadata(ws.log_table(log_id, "pose"))["enu_origin"])
    second = gps.slice(int(valid[1]), 1).to_pylist()[0]
    assert origin["latitude_deg"] == second["latitude"]
    assert origin["longitude_deg"] == second["longitude"]
    assert ws.manifest(log_id).read()["pose"]["reinitialised"] == 0
    assert any("ignored" in w for w in result.warnings)
    acc = result.accuracy
    assert acc is not None
    assert acc["horizontal_rmse_m"] <= 0.3
    assert acc["yaw_rmse_deg"] <= 0.5
