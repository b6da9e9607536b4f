"""Simulated sensors: where they sit, what they measure, and how they err.

Every sensor is simulated from the true state. The errors are the ones the paper's model has
to absorb (Sect. 3): range noise, pose-estimation error (from IMU, GPS, compass and wheel
errors) and latency (clock offsets and timestamp jitter between sensors).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.config import default_config


@dataclass(frozen=True)
class Mount:
    """A sensor's pose in ``base_link``: position (m) and roll, pitch, yaw (rad)."""

    frame_id: str
    xyz_m: tuple[float, float, float]
    rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation(self) -> FloatArray:
        """``base_link_from_sensor`` rotation matrix (3, 3)."""
        r, p, y = self.rpy_rad
        matrix: FloatArray = Rotation.from_euler("ZYX", [y, p, r]).as_matrix()
        return matrix


def _vehicle_mount(which: str) -> Mount:
    """The IMU's or GPS antenna's mount as the default configuration's ``[vehicle]`` gives it,
    so the simulator writes into ``/tf_static`` exactly what the pose stage falls back to
    when a log has none (one source for both)."""
    v = default_config().vehicle
    if which == "imu":
        x, y, z = v.imu_position_m
        roll, pitch, yaw = v.imu_orientation_rad
        return Mount(v.imu_frame, (x, y, z), (roll, pitch, yaw))
    x, y, z = v.gps_antenna_position_m
    return Mount(v.gps_frame, (x, y, z))


def laser_mounts(
    reach_m: tuple[float, ...] = (8.0, 11.5, 15.0, 19.5, 25.0),
    x_m: float = 2.2,
    height_m: float = 2.05,
) -> tuple[Mount, ...]:
    """Roof-mounted scanners tilted down so their centre beams meet flat ground ``reach_m``
    ahead of the rear axle (pitch positive is nose-down)."""
    spread = np.linspace(-0.3, 0.3, len(reach_m))
    return tuple(
        Mount(
            f"laser_{i + 1}",
            (x_m, float(spread[i]), height_m),
            (0.0, float(np.arctan2(height_m, reach - x_m)), 0.0),
        )
        for i, reach in enumerate(reach_m)
    )


