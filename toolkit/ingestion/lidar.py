"""The 3-D lidar role: ``sensor_msgs/PointCloud2`` clouds to the ``lidar`` table, a row a return.

A cloud is decoded without a Python loop per point (:mod:`toolkit.mcapio.pointcloud2`: a numpy
structured view of the message's own bytes, whatever the driver's layout). Per cloud:

- **Valid returns only.** Points without a finite x, y, z or exactly at the sensor's origin
  (Ouster's "no return") are dropped, whatever ``is_dense`` claims; so are rings not in
  ``[lidar] rings`` and ranges outside ``[min_range_m, max_range_m]``. Each is counted per
  reason (``lidar_non_finite``, ``lidar_zero_range``, ``lidar_ring_not_kept``,
  ``lidar_out_of_range``) in the manifest.
- **Each return at its own time.** ``[lidar] time`` names a driver's preset, ``auto`` (the
  preset whose driver writes these field names,
  :func:`~toolkit.mcapio.pointcloud2.preset_for_fields`) or ``custom`` (the ``time_*``
  keys). A cloud without a time field puts every return at its header stamp: motion
  correction is then off, which the manifest counts (``lidar_no_point_time``, clouds) and
  ingest says once on the terminal.
- **Clocks.** A header stamp further than ``[time] max_header_skew_ns`` from the log time is a
  sensor on its own clock (an Ouster in its default mode stamps time since boot: 1970 dates):
  the scan is re-anchored at its log time, its points keeping their offsets within the sweep,
  and counted (``lidar_sensor_clock``). Absolute per-point times on another clock than the
  header's are anchored the same way, at the header stamp (``lidar_point_clock``). Returns
  stamped further than :data:`MAX_SWEEP_NS` from their scan's stamp (implausible times, as
  after dropped packets) are dropped and counted (``lidar_time_outside_sweep``).
- **A sweep as long as its period.** Once every cloud is read, each cloud's span of point
  times is set against the topic's period (the median step between its clouds' stamps): a
  spinning lidar's sweep spans about one period. A span over :data:`SPAN_LONG` periods or
  under :data:`SPAN_SHORT` of one (a time field in another unit than the preset's, another
  field than the time, a driver's clock jumping within a sweep) is counted per cloud
  (``lidar_span_off_period``) and said on the terminal: the points are kept, as the times
  within each cloud are still ordered, but motion correction is then wrong.

The table's ``t_ns`` is the return's time, ``scan_t_ns`` its cloud's, both corrected by the
role's declared latency and clock offset. The rows of one batch are one table; the messages'
own checks (duplicates, bad payloads) are the ingest's, as for every role.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.arrays import IntArray
from toolkit.config import LidarConfig
from toolkit.errors import CloudLayoutError, StageError
from toolkit.ingestion.accounts import TopicAccount
from toolkit.ingestion.rows import Columns, ConvertContext, RoleRows
from toolkit.mcapio.pointcloud2 import (
    PRESETS,
    Cloud,
    PointTime,
    cloud_dtype,
    cloud_points,
    parse_cloud,
    point_times_ns,
    preset_for_fields,
    xyz_valid,
)

#: The message type of the role.
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"

#: A return stamped further than this from its scan's stamp is no return of that sweep: the
#: slowest spinning lidars of the drivers' table turn at 5 Hz (200 ms a sweep); 0.5 s leaves
#: room for a header at either end and a late packet, and no more.
MAX_SWEEP_NS = 500_000_000

#: A cloud's points spanning more than this many periods, or less than this share of one, is
#: no sweep of a lidar turning at the clouds' rate. A spinning lidar's sweep spans ~1 period
#: (ouster-ros: 1023/1024 of it; velodyne_pointcloud: one turn); 1.5 leaves room for a cloud
#: that closed late; 0.1 lets a driver crop its field of view to 36 degrees before being
#: questioned, while a unit read 1000 times too small (us as ns) always is.
SPAN_LONG = 1.5
SPAN_SHORT = 0.1

#: Fields that number a return's beam, by driver: ouster, velodyne, rslidar "ring"; nebula
#: "channel"; livox "line".
RING_FIELDS: tuple[str, ...] = ("ring", "channel", "line")
#: Fields holding a return's intensity (every driver of the table calls it so).
INTENSITY_FIELDS: tuple[str, ...] = ("intensity",)

#: Per-cloud counts this converter reports (see the module docstring).
COUNTS: tuple[str, ...] = (
    "lidar_non_finite",
    "lidar_zero_range",
    "lidar_ring_not_kept",
    "lidar_out_of_range",
    "lidar_time_outside_sweep",
    "lidar_no_point_time",
    "lidar_sensor_clock",
    "lidar_point_clock",
    "lidar_span_off_period",
)


def check_sweeps(accounts: Mapping[str, TopicAccount]) -> None:
    """Count, per lidar topic, the clouds whose span of point times is off the topic's period
    (``lidar_span_off_period``; the module docstring), from the (stamp, span) pairs ingest
    kept of each cloud, and free them. A topic of fewer than two clouds has no period."""
    for account in accounts.values():
        if not account.sweeps:
            continue
        stamps = np.concatenate([s for s, _ in account.sweeps])
        spans = np.concatenate([d for _, d in account.sweeps])
        account.sweeps.clear()
        steps = np.diff(np.unique(stamps))
        if not len(steps):
            continue
        period = float(np.median(steps))
        known = spans >= 0
        off = known & ((spans > SPAN_LONG * period) | (spans < SPAN_SHORT * period))
        account.counts["lidar_span_off_period"] += int(np.count_nonzero(off))
        account.period_ns = period


def lidar_notices(accounts: Mapping[str, TopicAccount]) -> list[str]:
    """What a user must know of the lidars' clouds, a line per topic and kind (the terminal
    says them; the manifest counts them)."""
    out: list[str] = []
    for topic, account in accounts.items():
        if account.role != "lidars":
            continue
        c = account.counts
        if c["lidar_no_point_time"]:
            out.append(
                f"{topic}: {c['lidar_no_point_time']} of {account.written} clouds have no "
                "per-point time: each return is at its cloud's stamp (motion correction off); "
                "set [lidar] time if the driver writes one"
            )
        if c["lidar_sensor_clock"]:
            out.append(
                f"{topic}: {c['lidar_sensor_clock']} clouds stamped on the sensor's own clock "
                "(far from the log's time): re-anchored at their log time, their points' offsets "
                "kept; set the driver to the system clock or declare [time] clock_offset_ns"
            )
        if c["lidar_point_clock"]:
            out.append(
                f"{topic}: {c['lidar_point_clock']} clouds' absolute point times are on another "
                "clock than their stamps: anchored at the stamp, offsets kept"
            )
        if c["lidar_span_off_period"]:
            out.append(
                f"{topic}: {c['lidar_span_off_period']} of {account.written} clouds' point "
                f"times span more than {SPAN_LONG:g} or less than {SPAN_SHORT:g} of the clouds' "
                f"period ({account.period_ns / 1e6:.1f} ms): motion correction will be wrong; "
                "check [lidar] time (its field and unit) against the driver"
            )
        if c["lidar_time_outside_sweep"]:
            out.append(
                f"{topic}: {c['lidar_time_outside_sweep']} returns stamped over "
                f"{MAX_SWEEP_NS / 1e9:g} s from their cloud's stamp dropped"
            )
    return out


def decode_clouds(topic: str) -> Any:
    """The decoder of a PointCloud2 topic: payloads -> ``{"cloud": (n,) object array}`` of
    :class:`~toolkit.mcapio.pointcloud2.Cloud` headers with zero-copy views of the points. A
    truncated payload raises a :class:`~toolkit.errors.CdrError` (ingest rejects it alone as
    ``bad_payload``)."""

    def decode(payloads: Sequence[bytes]) -> dict[str, np.ndarray]:
        clouds = np.empty(len(payloads), dtype=object)
        for i, payload in enumerate(payloads):
            clouds[i] = parse_cloud(payload, topic=topic)
        return {"cloud": clouds}

    return decode


def point_time_spec(settings: LidarConfig, field_names: Sequence[str]) -> tuple[str, PointTime]:
    """The name and the :class:`PointTime` of ``[lidar] time`` for a cloud with these fields."""
    if settings.time == "custom":
        unit: Any = settings.time_unit
        reference: Any = settings.time_reference
        header_at: Any = settings.header_at
        return "custom", PointTime(settings.time_field or None, unit, reference, header_at)
    name = preset_for_fields(field_names) if settings.time == "auto" else settings.time
    return name, PRESETS[name]


def lidar_from_pointcloud2(cols: Columns, log_time_ns: IntArray, ctx: ConvertContext) -> RoleRows:
    """sensor_msgs/PointCloud2 -> one row per valid return (the module docstring): t_ns,
    scan_t_ns, lidar (topic), frame_id, ring, x, y, z (sensor frame, m), intensity."""
    settings = ctx.lidar if ctx.lidar is not None else LidarConfig()
    clouds: Sequence[Cloud] = list(cols["cloud"])
    n = len(clouds)
    counts = {key: np.zeros(n, dtype=np.int64) for key in COUNTS}
    missing = np.zeros(n, dtype=bool)
    scan_t = np.zeros(n, dtype=np.int64)
    span = np.full(n, -1, dtype=np.int64)
    pieces: list[dict[str, Any]] = []
    for i, cloud in enumerate(clouds):
        log_t = int(log_time_ns[i])
        if cloud.stamp_ns == 0:
            missing[i], stamp = True, log_t
        elif abs(cloud.stamp_ns - log_t) > ctx.max_header_skew_ns > 0:
            counts["lidar_sensor_clock"][i], stamp = 1, log_t
        else:
            stamp = cloud.stamp_ns
        piece, t_scan = _cloud_rows(cloud, stamp, settings, counts, i)
        scan_t[i] = t_scan + (0 if missing[i] else ctx.correction_ns)
        if piece is not None:
            if not missing[i]:
                piece["t_ns"] += ctx.correction_ns
            piece["scan_t_ns"] = np.full(len(piece["t_ns"]), scan_t[i], dtype=np.int64)
            if counts["lidar_no_point_time"][i] == 0 and len(piece["t_ns"]) > 1:
                span[i] = int(piece["t_ns"][-1] - piece["t_ns"][0])  # in time order
            pieces.append(piece)
    message_of_row = np.concatenate(
        [np.full(len(p["t_ns"]), p["message"], dtype=np.int64) for p in pieces]
        or [np.zeros(0, dtype=np.int64)]
    )
    table = _table(pieces, [c.topic for c in clouds], [c.frame_id for c in clouds])
    metadata = {"lidar_time_presets": ",".join(sorted({p["preset"] for p in pieces}))}
    return RoleRows(
        table,
        finite=np.ones(n, dtype=bool),
        stamp_missing=missing,
        counts=counts,
        metadata=metadata if pieces else {},
        message_of_row=message_of_row,
        message_t_ns=scan_t,
        span_ns=span,
    )


def _cloud_rows(
    cloud: Cloud,
    stamp_ns: int,
    settings: LidarConfig,
    counts: dict[str, IntArray],
    i: int,
) -> tuple[dict[str, Any] | None, int]:
    """The valid returns of one cloud as columns, and the scan's stamp (ns, log clock)."""
    try:
        dtype = cloud_dtype(cloud.fields, cloud.point_step, cloud.is_bigendian, topic=cloud.topic)
        points = cloud_points(cloud, dtype)
    except CloudLayoutError as exc:
        raise StageError(f"{exc}; its clouds cannot be read") from None
    xyz, keep, drops = xyz_valid(points)
    counts["lidar_non_finite"][i] = drops.non_finite
    counts["lidar_zero_range"][i] = drops.zero_range
    names = tuple(dtype.names or ())
    preset, spec = point_time_spec(settings, names)
    try:
        t_ns = point_times_ns(points, cloud.stamp_ns, spec, topic=cloud.topic, keep=keep)
    except CloudLayoutError as exc:
        raise StageError(f"{exc}; set [lidar] time for this driver") from None
    if spec.field is None:
        counts["lidar_no_point_time"][i] = 1
    # Re-anchor on the log's clock: offsets within the sweep are kept.
    off_clock = len(t_ns) and abs(int(t_ns.min()) - cloud.stamp_ns) > MAX_SWEEP_NS
    if spec.reference == "absolute" and off_clock:
        counts["lidar_point_clock"][i] = 1
        t_ns = t_ns - t_ns.min() + np.int64(cloud.stamp_ns)
    t_ns = t_ns + np.int64(stamp_ns - cloud.stamp_ns)
    ring = _first_field(points, RING_FIELDS, keep)
    intensity = _first_field(points, INTENSITY_FIELDS, keep)
    xyz64 = xyz.astype(np.float64)
    range_m = np.sqrt(np.einsum("ij,ij->i", xyz64, xyz64))
    kept = np.ones(len(t_ns), dtype=bool)
    if settings.rings and ring is not None:
        in_rings = np.isin(ring, np.asarray(settings.rings))
        counts["lidar_ring_not_kept"][i] = int(np.count_nonzero(~in_rings))
        kept &= in_rings
    in_range = (range_m >= settings.min_range_m) & (range_m <= settings.max_range_m)
    counts["lidar_out_of_range"][i] = int(np.count_nonzero(kept & ~in_range))
    kept &= in_range
    in_sweep = np.abs(t_ns - np.int64(stamp_ns)) <= MAX_SWEEP_NS
    counts["lidar_time_outside_sweep"][i] = int(np.count_nonzero(kept & ~in_sweep))
    kept &= in_sweep
    if not kept.any():
        return None, stamp_ns
    # In time order within the cloud (a driver lays its points out ring by ring, each ring
    # sweeping the whole period): the clouds then arrive as sorted runs, which the table's
    # reorder buffer writes without sorting them again.
    rows = np.flatnonzero(kept)
    rows = rows[np.argsort(t_ns[rows], kind="stable")]
    return {
        "message": i,
        "preset": preset,
        "t_ns": t_ns[rows],
        "ring": None if ring is None else ring[rows].astype(np.uint16),
        "x": xyz[rows, 0].astype(np.float32),
        "y": xyz[rows, 1].astype(np.float32),
        "z": xyz[rows, 2].astype(np.float32),
        "intensity": None if intensity is None else intensity[rows].astype(np.float32),
    }, stamp_ns


