"""The view (``terrain viz``): the bundled sample's results as a Foxglove MCAP, read back.

Two workspaces from the session's projected sample: the shared pipeline run of
``test_learn.py`` (labelled, learned, evaluated: points coloured by their scores) and a copy
only labelled (no scores: every point grey). Each view is read back with the ``mcap`` reader
and *every* message decoded with the protobuf schema the file carries (``mcap-protobuf-support``
builds the message classes from the schema's ``FileDescriptorSet``), and compared with the
tables it was made from:
the expectations are derived from the tables and the documented rules, not from the stage's
own helpers.
"""

from __future__ import annotations

import hashlib
import math
import shutil
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from tests.stages.test_learn import build_pipeline
from toolkit.config import default_config
from toolkit.errors import StageError, WorkspaceError
from toolkit.publish.viz import VizResult, run_viz
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

CFG = default_config()
TOPICS = {
    "/tf": "foxglove.FrameTransforms",
    "/points": "foxglove.PointCloud",
    "/events": "foxglove.SceneUpdate",
    "/gps": "foxglove.LocationFix",
    "/truth/path": "foxglove.SceneUpdate",
}
#: The documented decimation: clouds of 0.5 s of scan stamps, at most 4096 points each;
#: /tf at 20 Hz; true path vertices at least 0.25 m apart.
PERIOD_NS = 500_000_000
MAX_POINTS = 4_096
TF_PERIOD_NS = 50_000_000
TRUTH_STEP_M = 0.25
RED = (1.0, 0.0, 0.0)
GREY = (128, 128, 128, 255)


# --------------------------------------------------------------------------------------
# Decoding: mcap-protobuf-support builds each message class from the schema the file carries
# (its FileDescriptorSet); the messages are then turned into plain dicts of their fields.


def as_dict(message: Any) -> dict[str, Any]:
    """Every field of a decoded protobuf message (defaults included), nested messages as
    dicts, repeated fields as lists."""
    out: dict[str, Any] = {}
    for field in message.DESCRIPTOR.fields:
        value = getattr(message, field.name)
        is_message = field.message_type is not None
        if field.is_repeated:
            out[field.name] = [as_dict(v) for v in value] if is_message else list(value)
        else:
            out[field.name] = as_dict(value) if is_message else value
    return out


def test_the_decoder_reads_what_the_sdk_encodes() -> None:
    """The decoding path, on a message the SDK encodes: nested messages, repeated doubles,
    enums, strings."""
    from foxglove.messages import LocationFix, LocationFixPositionCovarianceType, Timestamp
    from mcap.records import Schema

    fix = LocationFix(
        timestamp=Timestamp(12, 345),
        frame_id="gps",
        latitude=-35.5,
        longitude=0.0,
        altitude=802.25,
        position_covariance=[1.0, 0, 0, 0, 2.0, 0, 0, 0, 3.5],
        position_covariance_type=LocationFixPositionCovarianceType.DiagonalKnown,
    )
    schema = LocationFix.get_schema()
    record = Schema(id=1, name=schema.name, encoding=schema.encoding, data=schema.data)
    decode = DecoderFactory().decoder_for("protobuf", record)
    assert decode is not None
    got = as_dict(decode(fix.encode()))
    assert got["timestamp"] == {"seconds": 12, "nanos": 345}
    assert (got["frame_id"], got["latitude"], got["longitude"], got["altitude"]) == (
        "gps",
        -35.5,
        0.0,
        802.25,
    )
    assert got["position_covariance"] == [1.0, 0, 0, 0, 2.0, 0, 0, 0, 3.5]
    assert got["position_covariance_type"] == 2


# --------------------------------------------------------------------------------------
# Reading a view back


@dataclass(frozen=True)
class View:
    """A view read back: per topic, (log time, decoded message) in file order; its schemas
    and encodings; its metadata records."""

    messages: dict[str, list[tuple[int, dict[str, Any]]]]
    schemas: dict[str, tuple[str, str, str]]  # topic -> (schema name, encoding, msg encoding)
    metadata: dict[str, dict[str, str]]
    log_times: list[int]
    #: The summary section's message count per topic.
    summary_counts: dict[str, int]


