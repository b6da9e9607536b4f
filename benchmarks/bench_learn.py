"""Learn and evaluate on a workspace's tables: wall time and peak memory of each stage.

Runs ``terrain learn -w WS --overwrite`` and then ``terrain evaluate -w WS --overwrite``, each
in a fresh process, and prints each one's wall time, its own peak RSS (``ru_maxrss`` of the
child from ``wait4``: an upper bound, it may include the parent's pages at the fork), the
training set's size (events, positives, points kept, pairs) and the step timings the
manifest records. Make the workspace with ``bench_points.py --keep DIR`` (its ``DIR/ws``).

Usage: python benchmarks/bench_learn.py WS [--learn-only]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def run_stage(verb: str, ws: Path) -> tuple[float, float, str]:
    """Wall seconds, the child's own peak RSS (MB) and its stdout."""
    t0 = time.perf_counter()
    child = subprocess.Popen(
        [sys.executable, "-m", "toolkit", verb, "-w", str(ws), "--overwrite"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    out, err = child.stdout.read(), child.stderr.read()  # type: ignore[union-attr]
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{verb} failed: {err.strip()}")
    return wall, usage.ru_maxrss / 1024.0, out.strip()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--learn-only", action="store_true")
    args = ap.parse_args()
    ws = args.workspace
    print(f"load average before: {os.getloadavg()}")
    for verb in ("learn",) if args.learn_only else ("learn", "evaluate"):
        wall, peak_mb, out = run_stage(verb, ws)
        record = json.loads((ws / "manifest.json").read_text())["stages"][verb]
        print(
            f"{verb}: {wall:.1f} s wall, peak RSS <= {peak_mb:.0f} MB; rows {record['row_counts']}"
        )
        print(f"    timings {record['timings_s']}")
        print("    " + out.replace("\n", "\n    "))
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
