"""Laser returns projected with the TRUE pose lie on the true terrain, within the range noise,
when the lasers are ideal; with Stanley's errors, they miss it by what those errors predict.

The first part runs on a sample log simulated with :func:`~toolkit.sim.sensors.ideal_lasers`
(exact mounts, no bias, footprint, flex, dust or stamp jitter: the statistical range noise and
the 1 cm count only). It checks the ray caster, the scan timing (clock offsets, beam times)
and the extrinsics together, from the log alone: per beam, its true time is the header
stamp less the laser's clock offset (metadata) plus ``beam_index * time_increment``; the true
``base_link`` pose at that time is interpolated from ``/truth/odom`` (positions linearly,
rotations by Slerp); the laser's ``/tf_static`` extrinsic and the beam angle give the ray,
the range the point. The point's height is compared with the true terrain of the world
rebuilt from the metadata.

The vertical miss ``dz`` of a point is converted to a miss along the beam: a range error
``e`` moves the point by ``e u`` and the ground under it by ``e (dh/dt)`` (the terrain's
slope along the beam's horizontal direction, ``t`` the range), so ``e = dz / (u_z - dh/dt)``
(positive: the range is too long; this sign was reversed until the range bias needed it).
On flat ground this is ``-dz / |sin(elevation)|``; the slope term matters for the far lasers,
whose beams meet the ground at a few degrees, where a 2 % crossfall or a 5 % grade changes
the incidence angle severalfold. Both are reported; the assertions use the slope-aware one.

The second part runs on the sample log as simulated (every error on): with the published
``/tf_static`` the far lasers miss the ground by their mount's miscalibration; with the true
mounts, the true scan times and the range biases of ``terrain_sim`` the residual is the
statistical noise, the footprint's spread and the mounts' flex, and the flex shows as a pitch
error proportional to the body's specific force (read from the log's own IMU).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import toolkit.sim.simulate as simulate_module
from toolkit.sim.profiles import SimProfile, make_profile
from toolkit.sim.sensors import LaserParams, draw_laser_truth, ideal_lasers

from .conftest import SAMPLE_SEED
from .logdata import LASER_FRAMES, LASER_TOPICS, SimLog, load_log, on_grid_true_times

# Each check here projects hundreds of thousands of beams of logs simulated for it (the ideal
# lasers' sample log alone takes 26 s): run by .ci/run, left out of the README's command.
pytestmark = pytest.mark.slow

SCAN_STRIDE = 4  # every 4th scan of each laser: about 100 000 beams per laser
SLOPE_STEP_M = 0.025  # half the fine grid's spacing


@dataclass(frozen=True)
class BeamResiduals:
    dz: np.ndarray  # point height minus true terrain height (m)
    range_error: np.ndarray  # dz converted to a miss along the beam, slope-aware (m)
    range_error_flat: np.ndarray  # dz / |sin(elevation)| (m)
    d: np.ndarray  # lateral offset of the point from the route centreline (m)
    range_m: np.ndarray  # the beam's range (m)
    horizontal_m: np.ndarray  # its horizontal extent (m)
    angle_rad: np.ndarray  # the beam's angle in the scan plane (rad)
    scan: np.ndarray  # index of the beam's scan among those used
    scan_t_ns: np.ndarray  # true start of each scan used (one per scan)

    def __len__(self) -> int:
        return int(self.dz.size)


def true_scan_starts(log: SimLog, laser: int) -> np.ndarray:
    """Each scan's true start, exactly as the simulator computed it: ``start + phase + n /
    rate`` (``laser_phase_ns`` in terrain_sim), ``n`` the nearest to the stamp less the clock
    offset (its jitter, under 4 ms, is far below half the 13.3 ms period)."""
    topic = LASER_TOPICS[laser]
    period = 1e9 / LaserParams().rate_hz
    phase = float(log.json("laser_phase_ns")[LASER_FRAMES[laser]])
    late = log.stamps(topic) - log.clock_offsets[topic] - log.start_ns
    n = np.round((late - phase) / period)
    return np.round(log.start_ns + phase + n * period).astype(np.int64)


def beam_residuals(
    log: SimLog,
    laser: int,
    stride: int = SCAN_STRIDE,
    time_shift_ns: int = 0,
    *,
    true_lasers: bool = False,
    keep_bias: bool = False,
) -> BeamResiduals:
    """Residuals of every finite beam of every ``stride``-th scan of laser ``laser`` (0-4);
    ``time_shift_ns`` is added to the beams' true times (0 for the real check). With
    ``true_lasers`` the laser's true mount and its scans' true start times are used and its
    range bias taken off (unless ``keep_bias``; all from terrain_sim); else ``/tf_static``
    and stamp - offset."""
    topic = LASER_TOPICS[laser]
    frame = LASER_FRAMES[laser]
    scans = log.columns[topic]
    world = log.world
    truth = log.truth
    if true_lasers:
        mount = log.json("laser_true_mounts")[frame]
        mount_xyz = np.asarray(mount["xyz_m"], dtype=np.float64)
        r, p, y = mount["rpy_rad"]
        mount_rot = Rotation.from_euler("ZYX", [y, p, r])
        start = true_scan_starts(log, laser)[::stride] + time_shift_ns
        bias = 0.0 if keep_bias else float(log.json("laser_range_bias_m")[frame])
    else:
        mount_xyz, mount_q = log.static_transform(frame)
        mount_rot = Rotation.from_quat(mount_q)
        start = log.stamps(topic)[::stride] - log.clock_offsets[topic] + time_shift_ns
        bias = 0.0
    ranges = np.asarray(scans["ranges"][::stride], dtype=np.float64) - bias
    beams = ranges.shape[1]
    k = np.arange(beams)
    dt_beam_ns = float(scans["time_increment"][0]) * 1e9
    t_beam = start[:, None] + np.round(k[None, :] * dt_beam_ns).astype(np.int64)
    angle = float(scans["angle_min"][0]) + k * float(scans["angle_increment"][0])
    ok = np.isfinite(ranges) & truth.covers(t_beam)
    t = t_beam[ok]
    r = ranges[ok]
    scan = np.broadcast_to(np.arange(ranges.shape[0])[:, None], ranges.shape)[ok]
    a = np.broadcast_to(angle[None, :], ranges.shape)[ok]

    position = truth.interp(t, truth.position)
    world_from_base = truth.rotation_at(t)
    beam_in_laser = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    u = world_from_base.apply(mount_rot.apply(beam_in_laser))
    origin = position + world_from_base.apply(mount_xyz)
    p = origin + r[:, None] * u

    # Route coordinates: the guess is the vehicle's route s plus how far ahead the point is.
    s_vehicle = truth.interp(t, truth.route_s)
    _, _, heading = world.route.sample(s_vehicle)
    ahead = (p[:, 0] - position[:, 0]) * np.cos(heading) + (p[:, 1] - position[:, 1]) * np.sin(
        heading
    )
    s, d = world.route.to_route(p[:, 0], p[:, 1], s_vehicle + ahead)
    ground = world.terrain.height(s, d)
    dz = p[:, 2] - ground

    def ground_at(offset: float) -> np.ndarray:
        x = p[:, 0] + offset * u[:, 0]
        y = p[:, 1] + offset * u[:, 1]
        ss, dd = world.route.to_route(x, y, s)
        return world.terrain.height(ss, dd)

    slope = (ground_at(SLOPE_STEP_M) - ground_at(-SLOPE_STEP_M)) / (2 * SLOPE_STEP_M)
    return BeamResiduals(
        dz=dz,
        range_error=dz / (u[:, 2] - slope),
        range_error_flat=-dz / np.abs(u[:, 2]),
        d=d,
        range_m=r,
        horizontal_m=r * np.hypot(u[:, 0], u[:, 1]),
        angle_rad=a,
        scan=scan,
        scan_t_ns=start,
    )


@pytest.fixture(scope="module")
def ideal_sample_log(tmp_path_factory: pytest.TempPathFactory) -> SimLog:
    """The sample log (same seed) with ideal lasers: :func:`ideal_lasers` of its profile."""
    real = make_profile

    def ideal_profile(name: str, distance_m: float | None = None) -> SimProfile:
        prof = real(name, distance_m)
        laser = ideal_lasers(prof.sensors.laser)
        return dataclasses.replace(prof, sensors=dataclasses.replace(prof.sensors, laser=laser))

    path: Path = tmp_path_factory.mktemp("ideal") / "sample_ideal.mcap"
    with mock.patch.object(simulate_module, "make_profile", ideal_profile):
        simulate_module.simulate(path, profile="sample", seed=SAMPLE_SEED)
    log = load_log(path)
    assert log.json("sensors")["laser"]["beam_divergence_rad"] == 0.0
    return log


@pytest.fixture(scope="module")
def residuals(ideal_sample_log: SimLog) -> list[BeamResiduals]:
    return [beam_residuals(ideal_sample_log, i) for i in range(len(LASER_TOPICS))]


def _robust_std(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _summary(name: str, x: np.ndarray) -> str:
    a = np.abs(x)
    p90, p99, p999 = np.percentile(a, [90, 99, 99.9])
    return (
        f"{name}: n={x.size} median|e|={np.median(a):.4f} p90={p90:.4f} p99={p99:.4f} "
        f"p99.9={p999:.4f} robust std={_robust_std(x):.4f} median e={np.median(x):+.5f}"
    )


def test_laser_points_lie_on_true_terrain(residuals: list[BeamResiduals]) -> None:
    noise = make_profile("sample").sensors.laser.range_noise_m
    print()
    for i, res in enumerate(residuals):
        print(_summary(f"{LASER_FRAMES[i]} slope-aware", res.range_error))
        print(_summary(f"{LASER_FRAMES[i]} dz/|sin el| ", res.range_error_flat))
    e = np.concatenate([res.range_error for res in residuals])
    print(_summary("all lasers slope-aware", e))
    flat = np.concatenate([res.range_error_flat for res in residuals])
    print(_summary("all lasers dz/|sin el| ", flat))

    assert all(len(res) > 50_000 for res in residuals)
    a = np.abs(e)
    assert np.median(a) < 2 * noise
    assert np.percentile(a, 99) < 6 * noise
    # The bulk is the configured Gaussian range noise: robust std within 20 %, no bias.
    assert _robust_std(e) == pytest.approx(noise, rel=0.2)
    assert abs(np.median(e)) < 0.1 * noise
    for i, res in enumerate(residuals):
        ai = np.abs(res.range_error)
        assert np.median(ai) < 2 * noise, LASER_FRAMES[i]
        assert abs(np.median(res.range_error)) < 0.15 * noise, LASER_FRAMES[i]


def test_nearest_laser_residuals_are_pure_range_noise(residuals: list[BeamResiduals]) -> None:
    """laser_1 looks down steeply (8 m ahead), so pose and timing errors hardly matter: its
    residuals must be the configured range noise alone (Gaussian: median |e| = 0.674 sigma,
    99th percentile 2.58 sigma)."""
    noise = make_profile("sample").sensors.laser.range_noise_m
    e = residuals[0].range_error
    assert _robust_std(e) == pytest.approx(noise, rel=0.1)
    assert np.median(np.abs(e)) == pytest.approx(0.6745 * noise, rel=0.1)
    assert np.percentile(np.abs(e), 99) < 3.5 * noise


def test_laser_clock_offset_is_where_points_fit_best(ideal_sample_log: SimLog) -> None:
    """Shifting the far laser's beam times by +-1 ms from the metadata's clock offset makes the
    points fit the terrain worse: the offset and the beam timing are right to well under 1 ms."""
    laser = len(LASER_TOPICS) - 1
    med = {
        shift: float(
            np.median(
                np.abs(
                    beam_residuals(
                        ideal_sample_log, laser, stride=8, time_shift_ns=shift
                    ).range_error
                )
            )
        )
        for shift in (-1_000_000, 0, 1_000_000)
    }
    print(f"\n{LASER_FRAMES[laser]} median |range error| by time shift (ns): {med}")
    assert med[0] < 0.95 * med[-1_000_000]
    assert med[0] < 0.95 * med[1_000_000]


# -- the lasers as simulated: every error source on -----------------------------------------

GRAVITY_MPS2 = 9.80665
NS = 1_000_000_000


@pytest.fixture(scope="module")
def true_residuals(sample_log: SimLog) -> list[BeamResiduals]:
    return [
        beam_residuals(sample_log, i, stride=2, true_lasers=True) for i in range(len(LASER_TOPICS))
    ]


def test_metadata_holds_the_lasers_truth(sample_log: SimLog) -> None:
    """terrain_sim records the true mounts and biases the seed draws; /tf_static publishes
    the nominal mounts, which differ from the true ones by the stated amounts."""
    p = make_profile("sample").sensors.laser
    truth = draw_laser_truth(p, sample_log.seed)
    true_mounts = sample_log.json("laser_true_mounts")
    biases = sample_log.json("laser_range_bias_m")
    assert list(true_mounts) == list(LASER_FRAMES) == list(biases)
    lo, hi = p.rack_angle_error_rad
    for frame, mount, nominal, bias in zip(
        LASER_FRAMES, truth.mounts, p.mounts, truth.range_bias_m, strict=True
    ):
        assert true_mounts[frame] == {"xyz_m": list(mount.xyz_m), "rpy_rad": list(mount.rpy_rad)}
        assert biases[frame] == bias and abs(bias) <= p.range_bias_max_m
        xyz, q = sample_log.static_transform(frame)
        np.testing.assert_allclose(xyz, nominal.xyz_m, atol=1e-12)
        published = Rotation.from_quat(q)
        r, pitch, y = mount.rpy_rad
        true_rot = Rotation.from_euler("ZYX", [y, pitch, r])
        angle = (published.inv() * true_rot).magnitude()
        # Roll and pitch: the rack's lo..hi plus up to +-own each; yaw: +-own.
        own = p.laser_angle_error_rad
        assert 0.0 < angle <= np.sqrt(2 * (hi + own) ** 2 + own**2), frame
        assert np.all(np.abs(np.subtract(mount.xyz_m, xyz)) <= p.mount_xyz_error_m), frame
    print(f"\nbiases (mm): { {k: round(1000 * v, 1) for k, v in biases.items()} }")


def test_published_mounts_put_the_points_off_the_ground(
    sample_log: SimLog, true_residuals: list[BeamResiduals]
) -> None:
    """Projected with /tf_static's miscalibrated mounts the points miss the ground by more
    than with the true ones, most at range (a 0.2 degree pitch error is 8.7 cm at 25 m);
    with the true mounts, scan times and biases the near laser is nearly on it."""
    noise = make_profile("sample").sensors.laser.range_noise_m
    print()
    med = {}
    for i, true in enumerate(true_residuals):
        published = beam_residuals(sample_log, i, stride=2)
        med[i] = (np.median(np.abs(published.dz)), np.median(np.abs(true.dz)))
        print(
            f"{LASER_FRAMES[i]}: median |dz| published {med[i][0]:.4f} m, true {med[i][1]:.4f} m; "
            + _summary("true range error", true.range_error)
        )
        assert med[i][0] > 1.5 * med[i][1], LASER_FRAMES[i]
    assert med[4][0] > 2.5 * med[4][1]
    near = true_residuals[0].range_error
    assert abs(np.median(near)) < 0.5 * noise
    assert _robust_std(near) < 2 * noise


def test_range_bias_shows_as_the_near_lasers_mean_range_error(sample_log: SimLog) -> None:
    """With the true mounts and scan times but the bias left in, the near lasers' median
    range error is their bias (their beams are steep: the footprint and the flex move their
    range least)."""
    biases = sample_log.json("laser_range_bias_m")
    for i in (0, 1):
        e = beam_residuals(sample_log, i, stride=2, true_lasers=True, keep_bias=True).range_error
        bias = biases[LASER_FRAMES[i]]
        print(f"\n{LASER_FRAMES[i]}: median range error {np.median(e):+.4f} m, bias {bias:+.4f} m")
        assert np.median(e) == pytest.approx(bias, abs=0.005)


def test_mount_flex_follows_the_specific_force(
    sample_log: SimLog, true_residuals: list[BeamResiduals]
) -> None:
    """Per scan, the pitch error of the beams near the scan's centre (dz over horizontal
    range, over the cosine of the beam's angle: a pitch about base_link's y tilts a beam at
    angle a by pitch x cos a) against the IMU's (f_z - g) - f_x at the scan's time (the IMU
    reports the mean of the last 10 ms, so its sample 5 ms later): a line through about zero
    of slope ``flex_pitch_rad_per_mps2``, for near and far lasers alike."""
    p = make_profile("sample").sensors.laser
    imu = sample_log.columns["/imu/data"]
    t_imu = on_grid_true_times(
        sample_log.stamps("/imu/data"),
        sample_log.clock_offsets["/imu/data"],
        sample_log.start_ns,
        NS // 100,
    )
    _, q = sample_log.static_transform("imu_link")
    f = Rotation.from_quat(q).apply(
        np.stack([imu[f"linear_acceleration.{a}"] for a in "xyz"], axis=1)
    )
    drive = (f[:, 2] - GRAVITY_MPS2) - f[:, 0]
    half_scan_ns = 90 * p.time_increment_s * NS
    print(f"\nIMU (f_z - g) - f_x: std {drive.std():.2f} m/s^2")
    for i in (0, 2, 4):
        res = true_residuals[i]
        central = np.abs(res.angle_rad) < np.radians(20)
        pitch = (res.dz / (res.horizontal_m * np.cos(res.angle_rad)))[central]
        scan = res.scan[central]
        order = np.lexsort((pitch, scan))
        scan, pitch = scan[order], pitch[order]
        first = np.flatnonzero(np.r_[True, scan[1:] != scan[:-1]])
        count = np.diff(np.r_[first, scan.size])
        keep = count >= 20
        median = pitch[first + count // 2][keep]
        t_mid = res.scan_t_ns[scan[first][keep]] + half_scan_ns
        x = np.interp(t_mid + 5e6, t_imu, drive)
        slope, intercept = np.polyfit(x, median, 1)
        r = np.corrcoef(x, median)[0, 1]
        print(
            f"{LASER_FRAMES[i]}: pitch = {slope:.3e} rad/(m/s^2) x + {intercept:.2e} rad "
            f"(r {r:.3f}, {x.size} scans)"
        )
        assert slope == pytest.approx(p.flex_pitch_rad_per_mps2, rel=0.07), LASER_FRAMES[i]
        assert r > 0.95 and abs(intercept) < 0.5e-3


def test_laser_stamps_carry_the_hosts_jitter(sample_log: SimLog) -> None:
    """A scan's stamp is its true start (terrain_sim's phase) + the clock's offset + the
    clock's jitter + the host's: zero mean, std hypot(0.3, 1) ms, within 3 sigma of each."""
    sensors = make_profile("sample").sensors
    clock_ns = sensors.clock.jitter_std_s * NS
    host_ns = sensors.laser.stamp_jitter_s * NS
    for i, topic in enumerate(LASER_TOPICS):
        dev = (
            sample_log.stamps(topic)
            - sample_log.clock_offsets[topic]
            - true_scan_starts(sample_log, i)
        )
        assert abs(dev.mean()) < 5 * host_ns / np.sqrt(dev.size), topic
        assert dev.std() == pytest.approx(np.hypot(clock_ns, host_ns), rel=0.05), topic
        assert np.abs(dev).max() <= 3 * (clock_ns + host_ns) + 1, topic


def test_dust_drops_returns_in_bursts(sample_log: SimLog) -> None:
    """Dust is NaN (no return is +inf): a few % of scans lose beams to it, in runs of
    consecutive scans, each in one sector of at most ``dust_sector_beams[1]`` beams."""
    p = make_profile("sample").sensors.laser
    dusty_all, follows = [], []
    for topic in LASER_TOPICS:
        ranges = np.asarray(sample_log.columns[topic]["ranges"], dtype=np.float64)
        nan = np.isnan(ranges)
        dusty = nan.any(axis=1)
        dusty_all.append(dusty.mean())
        follows.append(dusty[1:][dusty[:-1]].mean() if dusty[:-1].any() else np.nan)
        spans = [np.ptp(np.flatnonzero(row)) + 1 for row in nan[dusty]]
        assert not spans or max(spans) <= p.dust_sector_beams[1], topic
        assert np.isinf(ranges).any(), topic  # no return: a different code
    print(f"\ndusty scans per laser {np.round(dusty_all, 4)}; P(dusty | dusty before) {follows}")
    assert 0.005 < np.mean(dusty_all) < 0.15
    assert np.nanmean(follows) > 0.9
