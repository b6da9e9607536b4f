"""What ``terrain viz`` shows, read from the workspace: a log's pose, events (with the
report's scores when they belong to them) and laser points in windows, every input checked
to be the file its stage recorded; and the geometry and colours of the view. Nothing here
knows Foxglove's messages (:mod:`toolkit.publish.emit` writes them). See ``docs/viz.md``."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.config import PipelineConfig
from toolkit.errors import StageError
from toolkit.layout import LogFiles, log_file_name
from toolkit.manifest import Manifest, file_sha256, require_finished
from toolkit.stages.runner import remedy
from toolkit.stages.tables import EVENT_COLUMNS
from toolkit.tableio import iter_table_batches, read_table, read_table_metadata
from toolkit.workspace import Workspace

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


# --------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PoseRows:
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
class EventRows:
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


def column_array(table: pa.Table, name: str) -> NDArray[np.generic]:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def require_times(t_ns: IntArray, path: Path) -> None:
    """MCAP log times are unsigned: a time before 1970 cannot be written."""
    if t_ns.size and int(t_ns.min()) < 0:
        raise StageError("holds negative times, which an MCAP log time cannot be", path=path)


def read_pose(path: Path) -> PoseRows:
    table = read_table(path, "pose", columns=list(POSE_COLUMNS))
    if table.num_rows == 0:
        raise StageError("no pose rows; nothing to view", path=path)
    cols = {name: column_array(table, name) for name in POSE_COLUMNS}
    t = np.asarray(cols["t_ns"], dtype=np.int64)
    require_times(t, path)
    f = {name: np.asarray(cols[name], dtype=np.float64) for name in POSE_COLUMNS[1:]}
    return PoseRows(t, f["x"], f["y"], f["z"], f["roll"], f["pitch"], f["yaw"])


def read_model_mu(path: Path) -> float | None:
    """``mu`` of ``model.json``, or None without a usable one (the points' colour then shows
    only the prediction, green or red)."""
    try:
        mu = float(json.loads(path.read_text(encoding="utf-8"))["mu"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return mu if math.isfinite(mu) else None


def read_scored_events(
    path: Path, scores_path: Path | None, log_id: str, warnings: list[str]
) -> EventRows:
    """The events, with the report's scores of this log's events when they belong to them
    (the same event ids with the same ruggedness: a label re-run since the report makes
    them stale, and a stale score shown on the wrong ground would mislead)."""
    table = read_table(path, "events", columns=list(EVENT_COLUMNS))
    cols = {name: column_array(table, name) for name in EVENT_COLUMNS}
    n = table.num_rows
    require_times(np.asarray(cols["t_end_ns"], dtype=np.int64), path)
    events = EventRows(cols, np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool), None)
    if scores_path is None:
        return events
    scores = read_table(
        scores_path,
        "scores",
        columns=["log_id", "event_id", "r_combined", "predicted", "ruggedness"],
    )
    every_r = np.asarray(column_array(scores, "r_combined"), dtype=np.float64)
    every_r = every_r[np.isfinite(every_r)]
    mine = scores.filter(pc.equal(scores.column("log_id"), log_id))
    sid = np.asarray(column_array(mine, "event_id"), dtype=np.int64)
    if sid.size == 0:
        return events
    ids = events.i64("event_id")
    order = np.argsort(ids, kind="stable")
    pos = np.minimum(np.searchsorted(ids[order], sid), max(n - 1, 0))
    k = order[pos] if n else np.zeros(sid.size, dtype=np.int64)
    same = np.zeros(sid.size, dtype=bool)
    if n:
        same = (ids[k] == sid) & np.isclose(
            events.f64("ruggedness")[k], np.asarray(column_array(mine, "ruggedness"), np.float64)
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
    r[k] = np.asarray(column_array(mine, "r_combined"), dtype=np.float64)
    predicted[k] = np.asarray(column_array(mine, "predicted"), dtype=bool)
    scored = np.zeros(n, dtype=bool)
    scored[k] = True
    low = float(every_r.min()) if every_r.size else None
    return EventRows(cols, r, predicted, scored, low)


def checked_inputs(
    workspace: Workspace, log_dir: Path, config: PipelineConfig, warnings: list[str]
) -> dict[str, str]:
    """Which inputs there are (name -> sha256), each checked to be the file the stage that
    wrote it recorded (a WorkspaceError naming the file otherwise); for each missing one, a
    warning saying how the log would get it, or why it cannot (under ``config``)."""
    files = LogFiles(log_dir)
    manifest = Manifest(files.manifest)
    pose_path = files.pose
    if not pose_path.is_file():
        raise StageError("input table missing; run `terrain pose` first", path=pose_path)
    producers = {
        log_file_name(layout): stage
        for layout, stage in (
            ("pose", "pose"),
            ("points", "project"),
            ("events", "label"),
            ("gps", "ingest"),
            ("truth_pose", "ingest"),
        )
    }
    hashes: dict[str, str] = {}
    for name, stage in producers.items():
        if (log_dir / name).is_file():
            hashes[name] = file_sha256(log_dir / name)
            require_finished(manifest.stage(stage), stage, {name: hashes[name]}, log_dir)
    for name, topic, stage in (
        (log_file_name("points"), TOPIC_POINTS, "project"),
        (log_file_name("events"), TOPIC_EVENTS, "label"),
    ):
        if name not in hashes:
            warnings.append(f"no {name}, so no {topic} ({remedy(stage, files, config)})")
    ws_manifest = Manifest(workspace.manifest_path)
    scores_key = str(workspace.scores_table.relative_to(workspace.root))
    model_key = workspace.model_path.name
    if workspace.scores_table.is_file():
        sha = file_sha256(workspace.scores_table)
        require_finished(
            ws_manifest.stage("evaluate"),
            "evaluate",
            {workspace.scores_table.name: sha},
            workspace.report_dir,
        )
        hashes[scores_key] = sha
    if workspace.model_path.is_file():
        sha = file_sha256(workspace.model_path)
        require_finished(
            ws_manifest.stage("learn"), "learn", {workspace.model_path.name: sha}, workspace.root
        )
        hashes[model_key] = sha
        # Scores and mu must come from one learning: scores from an earlier model coloured
        # against a later model's mu would show the wrong verdicts.
        evaluated = ws_manifest.stage("evaluate")
        if (
            scores_key in hashes
            and evaluated is not None
            and evaluated.inputs.get("model") != sha  # its needs, by layout name
        ):
            del hashes[scores_key]
            warnings.append(
                "report/scores.parquet scored an earlier model than model.json: points and "
                "events shown unscored (run `terrain evaluate`)"
            )
    return hashes


@dataclass(frozen=True)
class CloudSettings:
    """How the points are gathered into clouds: the log time each cloud gathers (by scan
    stamp, ns) and the most points one cloud holds."""

    period_ns: int = CLOUD_PERIOD_NS
    max_points: int = MAX_CLOUD_POINTS


@dataclass(frozen=True)
class Scene:
    """One log as the view shows it, read and checked: its inputs (name -> sha256), the
    pose, the events with their scores and the model's threshold mu. The points stay in
    ``log_dir``'s ``points.parquet``, streamed as the file is written."""

    log_dir: Path
    inputs_sha256: dict[str, str]
    pose: PoseRows
    #: The pose table's key-value metadata (its world frame and ENU origin).
    pose_metadata: dict[str, str]
    events: EventRows
    mu: float | None

    def has(self, name: str) -> bool:
        """Whether the log has the input of layout name ``name`` (``points``, ``gps``...)."""
        return log_file_name(name) in self.inputs_sha256


