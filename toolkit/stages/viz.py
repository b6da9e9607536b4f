"""View stage: one log's results as an MCAP file Foxglove opens (``terrain viz``).

The pipeline's results are tables; a person understands them best by watching the drive.
:func:`run_viz` writes the log's pose, laser points, labelled events, GPS fixes and (on
simulated logs) the true path into one MCAP file, in Foxglove's well-known message schemas
(protobuf, written by the ``foxglove-sdk`` package), on the log's own clock: open it in
Foxglove (or drag it onto app.foxglove.dev), choose ``world`` as the 3D panel's display
frame, and play.

Topics
------

``/tf`` (``foxglove.FrameTransforms``)
    The fused pose as the transform ``world`` -> ``base_link`` (the ``[vehicle] base_frame``;
    on the ground below the rear-axle centre): translation = the pose's x, y, z, rotation =
    its roll, pitch, yaw (Z-Y-X). The pose is 100 Hz; the view keeps the first pose row of
    every 1 / :data:`TF_RATE_HZ` s (20 Hz), between which Foxglove interpolates.
``/points`` (``foxglove.PointCloud``, frame ``world``)
    The laser points of ``points.parquet``, one cloud per :data:`CLOUD_PERIOD_NS` (0.5 s) of
    scan stamps, thinned evenly to at most :data:`MAX_CLOUD_POINTS` points (rows
    ``floor(i n / m)`` of the window's ``n`` rows in table order, ``m = min(n, max)``),
    logged at the time of the latest point in the window. Set the panel's decay time to keep
    the terrain on screen. Fields: ``x, y, z`` (float32, offsets from the cloud's pose, a
    whole-metre origin), ``red, green, blue, alpha`` (uint8) and ``r_combined`` (float32).
    *What the colour means*: the model's prediction for the stretch of ground the point lies
    on. A point lies on an event's stretch when, in plan view, it is within half the track
    (``[vehicle] track_m`` / 2) of the rear-axle path and its nearest point on that path is
    between the event's ``s_start_m`` and ``s_end_m``. Its colour comes from that event's
    score in ``report/scores.parquet`` (also its ``r_combined`` field): green at the lowest
    R_combined of the report (all logs), yellow halfway from there to the model's threshold
    ``mu`` (``model.json``), red at ``mu`` and above, that is, wherever the model predicts
    rough. (R_combined's scale is the model's own and often negative, so the ramp is
    anchored on the scores and mu, not on zero; without a usable mu, green or red by the
    prediction alone.) Grey: a point on no event's stretch (off the path, in a gap between
    events), on an event the report did not score, or every point when the workspace has no
    scores (or stale ones); ``r_combined`` is NaN there. To see the terrain's shape instead,
    colour by the ``z`` field in Foxglove.
``/events`` (``foxglove.SceneUpdate``)
    One box per labelled event (``events.parquet``), entity id = the event id: the event's
    stretch of the rear-axle path, ``s_end_m - s_start_m`` long (1.4 m by default) and one
    track wide, 5 cm tall lying on the ground (the pose's z), along the chord from where the
    rear axle entered to where it left. Logged when the rear axle leaves the stretch
    (``t_end_ns``), when its shock, hence its label, is known; it stays for the rest of the
    drive. Colour from the label: green (ruggedness 0) through yellow to red (ruggedness at
    or above ``[label] rough_threshold_g_per_mph``); every rough event is pure red.
    Half-transparent, so the points under it show. Its metadata (hover in Foxglove) holds
    the speed, shock, ruggedness, label and, when scored, R_combined and the prediction.
``/gps`` (``foxglove.LocationFix``)
    Every GPS fix of ``gps.parquet`` (for the Map panel), with its covariance diagonal when
    known. Rows without a fix (status -1, no position) are left out and counted.
``/truth/path`` (``foxglove.SceneUpdate``; simulated logs only)
    The true path of base_link (``truth_pose.parquet``, same frame as the pose) as one blue
    line strip (a vertex at the first row past every :data:`TRUTH_STEP_M` of distance along
    it, and at both ends), logged once at the truth's first time: where the vehicle really
    drove, against ``/tf``'s estimate.

The file's metadata record ``terrain.viz`` names the log, the toolkit version, the ENU
origin, the sha256 of every input and what the colours mean.

How it is made
--------------
Inputs are read in a generation of the log opened and discarded, never committed
(:mod:`toolkit.generations`): a consistent snapshot, under the log's lock, of files each
checked to be what the stage that wrote it recorded. The pose, events, GPS, truth and scores
are small and read whole; the points are streamed (:data:`POINT_BATCH` rows at a time), so
memory is bounded by a batch and a cloud window, and only the points kept are matched to
events (a KD-tree of the rear-axle path sampled every :data:`PATH_STEP_M`). Messages are
written in log-time order across topics (the small topics merged into the stream of clouds),
so Foxglove reads the file's chunks in sequence. The MCAP is written to a hidden file beside
``out_path`` and renamed over it only when complete; any error removes it.

Deterministic: the same inputs give the same bytes. Compression is single-threaded, channel
ids are the writer's own (from 1 per file), and the SDK writes no clock time; its name and
version (``foxglove-sdk-python/<version>``) are in the MCAP header, so another SDK version
may write other bytes.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import foxglove
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
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
from scipy.spatial import cKDTree

from toolkit import __version__
from toolkit.atomic import fsync_dir, fsync_file, temp_path_beside
from toolkit.config import PipelineConfig
from toolkit.errors import StageError
from toolkit.frames import ORIGIN_MIN_STATUS, valid_fixes
from toolkit.manifest import Manifest, file_sha256, require_finished
from toolkit.stages.tables import EVENT_COLUMNS
from toolkit.tableio import iter_table_batches, read_table, read_table_metadata
from toolkit.workspace import Workspace, refuse_inside_workspace

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

TOPIC_TF = "/tf"
TOPIC_POINTS = "/points"
TOPIC_EVENTS = "/events"
TOPIC_GPS = "/gps"
TOPIC_TRUTH = "/truth/path"
#: The fixed frame everything is drawn in: the pose's local ENU world frame.
WORLD_FRAME = "world"

#: Log time each point cloud gathers (by scan stamp), ns.
CLOUD_PERIOD_NS = 500_000_000
#: Most points in one cloud: 8 k points per second of log, ~0.6 GB per hour before zstd.
MAX_CLOUD_POINTS = 4_096
#: Rate of ``/tf``: Foxglove interpolates between transforms, 100 Hz would only add bytes.
TF_RATE_HZ = 20.0
#: Spacing of the true path's vertices along it, m (a vertex per this much distance).
TRUTH_STEP_M = 0.25
#: Points per read batch.
POINT_BATCH = 262_144
#: Largest spacing of the rear-axle path samples points are matched against, m (as the
#: tables stage's tyre paths): a point's distance to the path is over-estimated by at most
#: ``sqrt(r^2 + (step/2)^2) - r``, under a millimetre at half a track.
PATH_STEP_M = 0.05
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

POSE_COLUMNS = ("t_ns", "x", "y", "z", "roll", "pitch", "yaw")

POINT_COLUMNS = ("t_ns", "scan_t_ns", "x", "y", "z")
GPS_COLUMNS = ("t_ns", "latitude", "longitude", "altitude", "status", "position_covariance")

#: What each topic shows, written as channel metadata (``description``).
DESCRIPTIONS = {
    TOPIC_TF: "fused pose: world -> base_link",
    TOPIC_POINTS: (
        "laser points; colour: predicted roughness of the event stretch under the point, "
        "green (lowest R_combined of the report) - yellow (halfway to mu) - red (>= mu, "
        "predicted rough); grey: on no scored event"
    ),
    TOPIC_EVENTS: (
        "labelled events (1 track wide along the rear-axle path); colour: ruggedness, green "
        "(0) - yellow - red (rough, >= threshold)"
    ),
    TOPIC_GPS: "GPS fixes (rows without a fix left out)",
    TOPIC_TRUTH: "true path of base_link (simulated log)",
}


@dataclass(frozen=True)
class VizResult:
    """What :func:`run_viz` wrote: messages per topic and what they hold."""

    log_id: str
    out_path: Path
    #: ``/tf`` messages (one transform each).
    transforms: int
    #: ``/points`` messages, the points they hold, and the rows of ``points.parquet`` read.
    clouds: int
    cloud_points: int
    points_read: int
    #: ``/events`` messages (one box each), the rough ones, and those with a score.
    events: int
    rough_events: int
    scored_events: int
    #: Cloud points coloured by a score (on a scored event's stretch).
    coloured_points: int
    #: ``/gps`` messages, and the rows left out for having no fix.
    gps_fixes: int
    gps_without_fix: int
    #: ``/truth/path`` messages (0 or 1) and the vertices of its line.
    truth_paths: int
    truth_vertices: int
    bytes_written: int
    seconds: float
    warnings: tuple[str, ...] = ()

    @property
    def topics(self) -> dict[str, int]:
        """Messages per topic written (topics without data are not in the file)."""
        counts = {
            TOPIC_TF: self.transforms,
            TOPIC_POINTS: self.clouds,
            TOPIC_EVENTS: self.events,
            TOPIC_GPS: self.gps_fixes,
            TOPIC_TRUTH: self.truth_paths,
        }
        return {topic: n for topic, n in counts.items() if n}

    def summary(self) -> str:
        """One line for people: where, what per topic, how big, how long."""
        parts = [f"/tf {self.transforms}"]
        if self.clouds:
            parts.append(
                f"/points {self.clouds} clouds, {self.cloud_points} of {self.points_read} "
                f"points ({self.coloured_points} coloured by score)"
            )
        if self.events:
            parts.append(
                f"/events {self.events} boxes ({self.rough_events} rough, "
                f"{self.scored_events} scored)"
            )
        if self.gps_fixes or self.gps_without_fix:
            parts.append(
                f"/gps {self.gps_fixes} fixes ({self.gps_without_fix} rows without a fix left out)"
            )
        if self.truth_paths:
            parts.append(f"/truth/path {self.truth_vertices} vertices")
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return (
            f"{self.log_id}: view written to {self.out_path} ({'; '.join(parts)}), "
            f"{self.bytes_written / 1e6:.1f} MB in {self.seconds:.1f} s"
        )


# --------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Pose:
    """Pose rows (K,), time-sorted, as the pose stage wrote them."""

    t_ns: IntArray
    x: FloatArray
    y: FloatArray
    z: FloatArray
    roll: FloatArray
    pitch: FloatArray
    yaw: FloatArray

    def at(self, t_ns: IntArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """x, y, z and yaw linearly interpolated at ``t_ns`` (held at the ends)."""
        tp = (self.t_ns - self.t_ns[0]).astype(np.float64)
        tq = (t_ns - self.t_ns[0]).astype(np.float64)
        return (
            np.interp(tq, tp, self.x),
            np.interp(tq, tp, self.y),
            np.interp(tq, tp, self.z),
            np.interp(tq, tp, np.unwrap(self.yaw)),
        )


@dataclass(frozen=True)
class _Events:
    """A log's events (E,) in driving order, with their scores (NaN, False: unscored)."""

    columns: dict[str, NDArray[np.generic]]
    r_combined: FloatArray
    predicted: BoolArray
    scored: BoolArray
    #: The lowest R_combined of the whole report (every log's events): the colour ramp's
    #: green end, the same in every log's view. None without scores.
    r_low: float | None

    def __len__(self) -> int:
        return int(self.columns["event_id"].size)

    def f64(self, name: str) -> FloatArray:
        return np.asarray(self.columns[name], dtype=np.float64)

    def i64(self, name: str) -> IntArray:
        return np.asarray(self.columns[name], dtype=np.int64)

    @property
    def rough(self) -> BoolArray:
        return np.asarray(self.columns["rough"], dtype=bool)


