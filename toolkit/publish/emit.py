"""The view written as an MCAP file in Foxglove's well-known message schemas (protobuf,
through the ``foxglove-sdk`` package): one channel per topic, the small topics' messages
merged into the stream of point clouds in log-time order, deterministically (the same scene
gives the same bytes). See ``docs/viz.md``."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import foxglove
import numpy as np
from foxglove.channels import (
    FrameTransformsChannel,
    LocationFixChannel,
    PointCloudChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPWriteOptions
from foxglove.messages import (
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    LocationFix,
    LocationFixPositionCovarianceType,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    PointCloud,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    Vector3,
)
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.config import PipelineConfig
from toolkit.geometry.frames import ORIGIN_MIN_STATUS, valid_fixes
from toolkit.geometry.rotations import quaternion_zyx
from toolkit.layout import LogFiles
from toolkit.publish.scene import (
    DESCRIPTIONS,
    GPS_COLUMNS,
    TOPIC_EVENTS,
    TOPIC_GPS,
    TOPIC_POINTS,
    TOPIC_TF,
    TOPIC_TRUTH,
    TRUTH_STEP_M,
    WORLD_FRAME,
    AxlePath,
    Cloud,
    CloudSettings,
    EventRows,
    PoseRows,
    Scene,
    column_array,
    event_box_colors,
    iter_clouds,
    path_vertices,
    point_colors,
    require_times,
    tf_rows,
)
from toolkit.tableio import read_table

#: The event boxes: height (m) and opacity.
BOX_HEIGHT_M = 0.05
BOX_ALPHA = 0.5
#: Thickness of the true path's line, m.
TRUTH_LINE_M = 0.15
TRUTH_COLOR = (0.2, 0.45, 1.0, 1.0)
#: Colour (uint8 RGBA) of points on no scored event.
GREY = (128, 128, 128, 255)

#: One point of a cloud, little-endian as Foxglove reads it.
POINT_DTYPE = np.dtype(
    [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
        ("alpha", "u1"),
        ("r_combined", "<f4"),
    ]
)
_NUMERIC_TYPE = {
    np.dtype("<f4"): PackedElementFieldNumericType.Float32,
    np.dtype("u1"): PackedElementFieldNumericType.Uint8,
}


def _point_fields() -> list[PackedElementField]:
    fields = POINT_DTYPE.fields
    assert fields is not None  # a structured dtype
    return [
        PackedElementField(
            name=name, offset=int(fields[name][1]), type=_NUMERIC_TYPE[fields[name][0]]
        )
        for name in POINT_DTYPE.names or ()
    ]


POINT_FIELDS = _point_fields()


def _stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return Timestamp(sec, nsec)


def _color(rgb: FloatArray, alpha: float) -> Color:
    return Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=alpha)


def _identity() -> Pose:
    return Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(w=1.0))


# --------------------------------------------------------------------------------------
# The small topics, merged in time order
# --------------------------------------------------------------------------------------


class _Timeline:
    """The messages of the small topics in log-time order, logged as the clouds' times
    pass. Each stream is (times, ``emit``), ``emit(row)`` logging its row-th message; ties
    go by stream order, then row, so the order is deterministic."""

    def __init__(self, streams: list[tuple[IntArray, Callable[[int], None]]]) -> None:
        empty = [np.zeros(0, np.int64)]
        t = np.concatenate([s[0] for s in streams] + empty)
        rank = np.concatenate(
            [np.full(s[0].size, r, np.int64) for r, s in enumerate(streams)] + empty
        )
        row = np.concatenate([np.arange(s[0].size, dtype=np.int64) for s in streams] + empty)
        order = np.lexsort((row, rank, t))
        self._t, self._rank, self._row = t[order], rank[order], row[order]
        self._emit = tuple(s[1] for s in streams)
        self._next = 0

    def play_until(self, t_ns: int | None = None) -> None:
        """Log the messages not later than ``t_ns`` (all the rest with None)."""
        n = int(self._t.size)
        while self._next < n and (t_ns is None or int(self._t[self._next]) <= t_ns):
            self._emit[int(self._rank[self._next])](int(self._row[self._next]))
            self._next += 1


#: One small topic's messages: their log times and ``emit(row)``, which logs the row-th.
_Stream = tuple[IntArray, Callable[[int], None]]


def write_mcap(
    path: Path,
    scene: Scene,
    config: PipelineConfig,
    metadata: dict[str, str],
    clouds: CloudSettings,
) -> dict[str, int]:
    """Write the MCAP at ``path``; returns the counts of :class:`VizResult`."""
    # A context of our own: channels of the SDK's global context (anyone else's in this
    # process) would otherwise be recorded into this file too.
    ctx = foxglove.Context()
    # One compression thread: the output is then the same bytes on every machine.
    options = MCAPWriteOptions(compression_threads=0)
    counts = {
        "transforms": 0,
        "clouds": 0,
        "cloud_points": 0,
        "points_read": 0,
        "events": 0,
        "rough_events": 0,
        "scored_events": 0,
        "coloured_points": 0,
        "gps_fixes": 0,
        "gps_without_fix": 0,
        "truth_paths": 0,
        "truth_vertices": 0,
    }
    with foxglove.open_mcap(path, context=ctx, writer_options=options) as writer:
        writer.write_metadata("terrain.viz", metadata)
        timeline = _Timeline(_small_streams(scene, ctx, config, counts))
        # /points, the stream everything else is merged into
        if scene.has("points"):
            _log_clouds(scene, ctx, config, clouds, timeline, counts)
        timeline.play_until(None)  # the small topics' messages after the last cloud
    return counts


def _small_streams(
    scene: Scene, ctx: foxglove.Context, config: PipelineConfig, counts: dict[str, int]
) -> list[_Stream]:
    """The streams of ``/tf``, ``/gps``, ``/events`` and ``/truth/path`` (their channels
    made in this order, which numbers them in the file), their messages counted."""
    streams = [_tf_stream(scene.pose, ctx, config)]
    counts["transforms"] = int(streams[0][0].size)
    if scene.has("gps"):
        gps_stream, n_fix, n_without = _gps_stream(LogFiles(scene.log_dir).gps, ctx, config)
        streams.append(gps_stream)
        counts["gps_fixes"], counts["gps_without_fix"] = n_fix, n_without
    events = scene.events
    if len(events):
        streams.append(_event_stream(events, scene.pose, ctx, config))
        counts["events"] = len(events)
        counts["rough_events"] = int(events.rough.sum())
        counts["scored_events"] = int(events.scored.sum())
    if scene.has("truth_pose"):
        truth = _truth_stream(LogFiles(scene.log_dir).truth_pose, ctx)
        if truth is not None:
            stream, vertices = truth
            streams.append(stream)
            counts["truth_paths"], counts["truth_vertices"] = 1, vertices
    return streams


def _log_clouds(
    scene: Scene,
    ctx: foxglove.Context,
    config: PipelineConfig,
    clouds: CloudSettings,
    timeline: _Timeline,
    counts: dict[str, int],
) -> None:
    """``/points``: every window's cloud, each logged after the small topics' messages up
    to its time; a point coloured by the score of the event stretch it lies on."""
    cloud_channel = PointCloudChannel(
        TOPIC_POINTS, context=ctx, metadata={"description": DESCRIPTIONS[TOPIC_POINTS]}
    )
    axle = AxlePath.of(scene.pose)
    half = 0.5 * config.vehicle.track_m
    events = scene.events
    for cloud in iter_clouds(LogFiles(scene.log_dir).points, clouds.period_ns, clouds.max_points):
        counts["points_read"] += cloud.rows_read
        timeline.play_until(cloud.t_ns)
        on = axle.events_under(cloud.x, cloud.y, events, half)
        colored = on >= 0
        colored[colored] = events.scored[on[colored]]
        r = np.full(cloud.x.size, np.nan)
        r[colored] = events.r_combined[on[colored]]
        rgba = np.empty((cloud.x.size, 4), dtype=np.uint8)
        rgba[:] = GREY
        rgb = point_colors(r[colored], events.predicted[on[colored]], events.r_low, scene.mu)
        rgba[colored, :3] = np.round(rgb * 255.0).astype(np.uint8)
        cloud_channel.log(_point_cloud(cloud, rgba, r), log_time=cloud.t_ns)
        counts["clouds"] += 1
        counts["cloud_points"] += int(cloud.x.size)
        counts["coloured_points"] += int(colored.sum())


def _tf_stream(pose: PoseRows, ctx: foxglove.Context, config: PipelineConfig) -> _Stream:
    """``/tf``: the pose as the transform world -> base_link, at :data:`TF_RATE_HZ`."""
    tf_channel = FrameTransformsChannel(
        TOPIC_TF, context=ctx, metadata={"description": DESCRIPTIONS[TOPIC_TF]}
    )
    keep = tf_rows(pose.t_ns)
    qx, qy, qz, qw = quaternion_zyx(pose.roll[keep], pose.pitch[keep], pose.yaw[keep])
    base = config.vehicle.base_frame

    def emit_tf(i: int) -> None:
        k = int(keep[i])
        t = int(pose.t_ns[k])
        transform = FrameTransform(
            timestamp=_stamp(t),
            parent_frame_id=WORLD_FRAME,
            child_frame_id=base,
            translation=Vector3(x=float(pose.x[k]), y=float(pose.y[k]), z=float(pose.z[k])),
            rotation=Quaternion(x=float(qx[i]), y=float(qy[i]), z=float(qz[i]), w=float(qw[i])),
        )
        tf_channel.log(FrameTransforms(transforms=[transform]), log_time=t)

    return pose.t_ns[keep], emit_tf


def _gps_stream(
    path: Path, ctx: foxglove.Context, config: PipelineConfig
) -> tuple[_Stream, int, int]:
    """``/gps``: every fix (NavSatStatus STATUS_FIX or better with a finite position, as the
    world frame's origin is chosen); rows without one have no position to show."""
    table = read_table(path, "gps", columns=list(GPS_COLUMNS))
    ok = valid_fixes(table, ORIGIN_MIN_STATUS)
    t = np.asarray(column_array(table, "t_ns"), dtype=np.int64)[ok]
    require_times(t, path)
    lat = np.asarray(column_array(table, "latitude"), dtype=np.float64)[ok]
    lon = np.asarray(column_array(table, "longitude"), dtype=np.float64)[ok]
    alt = np.asarray(column_array(table, "altitude"), dtype=np.float64)[ok]
    cov = table.column("position_covariance").to_pylist()
    cov_ok = [c for c, keep in zip(cov, ok.tolist(), strict=True) if keep]
    channel = LocationFixChannel(
        TOPIC_GPS, context=ctx, metadata={"description": DESCRIPTIONS[TOPIC_GPS]}
    )
    frame = config.vehicle.gps_frame

    def emit(i: int) -> None:
        diag = cov_ok[i]
        known = diag is not None and len(diag) == 3 and all(math.isfinite(v) for v in diag)
        matrix = [0.0] * 9
        if known:
            matrix[0], matrix[4], matrix[8] = (float(v) for v in diag)
        fix = LocationFix(
            timestamp=_stamp(int(t[i])),
            frame_id=frame,
            latitude=float(lat[i]),
            longitude=float(lon[i]),
            altitude=float(alt[i]),
            position_covariance=matrix,
            position_covariance_type=(
                LocationFixPositionCovarianceType.DiagonalKnown
                if known
                else LocationFixPositionCovarianceType.Unknown
            ),
        )
        channel.log(fix, log_time=int(t[i]))

    return (t, emit), int(ok.sum()), int((~ok).sum())


def _event_stream(
    events: EventRows, pose: PoseRows, ctx: foxglove.Context, config: PipelineConfig
) -> _Stream:
    """``/events``: one box per event along the chord of its stretch of the rear-axle path,
    tilted to the chord's slope, lying on the ground."""
    t0, t1 = events.i64("t_start_ns"), events.i64("t_end_ns")
    x0, y0, z0, yaw0 = pose.at(t0)
    x1, y1, z1, _ = pose.at(t1)
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    run = np.hypot(dx, dy)
    # The chord's heading; the pose's yaw when the chord is too short to have one.
    heading = np.where(run > 1e-6, np.arctan2(dy, dx), yaw0)
    pitch = -np.arctan2(dz, run)  # Z-Y-X pitch is positive nose down
    qx, qy, qz, qw = quaternion_zyx(np.zeros_like(pitch), pitch, heading)
    length = events.f64("s_end_m") - events.f64("s_start_m")
    rgb = event_box_colors(
        events.f64("ruggedness"), events.rough, config.label.rough_threshold_g_per_mph
    )
    ids = events.i64("event_id")
    speed, shock, rug = events.f64("speed_mph"), events.f64("shock_g"), events.f64("ruggedness")
    track = config.vehicle.track_m
    channel = SceneUpdateChannel(
        TOPIC_EVENTS, context=ctx, metadata={"description": DESCRIPTIONS[TOPIC_EVENTS]}
    )

    def emit(i: int) -> None:
        info = [
            KeyValuePair(key="event_id", value=str(int(ids[i]))),
            KeyValuePair(key="speed_mph", value=f"{speed[i]:.3f}"),
            KeyValuePair(key="shock_g", value=f"{shock[i]:.4f}"),
            KeyValuePair(key="ruggedness_g_per_mph", value=f"{rug[i]:.5f}"),
            KeyValuePair(key="rough", value=str(bool(events.rough[i])).lower()),
        ]
        if events.scored[i]:
            info.append(KeyValuePair(key="r_combined", value=f"{events.r_combined[i]:.6g}"))
            info.append(KeyValuePair(key="predicted", value=str(bool(events.predicted[i])).lower()))
        box = CubePrimitive(
            pose=Pose(
                position=Vector3(
                    x=float(0.5 * (x0[i] + x1[i])),
                    y=float(0.5 * (y0[i] + y1[i])),
                    z=float(0.5 * (z0[i] + z1[i]) + 0.5 * BOX_HEIGHT_M),
                ),
                orientation=Quaternion(
                    x=float(qx[i]), y=float(qy[i]), z=float(qz[i]), w=float(qw[i])
                ),
            ),
            size=Vector3(x=float(length[i]), y=track, z=BOX_HEIGHT_M),
            color=_color(rgb[i], BOX_ALPHA),
        )
        entity = SceneEntity(
            timestamp=_stamp(int(t1[i])),
            frame_id=WORLD_FRAME,
            id=str(int(ids[i])),
            metadata=info,
            cubes=[box],
        )
        channel.log(SceneUpdate(entities=[entity]), log_time=int(t1[i]))

    return t1, emit


def _truth_stream(path: Path, ctx: foxglove.Context) -> tuple[_Stream, int] | None:
    """``/truth/path``: the true path as one line strip, or None when the table is empty."""
    table = read_table(path, "truth_pose", columns=["t_ns", "x", "y", "z"])
    if table.num_rows == 0:
        return None
    t = np.asarray(column_array(table, "t_ns"), dtype=np.int64)
    require_times(t, path)
    x, y, z = (np.asarray(column_array(table, c), dtype=np.float64) for c in ("x", "y", "z"))
    rows = path_vertices(x, y, z, TRUTH_STEP_M)
    channel = SceneUpdateChannel(
        TOPIC_TRUTH, context=ctx, metadata={"description": DESCRIPTIONS[TOPIC_TRUTH]}
    )
    first = int(t[0])

    def emit(_: int) -> None:
        line = LinePrimitive(
            type=LinePrimitiveLineType.LineStrip,
            pose=_identity(),
            thickness=TRUTH_LINE_M,
            points=[
                Point3(x=a, y=b, z=c)
                for a, b, c in zip(
                    x[rows].tolist(), y[rows].tolist(), z[rows].tolist(), strict=True
                )
            ],
            color=Color(r=TRUTH_COLOR[0], g=TRUTH_COLOR[1], b=TRUTH_COLOR[2], a=TRUTH_COLOR[3]),
        )
        entity = SceneEntity(
            timestamp=_stamp(first), frame_id=WORLD_FRAME, id="truth_path", lines=[line]
        )
        channel.log(SceneUpdate(entities=[entity]), log_time=first)

    return (np.array([first], dtype=np.int64), emit), int(rows.size)


def _point_cloud(cloud: Cloud, rgba: NDArray[np.uint8], r_combined: FloatArray) -> PointCloud:
    """The cloud as a PointCloud in ``world``: float32 offsets from a whole-metre origin
    near its points (float32 world coordinates would lose millimetres a few km out; offsets
    of laser range keep micrometres), built as one numpy buffer."""
    if cloud.x.size:
        origin = np.round([cloud.x.mean(), cloud.y.mean(), cloud.z.mean()])
    else:
        origin = np.zeros(3)
    buf = np.empty(cloud.x.size, dtype=POINT_DTYPE)
    buf["x"], buf["y"], buf["z"] = cloud.x - origin[0], cloud.y - origin[1], cloud.z - origin[2]
    buf["red"], buf["green"], buf["blue"], buf["alpha"] = rgba.T
    buf["r_combined"] = r_combined
    return PointCloud(
        timestamp=_stamp(cloud.t_ns),
        frame_id=WORLD_FRAME,
        pose=Pose(
            position=Vector3(x=float(origin[0]), y=float(origin[1]), z=float(origin[2])),
            orientation=Quaternion(w=1.0),
        ),
        point_stride=POINT_DTYPE.itemsize,
        fields=POINT_FIELDS,
        data=buf.tobytes(),
    )


__all__ = ["POINT_DTYPE", "POINT_FIELDS", "write_mcap"]
