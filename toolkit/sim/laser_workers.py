"""Casting the laser rays in worker processes, a few blocks ahead of the drive.

Casting is about two thirds of a race log's CPU time. Every random draw stays in the main
process, in block order, and a worker rebuilds the world from ``(params, seed)``
(deterministic), so only rays and ranges cross the process boundary and the log is the same
whatever the number of workers.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.pools import process_pool
from toolkit.sim.raycast import RayCaster
from toolkit.sim.terrain import WindowCache
from toolkit.sim.world import make_world
from toolkit.sim.world_params import WorldParams

# Casting the rays is about two thirds of a race log's CPU time and the rest (the vehicle,
# the other sensors, writing) stays in the main process: on two cores two casters and the
# main process share them best (6 km race: 10.3x real time, against 7.9x with one caster
# and 6.7x with none); beyond three the main process sets the pace.
MAX_DEFAULT_WORKERS = 3


def default_workers(workers: int | None, lasers: bool) -> int:
    """The caster processes to use: ``workers`` if given, else one per core up to
    :data:`MAX_DEFAULT_WORKERS` (none on one core); none without lasers or lidar (``lasers``
    False: nothing to cast)."""
    if workers is None:
        cores = os.cpu_count() or 1
        workers = min(cores, MAX_DEFAULT_WORKERS) if cores > 1 else 0
    if not lasers:
        workers = 0  # nothing to cast
    return workers


@dataclass(frozen=True)
class LaserRays:
    """One block's laser rays: ``origin`` and unit ``direction`` (n_scans * beams, 3) in ENU,
    with the scans' true start times, laser indices and the vehicle's speed (n_scans,), and
    the stretch of route (``s_lo_m`` .. ``s_hi_m``) the rays can reach."""

    starts_ns: NDArray[np.int64]
    laser_index: NDArray[np.intp]
    speed_mps: FloatArray
    origin: FloatArray
    direction: FloatArray
    s_hint_m: float
    s_lo_m: float
    s_hi_m: float


class BeamParams(Protocol):
    """What the ray caster needs of a scanner: the 2-D lasers'
    :class:`~toolkit.sim.sensors.LaserParams` or the lidar's
    :class:`~toolkit.sim.lidar.LidarParams`."""

    @property
    def range_max_m(self) -> float: ...
    @property
    def range_min_m(self) -> float: ...
    @property
    def beam_divergence_rad(self) -> float: ...
    @property
    def footprint_samples(self) -> int: ...
    @property
    def footprint_spacing_m(self) -> float: ...
    @property
    def occluder_samples(self) -> int: ...
    @property
    def occluder_spacing_m(self) -> float: ...
    @property
    def occluder_height_m(self) -> float: ...


class Rays(Protocol):
    """Rays to cast: ``origin`` and unit ``direction`` (n, 3) in ENU, and the stretch of
    route (``s_lo_m`` .. ``s_hi_m``) they can reach, ``s_hint_m`` near their origins."""

    @property
    def origin(self) -> FloatArray: ...
    @property
    def direction(self) -> FloatArray: ...
    @property
    def s_hint_m(self) -> float: ...
    @property
    def s_lo_m(self) -> float: ...
    @property
    def s_hi_m(self) -> float: ...


class LaserCaster:
    """Casts a block's rays into the world; lives in the main process or in a worker.

    A worker rebuilds the world from ``(params, seed)``, which is deterministic, so only the
    rays and ranges cross the process boundary. One caster per scanner kind (``laser``, and
    ``lidar`` when the log has one), sharing the world, each with its own terrain window
    (the lidar looks behind as far as ahead).
    """

    def __init__(
        self, world_params: WorldParams, seed: int, scanners: Mapping[str, BeamParams]
    ) -> None:
        world = make_world(world_params, seed)
        self.windows = {kind: WindowCache(world.terrain) for kind in scanners}
        self.casters = {
            kind: RayCaster(
                world.route,
                world.terrain.crossfall,
                max_range_m=p.range_max_m,
                min_range_m=p.range_min_m,
                divergence_rad=p.beam_divergence_rad,
                footprint_samples=p.footprint_samples,
                footprint_spacing_m=p.footprint_spacing_m,
                occluder_samples=p.occluder_samples,
                occluder_spacing_m=p.occluder_spacing_m,
                occluder_height_m=p.occluder_height_m,
            )
            for kind, p in scanners.items()
        }

    def __call__(self, kind: str, rays: Rays) -> FloatArray:
        window = self.windows[kind].covering(rays.s_lo_m, rays.s_hi_m)
        return self.casters[kind].cast(window, rays.origin, rays.direction, rays.s_hint_m)


_WORKER_CASTER: LaserCaster | None = None


def _init_caster_worker(
    world_params: WorldParams, seed: int, scanners: Mapping[str, BeamParams]
) -> None:
    global _WORKER_CASTER
    _WORKER_CASTER = LaserCaster(world_params, seed, scanners)


def _cast_now(caster: LaserCaster, kind: str, rays: Rays) -> Future[FloatArray]:
    """Cast in this process; a completed future, so both paths look alike to the caller."""
    done: Future[FloatArray] = Future()
    done.set_result(caster(kind, rays))
    return done


def _cast_in_worker(kind: str, rays: Rays) -> FloatArray:
    if _WORKER_CASTER is None:
        raise RuntimeError("laser worker used before its initialiser ran")
    return _WORKER_CASTER(kind, rays)


def start_laser_casting(
    stack: contextlib.ExitStack[Any],
    workers: int,
    world_params: WorldParams,
    seed: int,
    scanners: Mapping[str, BeamParams],
) -> Callable[[str, Rays], Future[FloatArray]]:
    """A function that starts casting a block's rays of one scanner kind (a key of
    ``scanners``: ``laser``, ``lidar``) and returns their ranges' future: in ``workers``
    processes (a pool that ``stack`` stops at once on an interrupt or error,
    :mod:`toolkit.pools`), or, with none, in this process."""
    if workers > 0:
        executor = stack.enter_context(
            process_pool(
                workers,
                initializer=_init_caster_worker,
                initargs=(world_params, seed, dict(scanners)),
            )
        )

        def start_cast(kind: str, rays: Rays) -> Future[FloatArray]:
            return executor.submit(_cast_in_worker, kind, rays)

        return start_cast
    return partial(_cast_now, LaserCaster(world_params, seed, scanners))
