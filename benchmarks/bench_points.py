"""Project, label and tables on a race log: wall time, rate and peak memory per stage.

Simulates (or reuses) a ``race`` log, ingests and poses it, then runs ``project``, ``label``
and ``tables`` each in a fresh process (``python -m toolkit <verb> -w WS --overwrite``), so each
stage's peak RSS (``ru_maxrss`` of the child) is its own. Prints per stage the wall time, the
real-time factor (log duration / wall) and the peak RSS, projection's points per second, and
the numbers sect. 7 reports (points and events per mile, positives per split).

Usage: python benchmarks/bench_points.py [--distance-m 16093] [--seed 501] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

METRES_PER_MILE = 1609.344


def run_stage(verb: str, ws: Path) -> tuple[float, float, str]:
    """Wall seconds, the child's own peak RSS (MB, from ``wait4``) and its stdout."""
    t0 = time.perf_counter()
    child = subprocess.Popen(
        [sys.executable, "-m", "toolkit", verb, "-w", str(ws), "--overwrite"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    out, err = child.stdout.read(), child.stderr.read()  # type: ignore[union-attr]
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if child.returncode != 0:
        raise SystemExit(f"{verb} failed: {err.strip()}")
    return wall, usage.ru_maxrss / 1024.0, out.strip()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--distance-m", type=float, default=16093.0)  # 10 miles
    ap.add_argument("--seed", type=int, default=501)
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_points_"))
    root.mkdir(parents=True, exist_ok=True)
    log = root / "race.mcap"
    env = dict(os.environ)
    if not log.exists():
        subprocess.run(
            [sys.executable, "-m", "toolkit", "sim", str(log), "--profile", "race",
             "--distance-m", str(args.distance_m), "--seed", str(args.seed)],
            check=True, env=env,
        )  # fmt: skip
    ws = root / "ws"
    if not (ws / "logs").exists():
        subprocess.run(
            [sys.executable, "-m", "toolkit", "ingest", str(log), "-w", str(ws)], check=True
        )
        subprocess.run([sys.executable, "-m", "toolkit", "pose", "-w", str(ws)], check=True)
    log_dir = next(p for p in (ws / "logs").iterdir() if not p.name.startswith("."))
    pose = pq.read_table(log_dir / "pose.parquet", columns=["t_ns"]).column("t_ns").to_numpy()
    duration_s = (pose[-1] - pose[0]) * 1e-9
    print(f"log: {duration_s:.0f} s, load average {os.getloadavg()}")
    for verb in ("project", "label", "tables"):
        wall, peak_mb, out = run_stage(verb, ws)
        print(
            f"{verb}: {wall:.1f} s wall, {duration_s / wall:.1f}x real time, peak RSS <= {peak_mb:.0f} MB"
        )
        print("   ", out.splitlines()[-1] if out else "")
    manifest = json.loads((log_dir / "manifest.json").read_text())
    project = manifest["stages"]["project"]
    points = project["row_counts"]["points"]
    ts = project["timings_s"]
    print(
        f"project: {points / ts['loop'] / 1e6:.2f} M points/s through the stage's loop (read, "
        f"project, write: {ts['loop']:.1f} s wall); threads' projecting time {ts['project']:.1f} s "
        f"({points / ts['project'] / 1e6:.2f} M points/s per thread); main thread: read "
        f"{ts['read']:.1f} s, write {ts['write']:.1f} s, figures {ts['figures']:.1f} s "
        f"({points} points)"
    )
    print(
        "tables timings:",
        json.loads((ws / "manifest.json").read_text())["stages"]["tables"]["timings_s"],
    )
    tables = json.loads((ws / "manifest.json").read_text())["stages"]["tables"]["row_counts"]
    events = pq.read_table(ws / "tables" / "events.parquet", columns=["s_end_m"])
    miles = float(events.column("s_end_m").to_numpy().max()) / METRES_PER_MILE
    n_events = tables["train_events"] + tables["test_events"]
    n_points = tables["train_points"] + tables["test_points"]
    pos = tables["train_positives"] + tables["test_positives"]
    print(
        f"{miles:.2f} miles: {n_events / miles:.0f} events/mile (sect. 7: ~1,150), "
        f"{n_points / miles:.0f} points/mile (~89,000), positives {pos} "
        f"({100 * pos / max(n_events, 1):.2f} %; sect. 7: 0.36-0.44 %): train "
        f"{tables['train_positives']}/{tables['train_events']}, test "
        f"{tables['test_positives']}/{tables['test_events']}"
    )


if __name__ == "__main__":
    main()