def _numpy(table: pa.Table, name: str) -> NDArray[np.generic]:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def _require_times(t_ns: IntArray, path: Path) -> None:
    """MCAP log times are unsigned: a time before 1970 cannot be written."""
    if t_ns.size and int(t_ns.min()) < 0:
        raise StageError("holds negative times, which an MCAP log time cannot be", path=path)


def _read_pose(path: Path) -> _Pose:
    table = read_table(path, "pose", columns=list(POSE_COLUMNS))
    if table.num_rows == 0:
        raise StageError("no pose rows; nothing to view", path=path)
    cols = {name: _numpy(table, name) for name in POSE_COLUMNS}
    t = np.asarray(cols["t_ns"], dtype=np.int64)
    _require_times(t, path)
    f = {name: np.asarray(cols[name], dtype=np.float64) for name in POSE_COLUMNS[1:]}
    return _Pose(t, f["x"], f["y"], f["z"], f["roll"], f["pitch"], f["yaw"])


def _read_model_mu(path: Path) -> float | None:
    """``mu`` of ``model.json``, or None without a usable one (the points' colour then shows
    only the prediction, green or red)."""
    try:
        mu = float(json.loads(path.read_text(encoding="utf-8"))["mu"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return mu if math.isfinite(mu) else None


def _read_events(path: Path, scores_path: Path | None, log_id: str, warnings: list[str]) -> _Events:
    """The events, with the report's scores of this log's events when they belong to them
    (the same event ids with the same ruggedness: a label re-run since the report makes
    them stale, and a stale score shown on the wrong ground would mislead)."""
    table = read_table(path, "events", columns=list(EVENT_COLUMNS))
    cols = {name: _numpy(table, name) for name in EVENT_COLUMNS}
    n = table.num_rows
    _require_times(np.asarray(cols["t_end_ns"], dtype=np.int64), path)
    events = _Events(cols, np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool), None)
    if scores_path is None:
        return events
    scores = read_table(
        scores_path,
        "scores",
        columns=["log_id", "event_id", "r_combined", "predicted", "ruggedness"],
    )
    every_r = np.asarray(_numpy(scores, "r_combined"), dtype=np.float64)
    every_r = every_r[np.isfinite(every_r)]
    mine = scores.filter(pc.equal(scores.column("log_id"), log_id))
    sid = np.asarray(_numpy(mine, "event_id"), dtype=np.int64)
    if sid.size == 0:
        return events
    ids = events.i64("event_id")
    order = np.argsort(ids, kind="stable")
    pos = np.minimum(np.searchsorted(ids[order], sid), max(n - 1, 0))
    k = order[pos] if n else np.zeros(sid.size, dtype=np.int64)
    same = np.zeros(sid.size, dtype=bool)
    if n:
        same = (ids[k] == sid) & np.isclose(
            events.f64("ruggedness")[k], np.asarray(_numpy(mine, "ruggedness"), np.float64)
        )
    if not same.all():
        warnings.append(
            f"{scores_path}: {int((~same).sum())} of this log's {sid.size} scores are not of "
            "its current events (labelled again since the report?), so points are left grey; "
            "run `terrain tables`, `learn` and `evaluate` again"
        )
        return events
    r = events.r_combined.copy()
    predicted = events.predicted.copy()
    r[k] = np.asarray(_numpy(mine, "r_combined"), dtype=np.float64)
    predicted[k] = np.asarray(_numpy(mine, "predicted"), dtype=bool)
    scored = np.zeros(n, dtype=bool)
    scored[k] = True
    low = float(every_r.min()) if every_r.size else None
    return _Events(cols, r, predicted, scored, low)


def _checked_inputs(workspace: Workspace, log_dir: Path, warnings: list[str]) -> dict[str, str]:
    """Which inputs there are (name -> sha256), each checked to be the file the stage that
    wrote it recorded (a WorkspaceError naming the file otherwise)."""
    manifest = Manifest(log_dir / Workspace.MANIFEST_NAME)
    pose_path = log_dir / "pose.parquet"
    if not pose_path.is_file():
        raise StageError("input table missing; run `terrain pose` first", path=pose_path)
    producers = {
        "pose.parquet": "pose",
        "points.parquet": "project",
        "events.parquet": "label",
        "gps.parquet": "ingest",
        "truth_pose.parquet": "ingest",
    }
    hashes: dict[str, str] = {}
    for name, stage in producers.items():
        if (log_dir / name).is_file():
            hashes[name] = file_sha256(log_dir / name)
            require_finished(manifest.stage(stage), stage, {name: hashes[name]}, log_dir)
    for name, topic, stage in (
        ("points.parquet", TOPIC_POINTS, "project"),
        ("events.parquet", TOPIC_EVENTS, "label"),
    ):
        if name not in hashes:
            warnings.append(f"no {name}, so no {topic} (run `terrain {stage}` for it)")
    ws_manifest = Manifest(workspace.manifest_path)
    if workspace.scores_table.is_file():
        sha = file_sha256(workspace.scores_table)
        require_finished(
            ws_manifest.stage("evaluate"),
            "evaluate",
            {workspace.scores_table.name: sha},
            workspace.report_dir,
        )
        hashes["report/scores.parquet"] = sha
    if workspace.model_path.is_file():
        sha = file_sha256(workspace.model_path)
        require_finished(
            ws_manifest.stage("learn"), "learn", {workspace.model_path.name: sha}, workspace.root
        )
        hashes["model.json"] = sha
        # Scores and mu must come from one learning: scores from an earlier model coloured
        # against a later model's mu would show the wrong verdicts.
        evaluated = ws_manifest.stage("evaluate")
        if (
            "report/scores.parquet" in hashes
            and evaluated is not None
            and evaluated.inputs.get("model.json") != sha
        ):
            del hashes["report/scores.parquet"]
            warnings.append(
                "report/scores.parquet scored an earlier model than model.json: points and "
                "events shown unscored (run `terrain evaluate`)"
            )
    return hashes


# --------------------------------------------------------------------------------------
# Geometry and colour
# --------------------------------------------------------------------------------------


def quaternion_zyx(
    roll: FloatArray, pitch: FloatArray, yaw: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(x, y, z, w) of the rotation R = Rz(yaw) Ry(pitch) Rx(roll) (Z-Y-X Euler angles, the
    pose's convention), element-wise."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


#: Where on the ramp a point not predicted rough stops (orange): only a verdict is red.
NOT_ROUGH_MAX = 0.9


def ramp_rgb(t: FloatArray) -> FloatArray:
    """Colours (N, 3) in [0, 1] for ``t`` in [0, 1] (clipped): green at 0, yellow at 0.5,
    red at 1. Through yellow rather than straight across, whose middle is a muddy brown."""
    t = np.clip(np.nan_to_num(t, nan=0.0), 0.0, 1.0)
    return np.column_stack(
        [np.minimum(2.0 * t, 1.0), np.minimum(2.0 * (1.0 - t), 1.0), np.zeros_like(t)]
    )


def event_box_colors(ruggedness: FloatArray, rough: BoolArray, threshold: float) -> FloatArray:
    """RGB (E, 3) of the event boxes: the ramp at ruggedness / threshold, rough ones red."""
    rgb = ramp_rgb(ruggedness / threshold)
    rgb[rough] = (1.0, 0.0, 0.0)
    return rgb


def point_colors(
    r_combined: FloatArray, predicted: BoolArray, low: float | None, mu: float | None
) -> FloatArray:
    """RGB (N, 3) of points on scored events: the ramp at ``(R_combined - low) / (mu -
    low)``, predicted rough ones red (R_combined's scale is the model's own, often negative:
    only its threshold mu and the scores themselves say what is low). Without a usable mu
    or low (None, or low >= mu), green or red by the prediction alone. A point not
    predicted rough is never redder than orange (:data:`NOT_ROUGH_MAX`), however close to
    mu: pure red means predicted rough."""
    if low is None or mu is None or not low < mu:
        t = predicted.astype(np.float64)
    else:
        t = np.minimum((r_combined - low) / (mu - low), NOT_ROUGH_MAX)
    rgb = ramp_rgb(t)
    rgb[predicted] = (1.0, 0.0, 0.0)
    return rgb


@dataclass(frozen=True)
class _AxlePath:
    """The rear-axle path sampled at most :data:`PATH_STEP_M` apart: a KD-tree of the
    samples' (x, y) and each sample's distance along the path, as the label stage measures
    it (cumulative horizontal distance over the pose rows, linear between them)."""

    tree: cKDTree
    s: FloatArray

    @classmethod
    def of(cls, pose: _Pose) -> _AxlePath:
        step = np.hypot(np.diff(pose.x), np.diff(pose.y))
        s_rows = np.concatenate([[0.0], np.cumsum(step)])
        pieces = np.maximum(np.ceil(step / PATH_STEP_M), 1).astype(np.int64)
        j = np.repeat(np.arange(step.size), pieces)
        f = (np.arange(j.size) - np.concatenate([[0], np.cumsum(pieces)[:-1]])[j]) / pieces[j]
        x = np.concatenate([pose.x[j] + f * (pose.x[j + 1] - pose.x[j]), pose.x[-1:]])
        y = np.concatenate([pose.y[j] + f * (pose.y[j + 1] - pose.y[j]), pose.y[-1:]])
        s = np.concatenate([s_rows[j] + f * step[j], s_rows[-1:]])
        return cls(cKDTree(np.c_[x, y]), s)

    def events_under(
        self, x: FloatArray, y: FloatArray, events: _Events, half_width_m: float
    ) -> IntArray:
        """Index into ``events`` of the stretch each point (x, y) lies on, -1 for none: within
        ``half_width_m`` of the path, its nearest sample inside an event's [s_start, s_end).
        A point nearest to either end of the whole path is beyond it, on no stretch."""
        n = self.s.size
        if x.size == 0 or len(events) == 0:
            return np.full(x.size, -1, dtype=np.int64)
        _, i = self.tree.query(np.c_[x, y], distance_upper_bound=half_width_m)
        i = np.asarray(i, dtype=np.int64)
        ok = (i > 0) & (i < n - 1)  # a miss is i == n
        s = self.s[np.clip(i, 0, n - 1)]
        k = np.searchsorted(events.f64("s_start_m"), s, side="right") - 1
        ok &= k >= 0
        k = np.maximum(k, 0)
        ok &= s < events.f64("s_end_m")[k]
        return np.where(ok, k, -1).astype(np.int64)


def _stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return Timestamp(sec, nsec)


def _color(rgb: FloatArray, alpha: float) -> Color:
    return Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=alpha)


def _identity() -> Pose:
    return Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(w=1.0))


def tf_rows(t_ns: IntArray, rate_hz: float = TF_RATE_HZ) -> IntArray:
    """Pose rows kept for ``/tf``: the first of every 1 / rate_hz s from the first row."""
    period = int(round(1e9 / rate_hz))
    bins = (t_ns - t_ns[0]) // period
    return np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]]).astype(np.int64)


