"""The tables stage: points under each rear tyre of each event, split by distance (sect. 7).

The events here are crafted from the pose (1.4 m stretches of the rear-axle path, a made-up
shock) so this test depends only on projection; the label stage has its own tests.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from tests.stages.crafted import record_stage_outputs
from toolkit.config import default_config
from toolkit.errors import StageError, WorkspaceError
from toolkit.manifest import file_sha256
from toolkit.stages.ingest import ingest_log
from toolkit.stages.runner import run_stage
from toolkit.stages.tables import SPEC as TABLES
from toolkit.stages.tables import TablesResult
from toolkit.tableio import read_table, write_table
from toolkit.tyre_paths import tyre_paths
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"
EVENT_LENGTH_M = 1.4
MPH = 0.44704


def craft_events(ws: Workspace, log_id: str) -> pa.Table:
    """Events every 1.4 m of the pose's path, with a deterministic made-up shock; written
    as a finished label stage would have."""
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    t = pose.column("t_ns").to_numpy()
    x, y = pose.column("x").to_numpy(), pose.column("y").to_numpy()
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    edges = np.arange(0.0, s[-1], EVENT_LENGTH_M)
    t_edges = np.interp(edges, s, t.astype(np.float64)).astype(np.int64)
    n = edges.size - 1
    speed = np.array(
        [
            pose.column("speed").to_numpy()[(t >= a) & (t < b)].mean()
            for a, b in zip(t_edges[:-1], t_edges[1:], strict=True)
        ]
    )
    shock = 0.05 + 0.3 * (np.arange(n) % 17 == 0)
    rugged = shock / (speed / MPH)
    events = pa.table(
        {
            "event_id": pa.array(np.arange(n), pa.int64()),
            "t_start_ns": pa.array(t_edges[:-1], pa.int64()),
            "t_end_ns": pa.array(t_edges[1:], pa.int64()),
            "s_start_m": pa.array(edges[:-1]),
            "s_end_m": pa.array(edges[1:]),
            "speed_mph": pa.array(speed / MPH),
            "shock_g": pa.array(shock),
            "ruggedness": pa.array(rugged),
            "rough": pa.array(rugged >= 0.02),
            "shock_t_ns": pa.array((t_edges[:-1] + t_edges[1:]) // 2, pa.int64()),
            "imu_samples": pa.array(np.full(n, 14, np.int32), pa.int32()),
            "truth_feature_height_m": pa.array(np.zeros(n)),
            "truth_feature_kind": pa.array([None] * n, pa.string()),
        }
    )
    log_dir = ws.log_dir(log_id)
    write_table(
        log_dir / "events.parquet", events, "events", source_sha256="crafted", config_hash="crafted"
    )
    record_stage_outputs(
        log_dir, "label", ["events.parquet"], {"pose": file_sha256(log_dir / "pose.parquet")}
    )
    return events


@pytest.fixture(scope="module")
def tabled(
    sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Workspace, str, pa.Table, TablesResult]:
    root, log_id = sample_projected
    ws = Workspace(tmp_path_factory.mktemp("tables") / "ws")
    shutil.copytree(root, ws.root, symlinks=True)
    events = craft_events(ws, log_id)
    return ws, log_id, events, run_stage(TABLES, ws, default_config())


def _polyline_distance(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of points p (N, 2) to the polyline (M, 2), exactly (segment by segment)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    w = p[:, None, :] - a[None]
    f = np.clip((w * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    d = np.linalg.norm(w - f[..., None] * ab, axis=-1)
    return np.asarray(d.min(axis=1))


def test_points_are_those_near_each_tyre_before_it_got_there(tabled) -> None:  # type: ignore[no-untyped-def]
    """Against brute force on a few events: the tyre's polyline from the pose rows, every
    point of the cloud: the table holds exactly the points within 30 cm seen before the
    event started (up to 1 mm at the radius: the path is sampled every 5 cm)."""
    ws, log_id, events, _ = tabled
    cfg = default_config()
    pose = read_table(ws.log_table(log_id, "pose"), "pose")
    t_pose = pose.column("t_ns").to_numpy()
    points = read_table(ws.log_table(log_id, "points"), "points", columns=["t_ns", "x", "y"])
    pt = points.column("t_ns").to_numpy()
    pxy = np.c_[points.column("x").to_numpy(), points.column("y").to_numpy()]
    table = read_table(ws.event_points_table, "event_points")
    kept = read_table(ws.events_table, "tables_events")
    kept_ids = set(kept.column("event_id").to_pylist())
    checked = 0
    for e in range(40, events.num_rows, 19):
        if e not in kept_ids:
            continue
        t0, t1 = events.column("t_start_ns")[e].as_py(), events.column("t_end_ns")[e].as_py()
        inside = (t_pose >= t0) & (t_pose <= t1)
        ts = np.concatenate([[t0], t_pose[inside], [t1]]).astype(np.float64)
        cx = np.interp(ts, t_pose, pose.column("x").to_numpy())
        cy = np.interp(ts, t_pose, pose.column("y").to_numpy())
        yaw = np.interp(ts, t_pose, np.unwrap(pose.column("yaw").to_numpy()))
        for sign, wheel in ((1, "left"), (-1, "right")):
            half = sign * cfg.vehicle.track_m / 2
            line = np.c_[cx - np.sin(yaw) * half, cy + np.cos(yaw) * half]
            seen = (pt < t0) & (pt >= t0 - int(cfg.tables.max_lookahead_s * 1e9))
            d = np.full(pt.size, np.inf)
            box = (
                seen
                & (np.abs(pxy[:, 0] - line[:, 0].mean()) < 3)
                & (np.abs(pxy[:, 1] - line[:, 1].mean()) < 3)
            )
            d[box] = _polyline_distance(pxy[box], line)
            mine = table.filter(
                pa.compute.and_(
                    pa.compute.equal(table.column("event_id"), e),
                    pa.compute.equal(table.column("wheel"), wheel),
                )
            )
            # A point is its time and position (two lasers may fire in the same nanosecond).
            got = set(
                zip(mine.column("t_ns").to_pylist(), mine.column("x").to_pylist(), strict=True)
            )

            def ident(mask: np.ndarray) -> set[tuple[int, float]]:
                return set(zip(pt[mask].tolist(), pxy[mask, 0].tolist(), strict=True))

            inner, outer = ident(d <= 0.299), ident(d <= 0.301)
            assert inner <= got <= outer, (e, wheel)
            assert len(got) >= 2
            checked += 1
    assert checked >= 20


def test_totals_agree_with_the_events_and_the_split_is_by_distance(tabled) -> None:  # type: ignore[no-untyped-def]
    ws, log_id, events, result = tabled
    table = read_table(ws.event_points_table, "event_points")
    kept = read_table(ws.events_table, "tables_events")
    split = np.array(kept.column("split").to_pylist())
    for name in ("train", "test"):
        mine = split == name
        assert result.splits[name].events == int(mine.sum()) > 50
        assert result.splits[name].rough == int(
            kept.column("rough").to_numpy(zero_copy_only=False)[mine].sum()
        )
        n_points = int(
            (kept.column("points_left").to_numpy() + kept.column("points_right").to_numpy())[
                mine
            ].sum()
        )
        assert result.splits[name].points == n_points
    assert table.num_rows == result.splits["train"].points + result.splits["test"].points
    # Every event kept has at least min_points_per_wheel under each tyre; the ones the
    # lasers never saw ahead of the tyres (the first metres of the log) were dropped.
    assert (
        kept.column("points_left").to_numpy().min() >= default_config().tables.min_points_per_wheel
    )
    assert result.rejects["too_few_points"] == events.num_rows - kept.num_rows > 0
    # First half of the distance trains, the second tests.
    mid = 0.5 * (kept.column("s_start_m").to_numpy() + kept.column("s_end_m").to_numpy())
    total = events.column("s_end_m").to_numpy().max()
    assert (mid[split == "train"] < total / 2).all() and (mid[split == "test"] >= total / 2).all()
    # tau is each point's time in seconds, before its event.
    starts = dict(
        zip(kept.column("event_id").to_pylist(), kept.column("t_start_ns").to_pylist(), strict=True)
    )
    t_start = np.array([starts[e] for e in table.column("event_id").to_pylist()])
    assert (table.column("t_ns").to_numpy() < t_start).all()
    np.testing.assert_allclose(
        table.column("tau").to_numpy(), table.column("t_ns").to_numpy() * 1e-9
    )
    assert "train:" in result.summary() and "test:" in result.summary()


def test_a_second_run_is_up_to_date(tabled) -> None:  # type: ignore[no-untyped-def]
    ws, _, _, result = tabled
    again = run_stage(TABLES, ws, default_config())
    assert again.status == "up_to_date"
    assert again.splits == result.splits


def test_the_left_tyre_is_on_the_left_whichever_way_the_vehicle_heads() -> None:
    """Heading north (yaw = pi/2, ENU): the left tyre is to the west (x < 0), the right to
    the east."""
    t = np.arange(0, 1_000_000_000, 10_000_000, dtype=np.int64)
    y = 5.0 * t * 1e-9
    paths = tyre_paths(
        t, np.c_[np.zeros_like(y), y], np.full(t.size, np.pi / 2), t[10:11], t[50:51], 1.65
    )
    np.testing.assert_allclose(paths.xy[paths.wheel == 0][:, 0], -0.825, atol=1e-12)
    np.testing.assert_allclose(paths.xy[paths.wheel == 1][:, 0], 0.825, atol=1e-12)


def test_events_and_points_of_an_earlier_pose_are_refused(tabled, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """After pose is re-run, tables must not match new tyre paths against points and events
    made from the old pose: one line naming the stage to run again."""
    ws, log_id, _, _ = tabled
    copy = Workspace(tmp_path / "ws")
    shutil.copytree(ws.root, copy.root, symlinks=True)
    log_dir = copy.log_dir(log_id)
    pose = read_table(log_dir / "pose.parquet", "pose")
    x = pose.column("x").to_numpy() + 5.0
    pose = pose.set_column(pose.schema.get_field_index("x"), "x", pa.array(x))
    write_table(
        log_dir / "pose.parquet", pose, "pose", source_sha256="crafted", config_hash="crafted"
    )
    record_stage_outputs(log_dir, "pose", ["pose.parquet"])
    with pytest.raises(
        WorkspaceError, match=r"label outputs beside it are stale \(made from another pose"
    ):
        run_stage(TABLES, copy, default_config(), overwrite=True)


def test_tyre_paths_are_dense_and_beside_the_axle() -> None:
    """A straight drive east at 10 m/s: the left tyre 0.825 m north, the right south,
    samples at most 5 cm apart."""
    t = np.arange(0, 2_000_000_000, 10_000_000, dtype=np.int64)
    x = 10.0 * t * 1e-9
    paths = tyre_paths(
        t,
        np.c_[x, np.zeros_like(x)],
        np.zeros_like(x),
        np.array([100_000_000]),
        np.array([240_000_000]),
        1.65,
    )
    left = paths.xy[paths.wheel == 0]
    right = paths.xy[paths.wheel == 1]
    np.testing.assert_allclose(left[:, 1], 0.825)
    np.testing.assert_allclose(right[:, 1], -0.825)
    assert left[:, 0].min() == pytest.approx(1.0) and left[:, 0].max() == pytest.approx(2.4)
    assert np.diff(np.sort(left[:, 0])).max() <= 0.05 + 1e-9


def test_without_labelled_logs_tables_refuses_in_one_line(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    ingest_log(SAMPLE_LOG, ws, default_config())
    with pytest.raises(StageError, match="run `terrain label`"):
        run_stage(TABLES, ws, default_config())
    assert not ws.events_table.exists()


def test_a_failing_matcher_leaves_the_last_tables_as_they_were(
    tabled, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """An error while a thread matches a batch reaches the caller as itself; the tables
    published before stay as they were and nothing half-written is left beside them."""
    from toolkit.stages import tables_points as tables

    ws = tabled[0]
    before = {p.name: file_sha256(p) for p in ws.tables_dir.iterdir()}
    monkeypatch.setattr(tables, "POINT_BATCH", 50_000)
    real = tables._match_batch
    calls = {"n": 0}

    def fails_on_the_third(*args):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 3:
            raise StageError("injected", path=ws.event_points_table)
        return real(*args)

    monkeypatch.setattr(tables, "_match_batch", fails_on_the_third)
    with pytest.raises(StageError, match="injected"):
        run_stage(TABLES, ws, default_config(), overwrite=True)
    assert {p.name: file_sha256(p) for p in ws.tables_dir.iterdir()} == before


def test_a_pose_read_in_small_batches_gives_the_same_tables(
    tabled, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """The pose is streamed (read forward, unwrapped as it comes, rows let go behind the
    points): read 7 rows at a time, across many pose batches per point batch and rows
    forgotten between point batches, the tables are those of the default run row for row."""
    from toolkit.stages import tables_points as tables

    ws = tabled[0]
    copy = Workspace(tmp_path / "ws")
    shutil.copytree(ws.root, copy.root, symlinks=True)
    monkeypatch.setattr(tables, "POSE_BATCH", 7)
    monkeypatch.setattr(tables, "POINT_BATCH", 30_000)
    run_stage(TABLES, copy, default_config(), overwrite=True)
    for name, schema in (("events", "tables_events"), ("event_points", "event_points")):
        mine = read_table(copy.tables_dir / f"{name}.parquet", schema)
        theirs = read_table(ws.tables_dir / f"{name}.parquet", schema)
        assert mine.num_rows > 0 and mine.equals(theirs), name


def test_points_out_of_time_order_are_refused(tabled, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Points more than a second out of time order could need pose rows already let go: one
    line naming the log and the stage to re-run, never a table matched against the wrong
    pose."""
    ws, log_id, _, _ = tabled
    copy = Workspace(tmp_path / "ws")
    shutil.copytree(ws.root, copy.root, symlinks=True)
    log_dir = copy.log_dir(log_id)
    points = read_table(log_dir / "points.parquet", "points")
    half = points.num_rows // 2
    swapped = pa.concat_tables([points.slice(half), points.slice(0, half)])
    write_table(
        log_dir / "points.parquet", swapped, "points", source_sha256="crafted", config_hash="c"
    )
    manifest = copy.manifest(log_id)
    record_stage_outputs(
        log_dir,
        "project",
        ["points.parquet"],
        manifest.stage("project").inputs,  # type: ignore[union-attr]
    )
    with pytest.raises(StageError, match=r"not in time order.*terrain project --overwrite"):
        run_stage(TABLES, copy, default_config(), overwrite=True)


