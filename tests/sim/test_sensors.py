"""Topic rates, clock offsets, noise levels, extrinsics and read-back, as configured.

The configuration is the profile's :class:`~toolkit.sim.sensors.SensorParams`
(``make_profile``); the log's ``terrain_sim`` metadata must say the same, and the messages must
behave accordingly when compared with ``/truth/odom``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from toolkit.sim.profiles import make_profile
from toolkit.sim.sensors import Mount, SensorParams
from toolkit.sim.simulate import SimResult

from .logdata import LASER_FRAMES, LASER_TOPICS, SimLog, on_grid_true_times

NS = 1_000_000_000


def _plain(obj: Any) -> Any:
    """A dataclass as the JSON the metadata holds (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(obj)))


def _params(profile: str) -> SensorParams:
    return make_profile(profile).sensors


def _expected_rates(p: SensorParams) -> dict[str, float]:
    return {
        **{t: p.laser.rate_hz for t in LASER_TOPICS},
        "/imu/data": p.imu.rate_hz,
        "/vehicle/wheel_speeds": p.wheels.rate_hz,
        "/gps/fix": p.gps.rate_hz,
        "/gps/heading": p.gps.heading_rate_hz,
        "/truth/odom": p.truth_rate_hz,
    }


def _quat_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """xyzw of R = Rz(yaw) Ry(pitch) Rx(roll), written out (not via the simulator's code)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def _dropout_mask(t_ns: np.ndarray, dropouts: list[list[int]]) -> np.ndarray:
    lost = np.zeros(t_ns.size, dtype=bool)
    for lo, hi in dropouts:
        lost |= (t_ns >= lo) & (t_ns < hi)
    return lost


# -- metadata ---------------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["sample", "calibration"])
def test_metadata_records_the_profile(profile: str, request: pytest.FixtureRequest) -> None:
    log: SimLog = request.getfixturevalue(f"{profile}_log")
    prof = make_profile(profile)
    assert log.meta["profile"] == profile
    assert log.json("sensors") == _plain(prof.sensors)
    assert log.json("world") == _plain(prof.world)
    assert log.json("vehicle") == _plain(prof.vehicle)
    assert set(log.clock_offsets) == set(_expected_rates(prof.sensors))
    assert log.clock_offsets["/truth/odom"] == 0
    max_ns = prof.sensors.clock.offset_max_s * NS
    assert all(abs(v) <= max_ns for v in log.clock_offsets.values())


# -- rates ------------------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["sample", "calibration"])
def test_topic_rates_match_sensor_params(profile: str, request: pytest.FixtureRequest) -> None:
    log: SimLog = request.getfixturevalue(f"{profile}_log")
    p = _params(profile)
    rates = _expected_rates(p)
    jitter_ns = p.clock.jitter_std_s * NS
    host_ns = p.laser.stamp_jitter_s * NS
    measured = {}
    for topic, rate in rates.items():
        st = np.sort(log.stamps(topic))
        period = NS / rate
        steps = np.diff(st)
        if topic == "/gps/heading":
            # The compass is silent during GPS dropouts: steps are whole periods.
            whole = np.round(steps / period)
            assert whole.min() >= 1
            dev = steps - whole * period
            n_periods = whole.sum()
        else:
            dev = steps - period
            n_periods = steps.size
        measured[topic] = n_periods / ((st[-1] - st[0]) / NS)
        assert measured[topic] == pytest.approx(rate, rel=0.01), topic
        # Every step is one period, give or take the stamp jitter of its two ends (<= 3 sigma;
        # a laser's stamp also carries the host's jitter, LaserParams.stamp_jitter_s).
        end = 3 * jitter_ns + (3 * host_ns if topic in LASER_TOPICS else 0.0)
        assert np.abs(dev).max() <= 2 * end + 3, topic
    print(f"\n{profile} rates (Hz):", {t: round(r, 4) for t, r in measured.items()})


def test_message_counts_match_duration(sample_log: SimLog, sample_result: SimResult) -> None:
    p = _params("sample")
    for topic, rate in _expected_rates(p).items():
        n = sample_result.message_counts[topic]
        assert n == np.asarray(sample_log.columns[topic]["header.stamp.sec"]).size
        if topic != "/gps/heading":
            assert n == pytest.approx(sample_result.duration_s * rate, abs=2), topic
    assert sample_result.message_counts["/tf_static"] == 1
    assert sample_result.message_counts["/truth/features"] == 1


# -- clocks -----------------------------------------------------------------------------------

ON_GRID = ("/imu/data", "/vehicle/wheel_speeds", "/gps/fix", "/gps/heading", "/truth/odom")


def _grid_period_ns(p: SensorParams, topic: str) -> int:
    return int(round(NS / _expected_rates(p)[topic]))


@pytest.mark.parametrize("topic", ON_GRID)
def test_clock_offsets_of_gridded_sensors(sample_log: SimLog, topic: str) -> None:
    """IMU, wheels, GPS, compass and truth sample on a grid of true times from the log's start;
    a stamp is true time + the sensor's clock offset + jitter (clipped at 3 sigma)."""
    p = _params("sample")
    period = _grid_period_ns(p, topic)
    st = sample_log.stamps(topic)
    # The offset, estimated from the stamps alone (offsets are well within half a period).
    phase = (st - sample_log.start_ns) % period
    phase = np.where(phase > period // 2, phase - period, phase)
    estimate = float(np.median(phase))
    offset = sample_log.clock_offsets[topic]
    jitter_ns = 0.0 if topic == "/truth/odom" else p.clock.jitter_std_s * NS
    # The median of n jitters has a standard error of about 1.25 jitter / sqrt(n).
    assert estimate == pytest.approx(offset, abs=5 * jitter_ns / np.sqrt(st.size) + 1)
    dev = st - offset - on_grid_true_times(st, offset, sample_log.start_ns, period)
    assert np.abs(dev).max() <= 3 * jitter_ns + 1
    if jitter_ns:
        assert np.std(dev) == pytest.approx(jitter_ns, rel=0.1)
    print(
        f"\n{topic}: offset {offset} ns, estimated {estimate:.0f} ns, jitter std "
        f"{np.std(dev):.0f} ns"
    )


@pytest.mark.parametrize("topic", [*LASER_TOPICS, *ON_GRID])
def test_clock_offsets_from_log_times(sample_log: SimLog, topic: str) -> None:
    """Messages are logged when published: a laser scan when its last beam is in (true scan
    start + span), every other message at its true time, each plus a transport latency drawn
    uniformly from ``latency_range_s``. So stamp - log time = offset + jitter - span - latency,
    whose mean gives the offset, for the lasers too (whose scan phase is unknown)."""
    p = _params("sample")
    lat_lo, lat_hi = (x * NS for x in p.clock.latency_range_s)
    span = (p.laser.beams - 1) * p.laser.time_increment_s * NS if topic in LASER_TOPICS else 0.0
    diff = (sample_log.stamps(topic) - sample_log.log_times[topic]).astype(np.float64)
    offset = sample_log.clock_offsets[topic]
    if topic == "/truth/odom":
        np.testing.assert_array_equal(diff, 0)
        return
    estimate = diff.mean() + span + 0.5 * (lat_lo + lat_hi)
    # Standard error of the mean: about (latency 0.87 ms + jitter 0.3 ms, and for a laser the
    # host's 1 ms) / sqrt(n) < 0.1 ms.
    assert estimate == pytest.approx(offset, abs=0.1e6), topic
    # And every single message within jitter and latency bounds (a laser's stamp also carries
    # the host's jitter, LaserParams.stamp_jitter_s).
    jitter3 = 3 * p.clock.jitter_std_s * NS
    if topic in LASER_TOPICS:
        jitter3 += 3 * p.laser.stamp_jitter_s * NS
    lo = offset - span - lat_hi - jitter3 - 3
    hi = offset - span - lat_lo + jitter3 + 3
    assert diff.min() >= lo and diff.max() <= hi, topic


# -- IMU --------------------------------------------------------------------------------------


def test_gyro_noise_against_truth(sample_log: SimLog) -> None:
    """Gyro minus the true body rate at the same true times, less a constant bias, has the
    configured white noise. The IMU reports the mean over its 10 ms; the reference is that
    mean from the 100 Hz truth (linear between the truth at t - 10 ms and t)."""
    p = _params("sample").imu
    imu = sample_log.columns["/imu/data"]
    tr = sample_log.truth
    t = on_grid_true_times(
        sample_log.stamps("/imu/data"),
        sample_log.clock_offsets["/imu/data"],
        sample_log.start_ns,
        int(round(NS / p.rate_hz)),
    )
    k = np.searchsorted(tr.t_ns, t)
    ok = (k >= 1) & (k < tr.t_ns.size)
    ok[ok] &= tr.t_ns[k[ok]] == t[ok]
    assert ok.sum() > 0.99 * t.size
    k = k[ok]
    gyro = np.stack([imu[f"angular_velocity.{a}"] for a in "xyz"], axis=1)[ok]
    window_mean = 0.55 * tr.omega_body[k] + 0.45 * tr.omega_body[k - 1]
    resid = gyro - window_mean
    bias = resid.mean(axis=0)
    std = (resid - bias).std(axis=0)
    print(
        f"\ngyro residual std per axis {std} rad/s (configured {p.gyro_noise_radps}); bias {bias}"
    )
    assert np.all(np.abs(bias) < 5 * p.gyro_bias_initial_radps)
    # Within 15 % of the configured noise (the brief allows a factor 1.5).
    np.testing.assert_allclose(std, p.gyro_noise_radps, rtol=0.15)
    # The reported covariance says the same.
    cov = np.asarray(imu["angular_velocity_covariance"])
    np.testing.assert_allclose(cov[:, [0, 4, 8]], p.gyro_noise_radps**2)
    acov = np.asarray(imu["linear_acceleration_covariance"])
    np.testing.assert_allclose(acov[:, [0, 4, 8]], p.accel_noise_mps2**2)


# -- GPS (its noise and drift against the truth: test_race_log.py, on the race log) ----------


def test_gps_dropouts(sample_log: SimLog) -> None:
    """During each listed dropout the receiver sends NO_FIX with NaN position, and the compass
    is silent; outside them every fix is valid and the compass speaks at every tick."""
    p = _params("sample").gps
    period = int(round(NS / p.rate_hz))
    dropouts = sample_log.json("gps_dropouts_ns")
    fix = sample_log.columns["/gps/fix"]
    t = on_grid_true_times(
        sample_log.stamps("/gps/fix"),
        sample_log.clock_offsets["/gps/fix"],
        sample_log.start_ns,
        period,
    )
    lost = _dropout_mask(t, dropouts)
    assert lost.sum() >= 20, "the sample log should contain at least one dropout"
    status = np.asarray(fix["status.status"])
    lat, lon = np.asarray(fix["latitude"]), np.asarray(fix["longitude"])
    np.testing.assert_array_equal(status[lost], -1)
    assert np.isnan(lat[lost]).all() and np.isnan(lon[lost]).all()
    assert (status[~lost] >= 0).all()
    assert np.isfinite(lat[~lost]).all() and np.isfinite(lon[~lost]).all()

    th = on_grid_true_times(
        sample_log.stamps("/gps/heading"),
        sample_log.clock_offsets["/gps/heading"],
        sample_log.start_ns,
        int(round(NS / p.heading_rate_hz)),
    )
    assert not _dropout_mask(th, dropouts).any()
    # Same rate, same grid: the compass speaks exactly at the fixes outside dropouts.
    np.testing.assert_array_equal(np.sort(th), np.sort(t[~lost]))
    print(f"\nGPS dropouts: {lost.sum()} NO_FIX fixes of {t.size}; {th.size} headings")


# -- extrinsics -------------------------------------------------------------------------------


def test_tf_static_holds_every_mount(sample_log: SimLog) -> None:
    p = _params("sample")
    mounts: list[Mount] = [*p.laser.mounts, p.imu.mount, p.gps.mount]
    assert [m.frame_id for m in p.laser.mounts] == list(LASER_FRAMES)
    tf = sample_log.columns["/tf_static"]["transforms"][0]
    assert sorted(tf["child_frame_id"].tolist()) == sorted(m.frame_id for m in mounts)
    assert set(tf["header.frame_id"].tolist()) == {"base_link"}
    for m in mounts:
        xyz, q = sample_log.static_transform(m.frame_id)
        np.testing.assert_allclose(xyz, m.xyz_m, atol=1e-12)
        expected = _quat_zyx(*m.rpy_rad)
        if np.dot(q, expected) < 0:
            expected = -expected
        np.testing.assert_allclose(q, expected, atol=1e-12)
    # The lasers look down and forward: centre beams meet flat ground ahead of the car.
    for m in p.laser.mounts:
        roll, pitch, yaw = m.rpy_rad
        assert 0.03 < pitch < 0.5 and roll == 0.0 and yaw == 0.0


# -- read-back --------------------------------------------------------------------------------


def test_whole_log_decodes_with_reference_decoder(
    sample_log: SimLog, sample_result: SimResult
) -> None:
    """Every message decodes with mcap_ros2's own decoder, and agrees with the columns."""
    counts: Counter[str] = Counter()
    stamps: dict[str, list[int]] = {}
    imu_z: list[float] = []
    laser_ranges: list[np.ndarray] = []
    with open(sample_result.path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if hasattr(msg, "header"):
                stamps.setdefault(channel.topic, []).append(
                    msg.header.stamp.sec * NS + msg.header.stamp.nanosec
                )
            if channel.topic == "/imu/data":
                imu_z.append(msg.linear_acceleration.z)
            elif channel.topic == LASER_TOPICS[0]:
                laser_ranges.append(np.asarray(msg.ranges, dtype=np.float32))
                assert len(msg.ranges) == 181
            elif channel.topic == "/tf_static":
                assert len(msg.transforms) == 7
            elif channel.topic == "/truth/features":
                assert len(msg.features) == sample_result.feature_count
    assert dict(counts) == sample_result.message_counts
    # Every message of a whole minute: five lasers at 75 Hz, IMU, wheels and truth at 100 Hz,
    # GPS and compass at 10 Hz, some 690 a second.
    assert sample_result.duration_s > 50.0
    assert sum(counts.values()) > 650 * sample_result.duration_s
    for topic, st in stamps.items():
        np.testing.assert_array_equal(np.asarray(st), sample_log.stamps(topic), err_msg=topic)
    np.testing.assert_array_equal(imu_z, sample_log.columns["/imu/data"]["linear_acceleration.z"])
    np.testing.assert_array_equal(
        np.stack(laser_ranges), sample_log.columns[LASER_TOPICS[0]]["ranges"]
    )