def path_vertices(x: FloatArray, y: FloatArray, z: FloatArray, step_m: float) -> IntArray:
    """Rows of a path kept as line vertices: the first row at or past every multiple of
    ``step_m`` of 3-D distance along it (row 0 for the first), and the last row."""
    s = np.concatenate(
        [[0.0], np.cumsum(np.sqrt(np.diff(x) ** 2 + np.diff(y) ** 2 + np.diff(z) ** 2))]
    )
    bins = np.floor(s / step_m)
    keep = np.r_[True, bins[1:] != bins[:-1]]
    keep[-1] = True
    return np.flatnonzero(keep).astype(np.int64)


def cloud_rows(n: int, max_points: int) -> IntArray:
    """Rows kept of a window of ``n`` rows: ``floor(i n / m)``, ``m = min(n, max_points)``,
    spread evenly over the window (over its lasers and beams, which come in scan order)."""
    m = min(n, max_points)
    return (np.arange(m, dtype=np.int64) * n) // max(m, 1)


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


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def run_viz(
    workspace: Workspace,
    log_id: str,
    out_path: Path,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    cloud_period_ns: int = CLOUD_PERIOD_NS,
    max_cloud_points: int = MAX_CLOUD_POINTS,
) -> VizResult:
    """Write the view of one log to ``out_path`` (see the module docstring). An existing
    ``out_path`` is refused unless ``overwrite``; a log the workspace does not have, or
    without a pose, is one StageError line naming it."""
    start = time.perf_counter()
    out_path = Path(out_path)
    if cloud_period_ns <= 0 or max_cloud_points <= 0:
        raise ValueError("cloud_period_ns and max_cloud_points must be positive")
    workspace.require_log(log_id)
    _refuse_existing(out_path, overwrite)
    # A generation opened and discarded: a consistent snapshot of the log's files under its
    # lock (a stage committing meanwhile cannot mix two versions of the log into the view).
    with workspace.change_log(log_id) as gen:
        return _write_view(
            workspace,
            log_id,
            gen.path,
            out_path,
            config,
            overwrite=overwrite,
            cloud_period_ns=cloud_period_ns,
            max_cloud_points=max_cloud_points,
            start=start,
        )


