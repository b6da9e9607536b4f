"""Benchmark: a 100 km simulated drive on the curved Earth (issue "Truth far from home",
point 1).

Simulates a race ``--km`` long on the simulator's curved Earth (its map frame: gravity along
the local vertical everywhere, GPS and heading through the same map), with the lasers
scanning only over two windows of ``--window-km``: one from ``--settle-km`` (after the
filter's first minutes, whose convergence would flatter the end) and the drive's last (the
points are judged there; casting the rays of the 90 km between would be most of an hour).
Ingests, poses and projects it with the default configuration, then compares the windows:

- the attitude error against the truth (``pose.parquet`` against ``truth_pose.parquet``, one
  frame): RMS and p95 of roll and pitch, RMS of yaw, degrees;
- the points' height error against the true terrain under them
  (:class:`toolkit.analysis.truth_terrain.TrueGround`): median and p90 of ``|error|``, and
  the same for the returns at 20-30 m range, where a tilted frame would show most; split
  into the pose's part and the sensors' part;
- where the window lies: its distance from the world origin, km;
- the pose's height error over the drive's first and last ``--stretch-km``.

Target: every error at the end no worse than 1.1 times the start's. Usage::

    python benchmarks/long_drive.py [--km 100] [--window-km 3] [--settle-km 1] [--seed 7]
                                    [--stretch-km 10] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.analysis.truth_terrain import true_ground, where_beams_hit
from toolkit.config import default_config
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.project import SPEC as PROJECT
from toolkit.stages.runner import run_stage
from toolkit.tableio import iter_table_batches, read_table
from toolkit.workspace import Workspace

#: Rows of points.parquet read at a time.
BATCH_ROWS = 1_048_576
#: Metres of route the simulator does not drive (the warm-up and the look-ahead at its end).
ROUTE_MARGIN_M = 200.0


def _angles(path: Path, table: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (n,) ns, positions (n, 3) m and unwrapped roll, pitch, yaw (n, 3) rad."""
    t = read_table(path, table, columns=("t_ns", "x", "y", "z", "roll", "pitch", "yaw"))
    c = {k: t.column(k).to_numpy() for k in t.column_names}
    rpy = np.unwrap(np.stack([c["roll"], c["pitch"], c["yaw"]], axis=1), axis=0)
    return c["t_ns"].astype(np.int64), np.c_[c["x"], c["y"], c["z"]], rpy


def attitude_errors(log_dir: Path, t_from_ns: int, t_to_ns: int) -> dict[str, float]:
    """Roll, pitch and yaw error against the truth over ``[t_from_ns, t_to_ns]``, degrees."""
    t, _, rpy = _angles(log_dir / "pose.parquet", "pose")
    tt, _, rpy_true = _angles(log_dir / "truth_pose.parquet", "truth_pose")
    keep = (t >= max(t_from_ns, tt[0])) & (t <= min(t_to_ns, tt[-1]))
    true_at = np.stack([np.interp(t[keep], tt, rpy_true[:, k]) for k in range(3)], axis=1)
    err = np.degrees((rpy[keep] - true_at + np.pi) % (2 * np.pi) - np.pi)
    out: dict[str, float] = {"pose_rows": int(keep.sum())}
    for k, name in enumerate(("roll", "pitch", "yaw")):
        out[f"{name}_rms_deg"] = float(np.sqrt(np.mean(err[:, k] ** 2)))
    for k, name in enumerate(("roll", "pitch")):
        out[f"{name}_p95_deg"] = float(np.percentile(np.abs(err[:, k]), 95))
    return out


def height_errors(log_dir: Path, t_from_ns: int, t_to_ns: int) -> dict[str, float]:
    """The points' height error against the true terrain over ``[t_from_ns, t_to_ns]``, m,
    and its two parts: the pose's (each point's height placed with the estimated pose minus
    placed with the true one, :func:`~toolkit.analysis.truth_terrain.where_beams_hit`) and
    the sensors' (the true-pose point against the terrain: range noise, mount flex, the
    terrain's own texture), so that a change between the windows is put where it is."""
    ground = true_ground(log_dir)
    if ground is None:
        raise SystemExit(f"{log_dir}: not a simulated log")
    total, pose_part, sensor_part, ranges = [], [], [], []
    for batch in iter_table_batches(
        log_dir / "points.parquet",
        "points",
        columns=("t_ns", "range", "x", "y", "z"),
        batch_rows=BATCH_ROWS,
    ):
        t = batch.column("t_ns").to_numpy()
        keep = (t >= t_from_ns) & (t <= t_to_ns)
        if not keep.any():
            continue
        xyz = np.stack([batch.column(c).to_numpy()[keep] for c in "xyz"], axis=1)
        true_xyz = where_beams_hit(log_dir, xyz, t[keep])
        total.append(ground(xyz))
        pose_part.append(xyz[:, 2] - true_xyz[:, 2])
        sensor_part.append(ground(true_xyz))
        ranges.append(batch.column("range").to_numpy()[keep])
    r = np.concatenate(ranges)
    out: dict[str, float] = {}
    for name, parts in (("", total), ("pose_", pose_part), ("sensor_", sensor_part)):
        e = np.concatenate(parts)
        ok = np.isfinite(e)
        far = ok & (r >= 20.0) & (r < 30.0)
        out |= {
            f"{name}points": int(ok.sum()),
            f"{name}median_abs_m": float(np.median(np.abs(e[ok]))),
            f"{name}p90_abs_m": float(np.percentile(np.abs(e[ok]), 90)),
            f"{name}mean_m": float(np.mean(e[ok])),
            f"{name}median_abs_20_30m_m": float(np.median(np.abs(e[far]))),
            f"{name}p90_abs_20_30m_m": float(np.percentile(np.abs(e[far]), 90)),
        }
    return out


