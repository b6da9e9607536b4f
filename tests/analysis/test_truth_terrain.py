"""Height error of projected points against the simulator's true terrain."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from toolkit.analysis.truth_terrain import (
    ALL_LASERS,
    CSV_HEADER,
    CSV_NAME,
    PNG_NAME,
    TILES_PER_QUERY,
    TrueGround,
    ZErrorAccumulator,
    ZErrorConfig,
    ZErrorResult,
    true_ground,
    write_z_error,
    z_error_of,
)
from toolkit.config import default_config
from toolkit.errors import ConfigError, StageError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.mounts import frame_mounts
from toolkit.model.projection import Counts
from toolkit.sim import simulate as simulate_module
from toolkit.sim.profiles import SimProfile, make_profile
from toolkit.sim.sensors import ideal_lasers
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.project_scans import LASER_COLUMNS, PoseStream, ScanBatch, project_batch
from toolkit.stages.runner import run_stage
from toolkit.tableio import iter_table_batches
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"


def test_statistics_by_laser_and_range() -> None:
    rng = np.random.default_rng(3)
    n = 200_000
    laser = np.where(rng.random(n) < 0.5, "/a", "/b")
    range_m = rng.uniform(0, 100, n)
    err = np.where(laser == "/a", 0.01, -0.02) + rng.normal(0, 0.01, n)
    err[:10] = np.nan  # off the modelled terrain
    acc = ZErrorAccumulator()
    for k in range(0, n, 30_000):  # streamed: the same as at once
        acc.feed(laser[k : k + 30_000], range_m[k : k + 30_000], err[k : k + 30_000])
    result = acc.result()
    assert result.points == n and result.off_terrain == 10
    assert result.lasers == ("/a", "/b")
    ok = np.isfinite(err)
    for name in ("/a", "/b", ALL_LASERS):
        mine = ok & ((laser == name) | (name == ALL_LASERS))
        e = err[mine]
        row = result.overall(name)
        assert row.count == e.size
        assert row.mean_m == pytest.approx(e.mean(), abs=1e-12)
        assert row.rms_m == pytest.approx(np.sqrt((e * e).mean()), rel=1e-12)
        # Quantiles to the 1 mm histogram bins (linear within them: far better here).
        assert row.median_m == pytest.approx(np.median(e), abs=2e-4)
        assert row.median_abs_m == pytest.approx(np.median(np.abs(e)), abs=2e-4)
        assert row.p90_abs_m == pytest.approx(np.percentile(np.abs(e), 90), abs=2e-4)
    # 5 m range bins up to 80 m; the last one takes everything beyond.
    bins = [r for r in result.rows if r.laser == "/a" and not math.isinf(r.range_hi_m)]
    assert [r.range_lo_m for r in bins] == [5.0 * k for k in range(15)]
    last = [r for r in result.rows if r.laser == "/a" and r.range_lo_m == 75.0][0]
    assert math.isinf(last.range_hi_m)
    assert last.count == int((ok & (laser == "/a") & (range_m >= 75)).sum())


def test_bad_z_error_input_is_refused() -> None:
    with pytest.raises(ConfigError, match="resolution_m"):
        ZErrorConfig(resolution_m=-1.0)
    with pytest.raises(StageError, match="one length"):
        ZErrorAccumulator().feed(["/a"], [1.0, 2.0], [0.0])


def test_a_log_that_is_not_simulated_has_no_true_ground(tmp_path: Path) -> None:
    assert true_ground(tmp_path) is None
    (tmp_path / "mcap_metadata.json").write_text(json.dumps({"other": {}}))
    assert true_ground(tmp_path) is None
    assert z_error_of(tmp_path) is None
    (tmp_path / "mcap_metadata.json").write_text(json.dumps({"terrain_sim": {"seed": "1"}}))
    with pytest.raises(StageError, match="cannot rebuild"):
        true_ground(tmp_path)


def test_the_files_are_written(tmp_path: Path) -> None:
    acc = ZErrorAccumulator()
    acc.feed(np.array(["/a", "/b"] * 50), np.arange(100.0), np.linspace(-0.01, 0.01, 100))
    result = acc.result()
    csv_a, png_a = write_z_error(result, tmp_path / "a", "synthetic")
    csv_b, png_b = write_z_error(result, tmp_path / "b", "synthetic")
    assert (csv_a.name, png_a.name) == (CSV_NAME, PNG_NAME)
    assert csv_a.read_bytes() == csv_b.read_bytes() and png_a.read_bytes() == png_b.read_bytes()
    rows = list(csv.DictReader(csv_a.open()))
    assert tuple(rows[0]) == CSV_HEADER and len(rows) == len(result.rows)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted([CSV_NAME, PNG_NAME])


# --------------------------------------------------------------------------------------
# The sample log
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def projected(sample_projected: tuple[Path, str]) -> Path:
    """The sample log ingested, posed and projected (shared, read-only): its log directory."""
    root, log_id = sample_projected
    return Workspace(root).log_dir(log_id)


@pytest.fixture(scope="module")
def ideal_projected(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sample profile's first 300 m simulated with ideal lasers
    (:func:`~toolkit.sim.sensors.ideal_lasers`: exact mounts, no bias, footprint, flex or
    jitter; only the range noise and the 1 cm resolution), ingested, posed and projected:
    its log directory. On it the points' error against the true terrain is the projection's
    own arithmetic plus the range noise."""
    real = simulate_module.make_profile

    def ideal_profile(name: str, distance_m: float | None = None) -> SimProfile:
        prof = real(name, distance_m)
        laser = ideal_lasers(prof.sensors.laser)
        return dataclasses.replace(prof, sensors=dataclasses.replace(prof.sensors, laser=laser))

    root = tmp_path_factory.mktemp("ideal_projected")
    log = root / "ideal.mcap"
    with mock.patch.object(simulate_module, "make_profile", ideal_profile):
        simulate_module.simulate(log, profile="sample", distance_m=300.0, seed=3)
    ws, config = Workspace(root / "ws"), default_config()
    log_id = ingest_log(log, ws, config).log_id
    run_stage(POSE, ws, config, log_id=log_id)
    run_stage(PROJECT, ws, config, log_id=log_id)
    return ws.log_dir(log_id)


