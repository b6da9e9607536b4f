"""Projection proper: scans to world points, without reading or writing, on 1 and 2 threads.

Takes a workspace whose log is ingested and posed (e.g. the one ``bench_points.py --keep DIR``
leaves), prepares ``--batches`` batches of scans in order (pose window, time since each
laser's previous scan), then projects them with
:func:`toolkit.stages.project_scans.project_prepared` on a pool of 1 and of 2 threads, as the
stage does, and prints points per second.

Usage: python benchmarks/bench_projection.py WORKSPACE [--batches 24]
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from toolkit.geometry.mounts import frame_mounts
from toolkit.stages import project, project_scans
from toolkit.tableio import iter_table_batches


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--batches", type=int, default=24)
    args = ap.parse_args()
    logs = args.workspace / "logs"
    log_dir = next(p for p in sorted(logs.iterdir()) if not p.name.startswith("."))
    laser = log_dir / "laser.parquet"
    mounts, _ = frame_mounts(
        log_dir / "tf_static.json", "base_link", project_scans.laser_frames(laser)
    )
    batches = iter_table_batches(
        laser, "laser", columns=project_scans.LASER_COLUMNS, batch_rows=project.SCAN_BATCH
    )
    poses, previous = project_scans.PoseStream(log_dir / "pose.parquet"), {}  # type: ignore[var-annotated]
    t = time.perf_counter()
    prepared = [
        project_scans.prepare_batch(
            project_scans.ScanBatch.from_record_batch(b), mounts, poses, previous
        )
        for _, b in zip(range(args.batches), batches, strict=False)
    ]
    prepare_s = time.perf_counter() - t
    print(f"load average {os.getloadavg()}; {len(prepared)} batches prepared in {prepare_s:.2f} s")
    for workers in (1, 2, 1, 2):
        t = time.perf_counter()
        with ThreadPoolExecutor(workers) as pool:
            n = sum(
                table.num_rows for table, _ in pool.map(project_scans.project_prepared, prepared)
            )
        wall = time.perf_counter() - t
        print(f"{workers} thread(s): {n / wall / 1e6:.2f} M points/s ({n} points, {wall:.2f} s)")


if __name__ == "__main__":
    main()
