"""The whole pipeline on a log: end-to-end wall time, then each stage's time and peak memory.

1. ``terrain run LOG -w WS`` in a fresh workspace, timed end to end: the real-time factor
   (log duration / wall) is the issue's figure (target at least 20x on this machine).
2. Each stage again in a fresh process (``terrain <verb> -w WS --overwrite``), for its own
   wall time and peak RSS (``ru_maxrss`` of the child from ``wait4``).

Usage: python benchmarks/bench_run.py LOG.mcap [--keep DIR] [--workers N]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

VERBS = ("ingest", "pose", "project", "label", "tables", "learn", "evaluate")


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall seconds and the child's peak RSS (MB)."""
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = child.stderr.read()  # type: ignore[union-attr]
    _, status, usage = os.wait4(child.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {err.strip()}")
    return time.perf_counter() - t0, usage.ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("log", type=Path)
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_run_"))
    ws = root / "ws"
    if ws.exists():
        shutil.rmtree(ws)
    terrain = [sys.executable, "-m", "toolkit", "-q"]
    workers = ["--workers", str(args.workers)] if args.workers is not None else []
    print(f"load average before: {os.getloadavg()}")
    wall, peak = timed([*terrain, "run", str(args.log), "-w", str(ws), *workers])
    log_dir = next(p for p in (ws / "logs").iterdir() if not p.name.startswith("."))
    t = pq.read_table(log_dir / "pose.parquet", columns=["t_ns"]).column("t_ns").to_numpy()
    duration_s = (t[-1] - t[0]) * 1e-9
    print(f"run: {duration_s:.0f} s of log in {wall:.1f} s: {duration_s / wall:.1f}x real time "
          f"(main process peak RSS {peak:.0f} MB)")  # fmt: skip
    for verb in VERBS:
        cmd = [*terrain, verb]
        cmd += [str(args.log), "-w", str(ws)] if verb == "ingest" else ["-w", str(ws)]
        wall, peak = timed([*cmd, "--overwrite"])
        print(f"  {verb:<9} {wall:7.1f} s  {duration_s / wall:7.1f}x  peak RSS {peak:6.0f} MB")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