def _errors_with_the_true_pose(log_dir: Path, ground: TrueGround) -> ZErrorResult:
    """The scans projected with the simulator's true pose (as the project stage does with
    the estimated one), every other batch of 2000 scans: half the log is plenty."""
    mounts, warnings = frame_mounts(
        log_dir / "tf_static.json", "base_link", [f"laser_{k}" for k in range(1, 6)]
    )
    assert len(mounts) == 5 and not warnings
    poses = PoseStream(log_dir / "truth_pose.parquet", "truth_pose")
    counts, previous = Counts(), {}  # type: ignore[var-annotated]
    acc = ZErrorAccumulator()
    batches = iter_table_batches(
        log_dir / "laser.parquet", "laser", columns=LASER_COLUMNS, batch_rows=2000
    )
    for k, batch in enumerate(batches):
        table = project_batch(ScanBatch.from_record_batch(batch), mounts, poses, previous, counts)
        if k % 2 == 0:
            xyz = np.stack([table[c].to_numpy() for c in "xyz"], axis=1)
            acc.feed(table["laser"], table["range"].to_numpy(), ground(xyz))
    return acc.result()


def _print_medians(truth: ZErrorResult, estimated: ZErrorResult) -> None:
    print()
    for name in truth.lasers:
        t, e = truth.overall(name).median_abs_m, estimated.overall(name).median_abs_m
        print(f"{name}: median |dz|, true pose {t * 1e3:.1f} mm, estimated {e * 1e3:.1f} mm")


def test_true_pose_points_lie_on_the_true_terrain_and_estimated_ones_do_not(
    ideal_projected: Path,
) -> None:
    """With ideal lasers and the true pose every laser's points are on the true ground within
    the range noise (the projection's arithmetic is exact); with the estimated pose (the
    points.parquet the stage wrote) they are centimetres off."""
    ground = true_ground(ideal_projected)
    assert isinstance(ground, TrueGround)
    truth = _errors_with_the_true_pose(ideal_projected, ground)
    estimated = z_error_of(ideal_projected)
    assert estimated is not None
    _print_medians(truth, estimated)
    assert truth.lasers == estimated.lasers and len(truth.lasers) == 5
    # Every other batch of a 300 m log's points.
    assert truth.points > 0.4 * estimated.points and estimated.points > 1_000_000
    assert estimated.off_terrain < estimated.points // 1000
    for name in truth.lasers:
        t, e = truth.overall(name), estimated.overall(name)
        assert t.median_abs_m < 0.005, (name, t)
        assert t.p90_abs_m < 0.02, (name, t)
        assert e.median_abs_m > 4 * t.median_abs_m, (name, e, t)