def _refuse_existing(out_path: Path, overwrite: bool) -> None:
    refuse_inside_workspace(out_path)  # never over a workspace's own files
    if out_path.is_dir():
        raise StageError("is a directory; give the view's file name", path=out_path)
    if out_path.exists() and not overwrite:
        raise StageError("already exists; pass --overwrite to replace it", path=out_path)


def _write_view(
    workspace: Workspace,
    log_id: str,
    log_dir: Path,
    out_path: Path,
    config: PipelineConfig,
    *,
    overwrite: bool,
    cloud_period_ns: int,
    max_cloud_points: int,
    start: float,
) -> VizResult:
    warnings: list[str] = []
    hashes = _checked_inputs(workspace, log_dir, warnings)
    pose_path = log_dir / "pose.parquet"
    pose = _read_pose(pose_path)
    pose_meta = read_table_metadata(pose_path)
    scores_path = workspace.scores_table if "report/scores.parquet" in hashes else None
    if "events.parquet" in hashes:
        events = _read_events(log_dir / "events.parquet", scores_path, log_id, warnings)
    else:
        none = np.zeros(0, dtype=bool)
        events = _Events({c: np.zeros(0) for c in EVENT_COLUMNS}, np.zeros(0), none, none, None)
    mu = _read_model_mu(workspace.model_path) if "model.json" in hashes else None
    if events.scored.any() and (mu is None or events.r_low is None or not events.r_low < mu):
        warnings.append(
            "no usable mu in model.json (or no score below it): points on scored events are "
            "red or green by the prediction alone"
        )

    metadata = {
        "log_id": log_id,
        "toolkit_version": __version__,
        "world_frame": pose_meta.get("frame_id", ""),
        "enu_origin": pose_meta.get("enu_origin", ""),
        "inputs_sha256": json.dumps(hashes, sort_keys=True),
        "mu": "" if mu is None else repr(mu),
        "r_combined_low": "" if events.r_low is None else repr(events.r_low),
        "rough_threshold_g_per_mph": repr(config.label.rough_threshold_g_per_mph),
        "cloud_period_ns": str(cloud_period_ns),
        "max_cloud_points": str(max_cloud_points),
        "tf_rate_hz": repr(TF_RATE_HZ),
        **{f"topic {t}": d for t, d in DESCRIPTIONS.items()},
    }

    tmp = temp_path_beside(out_path)
    try:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        counts = _write_mcap(
            tmp,
            log_dir,
            pose,
            events,
            mu,
            config,
            metadata,
            has_points="points.parquet" in hashes,
            has_gps="gps.parquet" in hashes,
            has_truth="truth_pose.parquet" in hashes,
            cloud_period_ns=cloud_period_ns,
            max_cloud_points=max_cloud_points,
        )
        fsync_file(tmp)
        # Checked again just before the rename: the file may have appeared while we wrote.
        _refuse_existing(out_path, overwrite)
        os.replace(tmp, out_path)
    except BaseException as exc:
        with contextlib.suppress(OSError):  # never written, or not even its directory
            tmp.unlink()
        if isinstance(exc, OSError):  # the file system's (the inputs' are ToolkitErrors)
            raise StageError(f"cannot write the view: {exc.strerror or exc}", out_path) from exc
        raise
    fsync_dir(out_path.parent)
    for warning in warnings:
        _log.warning("%s: %s", log_id, warning)
    return VizResult(
        log_id=log_id,
        out_path=out_path,
        bytes_written=out_path.stat().st_size,
        seconds=time.perf_counter() - start,
        warnings=tuple(warnings),
        **counts,
    )


