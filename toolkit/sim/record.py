"""The simulator's record in the metadata of the logs it writes, and the origin it holds.

``terrain sim`` adds an MCAP metadata record named :data:`SIM_RECORD` (profile, seed, the
world's parameters and its frame's geodetic origin): the stages that compare with the truth
rebuild the simulated world from it, and find its frame through :func:`sim_origin`.
:func:`sim_metadata` writes it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import TYPE_CHECKING

import toolkit
from toolkit.geometry.geodesy import GeodeticOrigin

if TYPE_CHECKING:
    from toolkit.sim.profiles import SimProfile
    from toolkit.sim.suite import SensorSuite

#: The metadata record and key holding the simulator's world-frame origin.
SIM_RECORD = "terrain_sim"
SIM_ORIGIN_KEY = "origin"


def sim_origin(mcap_metadata: Mapping[str, Mapping[str, str]]) -> GeodeticOrigin | None:
    """The simulator's world-frame origin from the log's metadata records (None if absent
    or unreadable: not a simulated log)."""
    text = mcap_metadata.get(SIM_RECORD, {}).get(SIM_ORIGIN_KEY)
    if text is None:
        return None
    try:
        o = json.loads(text)
        return GeodeticOrigin(
            float(o["latitude_deg"]), float(o["longitude_deg"]), float(o["altitude_m"])
        )
    except (ValueError, KeyError, TypeError):
        return None


def _jsonable(obj: object) -> object:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple | list):
        return [_jsonable(x) for x in obj]
    return obj


def sim_metadata(profile: SimProfile, seed: int, suite: SensorSuite) -> dict[str, str]:
    """The ``terrain_sim`` metadata record: enough to rebuild the world and every truth.

    Besides the parameters (``sensors`` holds every :class:`LaserParams` field), the lasers'
    draws: ``laser_true_mounts`` (frame -> true ``xyz_m`` and ``rpy_rad``; ``/tf_static`` has
    the nominal ones), ``laser_range_bias_m`` (frame -> constant range bias) and
    ``laser_phase_ns`` (frame -> true start of the first scan after ``start_time_ns``, so a
    scan's true start is ``start + phase + n / rate_hz``: the stamp less the clock offset,
    within its jitter, rounds to it)."""
    return {
        "profile": profile.name,
        "seed": str(seed),
        "toolkit_version": toolkit.__version__,
        "length_m": repr(profile.world.length_m),
        "start_time_ns": str(profile.start_time_ns),
        SIM_ORIGIN_KEY: json.dumps(_jsonable(profile.origin)),
        "world": json.dumps(_jsonable(profile.world)),
        "vehicle": json.dumps(_jsonable(profile.vehicle)),
        "sensors": json.dumps(_jsonable(profile.sensors)),
        "controller": json.dumps(_jsonable(profile.controller)),
        "clock_offsets_ns": json.dumps({t: c.offset_ns for t, c in suite.clocks.items()}),
        "gps_dropouts_ns": json.dumps(suite.dropouts),
        "wheel_scale": json.dumps(suite.wheel_scale.tolist()),
        "laser_true_mounts": json.dumps(
            {m.frame_id: {"xyz_m": m.xyz_m, "rpy_rad": m.rpy_rad} for m in suite.laser_truth.mounts}
        ),
        "laser_range_bias_m": json.dumps(
            {
                m.frame_id: b
                for m, b in zip(
                    suite.laser_truth.mounts, suite.laser_truth.range_bias_m, strict=True
                )
            }
        ),
        "laser_phase_ns": json.dumps(
            {
                m.frame_id: float(ph)
                for m, ph in zip(suite.laser_truth.mounts, suite.laser_phase_ns, strict=True)
            }
        ),
        **_lidar_metadata(profile, suite),
    }


def _lidar_metadata(profile: SimProfile, suite: SensorSuite) -> dict[str, str]:
    """The lidar's part of the record, only when the log has one (so a log without it keeps
    its record byte for byte): ``lidar`` (every :class:`~toolkit.sim.lidar.LidarParams`
    field, ``mount`` the published one) and ``lidar_truth``: the true ``mount`` (``xyz_m``,
    ``rpy_rad``), each ring's ``range_bias_m``, the clock's ``clock_offset_ns`` (a cloud's
    stamp less it is its first column's true time) and ``phase_ns`` (scan ``n``'s first
    column fires at ``start_time_ns + phase_ns + n / rate_hz``, column ``c`` ``c / (columns
    rate_hz)`` later)."""
    if profile.lidar is None or suite.lidar is None:
        return {}
    truth = suite.lidar.truth
    return {
        "lidar": json.dumps(_jsonable(profile.lidar)),
        "lidar_truth": json.dumps(
            {
                "mount": {"xyz_m": truth.mount.xyz_m, "rpy_rad": truth.mount.rpy_rad},
                "range_bias_m": truth.range_bias_m,
                "clock_offset_ns": truth.clock_offset_ns,
                "phase_ns": truth.phase_ns,
            }
        ),
    }


__all__ = ["SIM_ORIGIN_KEY", "SIM_RECORD", "sim_metadata", "sim_origin"]