@pytest.mark.slow  # simulates a log with Stanley's laser errors (22 s): run by .ci/run
def test_stanleys_laser_errors_put_the_true_pose_points_centimetres_off(
    projected: Path, tmp_path: Path
) -> None:
    """The sample log's lasers have Stanley's error sources (beam footprint, range bias,
    mounts miscalibrated against the published ones, flex): projected with the true pose and
    the published mounts, as a user would, their points are off the true ground by their own
    error, several times the ideal lasers' few millimetres and up to the bias and the tilt
    of a mount at range, and the z error file is written."""
    ground = true_ground(projected)
    assert isinstance(ground, TrueGround)
    truth = _errors_with_the_true_pose(projected, ground)
    estimated = z_error_of(projected)
    assert estimated is not None and truth.lasers == estimated.lasers
    _print_medians(truth, estimated)
    # The budget of a laser's own error: its range bias plus its mount's tilt (the rack's and
    # its own) seen at the far laser's 25-30 m, plus flex (sample seed 3: 11-107 mm).
    lp = make_profile("sample").sensors.laser
    tilt_rad = lp.rack_angle_error_rad[1] + lp.laser_angle_error_rad
    budget_m = lp.range_bias_max_m + 30.0 * np.tan(tilt_rad) + 0.02
    medians = [truth.overall(name).median_abs_m for name in truth.lasers]
    assert max(medians) > 0.01
    assert all(0.003 < m < budget_m for m in medians), (medians, budget_m)
    csv_path, png_path = write_z_error(estimated, tmp_path, "sample")
    assert csv_path.is_file() and png_path.stat().st_size > 10_000


def test_a_checked_stretch_of_road_costs_one_tile_and_reads_the_same_heights(
    projected: Path,
) -> None:
    """The project stage's z-error sample: points on every 8th terrain tile, less its last two
    coarse steps. Their heights, asked for one stretch at a time, are the ones the whole
    lookup gives, and asking them builds that stretch's tile alone (of each kind), not the
    tiles between it and the next stretch."""
    import pyarrow.parquet as pq

    ground = true_ground(projected)
    assert isinstance(ground, TrueGround)
    table = pq.read_table(projected / "points.parquet", columns=["x", "y", "z"])
    xyz = np.stack([table.column(c).to_numpy() for c in "xyz"], axis=1)[::16]
    s, d, z = ground.route_coordinates(xyz)
    terrain = ground.world.terrain
    tile_m, coarse_m = terrain.tile_length_m, terrain.coarse_spacing_m
    stretch = ground.checked_stretch(s, 8)
    on = stretch >= 0
    assert 0 < on.sum() < on.size
    k = np.floor(s[on] / tile_m)
    assert (stretch[on] == k).all() and (k % 8 == 0).all()
    assert (s[on] - k * tile_m < tile_m - 2 * coarse_m).all()
    near_end = (np.floor(s / tile_m) % 8 == 0) & (
        s - np.floor(s / tile_m) * tile_m > tile_m - 2 * coarse_m
    )
    assert near_end.any() and (stretch[near_end] == -1).all()
    assert (ground.checked_stretch(np.array([-1.0, terrain.route.length_m + 1.0]), 1) == -1).all()
    everything, _ = ground.height_m(xyz[on])
    for tile in np.unique(stretch[on]):
        rows = np.flatnonzero(stretch == tile)
        terrain.__dict__.pop("_tiles", None)  # a cold cache: count what this stretch builds
        heights = ground.terrain_height_m(s[rows], d[rows])
        assert sorted(terrain.__dict__["_tiles"]) == [("coarse", int(tile)), ("fine", int(tile))]
        # The same heights, to rounding (a window starting at another tile: 1e-14 m).
        np.testing.assert_allclose(
            heights, everything[np.searchsorted(np.flatnonzero(on), rows)], rtol=0, atol=1e-9
        )