def _write_mcap(
    path: Path,
    log_dir: Path,
    pose: _Pose,
    events: _Events,
    mu: float | None,
    config: PipelineConfig,
    metadata: dict[str, str],
    *,
    has_points: bool,
    has_gps: bool,
    has_truth: bool,
    cloud_period_ns: int,
    max_cloud_points: int,
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

    def channel_meta(topic: str) -> dict[str, str]:
        return {"description": DESCRIPTIONS[topic]}

    with foxglove.open_mcap(path, context=ctx, writer_options=options) as writer:
        writer.write_metadata("terrain.viz", metadata)
        streams: list[tuple[IntArray, Callable[[int], None]]] = []

        # /tf
        tf_channel = FrameTransformsChannel(TOPIC_TF, context=ctx, metadata=channel_meta(TOPIC_TF))
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

        streams.append((pose.t_ns[keep], emit_tf))
        counts["transforms"] = int(keep.size)

        # /gps
        if has_gps:
            gps_stream, n_fix, n_without = _gps_stream(log_dir / "gps.parquet", ctx, config)
            streams.append(gps_stream)
            counts["gps_fixes"], counts["gps_without_fix"] = n_fix, n_without

        # /events
        if len(events):
            streams.append(_event_stream(events, pose, ctx, config))
            counts["events"] = len(events)
            counts["rough_events"] = int(events.rough.sum())
            counts["scored_events"] = int(events.scored.sum())

        # /truth/path
        if has_truth:
            truth = _truth_stream(log_dir / "truth_pose.parquet", ctx)
            if truth is not None:
                stream, vertices = truth
                streams.append(stream)
                counts["truth_paths"], counts["truth_vertices"] = 1, vertices

        timeline = _Timeline(streams)

        # /points, the stream everything else is merged into
        if has_points:
            cloud_channel = PointCloudChannel(
                TOPIC_POINTS, context=ctx, metadata=channel_meta(TOPIC_POINTS)
            )
            axle = _AxlePath.of(pose)
            half = 0.5 * config.vehicle.track_m
            for cloud in _clouds(log_dir / "points.parquet", cloud_period_ns, max_cloud_points):
                counts["points_read"] += cloud.rows_read
                timeline.play_until(cloud.t_ns)
                on = axle.events_under(cloud.x, cloud.y, events, half)
                colored = on >= 0
                colored[colored] = events.scored[on[colored]]
                r = np.full(cloud.x.size, np.nan)
                r[colored] = events.r_combined[on[colored]]
                rgba = np.empty((cloud.x.size, 4), dtype=np.uint8)
                rgba[:] = GREY
                rgb = point_colors(r[colored], events.predicted[on[colored]], events.r_low, mu)
                rgba[colored, :3] = np.round(rgb * 255.0).astype(np.uint8)
                cloud_channel.log(_point_cloud(cloud, rgba, r), log_time=cloud.t_ns)
                counts["clouds"] += 1
                counts["cloud_points"] += int(cloud.x.size)
                counts["coloured_points"] += int(colored.sum())
        timeline.play_until(None)  # the small topics' messages after the last cloud
    return counts


def _gps_stream(
    path: Path, ctx: foxglove.Context, config: PipelineConfig
) -> tuple[tuple[IntArray, Callable[[int], None]], int, int]:
    """``/gps``: every fix (NavSatStatus STATUS_FIX or better with a finite position, as the
    world frame's origin is chosen); rows without one have no position to show."""
    table = read_table(path, "gps", columns=list(GPS_COLUMNS))
    ok = valid_fixes(table, ORIGIN_MIN_STATUS)
    t = np.asarray(_numpy(table, "t_ns"), dtype=np.int64)[ok]
    _require_times(t, path)
    lat = np.asarray(_numpy(table, "latitude"), dtype=np.float64)[ok]
    lon = np.asarray(_numpy(table, "longitude"), dtype=np.float64)[ok]
    alt = np.asarray(_numpy(table, "altitude"), dtype=np.float64)[ok]
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
    events: _Events, pose: _Pose, ctx: foxglove.Context, config: PipelineConfig
) -> tuple[IntArray, Callable[[int], None]]:
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


