"""Driving the vehicle along the route: the true state, block by block.

The vehicle's rear axle follows a *driven path*: the route's centreline shifted sideways by
a slow lane wander ``w(s)``. Its longitudinal speed comes from the reactive speed controller;
its vertical motion and attitude from the full-car suspension model driven by the terrain
under its four tyres (each tyre's footprint made one effective road height,
:class:`~toolkit.sim.tyre.TyreFootprint`). Each call of :meth:`Driver.step` advances one
block (0.1 s) at the dynamics rate (1 kHz) and returns the true state at every dynamics
sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.route import Route
from toolkit.sim.speed_control import (
    ReactiveSpeedController,
    ReactiveSpeedParams,
    safe_speed_profile,
)
from toolkit.sim.suspension import (
    INPUT_ACCEL_X,
    INPUT_ACCEL_Y,
    INPUT_ONE,
    INPUT_ROAD,
    INPUT_ROAD_RATE,
    N_INPUTS,
    Suspension,
    SuspensionBlock,
)
from toolkit.sim.terrain import Terrain, WindowCache
from toolkit.sim.tyre import TyreFootprint
from toolkit.sim.vehicle import VehicleParams

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class DrivenPath:
    """The rear axle's path, tabulated against centreline distance ``s_m`` (shape (n,)).

    ``sigma_m`` is distance along the driven path itself, ``wander_m`` the lateral offset
    from the centreline, ``heading_rad`` and ``curvature_per_m`` those of the driven path.
    """

    s_m: FloatArray
    sigma_m: FloatArray
    wander_m: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    curvature_per_m: FloatArray

    def at_sigma(self, sigma_m: FloatArray) -> dict[str, FloatArray]:
        s = np.interp(sigma_m, self.sigma_m, self.s_m)
        return {
            "s_m": s,
            "d_m": np.interp(s, self.s_m, self.wander_m),
            "x_m": np.interp(s, self.s_m, self.x_m),
            "y_m": np.interp(s, self.s_m, self.y_m),
            "heading_rad": np.interp(s, self.s_m, self.heading_rad),
            "curvature_per_m": np.interp(s, self.s_m, self.curvature_per_m),
        }


def make_driven_path(
    route: Route, rng: np.random.Generator, wander_amplitude_m: float, ds_m: float = 0.25
) -> DrivenPath:
    """Offset the centreline by a smooth lane wander (sinusoids of 60-400 m wavelength).

    Heading and curvature follow analytically from the offset's derivatives, so they are
    smooth (a polyline's would jump at every vertex and shake the simulated IMU).
    """
    s = np.arange(0.0, route.length_m - 1.0, ds_m)
    wavelengths = rng.uniform(60.0, 400.0, size=3)
    phases = rng.uniform(0, 2 * np.pi, size=3)
    amps = rng.uniform(0.5, 1.0, size=3) * wander_amplitude_m / 3
    k = 2 * np.pi / wavelengths
    arg = s[:, None] * k[None, :] + phases[None, :]
    w = (amps * np.sin(arg)).sum(axis=1)
    w1 = (amps * k * np.cos(arg)).sum(axis=1)
    w2 = -(amps * k**2 * np.sin(arg)).sum(axis=1)
    cx, cy, ch = route.sample(s)
    kc = np.interp(s, route.s_m, route.curvature_per_m)
    x = cx - w * np.sin(ch)
    y = cy + w * np.cos(ch)
    # d(path)/ds = (1 - kc w) t + w' n
    along = 1.0 - kc * w
    heading = ch + np.arctan2(w1, along)
    dsigma = np.hypot(along, w1)
    # Curvature of an offset curve: (kc + (d/ds) atan(w'/(1 - kc w))) / |d path / ds|.
    datan = (w2 * along + w1 * (kc * w1)) / (along**2 + w1**2)
    curvature = (kc + datan) / dsigma
    sigma = np.concatenate([[0.0], np.cumsum(0.5 * (dsigma[1:] + dsigma[:-1])) * ds_m])
    return DrivenPath(s, sigma, w, x, y, heading, curvature)


@dataclass
class TrueBlock:
    """The true state at every dynamics sample of one block; arrays (n,) or (n, 3).

    Position is that of ``base_link`` (ENU, m); attitude roll/pitch/yaw (rad, Z-Y-X);
    ``omega_body_radps`` body angular rates; ``specific_force_body_mps2`` what a perfect
    accelerometer at the IMU would read (gravity included); ``wheel_speed_mps`` (n, 4) in
    the order FL, FR, RL, RR. ``tyre_road_m`` (n, 4) is each tyre's effective road height
    (ENU z, m), ``tyre_force_n`` (n, 4) the force it pushes its wheel up with (N, zero while
    the wheel is off the ground), ``wheel_height_m`` and ``wheel_rate_mps`` (n, 4) the wheels'
    (unsprung masses') heights and vertical speeds, ENU, at static equilibrium on flat ground
    level with the road.
    """

    t_ns: NDArray[np.int64]
    sigma_m: FloatArray
    s_m: FloatArray
    d_m: FloatArray
    position_m: FloatArray
    roll_rad: FloatArray
    pitch_rad: FloatArray
    yaw_rad: FloatArray
    roll_rate_radps: FloatArray
    pitch_rate_radps: FloatArray
    speed_mps: FloatArray
    accel_mps2: FloatArray
    curvature_per_m: FloatArray
    velocity_world_mps: FloatArray
    omega_body_radps: FloatArray
    specific_force_body_mps2: FloatArray
    wheel_speed_mps: FloatArray
    tyre_road_m: FloatArray
    tyre_force_n: FloatArray
    wheel_height_m: FloatArray
    wheel_rate_mps: FloatArray

    def world_from_base(self) -> Rotation:
        """Attitude of ``base_link`` at every sample (computed once, then cached)."""
        cached = self.__dict__.get("_world_from_base")
        if cached is None:
            cached = Rotation.from_euler(
                "ZYX", np.stack([self.yaw_rad, self.pitch_rad, self.roll_rad], 1)
            )
            self.__dict__["_world_from_base"] = cached
        return cached

    def __len__(self) -> int:
        return int(self.t_ns.size)


class Driver:
    """Advances the vehicle through the world one block at a time.

    Holds the only mutable simulation state: distance, speed, the suspension state and the
    controller's speed cap (which the simulation loop lowers after a shock the IMU felt).
    """

    def __init__(
        self,
        route: Route,
        terrain: Terrain,
        path: DrivenPath,
        vehicle: VehicleParams,
        controller: ReactiveSpeedParams,
        imu_position_m: tuple[float, float, float],
        start_time_ns: int,
        initial_speed_mps: float,
        speed_schedule: tuple[tuple[float, float], ...] = (),
        dt_ns: int = 1_000_000,
    ) -> None:
        self.route = route
        self.terrain = terrain
        self.path = path
        self.vehicle = vehicle
        self.dt_ns = dt_ns
        self.dt_s = dt_ns * 1e-9
        self.suspension = Suspension.build(vehicle, self.dt_s)
        self.footprint = TyreFootprint.build(vehicle)
        self.controller = ReactiveSpeedController(controller)
        if speed_schedule:
            limits = np.full(route.s_m.size, speed_schedule[0][1])
            for s_from, v in speed_schedule:
                limits[route.s_m >= s_from] = v
            self.limit_mps = limits
        else:
            self.limit_mps = safe_speed_profile(
                route.s_m, route.speed_limit_mps, route.curvature_per_m, controller
            )
        self.imu_position_m = np.asarray(imu_position_m)
        self.t_ns = start_time_ns
        self.sigma_m = 2.0
        self.speed_mps = initial_speed_mps
        self.state: FloatArray | None = None
        self._road_last: FloatArray | None = None  # (4,) effective heights, last sample
        self.windows = WindowCache(terrain)

    @property
    def end_sigma_m(self) -> float:
        return float(self.path.sigma_m[-1]) - 60.0

    def step(self, n: int) -> TrueBlock:
        """Advance ``n`` dynamics samples; the block's first sample is the current time."""
        k = np.arange(n)
        a, v, a_eff, sigma = self._speed(n, k * self.dt_s)
        kin = self.path.at_sigma(sigma)
        heading = kin["heading_rad"]
        kappa = kin["curvature_per_m"]
        ch, sh = np.cos(heading), np.sin(heading)

        # The road under each tyre's footprint, made one effective height per tyre.
        road = self._tyre_road(kin, heading)  # (n, 4)
        prev = road[0] if self._road_last is None else self._road_last
        road_rate = np.diff(road, axis=0, prepend=prev[None, :]) / self.dt_s
        self._road_last = road[-1]

        a_lat = v**2 * kappa
        sus, acc = self._suspend(road, road_rate, a_eff, a_lat)
        states = sus.states
        b = self.vehicle.cg_from_rear_m
        pitch, roll = states[:, 1], states[:, 2]
        pitch_rate, roll_rate = states[:, 8], states[:, 9]
        z_base = states[:, 0] + b * pitch
        z_base_rate = states[:, 7] + b * pitch_rate
        z_base_acc = acc[:, 0] + b * acc[:, 1]
        yaw_rate = v * kappa
        omega = _body_rates(pitch, roll, pitch_rate, roll_rate, yaw_rate)
        alpha = np.stack([acc[:, 2], acc[:, 1], a_eff * kappa], axis=1)
        rot = Rotation.from_euler(
            "ZYX", np.stack([heading, pitch, roll], axis=1)
        )  # world_from_base
        a_base = np.stack([a_eff * ch - a_lat * sh, a_eff * sh + a_lat * ch, z_base_acc], axis=1)
        f_body = self._specific_force_at_imu(rot, a_base, alpha, omega)
        wheel = self._wheel_speeds(v, kappa, yaw_rate)

        # The reactive controller's shock comes from the IMU, after the block
        # (toolkit.sim.shock_meter, called by the simulation loop); here it recovers.
        v_end = max(self.speed_mps + a * n * self.dt_s, 0.0)
        distance = float(sigma[-1] - self.sigma_m) + 0.5 * (v[-1] + v_end) * self.dt_s
        self.controller.recover(distance)

        block = TrueBlock(
            t_ns=self.t_ns + k.astype(np.int64) * self.dt_ns,
            sigma_m=sigma,
            s_m=kin["s_m"],
            d_m=kin["d_m"],
            position_m=np.stack([kin["x_m"], kin["y_m"], z_base], axis=1),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=heading,
            roll_rate_radps=roll_rate,
            pitch_rate_radps=pitch_rate,
            speed_mps=v,
            accel_mps2=a_eff,
            curvature_per_m=kappa,
            velocity_world_mps=np.stack([v * ch, v * sh, z_base_rate], axis=1),
            omega_body_radps=omega,
            specific_force_body_mps2=f_body,
            wheel_speed_mps=wheel,
            tyre_road_m=road,
            tyre_force_n=sus.tyre_force_n,
            wheel_height_m=states[:, 3:7],
            wheel_rate_mps=states[:, 10:14],
        )
        block.__dict__["_world_from_base"] = rot
        self.t_ns += n * self.dt_ns
        self.sigma_m = float(sigma[-1]) + 0.5 * (v[-1] + v_end) * self.dt_s
        self.speed_mps = v_end
        return block

    def _speed(self, n: int, t_rel: FloatArray) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """The controller's acceleration ``a`` (m/s^2) held over the block, and at its ``n``
        samples (times ``t_rel`` s from its start) the speed ``v`` (m/s, never negative),
        the acceleration in effect ``a_eff`` (zero once stopped) and the distance along the
        driven path ``sigma`` (m, trapezoidal in ``v``)."""
        s_now = float(np.interp(self.sigma_m, self.path.sigma_m, self.path.s_m))
        limit = float(np.interp(s_now, self.route.s_m, self.limit_mps))
        a = self.controller.acceleration(self.speed_mps, limit)
        v = np.maximum(self.speed_mps + a * t_rel, 0.0)
        if a < 0 and self.speed_mps + a * t_rel[-1] < 0:
            a_eff = np.where(v > 0, a, 0.0)
        else:
            a_eff = np.full(n, a)
        sigma = (
            self.sigma_m + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]) * self.dt_s
        )
        return a, v, a_eff, sigma

    def _suspend(
        self, road: FloatArray, road_rate: FloatArray, a_x: FloatArray, a_y: FloatArray
    ) -> tuple[SuspensionBlock, FloatArray]:
        """The suspension's block over effective road heights ``road`` (n, 4) m and their
        rates (m/s) under the body's accelerations ``a_x``, ``a_y`` (n,) m/s^2, and the
        coordinates' second derivatives (n, 7); starts from equilibrium on the first call."""
        u = np.empty((road.shape[0], N_INPUTS))
        u[:, INPUT_ROAD] = road
        u[:, INPUT_ROAD_RATE] = road_rate
        u[:, INPUT_ACCEL_X] = a_x
        u[:, INPUT_ACCEL_Y] = a_y
        u[:, INPUT_ONE] = 1.0
        if self.state is None:
            self.state = self.suspension.equilibrium(u[0])
        sus = self.suspension.step_block(self.state, u)
        self.state = sus.end
        return sus, self.suspension.accelerations(sus, u)

    def _specific_force_at_imu(
        self, rot: Rotation, a_base: FloatArray, alpha: FloatArray, omega: FloatArray
    ) -> FloatArray:
        """The specific force (n, 3) m/s^2 at the IMU in base_link axes: base_link's origin's
        acceleration ``a_base`` (world axes) plus the lever arm's ``alpha x r + omega x
        (omega x r)`` (body axes, rad/s^2 and rad/s), plus gravity's reaction."""
        r = self.imu_position_m
        lever = np.cross(alpha, r) + np.cross(omega, np.cross(omega, r))
        a_imu = a_base + rot.apply(lever)
        a_imu[:, 2] += GRAVITY_MPS2
        f_body: FloatArray = rot.apply(a_imu, inverse=True)
        return f_body

    def _wheel_speeds(self, v: FloatArray, kappa: FloatArray, yaw_rate: FloatArray) -> FloatArray:
        """Each wheel's ground speed along its own heading (n, 4) m/s, FL, FR, RL, RR: the
        rear axle's ``v`` -+ ``yaw_rate`` x half the track; the front axle's is faster by
        ``sqrt(1 + (L kappa)^2)`` (it runs on a wider circle)."""
        p = self.vehicle
        half = p.track_m / 2
        front = v * np.sqrt(1.0 + (p.wheelbase_m * kappa) ** 2)
        wheel: FloatArray = np.stack(
            [
                front - yaw_rate * half,
                front + yaw_rate * half,
                v - yaw_rate * half,
                v + yaw_rate * half,
            ],
            axis=1,
        )
        return wheel

    def _tyre_road(self, kin: dict[str, FloatArray], heading: FloatArray) -> FloatArray:
        """Effective road height under each tyre, (n, 4), from the terrain under its footprint.

        The four contact centres (ground level below the axles, at the track's half-width
        from the vehicle's centreline) go to route coordinates; the footprint's cells are laid
        out around each in the wheel's own heading, relative to the route's heading there, in
        (s, d) directly: along the route a step ``a`` at offset ``d`` is ``a / (1 - kappa d)``
        of ``s``, and across it the curve bends away by ``kappa a^2 / 2``, under 0.4 mm over
        the footprint's 0.34 m at the route's tightest radius (180 m), which is left out.
        """
        p = self.vehicle
        fp = self.footprint
        half = p.track_m / 2
        lateral = np.array([half, -half, half, -half])
        forward = np.array([p.wheelbase_m, p.wheelbase_m, 0.0, 0.0])
        ch, sh = np.cos(heading)[:, None], np.sin(heading)[:, None]
        wx = kin["x_m"][:, None] + forward * ch - lateral * sh  # (n, 4)
        wy = kin["y_m"][:, None] + forward * sh + lateral * ch
        guess = kin["s_m"][:, None] + forward + 0.0 * wx
        ws, wd = self.route.to_route(wx.ravel(), wy.ravel(), guess.ravel())
        route_heading = self.route.sample(ws)[2]
        stretch = 1.0 / (1.0 - np.interp(ws, self.route.s_m, self.route.curvature_per_m) * wd)
        rel = heading.repeat(4) - route_heading  # (n * 4,)
        cr, sr = np.cos(rel)[:, None], np.sin(rel)[:, None]
        cs = ws[:, None] + (fp.forward_m * cr - fp.lateral_m * sr) * stretch[:, None]  # (n*4, m)
        cd = wd[:, None] + fp.forward_m * sr + fp.lateral_m * cr
        win = self.windows.covering(float(cs.min()), float(cs.max()) + 100.0)
        heights = win.height(cs.ravel(), cd.ravel()).reshape(heading.size, 4, fp.cells)
        return fp.effective_height(heights)


def _body_rates(
    pitch: FloatArray,
    roll: FloatArray,
    pitch_rate: FloatArray,
    roll_rate: FloatArray,
    yaw_rate: FloatArray,
) -> FloatArray:
    """Body rates (n, 3) rad/s about base_link's x, y, z from the Euler angles and rates
    (Z-Y-X, rad and rad/s): exact kinematics."""
    sp, cp = np.sin(pitch), np.cos(pitch)
    sr, cr = np.sin(roll), np.cos(roll)
    return np.stack(
        [
            roll_rate - yaw_rate * sp,
            pitch_rate * cr + yaw_rate * sr * cp,
            -pitch_rate * sr + yaw_rate * cr * cp,
        ],
        axis=1,
    )
