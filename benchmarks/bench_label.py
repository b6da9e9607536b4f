"""Label stage speed and memory on a long crafted log (no simulation needed).

A straight drive at 10 m/s for ``--minutes`` (default 60: 360,000 IMU rows, 25,700 events),
the IMU reading g plus road noise and a 0.5 G burst every 50 m, recorded as a finished ingest
and pose wrote it. Prints wall time, events and IMU rows per second, and the process's peak
RSS (``VmHWM``) before and after the stage, measured in a fresh process that only runs the
stage: the stage streams the IMU, so its increment should not grow with the log's IMU table
(compare ``--minutes 10`` and ``60``). Measured 2026-11-23: 10 min +33 MB, 60 min +65 MB
(the difference was the pose, then held whole). Measured 2026-11-26, the pose streamed too:
10 min +47.0 MB, 60 min +50.5 MB (peak 203.6 / 207.1 MB): flat; 60 min labelled in 6.6 s
(25,710 events, 3,900 events/s).

Usage: python benchmarks/bench_label.py [--minutes 60] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from toolkit.config import default_config
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.stages.test_label import LOG_ID, G, crafted_log  # noqa: E402


def peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def craft(root: Path, minutes: float) -> int:
    """The crafted workspace under ``root / "ws"``; returns its IMU rows."""
    shutil.rmtree(root / "ws", ignore_errors=True)
    n = int(minutes * 60 * 100)
    t = 1_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    rng = np.random.default_rng(1)
    az = G + 0.3 * rng.standard_normal(n)
    ts = (t - t[0]) * 1e-9
    centres = np.arange(2.5, ts[-1], 5.0)  # every 50 m at 10 m/s
    for c, i in zip(centres, np.searchsorted(ts, centres), strict=True):
        sl = slice(max(int(i) - 30, 0), int(i) + 30)
        u = ts[sl] - c
        az[sl] += 0.5 * G * np.exp(-0.5 * (u / 0.04) ** 2) * np.cos(2 * np.pi * 25 * u)
    accel = np.stack([np.zeros(n), np.zeros(n), az], axis=1)
    crafted_log(root / "ws", t, accel, t, 10.0 * ts, np.full(n, 10.0))
    return n


def run(root: Path, imu_rows: int, minutes: float) -> None:
    """Label the crafted log in this (fresh) process and print the figures."""
    ws = Workspace(root / "ws")
    before = peak_rss_mb()
    t0 = time.perf_counter()
    result = run_stage(LABEL, ws, default_config(), log_id=LOG_ID, overwrite=True)
    wall = time.perf_counter() - t0
    after = peak_rss_mb()
    rec = ws.manifest(LOG_ID).read()["stages"]["label"]
    print(result.summary())
    print(
        json.dumps(
            {
                "minutes": minutes,
                "imu_rows": imu_rows,
                "events": result.events,
                "wall_seconds": round(wall, 2),
                "events_per_s": round(result.events / wall, 1),
                "imu_rows_per_s": round(imu_rows / wall, 1),
                "peak_rss_mb_before_stage": round(before, 1),
                "peak_rss_mb_after_stage": round(after, 1),
                "timings_s": rec["timings_s"],
            },
            indent=1,
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--run", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_label_"))
    if args.run is not None:
        run(root, args.run, args.minutes)
        return
    rows = craft(root, args.minutes)
    cmd = [sys.executable, __file__, "--keep", str(root), "--minutes", str(args.minutes)]
    subprocess.run([*cmd, "--run", str(rows)], check=True)


if __name__ == "__main__":
    main()