def _truth_stream(
    path: Path, ctx: foxglove.Context
) -> tuple[tuple[IntArray, Callable[[int], None]], int] | None:
    """``/truth/path``: the true path as one line strip, or None when the table is empty."""
    table = read_table(path, "truth_pose", columns=["t_ns", "x", "y", "z"])
    if table.num_rows == 0:
        return None
    t = np.asarray(_numpy(table, "t_ns"), dtype=np.int64)
    _require_times(t, path)
    x, y, z = (np.asarray(_numpy(table, c), dtype=np.float64) for c in ("x", "y", "z"))
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


# --------------------------------------------------------------------------------------
# Point clouds
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Cloud:
    """The points kept of one window, its time (the latest point's) and the rows read."""

    t_ns: int
    x: FloatArray
    y: FloatArray
    z: FloatArray
    rows_read: int


def cloud_windows(scan_t_ns: IntArray, first_scan_ns: int, period_ns: int, floor: int) -> IntArray:
    """Window of each row: ``(scan_t_ns - first) // period``, never below an earlier row's
    (``floor``: the window open before these rows). The table is in scan order; a row out of
    it joins the window already open instead of reopening a closed one."""
    w = (scan_t_ns - first_scan_ns) // period_ns
    return np.maximum.accumulate(np.maximum(w, floor))


