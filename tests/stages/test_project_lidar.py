"""A simulated spinning lidar through ingest, pose and project: every return a point or a
counted reject, each placed near the true ground."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from toolkit.config import PipelineConfig, default_config
from toolkit.sim.simulate import simulate
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

pytestmark = pytest.mark.slow  # a simulated drive with a 3-D lidar and three stages


def lidar_config() -> PipelineConfig:
    """The default vehicle with its lasers replaced by the simulator's lidar."""
    cfg = default_config()
    topics = dataclasses.replace(cfg.topics, lasers=(), lidars=("/ouster/points",))
    evaluate = dataclasses.replace(cfg.evaluate, baseline_closest_laser=None)
    project = dataclasses.replace(cfg.project, keep="all")
    return dataclasses.replace(cfg, topics=topics, evaluate=evaluate, project=project)


@pytest.fixture(scope="module")
def projected(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One simulated drive with the lasers and the lidar, projected twice with the same pose:
    from its lidar (lidar_config) and from its lasers (the default)."""
    root = tmp_path_factory.mktemp("lidar_project")
    log = root / "drive.mcap"
    simulate(log, profile="calibration", distance_m=120.0, seed=11, lidar=True)
    out = {}
    for name, cfg in (("lidar", lidar_config()), ("lasers", default_config())):
        ws = Workspace(root / name)
        log_id = ingest_log(log, ws, cfg).log_id
        run_stage(POSE, ws, cfg, log_id=log_id)
        run_stage(PROJECT, ws, cfg, log_id=log_id)
        out[name] = root / name / "logs" / log_id
    return out


def test_every_lidar_return_is_a_point_or_a_counted_reject(projected: dict[str, Path]) -> None:
    log_dir = projected["lidar"]
    returns = pq.ParquetFile(log_dir / "lidar.parquet").metadata.num_rows
    points = pq.read_table(log_dir / "points.parquet", columns=["laser", "beam", "ring"])
    record = json.loads((log_dir / "manifest.json").read_text())["stages"]["project"]
    assert points.num_rows + sum(record["rejects"].values()) == returns
    assert {str(n).rsplit(" ring ", 1)[0] for n in points.column("laser").to_pylist()} == {
        "/ouster/points"
    }
    assert points.column("beam").equals(points.column("ring"))


def _near_z_error(log_dir: Path, scanner: str) -> float:
    """The median z error (m) of a scanner's points 5-10 m from it, by the project stage's
    own comparison with the simulator's terrain: for a lidar, its rings' medians weighted by
    their points (each ring is a laser of the points)."""
    with (log_dir / "z_error_by_laser_and_range.csv").open() as f:
        rows = [
            r
            for r in csv.DictReader(f)
            if r["range_lo_m"] == "5" and r["laser"].rsplit(" ring ", 1)[0] == scanner
        ]
    counts = [int(r["count"]) for r in rows]
    assert sum(counts) > 1000
    return sum(c * float(r["median_m"]) for c, r in zip(counts, rows, strict=True)) / sum(counts)


def test_lidar_points_sit_where_the_lasers_do(projected: dict[str, Path]) -> None:
    """Placed with the same pose, the lidar's ground near the vehicle is the lasers' to a few
    centimetres (what their own range biases and mounts differ by); the pose's own error on
    this short drive (tens of centimetres in height) is common to both. A frame, mount or time
    error of the lidar's would show as decimetres to metres."""
    lidar = _near_z_error(projected["lidar"], "/ouster/points")
    laser = _near_z_error(projected["lasers"], "/laser/front_1")
    assert abs(lidar - laser) < 0.05


def test_fig4_is_drawn_from_the_lidars_own_revisits(projected: dict[str, Path]) -> None:
    """The rings' sweeps read as scan lines: flat ground found and paired between clouds,
    the |dz| growing with the time between them, as the lasers' do."""
    fig4 = {
        name: json.loads((d / "manifest.json").read_text())["project"]["fig4"]
        for name, d in projected.items()
    }
    assert fig4["lidar"]["flat_points"] > 10_000
    assert fig4["lidar"]["pairs"] > 10_000
    assert fig4["lidar"]["slope_m_per_s"] > 0 and fig4["lasers"]["slope_m_per_s"] > 0
