"""Simulated sensors: where they sit, what they measure, and how they err.

Every sensor is simulated from the true state. The errors are the ones the paper's model has
to absorb (Sect. 3): range noise, pose-estimation error (from IMU, GPS, compass and wheel
errors) and latency (clock offsets and timestamp jitter between sensors).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation

from toolkit.config import default_config
from toolkit.sim.world import Route, TerrainWindow

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
    """A SICK LMS-like scanner: 181 beams at 0.5 degree, 75 Hz, 1-2 cm range noise."""

    rate_hz: float = 75.0
    beams: int = 181
    angle_min_rad: float = float(np.radians(-45.0))
    angle_increment_rad: float = float(np.radians(0.5))
    # The mirror turns once per scan; the 181 beams span a quarter of a turn.
    time_increment_s: float = 1.0 / 75.0 / 720.0
    range_min_m: float = 0.5
    range_max_m: float = 80.0
    range_noise_m: float = 0.015
    range_resolution_m: float = 2.0**-10  # about 1 mm
    dropout_probability: float = 0.002
    mounts: tuple[Mount, ...] = field(default_factory=laser_mounts)


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
        tol = self.tolerance_m * -uz[found]
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
        ranges[idx[found]] = best
        return ranges


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