def _clouds(path: Path, period_ns: int, max_points: int) -> Iterator[_Cloud]:
    """Stream ``points.parquet`` and yield each window's thinned cloud (see the module
    docstring)."""
    first: int | None = None
    open_w = np.iinfo(np.int64).min
    parts: list[tuple[IntArray, FloatArray, FloatArray, FloatArray]] = []

    def close() -> _Cloud:
        t = np.concatenate([p[0] for p in parts])
        keep = cloud_rows(t.size, max_points)
        x, y, z = (np.concatenate([p[k] for p in parts])[keep] for k in (1, 2, 3))
        return _Cloud(int(t.max()), x, y, z, int(t.size))

    for batch in iter_table_batches(
        path, "points", columns=list(POINT_COLUMNS), batch_rows=POINT_BATCH
    ):
        if batch.num_rows == 0:
            continue
        cols = {c: batch.column(c).to_numpy(zero_copy_only=False) for c in POINT_COLUMNS}
        t = np.asarray(cols["t_ns"], dtype=np.int64)
        _require_times(t, path)
        scan = np.asarray(cols["scan_t_ns"], dtype=np.int64)
        if first is None:
            first = int(scan[0])
        w = cloud_windows(scan, first, period_ns, open_w)
        cuts = np.flatnonzero(np.diff(w)) + 1
        for lo, hi in zip(np.r_[0, cuts].tolist(), np.r_[cuts, w.size].tolist(), strict=True):
            if int(w[lo]) != open_w:
                if parts:
                    yield close()
                parts, open_w = [], int(w[lo])
            parts.append(
                (
                    t[lo:hi],
                    np.asarray(cols["x"][lo:hi], np.float64),
                    np.asarray(cols["y"][lo:hi], np.float64),
                    np.asarray(cols["z"][lo:hi], np.float64),
                )
            )
    if parts:
        yield close()


def _point_cloud(cloud: _Cloud, rgba: NDArray[np.uint8], r_combined: FloatArray) -> PointCloud:
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


__all__ = [
    "CLOUD_PERIOD_NS",
    "MAX_CLOUD_POINTS",
    "POINT_DTYPE",
    "TF_RATE_HZ",
    "TOPIC_EVENTS",
    "TOPIC_GPS",
    "TOPIC_POINTS",
    "TOPIC_TF",
    "TOPIC_TRUTH",
    "VizResult",
    "cloud_rows",
    "cloud_windows",
    "event_box_colors",
    "point_colors",
    "quaternion_zyx",
    "run_viz",
    "tf_rows",
]
