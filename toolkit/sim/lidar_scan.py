"""The lidar's scans: each column's rays planned from the sensor's true pose at the column's
own time, cast with the lasers (:mod:`toolkit.sim.laser_workers`), and the columns gathered
into scans, given the sensor's errors and published as ouster-ros clouds.

A scan (one turn, 100 ms) spans block boundaries, so rays are planned a block's columns at a
time (:meth:`LidarSensor.plan`) and a scan is published once its last column's ranges are
back (:meth:`LidarSensor.finish`); every random draw is made there, in scan order, from the
lidar's own generator, so the log does not depend on the casting workers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.sim.drive import TrueBlock
from toolkit.sim.lidar import LIDAR_NOISE_STREAM, LidarParams, draw_lidar_truth
from toolkit.sim.lidar_cloud import POINT_DTYPE, encode_cloud
from toolkit.sim.messages import TOPIC_LIDAR, Outbox
from toolkit.sim.sensor_pose import flex_pitch, pose_at
from toolkit.sim.sensors import ClockParams

# A ray must descend at least this steeply (its direction's z) to be cast: the ray caster
# finds no ground for the others (RayCaster.cast), so they are culled before they travel to
# a worker (about half the lidar's rays, the beams above the horizon).
_MIN_DESCENT = 1e-3


@dataclass(frozen=True)
class LidarRays:
    """One block's lidar columns: their global indices ``column_k`` (m,) (scan ``k //
    columns``, column ``k % columns``), the vehicle's speed then (m,), and the rays cast:
    ``cast`` (r,) their flat indices into (m, beams), ``origin`` and unit ``direction``
    (r, 3) in ENU, and the stretch of route (``s_lo_m`` .. ``s_hi_m``) they can reach."""

    column_k: NDArray[np.int64]
    speed_mps: FloatArray
    cast: NDArray[np.intp]
    origin: FloatArray
    direction: FloatArray
    s_hint_m: float
    s_lo_m: float
    s_hi_m: float


@dataclass
class _Scan:
    """A scan being gathered: true footprint ranges (columns, beams) (inf: no return), the
    columns filled so far and the vehicle's speed at its first column."""

    ranges: FloatArray
    filled: int = 0
    speed_mps: float = 0.0


