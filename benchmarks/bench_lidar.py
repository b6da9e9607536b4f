"""Benchmark: the per-log stages on a 3-D lidar log (issue "3-D lidar", its speed targets).

Simulates (once, cached beside the script's output) a drive with the spinning lidar alone
(``terrain sim --lidar --no-lasers``: an Ouster OS1-32 at 512 x 10 Hz), then, in this process,
times ingest, pose and project on it with ``pipelines/lidar.toml`` (the lidar for the lasers,
the cloud kept near the tyres' paths), each as times real time (the drive's duration over the
stage's wall time), and the workspace's size against the log's.

Usage::

    python benchmarks/bench_lidar.py [--distance-m 600] [--seed 5] [--keep near_path|all]

Targets: ingest at least 30x real time, project at least 10x, the three together at least
8x, the workspace at most 3x the log.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

from toolkit.config import load_config
from toolkit.mcapio.info import scan_log
from toolkit.sim.simulate import simulate
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

REPO = Path(__file__).resolve().parents[1]


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distance-m", type=float, default=600.0)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--keep", choices=("near_path", "all"), default="near_path")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()))
    args = parser.parse_args()
    log = args.cache / f"bench_lidar_{args.seed}_{args.distance_m:g}.mcap"
    if not log.is_file():
        t = time.perf_counter()
        simulate(
            log,
            profile="race",
            distance_m=args.distance_m,
            seed=args.seed,
            lasers=False,
            lidar=True,
        )
        print(f"simulated {log.name} in {time.perf_counter() - t:.1f} s")
    duration_s = scan_log(log).duration_s
    cfg = load_config(REPO / "pipelines" / "lidar.toml")
    cfg = dataclasses.replace(cfg, project=dataclasses.replace(cfg.project, keep=args.keep))
    out: dict[str, object] = {"log_mb": log.stat().st_size / 1e6, "duration_s": duration_s}
    with tempfile.TemporaryDirectory() as tmp:
        ws = Workspace(Path(tmp) / "ws")
        t = time.perf_counter()
        result = ingest_log(log, ws, cfg)
        seconds = {"ingest": time.perf_counter() - t}
        for spec in (POSE, PROJECT):
            t = time.perf_counter()
            run_stage(spec, ws, cfg, log_id=result.log_id)
            seconds[spec.name] = time.perf_counter() - t
        out["rows"] = result.row_counts
        out["x_real_time"] = {k: round(duration_s / v, 1) for k, v in seconds.items()}
        out["x_real_time"]["ingest+pose+project"] = round(duration_s / sum(seconds.values()), 1)  # type: ignore[index]
        out["workspace_over_log"] = round(_size(Path(tmp) / "ws") / log.stat().st_size, 2)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