def test_heights_along_a_whole_route_are_asked_a_few_tiles_at_a_time(projected: Path) -> None:
    """Points along the whole sample route (14 tiles): the same heights as one query over
    all of them (to rounding), NaN off the modelled terrain, and no single query of the
    simulator's terrain spans more than TILES_PER_QUERY tiles (an hour's route at once
    was gigabytes of grid)."""
    ground = true_ground(projected)
    assert isinstance(ground, TrueGround)
    terrain = ground.world.terrain
    length_m = terrain.route.length_m
    rng = np.random.default_rng(0)
    s = np.r_[rng.uniform(0.0, length_m, 4000), -1.0, length_m + 1.0, np.nan, 10.0]
    d = np.r_[rng.uniform(-5.0, 5.0, 4000), 0.0, 0.0, 0.0, 1e3]
    spans: list[float] = []
    real = terrain.height

    def spy(s_m: np.ndarray, d_m: np.ndarray) -> np.ndarray:
        spans.append(float(np.max(s_m) - np.min(s_m)))
        return real(s_m, d_m)

    with mock.patch.object(terrain, "height", spy):
        got = ground.terrain_height_m(s, d)
    assert len(spans) >= 2
    assert max(spans) <= TILES_PER_QUERY * terrain.tile_length_m
    np.testing.assert_allclose(got[:4000], real(s[:4000], d[:4000]), rtol=0, atol=1e-9)
    assert np.isnan(got[4000:]).all()


def test_heights_are_the_same_with_one_fft_thread_or_two(projected: Path) -> None:
    """Evaluate's oracle synthesises the terrain with two FFT threads: the same heights,
    bit for bit, as with one (each built from cold caches)."""
    import scipy.fft

    from toolkit.sim import terrain

    first = true_ground(projected)
    assert isinstance(first, TrueGround)
    rng = np.random.default_rng(1)
    s = rng.uniform(0.0, first.world.terrain.route.length_m, 500)
    d = rng.uniform(-3.0, 3.0, 500)
    heights = []
    for workers in (1, 2):
        ground = true_ground(projected)
        assert isinstance(ground, TrueGround)
        terrain._raw_field.cache_clear()
        with scipy.fft.set_workers(workers):
            heights.append(ground.terrain_height_m(s, d))
    assert np.isfinite(heights[0]).all()
    np.testing.assert_array_equal(heights[0], heights[1])


