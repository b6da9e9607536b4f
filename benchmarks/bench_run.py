"""The whole pipeline on a log: end-to-end wall time, then each stage's time and peak memory.

1. ``terrain run LOG -w WS`` in a fresh workspace, timed end to end: the real-time factor
   (log duration / wall) is the issue's figure (target at least 20x on this machine).
2. Each stage again in a fresh process (``terrain <verb> -w WS --overwrite``), for its own
   wall time and peak RSS (``ru_maxrss`` of the child from ``wait4``).

3. With ``--rows-alone``: evaluate again with its rows trained one at a time
   (``ROW_WORKERS = 1``) into a copy of the workspace, timed, and its report compared with
   the run's, file for file (the two-cores report must be byte-identical).

Usage: python benchmarks/bench_run.py LOG.mcap [--keep DIR] [--workers N] [--no-stages]
[--rows-alone]
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
    ap.add_argument("--no-stages", action="store_true", help="only the end-to-end run")
    ap.add_argument("--rows-alone", action="store_true", help="evaluate one row at a time too")
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
    if args.rows_alone:
        rows_alone(ws, root / "ws-rows-alone", duration_s)
    for verb in () if args.no_stages else VERBS:
        cmd = [*terrain, verb]
        cmd += [str(args.log), "-w", str(ws)] if verb == "ingest" else ["-w", str(ws)]
        wall, peak = timed([*cmd, "--overwrite"])
        print(f"  {verb:<9} {wall:7.1f} s  {duration_s / wall:7.1f}x  peak RSS {peak:6.0f} MB")
    print(f"load average after: {os.getloadavg()}")


ROWS_ALONE = """
import sys
from pathlib import Path
from toolkit.config import load_config
from toolkit.stages import evaluate_rows
from toolkit.stages.evaluate import SPEC
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace
evaluate_rows.ROW_WORKERS = 1
ws = Workspace(Path(sys.argv[1]))
run_stage(SPEC, ws, load_config(ws.config_path), overwrite=True)
"""


def rows_alone(ws: Path, copy: Path, duration_s: float) -> None:
    """Evaluate again, one row at a time, in a copy of ``ws``; its report against the run's."""
    if copy.exists():
        shutil.rmtree(copy)
    shutil.copytree(ws, copy, symlinks=True)
    wall, peak = timed([sys.executable, "-c", ROWS_ALONE, str(copy)])
    both, alone = ws / "report", copy / "report"
    names = sorted(p.name for p in both.iterdir() if p.is_file())
    differ = [n for n in names if (both / n).read_bytes() != (alone / n).read_bytes()]
    print(f"  evaluate, one row at a time: {wall:.1f} s ({duration_s / wall:.1f}x), peak RSS "
          f"{peak:.0f} MB; report files differing from the run's: {differ or 'none'} "
          f"of {len(names)}")  # fmt: skip


if __name__ == "__main__":
    main()