def _config_keeping(keep: str, radius_m: float = 0.3):  # type: ignore[no-untyped-def]
    import dataclasses

    cfg = default_config()
    return dataclasses.replace(
        cfg,
        project=dataclasses.replace(cfg.project, keep=keep),
        model=dataclasses.replace(cfg.model, wheel_window_radius_m=radius_m),
    )


def test_a_cloud_kept_near_the_tyre_paths_makes_the_same_tables_to_the_bit(tabled) -> None:  # type: ignore[no-untyped-def]
    """``[project] keep = "near_path"`` leaves out most of the cloud, and the tables made from
    what it keeps are those made from every point, row for row and bit for bit."""
    from toolkit.stages.project import SPEC as PROJECT

    ws, log_id, _, _ = tabled
    names = {"events": "tables_events", "event_points": "event_points"}
    every = {n: read_table(ws.root / "tables" / f"{n}.parquet", s) for n, s in names.items()}
    all_points = read_table(ws.log_table(log_id, "points"), "points")
    near = _config_keeping("near_path")
    result = run_stage(PROJECT, ws, near, log_id=log_id, overwrite=True)
    kept = read_table(ws.log_table(log_id, "points"), "points")
    assert result.points == kept.num_rows
    assert result.far_from_path == all_points.num_rows - kept.num_rows
    assert kept.num_rows < 0.5 * all_points.num_rows
    assert "far from the tyres' paths left out" in result.summary()

    # The kept rows are rows of the full cloud, unchanged and in order (a point is its
    # laser, beam and time).
    def plain(table: pa.Table) -> pa.Table:
        return table.set_column(1, "laser", table["laser"].cast(pa.string()))

    def key(table: pa.Table) -> np.ndarray:
        laser = np.unique(table["laser"].cast(pa.string()).to_numpy(), return_inverse=True)[1]
        t = table["t_ns"].to_numpy() - int(all_points["t_ns"][0].as_py())
        return (t * 8 + laser) * 1024 + table["beam"].to_numpy()

    assert kept.num_rows > 0
    in_kept = np.isin(key(all_points), key(kept))
    assert plain(all_points).filter(pa.array(in_kept)).equals(plain(kept))
    run_stage(TABLES, ws, near, overwrite=True)
    for name, table in every.items():
        again = read_table(ws.root / "tables" / f"{name}.parquet", names[name])
        assert again.equals(table), name
    # A wider radius than the cloud was cut for: tables refuse, naming the log's points.
    with pytest.raises(StageError, match="kept only within 0.5 m") as err:
        run_stage(TABLES, ws, _config_keeping("near_path", radius_m=0.6), overwrite=True)
    assert "points.parquet" in str(err.value)
