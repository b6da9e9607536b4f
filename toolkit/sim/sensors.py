"""Simulated sensors: where they sit, what they measure, and how they err.

Every sensor is simulated from the true state. The errors are the ones the paper's model has
to absorb (Sect. 3): range noise, pose-estimation error (from IMU, GPS, compass and wheel
errors) and latency (clock offsets and timestamp jitter between sensors).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from toolkit.config import default_config
from toolkit.sim.route import Route
from toolkit.sim.terrain import TerrainWindow

FloatArray = NDArray[np.floating[Any]]


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
      beam's cone lights, seen in the scan's elevation with occlusion (:class:`RayCaster`),
      from up to ``footprint_samples`` sub-rays ``footprint_spacing_m`` apart on the ground
      and up to ``occluder_samples`` points ``occluder_spacing_m`` apart before the
      footprint, which catch what is up to ``occluder_height_m`` tall (the tallest rocks)
      there; lateral spread is neglected (see there). These sample counts give ranges
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
    (17: streams 11-16 are the other sensors', :class:`toolkit.sim.simulate.SensorSuite`;
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
# Laser ray casting


@dataclass(frozen=True)
class RayCaster:
    """Finds where laser rays meet the terrain.

    For each ray ``p(t) = o + t u`` (``u`` unit, ``t`` the range), the ground is met where
    ``g(t) = o_z + t u_z - h(s(t), d(t))`` first turns negative. The search:

    1. estimate ``t_s`` against the smooth ground: the route elevation ``z0(s)`` and the
       cross profile;
    2. march from ``up_margin_m`` above that estimate in steps of ``step_dz_m`` of ray descent
       until ``g < 0`` (the first crossing, so rocks occlude what is behind them, up to the
       step's resolution);
    3. refine the bracket by the Illinois variant of regula falsi to well below a mm.

    Route coordinates along a ray come from a second-order expansion around ``t_s``, exact
    to millimetres within the few metres a bracket spans (curve radii are >= 180 m).

    With ``divergence_rad`` > 0 the beam is a cone of that full angle, and the range is what
    a time-of-flight receiver makes of the echo of its whole footprint:

    4. in the vertical plane of the central ray (where the footprint is long: at Stanley's
       grazing angles of 5-20 degrees it is 3-12 times longer along the ground than across),
       the ground is sampled where sub-rays spread evenly over the cone meet the local
       plane of the smooth ground (grade and cross profile), at most ``footprint_samples``
       of them and ``footprint_spacing_m`` apart, plus at most ``occluder_samples`` points
       ``occluder_spacing_m`` apart before the footprint, far enough back to catch an
       occluder ``occluder_height_m`` tall that the lowest sub-ray would graze;
    5. a ground point is seen if no nearer point subtends a higher elevation (a running
       maximum of the elevation tangent from the sensor), so each gap between samples
       reflects the slice of the cone between the horizon before it and its own elevation;
    6. the range is the mean of those slices' ranges weighted by the cone's light in them
       (uniform across the cone). Where the footprint straddles a depth edge (the top of a
       rock and the ground behind it, a pothole's rim and its floor) the return falls
       between the surfaces: a mixed pixel. Light beyond the last sample would come back
       later as a separate echo and is left out.

    The cone's spread across the scan plane is neglected: there the spot is at most
    ``25 m x 4.4 mrad = 11 cm`` wide, half the beam spacing.
    """

    route: Route
    crossfall: Callable[[FloatArray], FloatArray]
    step_dz_m: float = 0.1
    up_margin_m: float = 0.35
    down_margin_m: float = 0.35
    refine_iterations: int = 16
    tolerance_m: float = 0.0005
    max_range_m: float = 80.0
    min_range_m: float = 0.5
    divergence_rad: float = 0.0
    footprint_tolerance_m: float = 0.005
    footprint_samples: int = 12
    footprint_spacing_m: float = 0.12
    occluder_samples: int = 8
    occluder_spacing_m: float = 0.3
    occluder_height_m: float = 0.2
    # A footprint reaches at most this far from the central hit (grazing rays on a falling
    # road would otherwise meet the ground plane arbitrarily far away).
    footprint_reach_m: float = 4.0

    def cast(
        self, window: TerrainWindow, origin: FloatArray, direction: FloatArray, s_hint_m: float
    ) -> FloatArray:
        """Ranges (n,) for rays ``origin`` (n, 3) + t ``direction`` (n, 3); inf: no return."""
        n = origin.shape[0]
        ranges = np.full(n, np.inf)
        uz = direction[:, 2]
        down = uz < -1e-3
        idx = np.flatnonzero(down)
        if idx.size == 0:
            return ranges
        o = origin[idx]
        u = direction[idx]
        uz = u[:, 2]

        # 1. smooth estimate against z0(s), s linearised along the route tangent ...
        x0, y0, h0 = self.route.sample(np.array([s_hint_m]))
        along = u[:, 0] * np.cos(h0[0]) + u[:, 1] * np.sin(h0[0])
        along_o = (o[:, 0] - x0[0]) * np.cos(h0[0]) + (o[:, 1] - y0[0]) * np.sin(h0[0])
        t = np.full(idx.size, 10.0)
        for _ in range(3):
            z0 = np.interp(s_hint_m + along_o + t * along, self.route.s_m, self.route.z0_m)
            t = np.clip((o[:, 2] - z0) / -uz, self.min_range_m, self.max_range_m)
        # Route coordinates along each ray: a second-order expansion about this point.
        p = o + t[:, None] * u
        s_s, d_s = self.route.to_route(p[:, 0], p[:, 1], s_hint_m + along_o + t * along)
        _, _, heading = self.route.sample(s_s)
        kappa = np.interp(s_s, self.route.s_m, self.route.curvature_per_m)
        a1 = u[:, 0] * np.cos(heading) + u[:, 1] * np.sin(heading)
        b1 = -u[:, 0] * np.sin(heading) + u[:, 1] * np.cos(heading)
        scale = 1.0 / (1.0 - kappa * d_s)
        # ds/dt = a1 / (1 - kappa d); dd/dt = b1; second order from the frame's rotation.
        s1 = a1 * scale
        s2 = kappa * a1 * b1 * scale**2
        d2 = -0.5 * kappa * a1**2 * scale
        t_expansion = t

        # ... then refine the estimate once with the cross profile at the ray's offset.
        tau = t - t_expansion
        d_est = d_s + tau * (b1 + tau * d2)
        z_smooth = np.interp(s_s, self.route.s_m, self.route.z0_m) + self.crossfall(d_est)
        t = np.clip((o[:, 2] - z_smooth) / -uz, self.min_range_m, self.max_range_m)

        def g(rows: NDArray[np.intp], tt: FloatArray) -> FloatArray:
            tau = tt - t_expansion[rows]
            s = s_s[rows] + tau * (s1[rows] + tau * s2[rows])
            d = d_s[rows] + tau * (b1[rows] + tau * d2[rows])
            gap: FloatArray = o[rows, 2] + tt * uz[rows] - window.height(s, d)
            return gap

        def ground_along(rows: NDArray[np.intp], tt: FloatArray) -> FloatArray:
            """Ground height under the rays ``rows`` at parameters ``tt`` (n, k)."""
            tau = tt - t_expansion[rows][:, None]
            s = s_s[rows][:, None] + tau * (s1[rows][:, None] + tau * s2[rows][:, None])
            d = d_s[rows][:, None] + tau * (b1[rows][:, None] + tau * d2[rows][:, None])
            heights: FloatArray = window.height(s.ravel(), d.ravel()).reshape(tt.shape)
            return heights

        # 2. march down from above the ground to the first crossing. A ray already below
        # ground where the march starts meets something higher than expected (a berm, a
        # hill's shoulder): start further back, up to twice.
        all_rows = np.arange(idx.size)
        t_lo = np.maximum(t - self.up_margin_m / -uz, self.min_range_m)
        g_lo = g(all_rows, t_lo)
        for _ in range(2):
            under = np.flatnonzero(g_lo <= 0)
            if under.size == 0:
                break
            t_lo[under] = np.maximum(
                t_lo[under] - 3 * self.up_margin_m / -uz[under], self.min_range_m
            )
            g_lo[under] = g(under, t_lo[under])
        step = self.step_dz_m / -uz
        t_end = np.minimum(t + self.down_margin_m / -uz, self.max_range_m)
        t_hi = np.full(idx.size, np.nan)
        g_hi = np.full(idx.size, np.nan)
        active = np.flatnonzero(g_lo > 0)
        cur_t = t_lo[active]
        cur_g = g_lo[active]
        while active.size:
            nxt_t = np.minimum(cur_t + step[active], t_end[active])
            nxt_g = g(active, nxt_t)
            hit = nxt_g <= 0
            done = hit | (nxt_t >= t_end[active])
            hit_rows = active[hit]
            t_lo[hit_rows] = cur_t[hit]
            g_lo[hit_rows] = cur_g[hit]
            t_hi[hit_rows] = nxt_t[hit]
            g_hi[hit_rows] = nxt_g[hit]
            keep = ~done
            active, cur_t, cur_g = active[keep], nxt_t[keep], nxt_g[keep]

        # 3. Illinois refinement of each bracket [t_lo (g>0), t_hi (g<=0)], until the
        # vertical miss is below ``tolerance_m`` times the ray's slope (a range error
        # under ``tolerance_m``), for at most ``refine_iterations`` steps.
        found = np.flatnonzero(np.isfinite(t_hi))
        a, fa = t_lo[found], g_lo[found]
        b, fb = t_hi[found], g_hi[found]
        side = np.zeros(found.size)
        best = np.where(np.abs(fa) < np.abs(fb), a, b)
        live = np.arange(found.size)
        # With a footprint the central crossing only places the footprint's samples: a few mm
        # of range is plenty (the echo's range comes from the samples).
        tolerance = self.tolerance_m if self.divergence_rad <= 0 else self.footprint_tolerance_m
        tol = tolerance * -uz[found]
        for _ in range(self.refine_iterations):
            fa_l, fb_l, a_l, b_l = fa[live], fb[live], a[live], b[live]
            c = b_l - fb_l * (b_l - a_l) / (fb_l - fa_l)
            fc = g(found[live], c)
            best[live] = c
            left = fc > 0
            # The end that stays twice in a row has its value halved (Illinois).
            side_l = side[live]
            fb_l = np.where(left & (side_l == 1), fb_l * 0.5, fb_l)
            fa_l = np.where(~left & (side_l == -1), fa_l * 0.5, fa_l)
            a[live] = np.where(left, c, a_l)
            fa[live] = np.where(left, fc, fa_l)
            b[live] = np.where(left, b_l, c)
            fb[live] = np.where(left, fb_l, fc)
            side[live] = np.where(left, 1, -1)
            live = live[np.abs(fc) > tol[live]]
            if live.size == 0:
                break
        if self.divergence_rad > 0 and found.size:
            # The smooth ground's slope along each ray at its hit (grade and cross profile),
            # per metre of horizontal distance: where the footprint's samples go.
            tau = best - t_expansion[found]
            s_c = s_s[found] + tau * (s1[found] + tau * s2[found])
            d_c = d_s[found] + tau * (b1[found] + tau * d2[found])
            grade = np.interp(s_c, self.route.s_m, np.gradient(self.route.z0_m, self.route.s_m))
            cross = (self.crossfall(d_c + 0.05) - self.crossfall(d_c - 0.05)) / 0.1
            ds_dt = s1[found] + 2 * tau * s2[found]
            dd_dt = b1[found] + 2 * tau * d2[found]
            slope = (grade * ds_dt + cross * dd_dt) / np.hypot(u[found, 0], u[found, 1])
            best = self._footprint(found, best, o[found], u[found], slope, ground_along)
        ranges[idx[found]] = best
        return ranges

    def _footprint(
        self,
        rows: NDArray[np.intp],
        t_c: FloatArray,
        o: FloatArray,
        u: FloatArray,
        slope: FloatArray,
        ground_along: Callable[[NDArray[np.intp], FloatArray], FloatArray],
    ) -> FloatArray:
        """Ranges (n,) of the echo of each beam's footprint (steps 4-6 of the class doc):
        ``t_c`` (n,) the central rays' first crossings, ``o``, ``u`` (n, 3) their origins and
        unit directions, ``slope`` (n,) the smooth ground's rise per metre along them;
        ``ground_along(rows, t)`` the ground height under the central ray of each row at ray
        parameters ``t`` (n, k).

        The march (step 2) can step over ground the central ray dips under for less than one
        step (the last few decimetres of a plateau or rock before its far edge, at grazing
        angles); the footprint's samples before the hit then stand above the central ray.
        Those rays are done again around the first such crossing of the sampled profile."""
        out, redo = self._footprint_once(rows, t_c, o, u, slope, ground_along)
        again = np.flatnonzero(np.isfinite(redo))
        if again.size:  # few: all at the most samples, in one go
            out[again], _ = self._profile(
                rows[again],
                redo[again],
                o[again],
                u[again],
                slope[again],
                ground_along,
                self.footprint_samples,
                self.occluder_samples,
            )
        return out

    def _footprint_once(
        self,
        rows: NDArray[np.intp],
        t_c: FloatArray,
        o: FloatArray,
        u: FloatArray,
        slope: FloatArray,
        ground_along: Callable[[NDArray[np.intp], FloatArray], FloatArray],
    ) -> tuple[FloatArray, FloatArray]:
        """One pass of :meth:`_footprint`: the ranges (n,), and (n,) where the sampled
        ground first rises above the central ray before ``t_c`` (its ray parameter; NaN
        where it does not).

        The samples are as many as their spacing needs, up to ``footprint_samples`` over the
        footprint (spacing ``footprint_spacing_m``) and ``occluder_samples`` before it
        (``occluder_spacing_m``), in three classes (a third, two thirds or all of both; a
        ray takes the class the larger need asks for): a near laser's 0.1 m footprint needs
        4, a far one's 1.4 m 12. Few classes, because each costs a pass of Python."""
        half = 0.5 * self.divergence_rad
        uh = np.hypot(u[:, 0], u[:, 1])
        tan_c = u[:, 2] / uh
        t_half = np.tan(half)
        rho_c = t_c * uh
        plane = -tan_c * rho_c + slope * rho_c  # as ``num`` in _profile
        den_lo = slope - (tan_c - t_half) / (1.0 + tan_c * t_half)
        den_hi = slope - (tan_c + t_half) / (1.0 - tan_c * t_half)
        reach = self.footprint_reach_m
        near = plane / np.maximum(den_lo, 1e-6)
        far = np.where(den_hi > 1e-6, plane / np.maximum(den_hi, 1e-6), rho_c + reach)
        length = np.clip(far - near, 0.0, 2 * reach)
        back = np.clip(self.occluder_height_m / np.maximum(den_lo, 1e-6), 0.0, reach)
        levels_fp = np.ceil(self.footprint_samples * np.array([1, 2, 3]) / 3).astype(int)
        levels_occ = np.ceil(self.occluder_samples * np.array([1, 2, 3]) / 3).astype(int)
        need_fp = np.searchsorted(levels_fp, length / self.footprint_spacing_m + 1.0)
        need_occ = np.searchsorted(levels_occ, back / self.occluder_spacing_m)
        group = np.minimum(np.maximum(need_fp, need_occ), 2)
        out = np.empty(t_c.size)
        redo = np.empty(t_c.size)
        for g in np.unique(group):
            sel = np.flatnonzero(group == g)
            out[sel], redo[sel] = self._profile(
                rows[sel],
                t_c[sel],
                o[sel],
                u[sel],
                slope[sel],
                ground_along,
                int(levels_fp[g]),
                int(levels_occ[g]),
            )
        return out, redo

    def _profile(
        self,
        rows: NDArray[np.intp],
        t_c: FloatArray,
        o: FloatArray,
        u: FloatArray,
        slope: FloatArray,
        ground_along: Callable[[NDArray[np.intp], FloatArray], FloatArray],
        k: int,
        m: int,
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`_footprint_once` for rays sampled ``k`` times over the footprint and ``m``
        times before it."""
        half = 0.5 * self.divergence_rad
        uh = np.hypot(u[:, 0], u[:, 1])  # horizontal length of the unit direction
        tan_c = u[:, 2] / uh
        rho_c = t_c * uh  # horizontal distance of the central hit
        above = -tan_c * rho_c  # sensor height above the central hit
        reach = self.footprint_reach_m
        # Sub-ray tangents, evenly spread over the cone; where each meets the local plane
        # z = z_c + slope (rho - rho_c), seen from the sensor: rho = (above + slope rho_c) /
        # (slope - tan). A sub-ray that never comes down to the plane is capped at the reach.
        # tan(el_c + offset) to first order: the offsets are at most 2.2 mrad, so the second
        # order (tan_c offset^2, below 1e-6) is far below the cone's width.
        offset = half * np.linspace(-1.0, 1.0, k)[None, :]
        tc = tan_c[:, None]
        tan_k = tc + offset * (1.0 + tc * tc)
        tan_lo, tan_hi = tan_k[:, 0], tan_k[:, -1]
        num = (above + slope * rho_c)[:, None]  # > 0: the sensor is above the plane
        den = slope[:, None] - tan_k  # falls with k, so rho_fp rises with k
        rho_fp = np.clip(
            num / np.maximum(den, 1e-6), (rho_c - reach)[:, None], (rho_c + reach)[:, None]
        )
        # Before the footprint: the lowest sub-ray is within occluder_height_m of the plane
        # for occluder_height_m / (slope - tan_lo) metres of horizontal distance.
        back = np.clip(self.occluder_height_m / np.maximum(den[:, 0], 1e-6), 0.0, reach)
        steps = np.arange(m, 0, -1) / m  # 1 .. 1/m of the way back
        rho_occ = np.maximum(
            rho_fp[:, :1] - back[:, None] * steps[None, :], self.min_range_m * uh[:, None]
        )
        rho = np.concatenate([rho_occ, rho_fp], axis=1)
        h = ground_along(rows, rho / uh[:, None])
        tan_g = (h - o[:, 2:3]) / rho  # elevation tangent of each ground sample
        horizon = np.maximum.accumulate(tan_g, axis=1)
        lo_b = np.maximum(horizon[:, :-1], tan_lo[:, None])  # slice of the cone per gap
        hi_b = np.minimum(horizon[:, 1:], tan_hi[:, None])
        light = np.maximum(hi_b - lo_b, 0.0)
        # The slice's middle sub-ray meets the ground between the gap's two samples, where
        # the (linear) profile's tangent reaches the middle tangent.
        # (A lit slice has t1 > t0; an unlit one any finite value.)
        mid = 0.5 * (lo_b + hi_b)
        t0 = tan_g[:, :-1]
        f = np.clip((mid - t0) / np.maximum(tan_g[:, 1:] - t0, 1e-12), 0.0, 1.0)
        rho_mid = rho[:, :-1] + f * (rho[:, 1:] - rho[:, :-1])
        total = light.sum(axis=1)
        lit = total > 0
        out = t_c.copy()
        # Range from horizontal distance with the central ray's secant: the cone's 2.2 mrad
        # change it by at most 2e-4 of the range.
        out[lit] = (light * rho_mid).sum(axis=1)[lit] / total[lit] / uh[lit]
        # Ground sampled before the hit (the samples before the cone's centre) that stands
        # above the central ray: it met the ground first there, between that sample and the
        # one before (linear in between).
        above_ray = tan_g[:, : m + k // 2] > tc + 1e-9
        redo = np.full(t_c.size, np.nan)
        hit_rows = np.flatnonzero(above_ray.any(axis=1))
        if hit_rows.size:
            j = np.argmax(above_ray[hit_rows], axis=1)
            i = np.maximum(j - 1, 0)
            ta, tb = tan_g[hit_rows, i], tan_g[hit_rows, j]
            ra, rb = rho[hit_rows, i], rho[hit_rows, j]
            w = np.where(tb > ta, (tan_c[hit_rows] - ta) / np.maximum(tb - ta, 1e-12), 1.0)
            w = np.where(j > 0, np.clip(w, 0.0, 1.0), 0.0)
            redo[hit_rows] = (ra + w * (rb - ra)) / uh[hit_rows]
        return out, redo


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
