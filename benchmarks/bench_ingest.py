"""Benchmark: ingesting race logs, against the naive loop and the bare pass (issue 3).

For each log, three ways of processing it, each in a fresh process (so peak RSS is its own):

* ``toolkit``: ``toolkit.stages.ingest.ingest_log`` into a fresh workspace;
* ``naive``: what a user would write: mcap's reader with mcap-ros2-support's decoder, Python
  lists of values per table, then ``pyarrow`` tables written to zstd Parquet;
* ``bare``: a pass over the file with mcap's reader that decodes nothing (the floor).

Usage::

    python benchmarks/bench_ingest.py LOG.mcap [LOG.mcap ...]
    python benchmarks/bench_ingest.py --make 10 60     # simulate race logs of 10 and 60 min first

Targets: toolkit at least 6x the naive loop, at most 2x the bare pass, and the same peak RSS
(within 20 %) for the 10- and 60-minute logs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

TOOLKIT = r"""
import json, resource, sys, time, tempfile
from pathlib import Path
from toolkit.config import default_config
from toolkit.stages.ingest import ingest_log
from toolkit.workspace import Workspace
log = Path(sys.argv[1])
with tempfile.TemporaryDirectory() as tmp:
    ws = Workspace(Path(tmp) / "ws")
    ws.create()
    t0 = time.perf_counter()
    result = ingest_log(log, ws, default_config(), overwrite=True)
    wall = time.perf_counter() - t0
rss = [int(l.split()[1]) / 1024 for l in open("/proc/self/status") if l.startswith("VmHWM")][0]
print(json.dumps({"wall_s": wall, "rss_mb": rss}))
"""

NAIVE = r"""
import json, resource, sys, time, tempfile
from pathlib import Path
import pyarrow as pa, pyarrow.parquet as pq
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
log = Path(sys.argv[1])
t0 = time.perf_counter()
imu, gps, heading, wheels, laser, truth = [], [], [], [], [], []
stamp = lambda m: m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
with open(log, "rb") as f:
    for _, channel, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
        topic = channel.topic
        if topic == "/imu/data":
            a, g = m.linear_acceleration, m.angular_velocity
            imu.append((stamp(m), a.x, a.y, a.z, g.x, g.y, g.z))
        elif topic == "/gps/fix":
            c = m.position_covariance
            gps.append((stamp(m), m.latitude, m.longitude, m.altitude, m.status.status, c[0], c[4], c[8]))
        elif topic == "/gps/heading":
            heading.append((stamp(m), m.yaw, m.yaw_std))
        elif topic == "/vehicle/wheel_speeds":
            wheels.append((stamp(m), m.front_left, m.front_right, m.rear_left, m.rear_right))
        elif topic.startswith("/laser/"):
            laser.append((stamp(m), topic, m.angle_min, m.angle_increment, m.time_increment, list(m.ranges)))
        elif topic == "/truth/odom":
            p, q = m.pose.pose.position, m.pose.pose.orientation
            truth.append((stamp(m), p.x, p.y, p.z, q.x, q.y, q.z, q.w))
with tempfile.TemporaryDirectory() as tmp:
    def write(name, rows, cols):
        table = pa.table({c: [r[i] for r in rows] for i, c in enumerate(cols)})
        pq.write_table(table, Path(tmp) / f"{name}.parquet", compression="zstd")
    write("imu", imu, ["t_ns", "ax", "ay", "az", "gx", "gy", "gz"])
    write("gps", gps, ["t_ns", "lat", "lon", "alt", "status", "cxx", "cyy", "czz"])
    write("heading", heading, ["t_ns", "yaw", "yaw_std"])
    write("wheels", wheels, ["t_ns", "fl", "fr", "rl", "rr"])
    write("laser", laser, ["t_ns", "laser", "angle_min", "angle_increment", "time_increment", "ranges"])
    write("truth", truth, ["t_ns", "x", "y", "z", "qx", "qy", "qz", "qw"])
wall = time.perf_counter() - t0
rss = [int(l.split()[1]) / 1024 for l in open("/proc/self/status") if l.startswith("VmHWM")][0]
print(json.dumps({"wall_s": wall, "rss_mb": rss}))
"""

BARE = r"""
import json, resource, sys, time
from mcap.reader import make_reader
t0 = time.perf_counter()
n = 0
with open(sys.argv[1], "rb") as f:
    for _ in make_reader(f).iter_messages():
        n += 1
wall = time.perf_counter() - t0
rss = [int(l.split()[1]) / 1024 for l in open("/proc/self/status") if l.startswith("VmHWM")][0]
print(json.dumps({"wall_s": wall, "rss_mb": rss, "messages": n}))
"""


def _run(code: str, log: Path) -> dict[str, float]:
    proc = subprocess.run(
        [sys.executable, "-c", code, str(log)], check=True, capture_output=True, text=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def _shape(log: Path) -> tuple[int, int, float]:
    """Messages, laser ranges and duration (s) of a log, from its summary."""
    from toolkit.mcapio.info import scan_log

    info = scan_log(log)
    d = info.to_dict()
    messages = int(d["message_count"])
    scans = sum(t["message_count"] for t in d["topics"] if t["topic"].startswith("/laser/"))
    return messages, scans * 181, float(d["duration_s"])


def _make(minutes: float, out_dir: Path) -> Path:
    from toolkit.sim.simulate import simulate

    # The race profile averages about 9 m/s: distance for the wanted duration, with margin.
    path = out_dir / f"race_{minutes:g}min.mcap"
    if not path.exists():
        simulate(path, profile="race", distance_m=minutes * 60 * 9.2, seed=1)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument(
        "--make", nargs="*", type=float, default=[], help="minutes of race log to simulate"
    )
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "terrain-bench")
    ap.add_argument("--skip-naive", action="store_true")
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    logs = list(args.logs) + [_make(m, args.dir) for m in args.make]
    for log in logs:
        messages, ranges, duration = _shape(log)
        size_mb = log.stat().st_size / 1e6
        print(
            f"{log.name}: {duration:.0f} s, {size_mb:.1f} MB, {messages} messages, {ranges} laser ranges"
        )
        results = {"bare": _run(BARE, log), "toolkit": _run(TOOLKIT, log)}
        if not args.skip_naive:
            results["naive"] = _run(NAIVE, log)
        for name, r in results.items():
            w = r["wall_s"]
            print(
                f"  {name:8s} {w:7.2f} s  {messages / w:10.0f} msg/s  {ranges / w / 1e6:7.2f} M ranges/s  "
                f"{size_mb / w:7.1f} MB/s  peak RSS {r['rss_mb']:.0f} MB"
            )
        t = results["toolkit"]["wall_s"]
        line = f"  toolkit vs bare: {t / results['bare']['wall_s']:.2f}x the time"
        if "naive" in results:
            line += f"; naive vs toolkit: {results['naive']['wall_s'] / t:.1f}x faster"
        print(line)


if __name__ == "__main__":
    main()