@dataclass(frozen=True)
class LaserParams:
    """Stanley's SICK LMS 291 scanners, and how they err.

    Geometry (Thrun et al. 2006, "Stanley: The robot that won the DARPA Grand Challenge",
    J. Field Robotics 23(9), Sect. 2 and 5; Stavens & Thrun 2006, Sect. 3): five scanners on
    the roof rack, tilted down at different angles, 181 beams at 0.5 degree, 75 Hz each.

    Range (SICK LMS 291 technical data, cm mode, as recalled: the sheet itself was not at
    hand here; SICK's own split of a device's error into a systematic part, constant for one
    device, and a statistical part, new every reading, is from its knowledge base "Measurement
    Errors LMSxxx", which gives +-30 mm and 12 mm for the LMS1xx, the same class):

    * ``range_noise_m``: statistical error, 1 sigma: 10 mm.
    * ``range_bias_max_m``: systematic error, typ. +-35 mm: each laser draws one constant
      bias, uniform in +-this, per seed (:func:`draw_laser_truth`).
    * ``range_resolution_m``: 10 mm, the cm mode's count (its 13-bit range word reaches
      81.91 m; the LMS 2xx telegram listing, and the Player ``sicklms200`` driver's
      ``range_res 10``: "10mm precision, 81.92m max range").
    * ``beam_divergence_rad``: 0.25 degree full angle (4.4 mrad; the spot grows 4.4 mm per
      metre of range). The return is the energy-weighted mean range of the ground the
      beam's cone lights, seen in the scan's elevation with occlusion
      (:class:`~toolkit.sim.raycast.RayCaster`), from up to ``footprint_samples`` sub-rays
      ``footprint_spacing_m`` apart on the ground and up to ``occluder_samples`` points
      ``occluder_spacing_m`` apart before the footprint, which catch what is up to
      ``occluder_height_m`` tall (the tallest rocks) there; lateral spread is neglected (see
      there). These sample counts give ranges
      within 5 cm RMS of 48 + 24 samples on a race log (judgement: numerics, not physics).

    Dropouts: single beams at random with ``dropout_probability`` (judgement), and dust
    (judgement: a desert race raises dust, more the faster it goes): per laser, a dust
    episode starts at ``dust_onset_per_s`` x speed / (10 m/s), lasts an exponential time of
    mean ``dust_duration_s``, and in each of its scans drops each beam of one contiguous
    sector of ``dust_sector_beams`` (uniform) with ``dust_drop_probability``. A dust dropout
    is NaN (REP 117: an invalid reading); no return within range is +inf.

    Extrinsics: ``/tf_static`` publishes ``mounts``; the lasers' true mounts differ by the
    rack's common pitch and roll error (each of magnitude uniform in ``rack_angle_error_rad``,
    random sign: the rack is calibrated to the IMU as one unit) plus each laser's own roll,
    pitch and yaw error (uniform in +-``laser_angle_error_rad``) and position error (each
    axis uniform in +-``mount_xyz_error_m``): up to 0.3 degree and 1.5 cm an axis (judgement:
    a calibration good to a few tenths of a degree; Thrun et al. 2006 Sect. 5 show that
    angular errors under half a degree already make false obstacles).

    Flex: each laser's pitch also moves with the body's specific force ``f`` (base frame,
    from the 1 kHz truth) by ``flex_pitch_rad_per_mps2 * ((f_z - g) - f_x)``: the laser's
    mass sits ahead of and above its bracket's hinge, so an upward and a braking
    acceleration both pitch it nose-down. Stiffness assumption (judgement): the laser's pitch
    mode on its bracket is near 25 Hz with its mass 0.1 m from the hinge, so the deflection is
    quasi-static below 25 Hz, ``a / (L omega_n^2)`` = 0.4 mrad per m/s^2 (0.23 degree per g).
    The static 1 g sag is part of the calibrated mount.

    Timing: each scan's stamp has, besides its clock's offset and jitter (:class:`ClockParams`),
    a jitter of ``stamp_jitter_s`` (1 sigma, clipped at 3 sigma): the LMS 291 stamps nothing,
    the host stamps a scan as it arrives over RS-422 (about 7 ms of transmission at 500 kbaud)
    and its scheduling varies by a millisecond or so (judgement; Stavens & Thrun Sect. 3:
    "communication latencies").
    """

    rate_hz: float = 75.0
    beams: int = 181
    angle_min_rad: float = float(np.radians(-45.0))
    angle_increment_rad: float = float(np.radians(0.5))
    # The mirror turns once per scan; the 181 beams span a quarter of a turn.
    time_increment_s: float = 1.0 / 75.0 / 720.0
    range_min_m: float = 0.5
    range_max_m: float = 80.0
    range_noise_m: float = 0.010
    range_bias_max_m: float = 0.035
    range_resolution_m: float = 0.01
    beam_divergence_rad: float = float(np.radians(0.25))
    footprint_samples: int = 12
    footprint_spacing_m: float = 0.12
    occluder_samples: int = 8
    occluder_spacing_m: float = 0.3
    occluder_height_m: float = 0.2
    dropout_probability: float = 0.002
    dust_onset_per_s: float = 0.1
    dust_duration_s: float = 0.5
    dust_sector_beams: tuple[int, int] = (20, 90)
    dust_drop_probability: float = 0.5
    rack_angle_error_rad: tuple[float, float] = (float(np.radians(0.1)), float(np.radians(0.2)))
    laser_angle_error_rad: float = float(np.radians(0.1))
    mount_xyz_error_m: float = 0.015
    flex_pitch_rad_per_mps2: float = 4e-4
    stamp_jitter_s: float = 0.001
    mounts: tuple[Mount, ...] = field(default_factory=laser_mounts)


def ideal_lasers(p: LaserParams) -> LaserParams:
    """``p`` with every error source but the statistical range noise and the quantisation
    switched off: exact mounts, no bias, footprint, flex, dust, stamp jitter or dropouts."""
    return replace(
        p,
        range_bias_max_m=0.0,
        beam_divergence_rad=0.0,
        dropout_probability=0.0,
        dust_onset_per_s=0.0,
        rack_angle_error_rad=(0.0, 0.0),
        laser_angle_error_rad=0.0,
        mount_xyz_error_m=0.0,
        flex_pitch_rad_per_mps2=0.0,
        stamp_jitter_s=0.0,
    )


@dataclass(frozen=True)
class LaserTruth:
    """What one log's lasers truly are (drawn once per seed): each laser's true mount (the
    published one plus its miscalibration) and its range bias (m), in ``mounts`` order."""

    mounts: tuple[Mount, ...]
    range_bias_m: tuple[float, ...]


