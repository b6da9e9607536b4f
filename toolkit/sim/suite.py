"""Every sensor of the simulated vehicle sampled from the true state, with its errors, and
encoded as the log's messages: IMU, wheel speeds, GPS fix and compass, the true odometry,
and the laser scans (rays planned here, cast by :mod:`toolkit.sim.laser_workers`).

Each sensor family draws its noise from a generator of its own, so a log without lasers is
the same log less its scans (see :class:`SensorSuite`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.geometry.map_frame import grid_minus_true_yaw_rad, world_to_geodetic
from toolkit.mcapio.cdr_encode import Column, encode_batch
from toolkit.sim.drive import TrueBlock
from toolkit.sim.laser_workers import LaserRays
from toolkit.sim.lidar_scan import LidarSensor
from toolkit.sim.messages import (
    BASE_FRAME,
    COVARIANCE_TYPE_DIAGONAL_KNOWN,
    COVARIANCE_TYPE_UNKNOWN,
    NAVSAT_SERVICE_GPS,
    NAVSAT_STATUS_GBAS_FIX,
    NAVSAT_STATUS_NO_FIX,
    TOPIC_GPS,
    TOPIC_HEADING,
    TOPIC_IMU,
    TOPIC_LASER,
    TOPIC_TRUTH_ODOM,
    TOPIC_WHEELS,
    WORLD_FRAME,
    Outbox,
    header_columns,
    quat_columns,
    vector_columns,
)
from toolkit.sim.profiles import SimProfile
from toolkit.sim.sensor_pose import flex_pitch, pose_at
from toolkit.sim.sensors import SensorParams, draw_laser_truth, gauss_markov
from toolkit.sim.world import World

BLOCK_SAMPLES = 100  # 0.1 s at the 1 kHz dynamics rate


def wrap_angle(a: FloatArray) -> FloatArray:
    """Angles wrapped to ``[-pi, pi)``."""
    return (a + np.pi) % (2 * np.pi) - np.pi


@dataclass
class _Clock:
    """One sensor's clock: a fixed offset, stamp jitter and transport latency (ns)."""

    offset_ns: int
    jitter_ns: float
    latency_ns: tuple[int, int]

    def stamps(self, rng: np.random.Generator, t_true_ns: NDArray[np.int64]) -> NDArray[np.int64]:
        jitter = np.clip(
            rng.normal(0.0, self.jitter_ns, t_true_ns.size), -3 * self.jitter_ns, 3 * self.jitter_ns
        )
        return t_true_ns + self.offset_ns + np.round(jitter).astype(np.int64)

    def log_times(
        self, rng: np.random.Generator, t_true_ns: NDArray[np.int64]
    ) -> NDArray[np.int64]:
        lo, hi = self.latency_ns
        return t_true_ns + rng.integers(lo, hi, t_true_ns.size, endpoint=True)


@dataclass(frozen=True)
class ImuSamples:
    """One block's IMU samples: true times ``t_true_ns`` (n,), specific force
    ``accel_mps2`` (n, 3) and rates ``gyro_radps`` (n, 3) in the IMU frame, errors included."""

    t_true_ns: NDArray[np.int64]
    accel_mps2: FloatArray
    gyro_radps: FloatArray


