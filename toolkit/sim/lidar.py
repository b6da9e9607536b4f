"""The spinning 3-D lidar (an Ouster OS1-32 on the roof): its parameters, its beams'
directions and timing, and the draws that make it err (its true mount, per-beam biases).

Off unless asked for (``terrain sim --lidar``, :attr:`toolkit.sim.profiles.SimProfile.lidar`);
it draws only from random streams of its own (:func:`draw_lidar_truth`), so a log without it
is byte for byte the log the simulator wrote before the lidar existed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.sensors import Mount

#: The random stream of the lidar's per-log draws (mount, biases, clock, phase); 19 draws
#: its per-scan noise. Streams 11-17 are the other sensors' (:func:`draw_laser_truth`).
LIDAR_TRUTH_STREAM = 18
LIDAR_NOISE_STREAM = 19


@dataclass(frozen=True)
class LidarParams:
    """An Ouster OS1-32 (uniform beam spacing) in its 512 x 10 Hz mode, and how it errs.

    Sources: Ouster OS1 datasheet (Rev 6/7, as recalled: the sheet was not at hand here) and
    the OS1 user guide's "Coordinate Frames and XYZ Calculation" (v1.14, Sect. 8) for the
    frames and the column order. Where a value is judgement it says so.

    Geometry and timing:

    * ``beams`` 32 channels, altitudes uniform from ``altitude_max_rad`` +22.5 deg down to
      -22.5 deg (the OS1's 45 deg vertical field of view; "uniform" beam configuration), so
      1.45 deg apart; ring 0 is the top beam (ouster-ros's ``ring``). The OS1's per-beam
      azimuth offsets (about +-3 deg, so beams of one column fire staggered in azimuth) are
      left out: every beam of a column points at the column's azimuth.
    * ``columns`` 512 per turn at ``rate_hz`` 10: a column every 195.3 us, 0.70 deg apart.
      Column 0 points backwards (-x of ``os_sensor``) and the head turns clockwise seen from
      above (the user guide's encoder angle ``2 pi (1 - m / W)`` in the lidar frame, which is
      turned 180 deg about z from the sensor frame): column 128 looks left, 256 ahead.
    * ``lidar_origin_z_m`` 36.18 mm: the lidar frame's origin above the sensor frame's
      (``lidar_to_sensor_transform``); the beams' own 15.8 mm radial offset from it
      (``lidar_origin_to_beam_origin_mm``) is left out.

    Range:

    * ``range_min_m`` 0.5 m (Rev 7 minimum range); ``range_max_m`` 100 m (the datasheet's
      range at 90 % detection probability on an 80 % target; on dark ground at grazing
      incidence real returns end sooner, which the drive's geometry mostly does anyway:
      the lowest beam below the horizon meets flat ground 150 m away from 1.9 m up).
    * ``range_noise_m``: precision (1 sigma) by range band, ``range_noise_bands_m`` the
      bands' upper ends: 1 cm to 20 m, 2 cm to 50 m, 5 cm beyond (the datasheet's table for
      Lambertian targets).
    * ``range_bias_max_m`` 3 cm: the datasheet's accuracy (+-3 cm, Lambertian) taken as the
      systematic part, constant per beam (each channel has its own detector and timing
      calibration): each beam draws a bias uniform in +-this, per seed (judgement).
    * ``range_resolution_m`` 1 mm: the range field counts millimetres.
    * ``beam_divergence_rad`` 0.18 deg full angle (FWHM, 3.1 mrad): the footprint and its
      mixed pixels as for the 2-D lasers (:class:`~toolkit.sim.raycast.RayCaster`: the cone
      in the ray's vertical plane, where the spot on the ground is long), with the same
      sample counts (:class:`~toolkit.sim.sensors.LaserParams`).

    Dropouts and dust as the 2-D lasers' (:class:`~toolkit.sim.sensors.LaserParams`,
    judgement): single points at random with ``dropout_probability``; a dust episode (onset
    ``dust_onset_per_s`` x speed / (10 m/s), mean length ``dust_duration_s``) hides, in each
    of its scans, each point of one azimuth sector of ``dust_sector_columns`` columns (all
    beams) with ``dust_drop_probability``. A lost point is what ouster-ros writes for no
    return: range 0 and x = y = z = 0.

    Echo strength (judgement; no terrain reflectance is simulated): ``reflectivity`` 35 (%:
    dry desert soil in the near infrared), ``intensity`` (signal photons) ``signal_at_10m``
    x (10 m / range)^2, ``ambient`` a constant daylight level. No return: intensity and
    reflectivity 0.

    Extrinsics: ``/tf_static`` publishes ``mount``; the true one differs by a roll, pitch and
    yaw error each uniform in +-``mount_angle_error_rad`` and a position error uniform in
    +-``mount_xyz_error_m`` an axis (judgement: as for one 2-D laser, rack and own error
    together). Flex: the pitch moves with the body's specific force as the 2-D lasers' do
    (``flex_pitch_rad_per_mps2``, the same bracket model: judgement).

    Timing: the OS1 stamps each column itself (no host jitter); its clock's offset from the
    log's clock is uniform in +-:attr:`ClockParams.offset_max_s` per log, and a scan is
    logged once its last column is in, after a latency uniform in
    :attr:`ClockParams.latency_range_s`.
    """

    beams: int = 32
    columns: int = 512
    rate_hz: float = 10.0
    altitude_max_rad: float = float(np.radians(22.5))
    altitude_min_rad: float = float(np.radians(-22.5))
    lidar_origin_z_m: float = 0.03618
    range_min_m: float = 0.5
    range_max_m: float = 100.0
    range_noise_bands_m: tuple[float, ...] = (20.0, 50.0)
    range_noise_m: tuple[float, ...] = (0.01, 0.02, 0.05)
    range_bias_max_m: float = 0.03
    range_resolution_m: float = 0.001
    beam_divergence_rad: float = float(np.radians(0.18))
    footprint_samples: int = 12
    footprint_spacing_m: float = 0.12
    occluder_samples: int = 8
    occluder_spacing_m: float = 0.3
    occluder_height_m: float = 0.2
    dropout_probability: float = 0.002
    dust_onset_per_s: float = 0.1
    dust_duration_s: float = 0.5
    dust_sector_columns: tuple[int, int] = (40, 160)
    dust_drop_probability: float = 0.5
    reflectivity: int = 35
    signal_at_10m: float = 600.0
    ambient: int = 300
    mount_angle_error_rad: float = float(np.radians(0.2))
    mount_xyz_error_m: float = 0.015
    flex_pitch_rad_per_mps2: float = 4e-4
    # On the roof's middle, level: the upper half of the beams looks above the horizon.
    mount: Mount = field(default_factory=lambda: Mount("os_sensor", (1.6, 0.0, 1.9)))

    @property
    def column_period_ns(self) -> float:
        """Time between two columns (ns): 195312.5 for 512 x 10 Hz."""
        return 1e9 / self.rate_hz / self.columns

    def altitudes_rad(self) -> FloatArray:
        """Each ring's altitude (beams,), ring 0 the highest (rad, up positive)."""
        alt: FloatArray = np.linspace(self.altitude_max_rad, self.altitude_min_rad, self.beams)
        return alt

    def azimuths_rad(self) -> FloatArray:
        """Each column's azimuth (columns,) in ``os_sensor`` (rad, from +x towards +y):
        pi - 2 pi c / columns (column 0 backwards, clockwise seen from above)."""
        az: FloatArray = np.pi - 2.0 * np.pi * np.arange(self.columns) / self.columns
        return az

    def directions(self) -> FloatArray:
        """Unit beam directions (columns, beams, 3) in ``os_sensor``."""
        az = self.azimuths_rad()[:, None]
        alt = self.altitudes_rad()[None, :]
        return np.stack(
            np.broadcast_arrays(np.cos(alt) * np.cos(az), np.cos(alt) * np.sin(az), np.sin(alt)),
            axis=2,
        )

    def noise_std_m(self, ranges_m: FloatArray) -> FloatArray:
        """The precision (1 sigma, m) at ``ranges_m`` (any shape)."""
        band = np.searchsorted(np.asarray(self.range_noise_bands_m), ranges_m)
        std: FloatArray = np.asarray(self.range_noise_m)[band]
        return std


def ideal_lidar(p: LidarParams) -> LidarParams:
    """``p`` with every error source but the precision and the quantisation switched off."""
    from dataclasses import replace

    return replace(
        p,
        range_bias_max_m=0.0,
        beam_divergence_rad=0.0,
        dropout_probability=0.0,
        dust_onset_per_s=0.0,
        mount_angle_error_rad=0.0,
        mount_xyz_error_m=0.0,
        flex_pitch_rad_per_mps2=0.0,
    )


@dataclass(frozen=True)
class LidarTruth:
    """What one log's lidar truly is (drawn once per seed): its true mount (the published
    one plus its miscalibration), each ring's range bias (m), its clock's offset from the
    log's clock (ns) and its phase: the true time of the first scan's first column after
    the log's start is ``start_time_ns + phase_ns``."""

    mount: Mount
    range_bias_m: tuple[float, ...]
    clock_offset_ns: int
    phase_ns: int


def draw_lidar_truth(p: LidarParams, seed: int, offset_max_s: float) -> LidarTruth:
    """The lidar's per-log draws, from a random stream of its own
    (:data:`LIDAR_TRUTH_STREAM`), so the other sensors' draws are as without it."""
    rng = np.random.default_rng([seed, LIDAR_TRUTH_STREAM])
    a = p.mount_angle_error_rad
    rpy = rng.uniform(-a, a, 3)
    xyz = rng.uniform(-p.mount_xyz_error_m, p.mount_xyz_error_m, 3)
    bias = rng.uniform(-p.range_bias_max_m, p.range_bias_max_m, p.beams)
    offset_ns = int(round(rng.uniform(-offset_max_s, offset_max_s) * 1e9))
    # Whole nanoseconds: added to a log time (1e18 ns), a float's ulp would be 256 ns.
    phase_ns = int(round(rng.uniform(0.0, 1e9 / p.rate_hz)))
    m = p.mount
    mount = Mount(
        m.frame_id,
        (m.xyz_m[0] + float(xyz[0]), m.xyz_m[1] + float(xyz[1]), m.xyz_m[2] + float(xyz[2])),
        (
            m.rpy_rad[0] + float(rpy[0]),
            m.rpy_rad[1] + float(rpy[1]),
            m.rpy_rad[2] + float(rpy[2]),
        ),
    )
    return LidarTruth(mount, tuple(float(b) for b in bias), offset_ns, phase_ns)
