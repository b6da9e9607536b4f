"""``terrain sim``: drive the simulated vehicle and write what its sensors saw as ROS 2 MCAP.

The loop advances the true state one 0.1 s block at a time (:class:`~toolkit.sim.drive.Driver`),
samples every sensor from it (:class:`~toolkit.sim.suite.SensorSuite`), encodes each sensor's
messages of the block in one vectorised batch, and writes them in log-time order
(:class:`~toolkit.sim.messages.Outbox`). Laser rays are cast a few blocks ahead in other
processes (:mod:`toolkit.sim.laser_workers`). Memory stays bounded: only the current block,
its predecessor and a few terrain tiles are alive at any time.

The topics and the ``terrain_sim`` metadata record (:func:`toolkit.sim.record.sim_metadata`)
are listed in ``docs/simulator.md``.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.config import default_config
from toolkit.errors import SimulationError
from toolkit.mcapio.cdr_encode import encode_message
from toolkit.mcapio.writer import LogWriter
from toolkit.progress import progress
from toolkit.sim.drive import Driver, TrueBlock, make_driven_path
from toolkit.sim.laser_workers import (
    BeamParams,
    LaserRays,
    Rays,
    default_workers,
    start_laser_casting,
)
from toolkit.sim.lidar import LidarParams
from toolkit.sim.lidar_scan import LidarRays
from toolkit.sim.messages import (
    TOPIC_TF_STATIC,
    TOPIC_TRUTH_FEATURES,
    Outbox,
    feature_message,
    register_topics,
    static_transforms,
)
from toolkit.sim.profiles import SimProfile, make_profile
from toolkit.sim.record import SIM_RECORD, sim_metadata
from toolkit.sim.shock_meter import ShockMeter
from toolkit.sim.suite import BLOCK_SAMPLES, ImuSamples, SensorSuite
from toolkit.sim.world import World, make_world

HISTORY_SAMPLES = 20  # of the previous block, for IMU averaging and scans across blocks
WARMUP_BLOCKS = 30  # let the suspension settle before recording


@dataclass(frozen=True)
class SimResult:
    """What ``simulate`` wrote."""

    path: Path
    profile: str
    seed: int
    duration_s: float
    distance_m: float
    message_counts: dict[str, int]
    feature_count: int
    #: The route's length, m: the drive recorded is shorter (:data:`ROUTE_UNDRIVEN_NOTE`).
    route_m: float = 0.0

    def summary(self) -> str:
        total = sum(self.message_counts.values())
        return (
            f"{self.path}: profile {self.profile}, seed {self.seed}, {self.duration_s:.1f} s, "
            f"{self.distance_m:.0f} m driven of the {self.route_m:.0f} m route "
            f"({ROUTE_UNDRIVEN_NOTE}), {total} messages on {len(self.message_counts)} topics, "
            f"{self.feature_count} rough features"
        )


#: Why a log drives less than its route: the suspension settles over the route's first
#: metres before recording starts (:data:`WARMUP_BLOCKS`), and the drive stops where the
#: controller's look-ahead reaches the route's end (``Driver.end_sigma_m``).
ROUTE_UNDRIVEN_NOTE = "its first metres settle the suspension, its last 60 m are look-ahead"


def _concat_blocks(a: TrueBlock, b: TrueBlock, tail: int) -> TrueBlock:
    values = {}
    for f in dataclasses.fields(TrueBlock):
        x, y = getattr(a, f.name), getattr(b, f.name)
        values[f.name] = np.concatenate([x[-tail:], y], axis=0)
    return TrueBlock(**values)


def simulate(
    out_path: Path,
    *,
    profile: str = "sample",
    distance_m: float | None = None,
    seed: int = 0,
    show_progress: bool = False,
    workers: int | None = None,
    lasers: bool = True,
    lidar: bool = False,
    laser_spans_m: Sequence[tuple[float, float]] | None = None,
) -> SimResult:
    """Simulate a drive and write it to ``out_path`` (complete, or not at all).

    ``workers`` processes cast the laser rays (default: as many as the machine has cores, up
    to :data:`~toolkit.sim.laser_workers.MAX_DEFAULT_WORKERS`; none on one core); the log
    does not depend on it. ``lasers=False`` leaves the laser scans out: the same log less its
    scans (every other sensor draws its noise from a generator of its own), a fast log for
    judging the physics and the labels. ``lidar=True`` adds the spinning 3-D lidar
    (:class:`~toolkit.sim.lidar.LidarParams`, on ``/ouster/points``); without it the log is
    the one written before the lidar existed (it draws from generators of its own).
    ``laser_spans_m``, (from, to) metres driven: the lasers scan only in blocks that start
    inside one of them (a long drive whose points are judged at a few places, cast where
    they are judged; the scans' noise then differs from a log scanned all the way, every
    other sensor's does not). None: everywhere.
    """
    spans = tuple(laser_spans_m) if laser_spans_m is not None else None
    if spans is not None and any(not (0.0 <= a < b) for a, b in spans):
        raise SimulationError(f"laser spans must be 0 <= from < to metres, got {spans}")
    prof = make_profile(profile, distance_m)
    if lidar and prof.lidar is None:
        prof = dataclasses.replace(prof, lidar=LidarParams())
    workers = default_workers(workers, lasers or prof.lidar is not None)
    world = make_world(prof.world, seed)
    driver, prev = _warmed_up_driver(prof, world, seed)
    suite = SensorSuite(prof, world, seed, prof.start_time_ns)
    start_sigma = driver.sigma_m
    # Progress in metres of route, known exactly (blocks depend on the speeds to come: an
    # estimate from the warm-up's speed ran past 100 % on races that sped up).
    route_m = int(np.ceil(driver.end_sigma_m - start_sigma))

    with LogWriter(out_path) as writer:
        out = _start_log(writer, prof, world, seed, suite, lasers)
        bar = progress(total=route_m, desc="sim", unit="m") if show_progress else None
        # Laser casting is most of the work; with workers it runs a few blocks ahead in other
        # processes while this one drives. Every random draw happens here, in block order,
        # so the log is the same whatever the number of workers.
        with contextlib.ExitStack() as stack:
            scanners: dict[str, BeamParams] = {"laser": prof.sensors.laser}
            if prof.lidar is not None:
                scanners["lidar"] = prof.lidar
            start_cast = start_laser_casting(stack, workers, prof.world, seed, scanners)
            loop = _BlockLoop(driver, suite, out, start_cast, bar, start_sigma, spans)
            meter = ShockMeter.for_imu(prof.sensors.imu.rate_hz, default_config().label)
            loop.run(prev, meter, lasers, ahead=2 * workers)
        out.flush(before_ns=None)
        if bar is not None:
            bar.close()
        duration_s = (driver.t_ns - prof.start_time_ns) * 1e-9
    return SimResult(
        path=out_path,
        profile=prof.name,
        seed=seed,
        duration_s=duration_s,
        distance_m=driver.sigma_m - start_sigma,
        message_counts=dict(out.counts),
        feature_count=len(world.features),
        route_m=prof.world.length_m,
    )


def _warmed_up_driver(prof: SimProfile, world: World, seed: int) -> tuple[Driver, TrueBlock]:
    """The driver at the start of the log, after :data:`WARMUP_BLOCKS` blocks that let the
    suspension settle, and the last of those blocks."""
    path = make_driven_path(world.route, np.random.default_rng([seed, 4]), prof.lane_wander_m)
    driver = Driver(
        world.route,
        world.terrain,
        path,
        prof.vehicle,
        prof.controller,
        prof.sensors.imu.mount.xyz_m,
        prof.start_time_ns - WARMUP_BLOCKS * BLOCK_SAMPLES * 1_000_000,
        prof.initial_speed_mps,
        prof.speed_schedule,
    )
    prev = driver.step(BLOCK_SAMPLES)
    for _ in range(WARMUP_BLOCKS - 1):
        prev = driver.step(BLOCK_SAMPLES)
    return driver, prev


def _start_log(
    writer: LogWriter, prof: SimProfile, world: World, seed: int, suite: SensorSuite, lasers: bool
) -> Outbox:
    """Register the topics, add the ``terrain_sim`` record and queue the once-only messages
    (``/tf_static``, ``/truth/features``) at the log's start; the outbox for the rest."""
    register_topics(writer, suite.topics_laser if lasers else [], lidar=suite.lidar is not None)
    writer.add_metadata(SIM_RECORD, sim_metadata(prof, seed, suite))
    out = Outbox(writer)
    t0 = np.array([prof.start_time_ns], dtype=np.int64)
    extra = () if prof.lidar is None else (prof.lidar.mount,)
    tf_static = static_transforms(prof.sensors, prof.start_time_ns, extra)
    out.add(TOPIC_TF_STATIC, t0, [encode_message("tf2_msgs/msg/TFMessage", tf_static)])
    features = feature_message(world, prof.start_time_ns)
    out.add(
        TOPIC_TRUTH_FEATURES,
        t0,
        [encode_message("terrain_msgs/msg/RoughFeatureArray", features)],
    )
    return out


@dataclass(frozen=True)
class _Pending:
    """A block driven whose messages wait for its rays' ranges: the true state, its IMU
    samples, and the lasers' and the lidar's rays with their ranges' futures."""

    block: TrueBlock
    imu: ImuSamples | None
    rays: LaserRays | None
    ranges: Future[FloatArray] | None
    lidar_rays: LidarRays | None
    lidar_ranges: Future[FloatArray] | None


@dataclass
class _BlockLoop:
    """Drives block by block and writes each block's messages once its laser ranges are
    back, keeping up to ``ahead`` blocks in flight."""

    driver: Driver
    suite: SensorSuite
    out: Outbox
    start_cast: Callable[[str, Rays], Future[FloatArray]]
    bar: Any
    #: Where along the route the log starts (m): the bar counts metres from it.
    start_sigma_m: float = 0.0
    #: Metres driven (from, to) where the lasers scan; None: everywhere.
    laser_spans_m: tuple[tuple[float, float], ...] | None = None
    pending: deque[_Pending] = dataclasses.field(default_factory=deque)

    def run(self, prev: TrueBlock, meter: ShockMeter, lasers: bool, ahead: int) -> None:
        """Drive to the route's end from ``prev``, the last block driven, and write it all."""
        driver, suite = self.driver, self.suite
        while driver.sigma_m < driver.end_sigma_m:
            block = driver.step(BLOCK_SAMPLES)
            ext = _concat_blocks(prev, block, HISTORY_SAMPLES)
            imu = suite.sample_imu(ext, HISTORY_SAMPLES)
            if imu is not None:  # the controller reads the shock its IMU felt
                shock_g = meter.read(imu.accel_mps2[:, 2])
                driver.controller.on_shock(shock_g, float(block.speed_mps[-1]))
            scan = lasers and self._scans_at(float(block.sigma_m[0]) - self.start_sigma_m)
            rays = suite.plan_lasers(ext, HISTORY_SAMPLES) if scan else None
            future = self.start_cast("laser", rays) if rays is not None else None
            lidar = suite.lidar.plan(ext, HISTORY_SAMPLES) if suite.lidar is not None else None
            lidar_future = self.start_cast("lidar", lidar) if lidar is not None else None
            self.pending.append(_Pending(block, imu, rays, future, lidar, lidar_future))
            if len(self.pending) > ahead:
                self.finish_oldest()
            prev = block
        while self.pending:
            self.finish_oldest()

    def _scans_at(self, driven_m: float) -> bool:
        """Whether the lasers scan in a block that starts ``driven_m`` into the log."""
        spans = self.laser_spans_m
        return spans is None or any(a <= driven_m < b for a, b in spans)

    def finish_oldest(self) -> None:
        """Encode the oldest pending block's messages and release those due before its end."""
        done = self.pending.popleft()
        block, imu, rays, future = done.block, done.imu, done.rays, done.ranges
        suite, out = self.suite, self.out
        suite.imu(imu, out)
        suite.wheels(block, out)
        suite.gps(block, out)
        suite.truth(block, out)
        if rays is not None and future is not None:
            suite.finish_lasers(rays, future.result(), out)
        lidar, lidar_rays, lidar_ranges = suite.lidar, done.lidar_rays, done.lidar_ranges
        if lidar is not None and lidar_rays is not None and lidar_ranges is not None:
            lidar.finish(lidar_rays, lidar_ranges.result(), out)
        out.flush(before_ns=int(block.t_ns[-1]) + self.driver.dt_ns)
        if self.bar is not None:  # metres driven by the end of this block
            self.bar.update(max(0, int(block.sigma_m[-1] - self.start_sigma_m) - self.bar.n))