class SensorSuite:
    """Samples every sensor from the true state, with the errors of :class:`SensorParams`."""

    def __init__(self, profile: SimProfile, world: World, seed: int, start_ns: int) -> None:
        self.p: SensorParams = profile.sensors
        self.profile = profile
        self.world = world
        self.start_ns = start_ns
        # Each sensor family draws its noise from a generator of its own: the lasers only from
        # laser_rng, the IMU from imu_rng, GPS, compass and wheels from rng. So a log made
        # without lasers (--no-lasers) is the same log less its scans, and a change to the
        # laser model leaves every other sensor's noise as it was.
        self.rng = np.random.default_rng([seed, 11])
        self.imu_rng = np.random.default_rng([seed, 15])
        clock_rng = np.random.default_rng([seed, 12])
        c = self.p.clock
        self.clocks: dict[str, _Clock] = {}
        self.topics_laser = [TOPIC_LASER.format(i + 1) for i in range(len(self.p.laser.mounts))]
        for topic in [*self.topics_laser, TOPIC_IMU, TOPIC_GPS, TOPIC_HEADING, TOPIC_WHEELS]:
            self.clocks[topic] = _Clock(
                offset_ns=int(round(clock_rng.uniform(-c.offset_max_s, c.offset_max_s) * 1e9)),
                jitter_ns=c.jitter_std_s * 1e9,
                latency_ns=(int(c.latency_range_s[0] * 1e9), int(c.latency_range_s[1] * 1e9)),
            )
        self.clocks[TOPIC_TRUTH_ODOM] = _Clock(0, 0.0, (0, 0))
        period = 1e9 / self.p.laser.rate_hz
        self.laser_phase_ns = clock_rng.uniform(0, period, len(self.p.laser.mounts))
        imu = self.p.imu
        bias_rng = np.random.default_rng([seed, 13])
        self.accel_bias = bias_rng.normal(0, imu.accel_bias_initial_mps2, 3)
        self.gyro_bias = bias_rng.normal(0, imu.gyro_bias_initial_radps, 3)
        self.wheel_scale = 1.0 + bias_rng.normal(0, self.p.wheels.scale_error_std, 4)
        self.gps_drift = bias_rng.normal(0, self.p.gps.drift_std_m, 3)
        self.dropouts = self._dropouts(np.random.default_rng([seed, 14]))
        beams = self.p.laser.beams
        angles = self.p.laser.angle_min_rad + np.arange(beams) * self.p.laser.angle_increment_rad
        dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros(beams)])
        # The lasers' true mounts (the published ones are miscalibrated) and range biases.
        self.laser_truth = draw_laser_truth(self.p.laser, seed)
        self._beam_dirs_base = [m.rotation() @ dirs for m in self.laser_truth.mounts]  # (3, beams)
        self.laser_rng = np.random.default_rng([seed, 16])
        self._dust_until_ns = np.full(len(self.p.laser.mounts), np.iinfo(np.int64).min)
        self._dust_sector = np.zeros((len(self.p.laser.mounts), 2), dtype=np.intp)
        # The lidar draws from generators of its own too (toolkit.sim.lidar).
        self.lidar = (
            None
            if profile.lidar is None
            else LidarSensor(profile.lidar, seed, start_ns, self.p.clock)
        )

    # -- schedules --------------------------------------------------------------------------

    def _dropouts(self, rng: np.random.Generator) -> list[tuple[int, int]]:
        """GPS dropout intervals [start, end) in true time (ns), for up to 3 hours of log."""
        g = self.p.gps
        out = [
            (self.start_ns + int(t * 1e9), self.start_ns + int((t + dur) * 1e9))
            for t, dur in g.scheduled_dropouts_s
        ]
        if g.dropouts_per_hour <= 0:
            return sorted(out)
        t = 0.0
        while t < 3 * 3600.0:
            t += rng.exponential(3600.0 / g.dropouts_per_hour)
            dur = rng.uniform(*g.dropout_duration_s)
            out.append((self.start_ns + int(t * 1e9), self.start_ns + int((t + dur) * 1e9)))
            t += dur
        return sorted(out)

    def in_dropout(self, t_ns: NDArray[np.int64]) -> NDArray[np.bool_]:
        mask = np.zeros(t_ns.size, dtype=bool)
        for lo, hi in self.dropouts:
            if lo > t_ns[-1]:
                break
            mask |= (t_ns >= lo) & (t_ns < hi)
        return mask

    def _ticks(self, block: TrueBlock, rate_hz: float) -> NDArray[np.intp]:
        """Indices of the block's samples that fall on a ``rate_hz`` tick."""
        return self._ticks_of(block.t_ns, rate_hz)

    def _ticks_of(self, t_ns: NDArray[np.int64], rate_hz: float) -> NDArray[np.intp]:
        """Indices of the true times ``t_ns`` (ns) that fall on a ``rate_hz`` tick of the
        log's clock (ticks at ``start_ns + j / rate_hz``)."""
        period_ns = int(round(1e9 / rate_hz))
        return np.flatnonzero((t_ns - self.start_ns) % period_ns == 0)

    def _publish(
        self,
        out: Outbox,
        topic: str,
        t_true: NDArray[np.int64],
        frame_id: str,
        schema: str,
        fields: dict[str, Column],
    ) -> None:
        """Messages of ``schema`` on ``topic``, one per true time ``t_true`` (ns): a header
        stamped by the topic's clock (in ``frame_id``), then ``fields``; logged when that
        clock says they arrive."""
        clock = self.clocks[topic]
        cols = {**header_columns(clock.stamps(self.rng, t_true), frame_id), **fields}
        out.add(topic, clock.log_times(self.rng, t_true), encode_batch(schema, cols))

    # -- sensors ----------------------------------------------------------------------------

    def sample_imu(self, ext: TrueBlock, first: int) -> ImuSamples | None:
        """The IMU's 100 Hz samples over the block that starts at ``first`` of ``ext``, each
        the mean over its 10 ms (what an integrating IMU reports), with noise and bias.

        Drawn when the block is driven, from a generator of the IMU's own, so the speed
        controller can read them at once (:class:`~toolkit.sim.shock_meter.ShockMeter`)
        whatever the order the other sensors' messages are made in."""
        p = self.p.imu
        cur_t = ext.t_ns[first:]
        ticks = self._ticks_of(cur_t, p.rate_hz) + first
        if ticks.size == 0:
            return None
        per = int(round(1e9 / p.rate_hz / (ext.t_ns[1] - ext.t_ns[0])))
        idx = ticks[:, None] - np.arange(per)[None, ::-1]
        f = ext.specific_force_body_mps2[idx].mean(axis=1)
        w = ext.omega_body_radps[idx].mean(axis=1)
        n = ticks.size
        dt = 1.0 / p.rate_hz
        rng = self.imu_rng
        a_walk = np.cumsum(
            rng.normal(0, p.accel_bias_walk_mps2_per_sqrt_s * np.sqrt(dt), (n, 3)), 0
        )
        g_walk = np.cumsum(
            rng.normal(0, p.gyro_bias_walk_radps_per_sqrt_s * np.sqrt(dt), (n, 3)), 0
        )
        accel = f + self.accel_bias + a_walk + rng.normal(0, p.accel_noise_mps2, (n, 3))
        gyro = w + self.gyro_bias + g_walk + rng.normal(0, p.gyro_noise_radps, (n, 3))
        self.accel_bias = self.accel_bias + a_walk[-1]
        self.gyro_bias = self.gyro_bias + g_walk[-1]
        return ImuSamples(ext.t_ns[ticks], accel, gyro)

    def imu(self, samples: ImuSamples | None, out: Outbox) -> None:
        """The IMU's messages for samples drawn by :meth:`sample_imu`."""
        if samples is None:
            return
        p = self.p.imu
        fields: dict[str, Column] = {
            # No orientation estimate: covariance[0] = -1 by the sensor_msgs/Imu convention.
            "orientation_covariance": np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0]),
            **vector_columns("angular_velocity", samples.gyro_radps),
            "angular_velocity_covariance": np.diag([p.gyro_noise_radps**2] * 3).ravel(),
            **vector_columns("linear_acceleration", samples.accel_mps2),
            "linear_acceleration_covariance": np.diag([p.accel_noise_mps2**2] * 3).ravel(),
        }
        self._publish(
            out, TOPIC_IMU, samples.t_true_ns, p.mount.frame_id, "sensor_msgs/msg/Imu", fields
        )

    def wheels(self, block: TrueBlock, out: Outbox) -> None:
        p = self.p.wheels
        ticks = self._ticks(block, p.rate_hz)
        if ticks.size == 0:
            return
        speeds = block.wheel_speed_mps[ticks] * self.wheel_scale
        speeds = speeds + self.rng.normal(0, p.noise_mps, speeds.shape)
        t_true = block.t_ns[ticks]
        fields: dict[str, Column] = {
            "front_left": speeds[:, 0],
            "front_right": speeds[:, 1],
            "rear_left": speeds[:, 2],
            "rear_right": speeds[:, 3],
        }
        self._publish(out, TOPIC_WHEELS, t_true, BASE_FRAME, "terrain_msgs/msg/WheelSpeeds", fields)

    def gps(self, block: TrueBlock, out: Outbox) -> None:
        g = self.p.gps
        ticks = self._ticks(block, g.rate_hz)
        if ticks.size == 0:
            return
        n = ticks.size
        rot = block.world_from_base()[ticks]
        antenna = block.position_m[ticks] + rot.apply(np.asarray(g.mount.xyz_m))
        drift = gauss_markov(
            self.rng, n, 1.0 / g.rate_hz, g.drift_std_m, g.drift_tau_s, self.gps_drift
        )
        self.gps_drift = drift[-1]
        white = self.rng.normal(0, 1, (n, 3)) * np.array(
            [g.horizontal_noise_m, g.horizontal_noise_m, g.vertical_noise_m]
        )
        enu = antenna + drift + white
        lat, lon, alt = world_to_geodetic(enu, self.profile.origin)
        t_true = block.t_ns[ticks]
        lost = self.in_dropout(t_true)
        var_h = g.horizontal_noise_m**2 + g.drift_std_m**2
        var_v = g.vertical_noise_m**2 + g.drift_std_m**2
        cov = np.tile([var_h, 0, 0, 0, var_h, 0, 0, 0, var_v], (n, 1))
        cov[lost] = 0.0
        fields: dict[str, Column] = {
            "status.status": np.where(lost, NAVSAT_STATUS_NO_FIX, NAVSAT_STATUS_GBAS_FIX).astype(
                np.int8
            ),
            "status.service": np.uint16(NAVSAT_SERVICE_GPS),
            "latitude": np.where(lost, np.nan, lat),
            "longitude": np.where(lost, np.nan, lon),
            "altitude": np.where(lost, np.nan, alt),
            "position_covariance": cov,
            "position_covariance_type": np.where(
                lost, COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_DIAGONAL_KNOWN
            ).astype(np.uint8),
        }
        self._publish(out, TOPIC_GPS, t_true, g.mount.frame_id, "sensor_msgs/msg/NavSatFix", fields)

        ticks_h = self._ticks(block, g.heading_rate_hz)
        t_h = block.t_ns[ticks_h]
        ticks_h = ticks_h[~self.in_dropout(t_h)] if ticks_h.size else ticks_h
        if ticks_h.size == 0:
            return
        t_true = block.t_ns[ticks_h]
        # The compass reads true north; the world is a map whose north turns from it by the
        # meridian convergence (toolkit.geometry.map_frame).
        lat, lon, _ = world_to_geodetic(block.position_m[ticks_h], self.profile.origin)
        true_yaw = block.yaw_rad[ticks_h] - grid_minus_true_yaw_rad(lat, lon, self.profile.origin)
        yaw = wrap_angle(true_yaw + self.rng.normal(0, g.heading_noise_rad, ticks_h.size))
        fields = {"yaw": yaw, "yaw_std": np.full(ticks_h.size, g.heading_noise_rad)}
        self._publish(out, TOPIC_HEADING, t_true, BASE_FRAME, "terrain_msgs/msg/GpsHeading", fields)

    def truth(self, block: TrueBlock, out: Outbox) -> None:
        ticks = self._ticks(block, self.p.truth_rate_hz)
        if ticks.size == 0:
            return
        rot = block.world_from_base()[ticks]
        v_body = rot.apply(block.velocity_world_mps[ticks], inverse=True)
        t_true = block.t_ns[ticks]
        cols: dict[str, Column] = {
            **header_columns(t_true, WORLD_FRAME),
            "child_frame_id": BASE_FRAME,
            **vector_columns("pose.pose.position", block.position_m[ticks]),
            **quat_columns("pose.pose.orientation", rot.as_quat()),
            **vector_columns("twist.twist.linear", v_body),
            **vector_columns("twist.twist.angular", block.omega_body_radps[ticks]),
        }
        out.add(TOPIC_TRUTH_ODOM, t_true, encode_batch("nav_msgs/msg/Odometry", cols))

    def plan_lasers(self, ext: TrueBlock, first: int) -> LaserRays | None:
        """The rays of every scan that ends within this block, each beam cast from the
        sensor's true pose at the beam's own time: the vehicle's true pose, the laser's true
        (miscalibrated) mount, and the mount's flex under the body's specific force."""
        lp = self.p.laser
        period_ns = 1e9 / lp.rate_hz
        span_ns = (lp.beams - 1) * lp.time_increment_s * 1e9
        t0 = int(ext.t_ns[first])
        t_last = int(ext.t_ns[-1])
        dt_ns = int(ext.t_ns[1] - ext.t_ns[0])
        t_ext = (ext.t_ns - t0).astype(np.float64)
        frac = np.arange(lp.beams) / (lp.beams - 1)
        scans: list[tuple[int, int]] = []
        for i in range(len(lp.mounts)):
            # Scans whose last beam falls in (t0 - dt, t_last].
            base = self.start_ns + self.laser_phase_ns[i] + span_ns
            n_lo = int(np.floor((t0 - dt_ns - base) / period_ns)) + 1
            n_hi = int(np.floor((t_last - base) / period_ns))
            for n in range(max(n_lo, 0), n_hi + 1):
                start = self.start_ns + self.laser_phase_ns[i] + n * period_ns
                scans.append((i, int(round(start))))
        if not scans:
            return None
        starts = np.array([s for _, s in scans], dtype=np.int64)
        lasers_idx = np.array([i for i, _ in scans])
        t_start = (starts - t0).astype(np.float64)
        t_end = t_start + span_ns
        rot0, pos0 = self._pose_at(ext, t_ext, t_start)
        rot1, pos1 = self._pose_at(ext, t_ext, t_end)
        # The mounts flex: a pitch about base_link's y axis at the laser (so it turns the
        # beams, not where they start), quasi-static in the specific force (LaserParams).
        turn0 = rot0 @ self._flex_pitch(ext, t_ext, t_start)
        turn1 = rot1 @ self._flex_pitch(ext, t_ext, t_end)
        # Beams sweep during the scan: interpolate the sensor's pose between the scan's
        # first and last beam (rotations of a few mrad, so linear is exact to 1e-5).
        origin = np.empty((len(scans), lp.beams, 3))
        direction = np.empty((len(scans), lp.beams, 3))
        for i, mount in enumerate(self.laser_truth.mounts):
            rows = np.flatnonzero(lasers_idx == i)
            if rows.size == 0:
                continue
            m = np.asarray(mount.xyz_m)
            v = self._beam_dirs_base[i]  # (3, beams)
            o0 = pos0[rows] + rot0[rows] @ m
            o1 = pos1[rows] + rot1[rows] @ m
            d0 = np.einsum("kij,jb->kbi", turn0[rows], v)
            d1 = np.einsum("kij,jb->kbi", turn1[rows], v)
            origin[rows] = o0[:, None, :] + (o1 - o0)[:, None, :] * frac[None, :, None]
            direction[rows] = d0 + (d1 - d0) * frac[None, :, None]
        direction /= np.linalg.norm(direction, axis=2, keepdims=True)
        s_mid = float(ext.s_m[min(first + BLOCK_SAMPLES // 2, ext.s_m.size - 1)])
        return LaserRays(
            starts_ns=starts,
            laser_index=lasers_idx,
            speed_mps=np.interp(t_start, t_ext, ext.speed_mps),
            origin=origin.reshape(-1, 3),
            direction=direction.reshape(-1, 3),
            s_hint_m=s_mid + 15.0,
            s_lo_m=float(ext.s_m[first]) - 5.0,
            s_hi_m=float(ext.s_m[-1]) + lp.range_max_m + 20.0,
        )

    def finish_lasers(self, rays: LaserRays, ranges: FloatArray, out: Outbox) -> None:
        """The scans' measured ranges (:meth:`measured_ranges`), their stamps (with the
        host's jitter) and their encoding."""
        lp = self.p.laser
        span_ns = (lp.beams - 1) * lp.time_increment_s * 1e9
        starts, lasers_idx = rays.starts_ns, rays.laser_index
        ranges = self.measured_ranges(rays, ranges)
        jitter_ns = lp.stamp_jitter_s * 1e9
        for i, mount in enumerate(lp.mounts):
            rows = np.flatnonzero(lasers_idx == i)
            if rows.size == 0:
                continue
            topic = self.topics_laser[i]
            clock = self.clocks[topic]
            t_true = starts[rows]
            host = np.clip(
                self.laser_rng.normal(0.0, jitter_ns, rows.size), -3 * jitter_ns, 3 * jitter_ns
            )
            stamps = clock.stamps(self.laser_rng, t_true) + np.round(host).astype(np.int64)
            cols = {
                **header_columns(stamps, mount.frame_id),
                "angle_min": lp.angle_min_rad,
                "angle_max": lp.angle_min_rad + (lp.beams - 1) * lp.angle_increment_rad,
                "angle_increment": lp.angle_increment_rad,
                "time_increment": lp.time_increment_s,
                "scan_time": 1.0 / lp.rate_hz,
                "range_min": lp.range_min_m,
                "range_max": lp.range_max_m,
                "ranges": ranges[rows],
            }
            # The scan is published once complete.
            out.add(
                topic,
                clock.log_times(self.laser_rng, t_true + int(span_ns)),
                encode_batch("sensor_msgs/msg/LaserScan", cols),
            )

    def measured_ranges(self, rays: LaserRays, ranges: FloatArray) -> NDArray[np.float32]:
        """What the scanners report (n_scans, beams) for the footprint ranges ``ranges``
        (n_scans * beams,; inf: no return): plus each laser's constant bias and the
        statistical noise, random dropouts (inf), out-of-range readings (inf), dust (NaN),
        quantised to ``range_resolution_m``."""
        lp = self.p.laser
        n_scans = rays.starts_ns.size
        bias = np.asarray(self.laser_truth.range_bias_m)[rays.laser_index]
        ranges = ranges + np.repeat(bias, lp.beams)
        ranges = ranges + self.laser_rng.normal(0, lp.range_noise_m, ranges.size)
        ranges[self.laser_rng.random(ranges.size) < lp.dropout_probability] = np.inf
        ranges[(ranges < lp.range_min_m) | (ranges > lp.range_max_m)] = np.inf
        ranges = ranges.reshape(n_scans, lp.beams)
        ranges[self._dust(rays)] = np.nan
        # The scanner reports ranges in counts of range_resolution_m (NaN and inf stay).
        ranges = np.round(ranges / lp.range_resolution_m) * lp.range_resolution_m
        return ranges.astype(np.float32)

    def _dust(self, rays: LaserRays) -> NDArray[np.bool_]:
        """Beams (n_scans, beams) lost in dust. Per laser a dust episode starts at a rate
        growing with speed, lasts an exponential time and hides one sector of beams in part
        (LaserParams); the state carries over from block to block. One step per scan (not per
        beam): an episode is a run of scans."""
        lp = self.p.laser
        lost = np.zeros((rays.starts_ns.size, lp.beams), dtype=bool)
        if lp.dust_onset_per_s <= 0:
            return lost
        rng = self.laser_rng
        period_s = 1.0 / lp.rate_hz
        p_start = 1.0 - np.exp(-lp.dust_onset_per_s * rays.speed_mps / 10.0 * period_s)
        draws = rng.random(rays.starts_ns.size)
        beam = np.arange(lp.beams)
        for row in np.argsort(rays.starts_ns, kind="stable"):
            i = int(rays.laser_index[row])
            start = int(rays.starts_ns[row])
            if start >= self._dust_until_ns[i] and draws[row] < p_start[row]:
                duration_ns = int(rng.exponential(lp.dust_duration_s) * 1e9)
                self._dust_until_ns[i] = start + duration_ns
                width = int(rng.integers(lp.dust_sector_beams[0], lp.dust_sector_beams[1] + 1))
                first = int(rng.integers(0, lp.beams - width + 1))
                self._dust_sector[i] = (first, first + width)
            if start < self._dust_until_ns[i]:
                lo, hi = self._dust_sector[i]
                lost[row] = (beam >= lo) & (beam < hi)
        dusty = lost.any(axis=1)
        lost[dusty] &= rng.random((int(dusty.sum()), lp.beams)) < lp.dust_drop_probability
        return lost

    def _flex_pitch(self, ext: TrueBlock, t_ext: FloatArray, t: FloatArray) -> FloatArray:
        """The lasers' mounts' flex at times ``t`` (k,): rotations (k, 3, 3)."""
        return flex_pitch(ext, t_ext, t, self.p.laser.flex_pitch_rad_per_mps2)

    @staticmethod
    def _pose_at(ext: TrueBlock, t_ext: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``world_from_base`` rotations (k, 3, 3) and positions (k, 3) at times ``t``."""
        return pose_at(ext, t_ext, t)
