"""Benchmark: a log's cloud with its world origin moved far from the drive (issue "Truth far
from home", point 1).

The sample log is ingested once, then posed and projected twice: with its own origin (the
first agreeing GPS fix) and with the origin moved ``--km`` west of it along its parallel
(as if the log were one of a course whose frame is far away). The second cloud is taken
through geodetic coordinates into the first one's frame and compared at the returns of
20-30 m range (:mod:`toolkit.analysis.cloud_frames`). Usage::

    python benchmarks/curved_earth.py [--km 30 100]

Target: p95 of the height difference within 0.02 m at 30 and 100 km.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.analysis.cloud_frames import frame_agreement, read_cloud
from toolkit.config import default_config
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.stages import pose_inputs
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_logs" / "sample.mcap"
#: Mean Earth radius (IUGG), m: only to place the moved origin about ``km`` away.
EARTH_RADIUS_M = 6_371_000.0


def moved_origin(origin: GeodeticOrigin, km: float) -> GeodeticOrigin:
    """``origin`` moved ``km`` west along its parallel."""
    dlon = np.degrees(km * 1e3 / (EARTH_RADIUS_M * np.cos(np.radians(origin.latitude_deg))))
    return dataclasses.replace(origin, longitude_deg=origin.longitude_deg - float(dlon))


def pose_and_project_with_origin_moved(ws: Workspace, log_id: str, km: float) -> None:
    """Pose and project ``log_id`` again with its world origin moved ``km`` west."""
    real = pose_inputs.choose_enu_origin

    def far(*args: Any, **kwargs: Any) -> Any:
        chosen = real(*args, **kwargs)
        return None if chosen is None else (moved_origin(chosen[0], km), chosen[1])

    pose_inputs.choose_enu_origin = far  # type: ignore[assignment]
    try:
        run_stage(POSE, ws, default_config(), log_id=log_id, overwrite=True)
        run_stage(PROJECT, ws, default_config(), log_id=log_id, overwrite=True)
    finally:
        pose_inputs.choose_enu_origin = real


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--km", type=float, nargs="+", default=[30.0, 100.0])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ws = Workspace(Path(tmp) / "near")
        log_id = ingest_log(SAMPLE, ws, default_config()).log_id
        run_stage(POSE, ws, default_config(), log_id=log_id)
        run_stage(PROJECT, ws, default_config(), log_id=log_id)
        near = read_cloud(ws.log_dir(log_id) / "points.parquet")
        for km in args.km:
            far_ws = Workspace(shutil.copytree(ws.root, Path(tmp) / f"far{km:g}", symlinks=True))
            pose_and_project_with_origin_moved(far_ws, log_id, km)
            far = read_cloud(far_ws.log_dir(log_id) / "points.parquet")
            agreement = frame_agreement(near, far, 20.0, 30.0)
            print(json.dumps({"km": km, **dataclasses.asdict(agreement)}))


if __name__ == "__main__":
    main()