def read_scene(
    workspace: Workspace, log_id: str, log_dir: Path, config: PipelineConfig, warnings: list[str]
) -> Scene:
    """The scene of the log in ``log_dir`` (a snapshot of ``log_id``'s folder), every input
    checked; what is missing or stale is appended to ``warnings``."""
    hashes = checked_inputs(workspace, log_dir, config, warnings)
    pose_path = LogFiles(log_dir).pose
    pose = read_pose(pose_path)
    pose_meta = read_table_metadata(pose_path)
    scored = str(workspace.scores_table.relative_to(workspace.root))
    scores_path = workspace.scores_table if scored in hashes else None
    if log_file_name("events") in hashes:
        events = read_scored_events(LogFiles(log_dir).events, scores_path, log_id, warnings)
    else:
        none = np.zeros(0, dtype=bool)
        events = EventRows({c: np.zeros(0) for c in EVENT_COLUMNS}, np.zeros(0), none, none, None)
    mu = read_model_mu(workspace.model_path) if workspace.model_path.name in hashes else None
    if events.scored.any() and (mu is None or events.r_low is None or not events.r_low < mu):
        warnings.append(
            "no usable mu in model.json (or no score below it): points on scored events are "
            "red or green by the prediction alone"
        )
    return Scene(log_dir, hashes, pose, pose_meta, events, mu)


# --------------------------------------------------------------------------------------
# Geometry and colour
# --------------------------------------------------------------------------------------


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
class AxlePath:
    """The rear-axle path sampled at most :data:`PATH_STEP_M` apart: a KD-tree of the
    samples' (x, y) and each sample's distance along the path, as the label stage measures
    it (cumulative horizontal distance over the pose rows, linear between them)."""

    tree: cKDTree
    s: FloatArray

    @classmethod
    def of(cls, pose: PoseRows) -> AxlePath:
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
        self, x: FloatArray, y: FloatArray, events: EventRows, half_width_m: float
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
# Point clouds
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cloud:
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


def iter_clouds(path: Path, period_ns: int, max_points: int) -> Iterator[Cloud]:
    """Stream ``points.parquet`` and yield each window's thinned cloud (``docs/viz.md``,
    ``/points``)."""
    first: int | None = None
    open_w = np.iinfo(np.int64).min
    parts: list[tuple[IntArray, FloatArray, FloatArray, FloatArray]] = []

    def close() -> Cloud:
        t = np.concatenate([p[0] for p in parts])
        keep = cloud_rows(t.size, max_points)
        x, y, z = (np.concatenate([p[k] for p in parts])[keep] for k in (1, 2, 3))
        return Cloud(int(t.max()), x, y, z, int(t.size))

    for batch in iter_table_batches(
        path, "points", columns=list(POINT_COLUMNS), batch_rows=POINT_BATCH
    ):
        if batch.num_rows == 0:
            continue
        cols = {c: batch.column(c).to_numpy(zero_copy_only=False) for c in POINT_COLUMNS}
        t = np.asarray(cols["t_ns"], dtype=np.int64)
        require_times(t, path)
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


__all__ = [
    "CLOUD_PERIOD_NS",
    "DESCRIPTIONS",
    "MAX_CLOUD_POINTS",
    "TF_RATE_HZ",
    "TOPIC_EVENTS",
    "TOPIC_GPS",
    "TOPIC_POINTS",
    "TOPIC_TF",
    "TOPIC_TRUTH",
    "WORLD_FRAME",
    "AxlePath",
    "Cloud",
    "CloudSettings",
    "EventRows",
    "PoseRows",
    "Scene",
    "checked_inputs",
    "cloud_rows",
    "cloud_windows",
    "event_box_colors",
    "iter_clouds",
    "path_vertices",
    "point_colors",
    "ramp_rgb",
    "read_model_mu",
    "read_pose",
    "read_scene",
    "read_scored_events",
    "tf_rows",
]