@dataclass
class LidarSensor:
    """The spinning lidar of :class:`LidarParams`: plans rays, gathers and publishes scans."""

    p: LidarParams
    seed: int
    start_ns: int
    clock: ClockParams
    scans: dict[int, _Scan] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = self.p
        self.truth = draw_lidar_truth(p, self.seed, self.clock.offset_max_s)
        self.rng = np.random.default_rng([self.seed, LIDAR_NOISE_STREAM])
        self.dirs_sensor = p.directions()  # (columns, beams, 3)
        r_mount = self.truth.mount.rotation()
        self.dirs_base = self.dirs_sensor @ r_mount.T  # base_link, the true mount's
        self.origin_base = np.asarray(self.truth.mount.xyz_m) + r_mount @ np.array(
            [0.0, 0.0, p.lidar_origin_z_m]
        )
        self.first_column_ns = self.start_ns + self.truth.phase_ns
        self.dust_until_ns = np.iinfo(np.int64).min
        self.dust_sector = (0, 0)

    # -- planning ----------------------------------------------------------------------------

    def plan(self, ext: TrueBlock, first: int) -> LidarRays | None:
        """The rays of the columns fired within the block that starts at ``first`` of
        ``ext``, each cast from the sensor's true pose at its column's time: the vehicle's
        true pose, the true mount and the mount's flex (so the vehicle's motion during the
        turn shows in the cloud)."""
        p = self.p
        col_ns = p.column_period_ns
        t0 = int(ext.t_ns[first])
        dt_ns = int(ext.t_ns[1] - ext.t_ns[0])
        k_lo = max(int(np.floor((t0 - dt_ns - self.first_column_ns) / col_ns)) + 1, 0)
        k_hi = int(np.floor((int(ext.t_ns[-1]) - self.first_column_ns) / col_ns))
        if k_hi < k_lo:
            return None
        k = np.arange(k_lo, k_hi + 1, dtype=np.int64)
        t_ext = (ext.t_ns - t0).astype(np.float64)
        t = float(self.first_column_ns - t0) + k * col_ns  # ints first: ns exact
        rot, pos = pose_at(ext, t_ext, t)
        turn = rot @ flex_pitch(ext, t_ext, t, p.flex_pitch_rad_per_mps2)
        direction = np.einsum("kij,kbj->kbi", turn, self.dirs_base[k % p.columns])
        origin = pos + rot @ self.origin_base
        down = direction[:, :, 2] < -_MIN_DESCENT
        cast = np.flatnonzero(down.ravel())
        s = ext.s_m[first:]
        reach = p.range_max_m + 20.0
        return LidarRays(
            column_k=k,
            speed_mps=np.interp(t, t_ext, ext.speed_mps),
            cast=cast,
            origin=np.repeat(origin, p.beams, axis=0)[cast],
            direction=direction[down],
            s_hint_m=float(s[s.size // 2]),
            # Not below the route's start: a window asked to reach before it would be
            # rebuilt at every block (WindowCache.covering).
            s_lo_m=max(float(s[0]) - reach, 0.0),
            s_hi_m=float(s[-1]) + reach,
        )

    # -- scans -------------------------------------------------------------------------------

    def finish(self, rays: LidarRays, ranges: FloatArray, out: Outbox) -> None:
        """File the block's ranges (the cast rays' true footprint ranges, inf: no return)
        into their scans and publish every scan now complete."""
        p = self.p
        full = np.full((rays.column_k.size, p.beams), np.inf)
        full.ravel()[rays.cast] = ranges
        scan_of = rays.column_k // p.columns
        for n in np.unique(scan_of).tolist():
            rows = np.flatnonzero(scan_of == n)
            scan = self.scans.get(n)
            if scan is None:
                scan = _Scan(np.full((p.columns, p.beams), np.inf))
                scan.speed_mps = float(rays.speed_mps[rows[0]])
                self.scans[n] = scan
            scan.ranges[rays.column_k[rows] % p.columns] = full[rows]
            scan.filled += rows.size
            if scan.filled == p.columns:
                self._publish(n, scan, out)
                del self.scans[n]

    def _publish(self, n: int, scan: _Scan, out: Outbox) -> None:
        """Scan ``n``'s cloud: measured ranges (:meth:`measured_ranges`), points in the
        sensor frame, stamped at its first column by the sensor's clock, logged once its
        last column is in."""
        p = self.p
        col_ns = p.column_period_ns
        t_first = self.first_column_ns + int(round(n * p.columns * col_ns))
        mm = self.measured_mm(scan.ranges, t_first, scan.speed_mps)  # (columns, beams)
        r = mm * p.range_resolution_m
        hit = mm > 0
        xyz = self.dirs_sensor * r[:, :, None]
        xyz[..., 2] += np.where(hit, p.lidar_origin_z_m, 0.0)
        pts = np.zeros((p.beams, p.columns), dtype=POINT_DTYPE)
        pts["x"], pts["y"], pts["z"] = xyz[..., 0].T, xyz[..., 1].T, xyz[..., 2].T
        safe = np.where(hit, r, 1.0)
        intensity = np.clip(p.signal_at_10m * (10.0 / safe) ** 2, 0.0, 65535.0)
        pts["intensity"] = np.where(hit, intensity, 0.0).T
        pts["t"] = np.round(np.arange(p.columns) * col_ns).astype(np.uint32)[None, :]
        pts["reflectivity"] = np.where(hit, p.reflectivity, 0).T
        pts["ring"] = np.arange(p.beams, dtype=np.uint16)[:, None]
        pts["ambient"] = p.ambient
        pts["range"] = mm.T
        stamp = t_first + self.truth.clock_offset_ns
        lo, hi = self.clock.latency_range_s
        t_last = self.first_column_ns + int(round((n * p.columns + p.columns - 1) * col_ns))
        log_ns = t_last + int(self.rng.integers(int(lo * 1e9), int(hi * 1e9), endpoint=True))
        payload = encode_cloud(stamp, self.truth.mount.frame_id, pts)
        out.add(TOPIC_LIDAR, np.array([log_ns], dtype=np.int64), [payload])

    def measured_mm(
        self, ranges: FloatArray, t_first_ns: int, speed_mps: float
    ) -> NDArray[np.uint32]:
        """What the sensor reports (columns, beams), in mm (0: no return), for the true
        footprint ranges ``ranges`` (columns, beams; inf: no return): plus each ring's bias
        and the range-dependent precision, random dropouts, out-of-range readings and dust
        lost, quantised to ``range_resolution_m``."""
        p = self.p
        rng = self.rng
        r = ranges + np.asarray(self.truth.range_bias_m)[None, :]
        r = r + rng.standard_normal(r.shape) * p.noise_std_m(r)
        r[rng.random(r.shape) < p.dropout_probability] = np.inf
        r[(r < p.range_min_m) | (r > p.range_max_m)] = np.inf
        r[self._dust(t_first_ns, speed_mps)] = np.inf
        ok = np.isfinite(r)
        return np.where(ok, np.round(np.where(ok, r, 0.0) / p.range_resolution_m), 0).astype(
            np.uint32
        )

    def _dust(self, t_first_ns: int, speed_mps: float) -> NDArray[np.bool_]:
        """Points (columns, beams) lost in dust in the scan starting at ``t_first_ns``: an
        episode starts at a rate growing with speed, lasts an exponential time and hides
        part of one azimuth sector (:class:`LidarParams`); one step per scan."""
        p = self.p
        lost = np.zeros((p.columns, p.beams), dtype=bool)
        if p.dust_onset_per_s <= 0:
            return lost
        rng = self.rng
        p_start = 1.0 - np.exp(-p.dust_onset_per_s * speed_mps / 10.0 / p.rate_hz)
        if t_first_ns >= self.dust_until_ns and rng.random() < p_start:
            self.dust_until_ns = t_first_ns + int(rng.exponential(p.dust_duration_s) * 1e9)
            width = int(rng.integers(p.dust_sector_columns[0], p.dust_sector_columns[1] + 1))
            self.dust_sector = (int(rng.integers(0, p.columns)), width)
        if t_first_ns < self.dust_until_ns:
            first, width = self.dust_sector
            sector = (np.arange(p.columns) - first) % p.columns < width  # wraps round
            lost[sector] = rng.random((int(sector.sum()), p.beams)) < p.dust_drop_probability
        return lost
