"""Pose stage speed on a race log: filter steps/s and x real time.

Usage: python benchmarks/bench_pose.py [--distance-m 5000] [--seed 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from toolkit.config import default_config
from toolkit.sim.simulate import simulate
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--distance-m", type=float, default=5000.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_pose_"))
    root.mkdir(parents=True, exist_ok=True)
    log = root / "race.mcap"
    if not log.exists():
        simulate(log, profile="race", distance_m=args.distance_m, seed=args.seed)
    # A fresh workspace each time: a kept one may hold another configuration's outputs.
    shutil.rmtree(root / "ws", ignore_errors=True)
    ws = Workspace(root / "ws")
    cfg = default_config()
    log_id = ingest_log(log, ws, cfg).log_id
    t0 = time.perf_counter()
    result = run_stage(POSE, ws, cfg, log_id=log_id, overwrite=True)
    wall = time.perf_counter() - t0
    man = ws.manifest(log_id).read()
    rec = man["stages"]["pose"] if "stages" in man else {}
    detail = man["pose"]
    duration = result.rows / cfg.pose.output_rate_hz
    print(
        json.dumps(
            {
                "log_seconds": round(duration, 1),
                "wall_seconds": round(wall, 2),
                "x_real_time_stage": round(duration / wall, 1),
                "x_real_time_filter": detail["x_real_time"],
                "epochs_per_s": round(detail["epochs"] / wall, 1),
                "imu_samples_per_s": round(detail["imu_samples"] / wall, 1),
                "timings_s": rec.get("timings_s"),
                "accuracy": result.accuracy,
                "gated": detail["gated"],
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