def pose_height_by_stretch(log_dir: Path, stretch_km: float) -> dict[str, float]:
    """The pose's height error against the truth (m) over the drive's first and last
    ``stretch_km``: RMS and median of ``|error|``, and how far from the origin each lies.
    The height comes from the GPS alone (nothing else measures it), whose simulated
    receiver drifts (a Gauss-Markov process, 0.15 m, 120 s): stretches of many time
    constants average that out, where a few minutes' window draws one value of it."""
    t, xyz, _ = _angles(log_dir / "pose.parquet", "pose")
    tt, true_xyz, _ = _angles(log_dir / "truth_pose.parquet", "truth_pose")
    dz = xyz[:, 2] - np.interp(t, tt, true_xyz[:, 2])
    driven_km = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xyz[:, :2], axis=0).T))] / 1e3
    out: dict[str, float] = {}
    for name, keep in (
        ("first", driven_km <= stretch_km),
        ("last", driven_km >= driven_km[-1] - stretch_km),
    ):
        out[f"{name}_rms_m"] = float(np.sqrt(np.mean(dz[keep] ** 2)))
        out[f"{name}_median_abs_m"] = float(np.median(np.abs(dz[keep])))
        out[f"{name}_from_origin_km"] = float(np.hypot(*xyz[keep, :2].T).mean() / 1e3)
    out["last_over_first_rms"] = out["last_rms_m"] / out["first_rms_m"]
    return out


def windows(log_dir: Path) -> list[tuple[int, int]]:
    """The two stretches the lasers scanned: (first, last) point time of each, ns."""
    times = np.concatenate(
        [
            b.column("t_ns").to_numpy()
            for b in iter_table_batches(
                log_dir / "points.parquet", "points", columns=("t_ns",), batch_rows=BATCH_ROWS
            )
        ]
    )
    times.sort()
    gap = int(np.argmax(np.diff(times)))  # the unscanned 90 km between the windows
    return [(int(times[0]), int(times[gap])), (int(times[gap + 1]), int(times[-1]))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--km", type=float, default=100.0)
    parser.add_argument("--window-km", type=float, default=3.0)
    parser.add_argument(
        "--stretch-km", type=float, default=10.0, help="the pose's height over this much"
    )
    parser.add_argument("--settle-km", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--keep", type=Path, help="keep the log and workspace here (and reuse them if there)"
    )
    args = parser.parse_args()
    # Imported here: the simulator is the benchmark's input, not part of what it measures.
    from toolkit.sim.simulate import simulate

    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        window_m = args.window_km * 1e3
        last_from_m = args.km * 1e3 - ROUTE_MARGIN_M - window_m
        report: dict[str, Any] = {"seed": args.seed}
        clock = time.perf_counter()
        if not (root / "long.mcap").is_file():
            sim = simulate(
                root / "long.mcap",
                profile="race",
                distance_m=args.km * 1e3,
                seed=args.seed,
                laser_spans_m=(
                    (args.settle_km * 1e3, args.settle_km * 1e3 + window_m),
                    (last_from_m, float("inf")),
                ),
                show_progress=True,
            )
            report["sim_wall_s"] = round(time.perf_counter() - clock, 1)
            report["log_s"] = round(sim.duration_s, 1)
        clock = time.perf_counter()
        ws = Workspace(root / "ws")
        # Up to date when kept from an earlier run: each stage then does nothing.
        log_id = ingest_log(root / "long.mcap", ws, default_config()).log_id
        run_stage(POSE, ws, default_config(), log_id=log_id)
        run_stage(PROJECT, ws, default_config(), log_id=log_id)
        report["stages_wall_s"] = round(time.perf_counter() - clock, 1)
        log_dir = ws.log_dir(log_id)
        t, xyz, _ = _angles(log_dir / "pose.parquet", "pose")
        report["driven_km"] = round(float(np.hypot(*np.diff(xyz[:, :2], axis=0).T).sum()) / 1e3, 2)
        for name, (lo, hi) in zip(("start", "end"), windows(log_dir), strict=True):
            inside = (t >= lo) & (t <= hi)
            report[name] = {
                "from_origin_km": round(float(np.hypot(*xyz[inside, :2].T).mean()) / 1e3, 2),
                "seconds": round((hi - lo) * 1e-9, 1),
                **attitude_errors(log_dir, lo, hi),
                **height_errors(log_dir, lo, hi),
            }
        ratios = {
            k: report["end"][k] / report["start"][k]
            for k in report["start"]
            if k.endswith(("_deg", "abs_m", "abs_20_30m_m"))
        }
        report["pose_height"] = pose_height_by_stretch(log_dir, args.stretch_km)
        report["end_over_start"] = {k: round(v, 3) for k, v in ratios.items()}
        report["target_met"] = all(v <= 1.1 for v in ratios.values())
        print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