def test_a_short_route_checks_closer_stretches(projected: Path) -> None:
    """Every 8th tile on a long route; on the sample log's 0.7 km (14 tiles) that would be two
    stretches, so the check takes every tile there, and never fewer than one."""
    ground = true_ground(projected)
    assert isinstance(ground, TrueGround)
    tiles = math.ceil(ground.world.route.length_m / ground.world.terrain.tile_length_m)
    assert 10 <= tiles < 30
    assert ground.stretch_every(15, 8) == 1
    assert ground.stretch_every(2, 8) == min(8, tiles // 2)
    assert ground.stretch_every(1, 8) == 8
    assert ground.stretch_every(1000, 8) == 1


def write_pose_table(
    path: Path, name: str, t_ns: np.ndarray, xyz: np.ndarray, rpy: np.ndarray
) -> None:
    """A ``pose``-shaped table (``name``: pose or truth_pose) with the given track."""
    import pyarrow as pa

    from toolkit.tableio import load_table_schema, write_table

    given = dict(zip(("x", "y", "z", "roll", "pitch", "yaw"), [*xyz.T, *rpy.T], strict=True))
    cols = {}
    for spec in load_table_schema(name).columns:
        if spec.name == "t_ns":
            cols[spec.name] = pa.array(t_ns, pa.int64())
        else:
            values = given.get(spec.name, np.zeros(t_ns.size))
            cols[spec.name] = pa.array(np.asarray(values, np.float64), spec.arrow_type())
    write_table(path, pa.table(cols), name, source_sha256="0" * 64, config_hash="test")


def test_beams_are_moved_by_the_pose_error_at_their_time(tmp_path: Path) -> None:
    """A point placed with an estimated pose 0.2 m east and 0.02 rad of yaw off the truth,
    turning as it drives, lands back where the true pose puts the same beam; a point seen
    outside the poses' times has no place."""
    from scipy.spatial.transform import Rotation

    from toolkit.analysis.truth_terrain import where_beams_hit

    t_ns = np.arange(0, 2_000_000_000, 10_000_000, dtype=np.int64)  # 2 s at 100 Hz
    s = t_ns * 1e-9
    true_xyz = np.c_[10.0 * s, 0.5 * s**2, 0.1 * s]
    true_rpy = np.c_[0.02 * np.sin(s), 0.01 * s, 0.3 * s]
    est_xyz = true_xyz + [0.2, 0.0, 0.05]
    est_rpy = true_rpy + [0.0, 0.0, 0.02]
    write_pose_table(tmp_path / "pose.parquet", "pose", t_ns, est_xyz, est_rpy)
    write_pose_table(tmp_path / "truth_pose.parquet", "truth_pose", t_ns, true_xyz, true_rpy)
    # Beams 10-20 m ahead, at times between pose rows.
    rng = np.random.default_rng(5)
    beam_t = np.sort(rng.integers(0, t_ns[-1], 50))
    beam_base = np.c_[rng.uniform(10, 20, 50), rng.uniform(-3, 3, 50), np.full(50, -2.0)]

    def world(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
        k = np.searchsorted(t_ns, beam_t, side="right") - 1
        f = ((beam_t - t_ns[k]) / 1e7)[:, None]
        pos = xyz[k] + f * (xyz[k + 1] - xyz[k])
        rot = Rotation.from_euler("ZYX", (rpy[k] + f * (rpy[k + 1] - rpy[k]))[:, ::-1])
        return np.asarray(rot.apply(beam_base) + pos)

    placed = world(est_xyz, est_rpy)
    hit = where_beams_hit(tmp_path, placed, beam_t)
    # Slerp and the linear blend of small Euler steps differ by far less than a millimetre.
    assert np.abs(hit - world(true_xyz, true_rpy)).max() < 1e-3
    assert np.abs(placed - world(true_xyz, true_rpy)).max() > 0.2  # the error was there
    outside = where_beams_hit(tmp_path, placed[:2], np.array([-1, t_ns[-1] + 1]))
    assert np.isnan(outside).all()


def test_beams_need_both_poses(tmp_path: Path) -> None:
    from toolkit.analysis.truth_terrain import where_beams_hit

    t_ns = np.arange(0, 100_000_000, 10_000_000, dtype=np.int64)
    write_pose_table(tmp_path / "pose.parquet", "pose", t_ns, np.zeros((10, 3)), np.zeros((10, 3)))
    with pytest.raises(StageError, match="truth_pose"):
        where_beams_hit(tmp_path, np.zeros((1, 3)), np.array([5]))


def test_points_far_away_reach_the_simulators_frame_as_they_are() -> None:
    """The pose's frame and the simulator's are maps about origins a GPS error apart: a
    point 100 km out keeps its place across them to the millimetre (taken through tangent
    planes, the 10 m between the origins tilted one against the other: 0.16 m of height)."""
    from toolkit.geometry.map_frame import geodetic_to_world
    from toolkit.sim.world import make_world

    sim_origin = GeodeticOrigin(35.0, -117.0, 600.0)
    pose_origin = GeodeticOrigin(35.0, -117.0 + 10.0 / 91_290.0, 600.4)  # 10 m east
    ground = TrueGround(make_world(make_profile("sample", 150.0).world, 1), sim_origin, pose_origin)
    lat = np.array([35.0, 35.9, 35.0, 34.3])
    lon = np.array([-117.0, -117.0, -115.9, -117.8])
    alt = np.array([600.0, 640.0, 580.0, 610.0])
    moved = ground.to_sim(geodetic_to_world(lat, lon, alt, pose_origin))
    np.testing.assert_allclose(moved, geodetic_to_world(lat, lon, alt, sim_origin), atol=1e-3)
