"""What the IMU's z accelerometer feels: gravity on flat road, shock over obstacles, and the
paper's Fig. 5 (peak shock over a static obstacle grows linearly with speed), on the
``calibration`` profile: a straight, flat road (ISO class B) with five identical ridges,
each driven over at its own constant speed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from toolkit.model.shock import design_shock_fir
from toolkit.sim.profiles import CALIBRATION_SPEEDS_MPS, make_profile

from .logdata import GRAVITY_MPS2, SimLog, on_grid_true_times
from .reference_labeller import filtered_shock

# Shock windows: from the front wheels one metre before the obstacle until the rear wheels
# are 5 m past it. Smooth reference: the 75 m of road ending 15 m before the front wheels
# reach the obstacle (same speed, no obstacle).
BEFORE_M = 1.0
AFTER_M = 5.0
SMOOTH_LENGTH_M = 75.0
SMOOTH_GAP_M = 15.0


@dataclass(frozen=True)
class ImuTrack:
    """IMU z samples with the rear axle's route distance and speed at their true times."""

    t_ns: np.ndarray
    accel_z: np.ndarray
    s_m: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray  # truth longitudinal acceleration
    shock: np.ndarray  # filtered (0-10 Hz removed), at delay-compensated positions
    shock_s_m: np.ndarray
    settled: np.ndarray


def imu_track(log: SimLog) -> ImuTrack:
    imu = log.columns["/imu/data"]
    p = make_profile(log.meta["profile"]).sensors.imu
    t = on_grid_true_times(
        log.stamps("/imu/data"),
        log.clock_offsets["/imu/data"],
        log.start_ns,
        int(round(1e9 / p.rate_hz)),
    )
    az = np.asarray(imu["linear_acceleration.z"], dtype=np.float64)
    tr = log.truth
    inside = tr.covers(t)
    t, az = t[inside], az[inside]
    speed = tr.speed
    accel = np.gradient(speed, (tr.t_ns - tr.t_ns[0]) * 1e-9)
    # The label stage's own filter (the paper's: 40 taps, 0-10 Hz removed), as issue 11 asks.
    t_f, shock, settled = filtered_shock(t, az, p.rate_hz, design_shock_fir(p.rate_hz).taps)
    return ImuTrack(
        t_ns=t,
        accel_z=az,
        s_m=tr.interp(t, tr.route_s),
        speed_mps=tr.interp(t, speed),
        accel_mps2=tr.interp(t, accel),
        shock=shock,
        shock_s_m=tr.interp(np.clip(t_f, tr.t_ns[0], tr.t_ns[-1]), tr.route_s),
        settled=settled & tr.covers(t_f),
    )


@dataclass(frozen=True)
class ObstaclePass:
    s_m: float
    speed_mps: float
    peak_g: float
    smooth_rms_g: float


@pytest.fixture(scope="module")
def track(calibration_log: SimLog) -> ImuTrack:
    return imu_track(calibration_log)


@pytest.fixture(scope="module")
def passes(calibration_log: SimLog, track: ImuTrack) -> list[ObstaclePass]:
    feats = calibration_log.columns["/truth/features"]["features"][0]
    wheelbase = make_profile("calibration").vehicle.wheelbase_m
    out = []
    for kind, lo, hi in zip(feats["kind"], feats["s_start_m"], feats["s_end_m"], strict=True):
        assert kind == "ridge"
        s = track.shock_s_m
        window = track.settled & (s > lo - wheelbase - BEFORE_M) & (s < hi + AFTER_M)
        smooth_hi = lo - wheelbase - SMOOTH_GAP_M
        smooth = track.settled & (s > smooth_hi - SMOOTH_LENGTH_M) & (s < smooth_hi)
        assert window.sum() > 10 and smooth.sum() > 300
        centre = 0.5 * (lo + hi)
        out.append(
            ObstaclePass(
                s_m=float(centre),
                speed_mps=float(np.interp(centre, track.s_m, track.speed_mps)),
                peak_g=float(np.abs(track.shock[window]).max() / GRAVITY_MPS2),
                smooth_rms_g=float(np.sqrt(np.mean(track.shock[smooth] ** 2)) / GRAVITY_MPS2),
            )
        )
    return out


def test_flat_road_at_constant_speed_reads_one_g(calibration_log: SimLog, track: ImuTrack) -> None:
    """Away from the obstacles, at constant speed, the mean z acceleration is g within 1 %."""
    feats = calibration_log.columns["/truth/features"]["features"][0]
    near = np.zeros(track.s_m.size, dtype=bool)
    for lo, hi in zip(feats["s_start_m"], feats["s_end_m"], strict=True):
        near |= (track.s_m > lo - 20.0) & (track.s_m < hi + 20.0)
    steady = ~near & (np.abs(track.accel_mps2) < 0.02)
    world = calibration_log.world
    assert np.all(world.route.z0_m == 0.0) and np.all(world.route.curvature_per_m == 0.0)
    assert steady.sum() > 3000
    mean_z = float(track.accel_z[steady].mean())
    print(
        f"\nflat road, constant speed: mean IMU z = {mean_z:.4f} m/s^2 over {steady.sum()} "
        f"samples ({mean_z / GRAVITY_MPS2 - 1:+.4%} from g)"
    )
    assert mean_z == pytest.approx(GRAVITY_MPS2, rel=0.01)
    # And per constant-speed stretch.
    for v in CALIBRATION_SPEEDS_MPS:
        at_v = steady & (np.abs(track.speed_mps - v) < 0.05)
        assert at_v.sum() > 300, v
        assert track.accel_z[at_v].mean() == pytest.approx(GRAVITY_MPS2, rel=0.01), v


def test_calibration_obstacles_show_as_shock(passes: list[ObstaclePass]) -> None:
    print()
    for p in passes:
        print(
            f"ridge at {p.s_m:7.1f} m, {p.speed_mps:5.2f} m/s: peak {p.peak_g:.3f} G, smooth "
            f"rms {p.smooth_rms_g:.4f} G, ratio {p.peak_g / p.smooth_rms_g:.1f}"
        )
    assert len(passes) == len(CALIBRATION_SPEEDS_MPS)
    for p in passes:
        assert p.peak_g > 5 * p.smooth_rms_g, p
    # Each obstacle is driven at its own scheduled speed.
    np.testing.assert_allclose([p.speed_mps for p in passes], CALIBRATION_SPEEDS_MPS, atol=0.1)


def test_peak_shock_is_linear_in_speed(passes: list[ObstaclePass]) -> None:
    """The paper's Fig. 5: peak shock over a static obstacle against speed fits a line."""
    v = np.array([p.speed_mps for p in passes])
    g = np.array([p.peak_g for p in passes])
    slope, intercept = np.polyfit(v, g, 1)
    fit = slope * v + intercept
    r2 = 1 - np.sum((g - fit) ** 2) / np.sum((g - g.mean()) ** 2)
    print(
        f"\nFig. 5: peak G = {slope:.4f} * v + {intercept:.4f}, r^2 = {r2:.4f}; "
        f"speeds {np.round(v, 2).tolist()}, peaks {np.round(g, 3).tolist()}"
    )
    assert slope > 0
    assert r2 >= 0.9