def read_view(path: Path) -> View:
    messages: dict[str, list[tuple[int, dict[str, Any]]]] = defaultdict(list)
    schemas: dict[str, tuple[str, str, str]] = {}
    factory = DecoderFactory()
    log_times: list[int] = []
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None, channel.topic
            schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            decode = factory.decoder_for(channel.message_encoding, schema)
            assert decode is not None, schema.name
            decoded = as_dict(decode(message.data))
            messages[channel.topic].append((message.log_time, decoded))
            log_times.append(message.log_time)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        summary_counts = {
            summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()
        }
    return View(dict(messages), schemas, metadata, log_times, summary_counts)


def ns(stamp: dict[str, int]) -> int:
    return stamp["seconds"] * 1_000_000_000 + stamp["nanos"]


def column(path: Path, schema: str, name: str) -> np.ndarray:
    return np.asarray(read_table(path, schema, columns=[name]).column(name).to_numpy())


def cloud_xyz_rgba(msg: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A PointCloud's world coordinates (N, 3), RGBA (N, 4) and r_combined (N,), read
    through its own field table and pose."""
    types = {7: "<f4", 1: "u1"}  # PackedElementField.NumericType FLOAT32, UINT8
    dtype = np.dtype(
        {
            "names": [f["name"] for f in msg["fields"]],
            "formats": [types[f["type"]] for f in msg["fields"]],
            "offsets": [f["offset"] for f in msg["fields"]],
            "itemsize": msg["point_stride"],
        }
    )
    assert len(msg["data"]) % msg["point_stride"] == 0
    pts = np.frombuffer(msg["data"], dtype=dtype)
    pose = msg["pose"]
    q = pose["orientation"]
    assert (q["x"], q["y"], q["z"], q["w"]) == (0.0, 0.0, 0.0, 1.0)
    origin = np.array([pose["position"][a] for a in "xyz"])
    xyz = np.c_[pts["x"], pts["y"], pts["z"]].astype(np.float64) + origin
    rgba = np.c_[pts["red"], pts["green"], pts["blue"], pts["alpha"]]
    return xyz, rgba, pts["r_combined"].astype(np.float64)


def yaw_pitch_roll(q: dict[str, float]) -> tuple[float, float, float]:
    """Z-Y-X Euler angles of a unit quaternion."""
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return yaw, pitch, roll


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


# --------------------------------------------------------------------------------------
# Fixtures


@dataclass(frozen=True)
class Made:
    ws: Workspace
    log_id: str
    path: Path
    result: VizResult
    view: View

    def table(self, name: str) -> Path:
        return self.ws.log_table(self.log_id, name)


def make_view(ws: Workspace, log_id: str, out: Path) -> Made:
    result = run_viz(ws, log_id, out, CFG)
    return Made(ws, log_id, out, result, read_view(out))


@pytest.fixture(scope="module")
def scored(sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory) -> Made:
    """The view of a copy of the shared pipeline run (scores and model present)."""
    pipeline = build_pipeline(sample_projected, tmp_path_factory)
    ws = Workspace(tmp_path_factory.mktemp("viz_scored") / "ws")
    shutil.copytree(pipeline.ws.root, ws.root, symlinks=True)
    return make_view(ws, pipeline.log_id, ws.root.parent / "view.mcap")


@pytest.fixture(scope="module")
def labelled(sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory) -> Made:
    """The view of a copy of the projected sample, only labelled (no scores, no model)."""
    root, log_id = sample_projected
    ws = Workspace(tmp_path_factory.mktemp("viz_labelled") / "ws")
    shutil.copytree(root, ws.root, symlinks=True)
    run_stage(LABEL, ws, CFG, log_id=log_id)
    return make_view(ws, log_id, ws.root.parent / "out" / "view.mcap")


# --------------------------------------------------------------------------------------
# Topics, counts, order


def test_every_topic_is_there_in_foxglove_schemas_with_its_count(scored: Made) -> None:
    view, r = scored.view, scored.result
    assert {t: s[0] for t, s in view.schemas.items()} == TOPICS
    assert {(s[1], s[2]) for s in view.schemas.values()} == {("protobuf", "protobuf")}
    pose_t = column(scored.table("pose"), "pose", "t_ns")
    bins = (pose_t - pose_t[0]) // TF_PERIOD_NS
    n_tf = int(np.count_nonzero(np.r_[True, bins[1:] != bins[:-1]]))
    gps = read_table(scored.table("gps"), "gps")
    status = gps.column("status").to_numpy()
    lat = gps.column("latitude").to_numpy()
    n_fix = int(np.count_nonzero((status >= 0) & np.isfinite(lat)))
    n_events = read_table(scored.table("events"), "events").num_rows
    counts = {topic: len(msgs) for topic, msgs in view.messages.items()}
    assert counts["/tf"] == n_tf == r.transforms
    assert n_tf == math.ceil(pose_t.size / 5)  # the sample's pose is exactly 100 Hz
    assert counts["/events"] == n_events == r.events
    assert counts["/gps"] == n_fix == r.gps_fixes
    assert r.gps_without_fix == gps.num_rows - n_fix > 0  # the sample has a GPS outage
    assert counts["/truth/path"] == 1 == r.truth_paths
    assert counts["/points"] == r.clouds
    assert r.topics == counts == view.summary_counts
    assert scored.result.warnings == ()
    meta = view.metadata["terrain.viz"]
    assert meta["log_id"] == scored.log_id
    assert "points.parquet" in meta["inputs_sha256"]
    assert scored.result.summary().startswith(f"{scored.log_id}: view written to ")
    # The rows without a fix were left out, not shown: the summary says so.
    assert f"{r.gps_without_fix} rows without a fix left out" in scored.result.summary()


def test_messages_are_in_log_time_order(scored: Made) -> None:
    """Written in time order across topics, so Foxglove reads the chunks in sequence."""
    t = np.asarray(scored.view.log_times)
    assert np.all(np.diff(t) >= 0)


# --------------------------------------------------------------------------------------
# /tf


def test_transforms_are_the_pose(scored: Made) -> None:
    pose = read_table(scored.table("pose"), "pose")
    cols = {c: pose.column(c).to_numpy() for c in ("t_ns", "x", "y", "z", "roll", "pitch", "yaw")}
    row_of = {int(t): k for k, t in enumerate(cols["t_ns"])}
    got = []
    for log_time, msg in scored.view.messages["/tf"]:
        (tf,) = msg["transforms"]
        assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "base_link")
        assert ns(tf["timestamp"]) == log_time
        k = row_of[log_time]
        got.append(k)
        assert [tf["translation"][a] for a in "xyz"] == [cols[a][k] for a in "xyz"]
        q = tf["rotation"]
        assert math.isclose(sum(q[a] ** 2 for a in "xyzw"), 1.0, rel_tol=1e-12)
        yaw, pitch, roll = yaw_pitch_roll(q)
        want = np.array([cols["yaw"][k], cols["pitch"][k], cols["roll"][k]])
        assert np.allclose(wrap(np.array([yaw, pitch, roll]) - want), 0.0, atol=1e-9)
    assert got == list(range(0, pose.num_rows, 5))


# --------------------------------------------------------------------------------------
# /events


def test_one_box_per_event_coloured_by_ruggedness(scored: Made) -> None:
    events = read_table(scored.table("events"), "events").to_pydict()
    by_id = {eid: k for k, eid in enumerate(events["event_id"])}
    seen = []
    colours: list[tuple[float, float, float, float, bool]] = []
    for log_time, msg in scored.view.messages["/events"]:
        (entity,) = msg["entities"]
        (box,) = entity["cubes"]
        k = by_id[int(entity["id"])]
        seen.append(int(entity["id"]))
        assert entity["frame_id"] == "world"
        assert log_time == ns(entity["timestamp"]) == events["t_end_ns"][k]
        size = box["size"]
        assert math.isclose(size["x"], events["s_end_m"][k] - events["s_start_m"][k])
        assert math.isclose(size["y"], CFG.vehicle.track_m)
        meta = {kv["key"]: kv["value"] for kv in entity["metadata"]}
        assert meta["rough"] == str(events["rough"][k]).lower()
        c = box["color"]
        colours.append((events["ruggedness"][k], c["r"], c["g"], c["b"], events["rough"][k]))
        if events["rough"][k]:
            assert (c["r"], c["g"], c["b"]) == RED
        else:
            assert c["g"] > 0.0 and c["b"] == 0.0  # never pure red
    assert sorted(seen) == sorted(events["event_id"])
    assert any(c[4] for c in colours) and not all(c[4] for c in colours)
    smooth = sorted(c for c in colours if not c[4])
    reds, greens = np.array([c[1] for c in smooth]), np.array([c[2] for c in smooth])
    assert np.all(np.diff(reds) >= 0) and np.all(np.diff(greens) <= 0)  # green -> red


def test_boxes_lie_on_the_rear_axle_path(scored: Made) -> None:
    """Each box's centre is the middle of the chord of its stretch: between the pose's
    positions at its start and end times."""
    pose = read_table(scored.table("pose"), "pose")
    t_ns = pose.column("t_ns").to_numpy()
    t = (t_ns - t_ns[0]).astype(np.float64)  # ns since the first row: exact in a float64
    events = read_table(scored.table("events"), "events").to_pydict()
    by_id = {eid: k for k, eid in enumerate(events["event_id"])}
    for _, msg in scored.view.messages["/events"]:
        (entity,) = msg["entities"]
        k = by_id[int(entity["id"])]
        centre = entity["cubes"][0]["pose"]["position"]
        when = np.array([events["t_start_ns"][k], events["t_end_ns"][k]]) - t_ns[0]
        for a in "xy":
            ends = np.interp(when.astype(np.float64), t, pose.column(a).to_numpy())
            assert math.isclose(centre[a], ends.mean(), abs_tol=1e-6)


# --------------------------------------------------------------------------------------
# /gps and /truth/path


def test_gps_fixes_are_the_table(scored: Made) -> None:
    gps = read_table(scored.table("gps"), "gps").to_pydict()
    rows = [
        k
        for k, (s, lat) in enumerate(zip(gps["status"], gps["latitude"], strict=True))
        if s >= 0 and lat is not None and math.isfinite(lat)
    ]
    fixes = scored.view.messages["/gps"]
    assert len(fixes) == len(rows)
    for (log_time, fix), k in zip(fixes, rows, strict=True):
        assert log_time == ns(fix["timestamp"]) == gps["t_ns"][k]
        assert (fix["latitude"], fix["longitude"], fix["altitude"]) == (
            gps["latitude"][k],
            gps["longitude"][k],
            gps["altitude"][k],
        )
        cov = np.array(fix["position_covariance"]).reshape(3, 3)
        assert list(np.diag(cov)) == list(gps["position_covariance"][k])
        assert fix["position_covariance_type"] == 2  # DIAGONAL_KNOWN


def test_truth_path_is_the_true_pose(scored: Made) -> None:
    truth = read_table(scored.table("truth_pose"), "truth_pose")
    xyz = np.c_[[truth.column(a).to_numpy() for a in "xyz"]].T
    ((log_time, msg),) = scored.view.messages["/truth/path"]
    (entity,) = msg["entities"]
    (line,) = entity["lines"]
    assert log_time == truth.column("t_ns")[0].as_py()
    assert line["type"] == 0  # LINE_STRIP
    v = np.array([[p[a] for a in "xyz"] for p in line["points"]])
    assert v.shape[0] == scored.result.truth_vertices
    assert np.array_equal(v[0], xyz[0]) and np.array_equal(v[-1], xyz[-1])
    # The vertices are the rows at or just past each multiple of the step along the path.
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))]
    rows = np.unique(np.r_[np.searchsorted(s, np.arange(0.0, s[-1], TRUTH_STEP_M)), s.size - 1])
    assert np.array_equal(v, xyz[rows])


# --------------------------------------------------------------------------------------
# /points


def expected_clouds(points_path: Path) -> list[tuple[int, np.ndarray]]:
    """(log time, rows of points.parquet) of each cloud by the documented rule: windows of
    0.5 s of scan stamps from the first row's, never going back; ``floor(i n / m)`` of each
    window's n rows, m = min(n, 4096); the time of the window's latest point."""
    table = pq.read_table(points_path, columns=["t_ns", "scan_t_ns"])
    t = table.column("t_ns").to_numpy()
    scan = table.column("scan_t_ns").to_numpy()
    w = np.maximum.accumulate((scan - scan[0]) // PERIOD_NS)
    starts = np.flatnonzero(np.r_[True, w[1:] != w[:-1]])
    ends = np.r_[starts[1:], w.size]
    clouds = []
    for lo, hi in zip(starts, ends, strict=True):
        n = hi - lo
        m = min(n, MAX_POINTS)
        clouds.append((int(t[lo:hi].max()), lo + (np.arange(m) * n) // m))
    return clouds


def test_clouds_hold_the_points_of_the_table(scored: Made) -> None:
    path = scored.table("points")
    table = read_table(path, "points", columns=["x", "y", "z"])
    xyz = np.c_[[table.column(a).to_numpy() for a in "xyz"]].T
    expected = expected_clouds(path)
    clouds = scored.view.messages["/points"]
    assert len(clouds) == len(expected) > 100
    total = 0
    for (log_time, msg), (t_want, rows) in zip(clouds, expected, strict=True):
        assert msg["frame_id"] == "world"
        assert log_time == ns(msg["timestamp"]) == t_want
        got, _, _ = cloud_xyz_rgba(msg)
        assert got.shape == (rows.size, 3)
        # float32 offsets from the cloud's origin: micrometres.
        assert np.abs(got - xyz[rows]).max() < 2e-5
        total += rows.size
    assert total == scored.result.cloud_points
    assert scored.result.points_read == xyz.shape[0]


def test_points_are_coloured_by_the_score_of_the_event_under_them(scored: Made) -> None:
    """A coloured point carries the R_combined of one of this log's scored events and lies
    on that event's stretch: within half a track of the rear-axle path between the event's
    start and end. Predicted rough ones are red, the rest not; uncoloured ones grey, NaN."""
    scores = read_table(scored.ws.scores_table, "scores").to_pydict()
    mine = [k for k, lid in enumerate(scores["log_id"]) if lid == scored.log_id]
    # The points carry R_combined as float32: which events' it is, by that (several events
    # may share a value: with W >= 0 many score exactly 0).
    events_of_r: dict[float, list[int]] = {}
    for k in mine:
        events_of_r.setdefault(float(np.float32(scores["r_combined"][k])), []).append(
            scores["event_id"][k]
        )
    predicted = {scores["event_id"][k]: scores["predicted"][k] for k in mine}
    events = read_table(scored.table("events"), "events").to_pydict()
    row_of = {e: k for k, e in enumerate(events["event_id"])}
    pose = read_table(scored.table("pose"), "pose")
    pt = pose.column("t_ns").to_numpy()
    pxy = np.c_[pose.column("x").to_numpy(), pose.column("y").to_numpy()]

    xy, rgba, r = [], [], []
    for _, msg in scored.view.messages["/points"]:
        cxyz, crgba, cr = cloud_xyz_rgba(msg)
        on = np.isfinite(cr)
        assert (crgba[~on] == GREY).all()
        xy.append(cxyz[on, :2])
        rgba.append(crgba[on])
        r.append(cr[on])
    all_xy, all_rgba, all_r = np.concatenate(xy), np.concatenate(rgba), np.concatenate(r)
    assert all_r.size == scored.result.coloured_points > 0
    n_red = 0
    for value in np.unique(all_r):
        candidates = events_of_r[float(value)]
        at = all_r == value
        d = np.full(int(at.sum()), np.inf)
        for event in candidates:
            k = row_of[event]
            # The rear-axle path over the event (pose rows inside, both ends interpolated).
            ends = [events["t_start_ns"][k], events["t_end_ns"][k]]
            inner = (pt > ends[0]) & (pt < ends[1])
            path = np.r_[
                [[np.interp(ends[0], pt, pxy[:, j]) for j in range(2)]],
                pxy[inner],
                [[np.interp(ends[1], pt, pxy[:, j]) for j in range(2)]],
            ]
            d = np.minimum(d, _distance_to_polyline(all_xy[at], path))
        assert d.max() <= CFG.vehicle.track_m / 2 + 1e-3, (candidates[:3], d.max())
        verdicts = {predicted[e] for e in candidates}
        assert len(verdicts) == 1  # equal scores, equal verdicts (rough iff r > mu)
        if verdicts.pop():
            assert (all_rgba[at] == (255, 0, 0, 255)).all()
            n_red += int(at.sum())
        else:
            assert (all_rgba[at, 1] > 0).all()  # some green: not red
    # Red exactly where the model said rough (on the sample it may say so nowhere).
    assert (n_red > 0) == any(predicted[e] for es in events_of_r.values() for e in es)


def _distance_to_polyline(p: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance (N,) of points (N, 2) to a polyline (M, 2)."""
    a, b = path[:-1], path[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(axis=1), 1e-18)
    t = np.clip(((p[:, None, :] - a[None]) * ab[None]).sum(axis=2) / L2, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.asarray(np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1))


def test_without_scores_every_point_is_grey(labelled: Made) -> None:
    r = labelled.result
    assert not labelled.ws.scores_table.exists()
    assert r.scored_events == 0 and r.coloured_points == 0
    assert r.events == read_table(labelled.table("events"), "events").num_rows > 0
    assert r.clouds == len(labelled.view.messages["/points"]) > 0
    for _, msg in labelled.view.messages["/points"]:
        _, rgba, rc = cloud_xyz_rgba(msg)
        assert (rgba == GREY).all() and np.isnan(rc).all()
    for _, msg in labelled.view.messages["/events"]:
        meta = {kv["key"] for kv in msg["entities"][0]["metadata"]}
        assert "r_combined" not in meta


# --------------------------------------------------------------------------------------
# Files: deterministic, atomic, refusals


def test_same_inputs_same_bytes(scored: Made, tmp_path: Path) -> None:
    again = run_viz(scored.ws, scored.log_id, tmp_path / "again.mcap", CFG)
    assert again.topics == scored.result.topics
    digest = [hashlib.sha256(p.read_bytes()).hexdigest() for p in (scored.path, again.out_path)]
    assert digest[0] == digest[1]


def test_existing_output_is_refused_unless_overwrite(scored: Made, tmp_path: Path) -> None:
    out = tmp_path / "view.mcap"
    out.write_bytes(b"mine")
    with pytest.raises(StageError, match="already exists") as info:
        run_viz(scored.ws, scored.log_id, out, CFG)
    assert str(out) in str(info.value) and "\n" not in str(info.value)
    assert out.read_bytes() == b"mine"
    run_viz(scored.ws, scored.log_id, out, CFG, overwrite=True)
    assert out.read_bytes() == scored.path.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.mcap"]  # no temporary left


def test_unknown_log_is_one_line_naming_it_and_the_logs_there(scored: Made, tmp_path: Path) -> None:
    out = tmp_path / "view.mcap"
    with pytest.raises(WorkspaceError, match="no log 'nosuchlog-000000000000' in the") as info:
        run_viz(scored.ws, "nosuchlog-000000000000", out, CFG)
    assert str(info.value).endswith(f"its logs: {scored.log_id}")
    assert "\n" not in str(info.value)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_missing_pose_is_one_line_naming_the_file(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    (ws.logs_dir / "posed-000000000000").mkdir()
    out = tmp_path / "view.mcap"
    with pytest.raises(StageError) as info:
        run_viz(ws, "posed-000000000000", out, CFG)
    assert str(ws.log_table("posed-000000000000", "pose")) in str(info.value)
    assert "\n" not in str(info.value)
    assert not out.exists()


def test_an_unwritable_output_is_one_line_naming_it(scored: Made, tmp_path: Path) -> None:
    (tmp_path / "file").write_bytes(b"")
    out = tmp_path / "file" / "view.mcap"  # under a regular file: no directory can be made
    with pytest.raises(StageError, match="cannot write the view") as info:
        run_viz(scored.ws, scored.log_id, out, CFG)
    assert str(out) in str(info.value) and "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_a_posed_log_without_points_or_events_shows_what_it_has(
    sample_projected: tuple[Path, str], tmp_path: Path
) -> None:
    """Before ``project`` and ``label`` (or on a vehicle without lasers): the pose, GPS and
    truth, and a warning naming each table missing."""
    root, log_id = sample_projected
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(
        root, ws.root, symlinks=True, ignore=shutil.ignore_patterns("points.parquet", "laser.*")
    )
    result = run_viz(ws, log_id, tmp_path / "view.mcap", CFG)
    view = read_view(tmp_path / "view.mcap")
    assert set(view.messages) == {"/tf", "/gps", "/truth/path"}
    assert result.topics == {t: len(m) for t, m in view.messages.items()}
    assert (result.clouds, result.events) == (0, 0)
    assert any("points.parquet" in w for w in result.warnings)
    assert any("events.parquet" in w for w in result.warnings)


def test_no_view_is_written_inside_a_workspace(scored: Made) -> None:
    """``--out WS/model.json --overwrite`` replaced the model before: nothing inside a
    workspace is a view's to replace."""
    model = scored.ws.model_path
    before = model.read_bytes() if model.is_file() else None
    for inside in (
        model,
        scored.ws.root / "view.mcap",
        scored.ws.log_dir(scored.log_id) / "v.mcap",
    ):
        with pytest.raises(WorkspaceError, match="lies inside the workspace"):
            run_viz(scored.ws, scored.log_id, inside, CFG, overwrite=True)
    assert (model.read_bytes() if model.is_file() else None) == before
    assert not (scored.ws.root / "view.mcap").exists()