def draw_laser_truth(p: LaserParams, seed: int) -> LaserTruth:
    """The true mounts and range biases of a log's lasers, from their own random stream
    (17: streams 11-16 are the other sensors', :class:`toolkit.sim.suite.SensorSuite`;
    sharing one, as 15 did with the IMU's noise, would correlate the two)."""
    rng = np.random.default_rng([seed, 17])
    n = len(p.mounts)
    lo, hi = p.rack_angle_error_rad
    rack = rng.uniform(lo, hi, 2) * rng.choice([-1.0, 1.0], 2)  # roll, pitch
    a = p.laser_angle_error_rad
    own = rng.uniform(-a, a, (n, 3))  # roll, pitch, yaw
    xyz = rng.uniform(-p.mount_xyz_error_m, p.mount_xyz_error_m, (n, 3))
    bias = rng.uniform(-p.range_bias_max_m, p.range_bias_max_m, n)
    mounts = tuple(
        Mount(
            m.frame_id,
            (
                m.xyz_m[0] + float(xyz[i, 0]),
                m.xyz_m[1] + float(xyz[i, 1]),
                m.xyz_m[2] + float(xyz[i, 2]),
            ),
            (
                m.rpy_rad[0] + float(rack[0] + own[i, 0]),
                m.rpy_rad[1] + float(rack[1] + own[i, 1]),
                m.rpy_rad[2] + float(own[i, 2]),
            ),
        )
        for i, m in enumerate(p.mounts)
    )
    return LaserTruth(mounts, tuple(float(b) for b in bias))


@dataclass(frozen=True)
class ImuParams:
    """A tactical-grade IMU at 100 Hz. Noise per sample; bias random walks per sqrt(s)."""

    rate_hz: float = 100.0
    mount: Mount = field(default_factory=lambda: _vehicle_mount("imu"))
    accel_noise_mps2: float = 0.05
    gyro_noise_radps: float = 0.002
    accel_bias_initial_mps2: float = 0.05
    gyro_bias_initial_radps: float = 0.002
    accel_bias_walk_mps2_per_sqrt_s: float = 0.0005
    gyro_bias_walk_radps_per_sqrt_s: float = 1e-5


@dataclass(frozen=True)
class GpsParams:
    """A differential GPS at 10 Hz with white noise, slow drift and dropouts.

    The drift is a first-order Gauss-Markov process (``drift_std_m``, time constant
    ``drift_tau_s``). Dropouts arrive as a Poisson process and last 3-12 s; during one the
    receiver publishes fixes with status NO_FIX and NaN position, and the compass is silent.
    """

    rate_hz: float = 10.0
    mount: Mount = field(default_factory=lambda: _vehicle_mount("gps"))
    horizontal_noise_m: float = 0.10
    vertical_noise_m: float = 0.20
    drift_std_m: float = 0.15
    drift_tau_s: float = 120.0
    dropouts_per_hour: float = 20.0
    dropout_duration_s: tuple[float, float] = (3.0, 12.0)
    # Dropouts at fixed times (start_s after the log starts, duration_s), besides the random ones.
    scheduled_dropouts_s: tuple[tuple[float, float], ...] = ()
    heading_rate_hz: float = 10.0
    heading_noise_rad: float = 0.005


@dataclass(frozen=True)
class WheelParams:
    """Wheel-speed sensors at 100 Hz: per-wheel scale error and white noise."""

    rate_hz: float = 100.0
    scale_error_std: float = 0.005
    noise_mps: float = 0.03


@dataclass(frozen=True)
class ClockParams:
    """Per-sensor clock offsets (drawn once per log, up to ``offset_max_s``) and jitter."""

    offset_max_s: float = 0.004
    jitter_std_s: float = 0.0003
    latency_range_s: tuple[float, float] = (0.001, 0.004)


@dataclass(frozen=True)
class SensorParams:
    laser: LaserParams = field(default_factory=LaserParams)
    imu: ImuParams = field(default_factory=ImuParams)
    gps: GpsParams = field(default_factory=GpsParams)
    wheels: WheelParams = field(default_factory=WheelParams)
    clock: ClockParams = field(default_factory=ClockParams)
    truth_rate_hz: float = 100.0


# --------------------------------------------------------------------------------------------
# Noise processes


def gauss_markov(
    rng: np.random.Generator, n: int, dt_s: float, std: float, tau_s: float, x0: FloatArray
) -> FloatArray:
    """First-order Gauss-Markov samples (n, k) with stationary std ``std``, starting at x0."""
    phi = np.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, x0.size)) * std * np.sqrt(1 - phi**2)
    out, _ = lfilter([1.0], [1.0, -phi], w, axis=0, zi=phi * x0[None, :])
    return np.asarray(out)