def _first_field(points: np.ndarray, names: Sequence[str], keep: np.ndarray) -> Any:
    """The first of ``names`` the points hold, at the kept points (None when none)."""
    for name in names:
        if name in (points.dtype.names or ()) and points[name].ndim == 1:
            return points[name][keep]
    return None


def _repeated(values: Sequence[str], message_of_row: IntArray) -> pa.Array:
    """Per-message strings repeated over their rows, as dictionary codes (no Python string
    per row)."""
    uniques = sorted(set(values))
    code = np.array([uniques.index(v) for v in values], dtype=np.int32)
    return pa.DictionaryArray.from_arrays(pa.array(code[message_of_row]), pa.array(uniques))


def _table(pieces: list[dict[str, Any]], topics: Sequence[str], frames: Sequence[str]) -> pa.Table:
    """The batch's rows: the pieces concatenated, nullable columns null where a cloud lacks
    the field."""
    message = np.concatenate(
        [np.full(len(p["t_ns"]), p["message"], dtype=np.int64) for p in pieces]
        or [np.zeros(0, dtype=np.int64)]
    )

    def column(name: str, dtype: Any) -> pa.Array:
        parts = [
            p[name] if p[name] is not None else np.zeros(len(p["t_ns"]), dtype) for p in pieces
        ]
        values = np.concatenate(parts) if parts else np.zeros(0, dtype)
        if all(p[name] is not None for p in pieces):
            return pa.array(values)
        null = np.concatenate([np.full(len(p["t_ns"]), p[name] is None) for p in pieces])
        return pa.array(values, mask=null)

    return pa.table(
        {
            "t_ns": column("t_ns", np.int64),
            "scan_t_ns": column("scan_t_ns", np.int64),
            "lidar": _repeated(topics, message) if len(topics) else pa.array([], pa.string()),
            "frame_id": _repeated(frames, message) if len(frames) else pa.array([], pa.string()),
            "ring": column("ring", np.uint16),
            "x": column("x", np.float32),
            "y": column("y", np.float32),
            "z": column("z", np.float32),
            "intensity": column("intensity", np.float32),
        }
    )


__all__ = [
    "COUNTS",
    "MAX_SWEEP_NS",
    "SPAN_LONG",
    "SPAN_SHORT",
    "check_sweeps",
    "POINTCLOUD2",
    "decode_clouds",
    "lidar_from_pointcloud2",
    "lidar_notices",
    "point_time_spec",
]
