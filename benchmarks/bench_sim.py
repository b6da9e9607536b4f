"""Benchmark: ``terrain sim --profile race`` for a log of about ten simulated minutes.

Runs the simulator in a fresh process per configuration (so peak RSS is its own), and prints
simulated seconds, wall seconds, the real-time factor and peak RSS. Usage::

    python benchmarks/bench_sim.py [--distance-m 5400] [--workers 0 1] [--seed 1]

The target (issue 2) is at least 10x faster than real time on the project machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from pathlib import Path
from toolkit.sim.simulate import simulate
out, distance, seed, workers = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
t0 = time.perf_counter()
r = simulate(Path(out), profile="race", distance_m=distance, seed=seed, workers=workers)
wall = time.perf_counter() - t0
print(json.dumps({"sim_s": r.duration_s, "wall_s": wall, "distance_m": r.distance_m,
                  "messages": sum(r.message_counts.values()), "bytes": Path(out).stat().st_size,
                  "rss_mb": [int(l.split()[1]) / 1024 for l in open("/proc/self/status") if l.startswith("VmHWM")][0]}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--distance-m", type=float, default=5400.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for workers in args.workers:
            out = Path(tmp) / f"race_w{workers}.mcap"
            t0 = time.perf_counter()
            proc = subprocess.run(
                [
                    sys.executable,
                    "-c",
                    CHILD,
                    str(out),
                    str(args.distance_m),
                    str(args.seed),
                    str(workers),
                ],
                check=True,
                capture_output=True,
                text=True,
            )
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
            print(
                f"workers={workers}: {r['sim_s']:.1f} s simulated ({r['distance_m']:.0f} m, "
                f"{r['messages']} messages, {r['bytes'] / 1e6:.1f} MB) in {r['wall_s']:.1f} s "
                f"wall -> {r['sim_s'] / r['wall_s']:.1f}x real time; peak RSS {r['rss_mb']:.0f} MB "
                f"(largest child so far {children:.0f} MB); process total "
                f"{time.perf_counter() - t0:.1f} s"
            )


if __name__ == "__main__":
    main()
