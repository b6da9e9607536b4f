"""The label rate of the simulated race over several seeds: issue 11's "must show" in numbers.

For each seed: simulates a ``race`` log (default 6 km), ingests, poses and labels it with the
label stage's filter, then labels it again with the filter's stop edge at 9, 10 and 11 Hz
(pass edge 5 Hz above, 40 taps), and counts what lies under each positive event (the truth
feature's kind, or background roughness). Prints one line per seed and a summary; writes
``seeds.json`` into ``--out``. Logs are kept in ``--out`` so a rerun skips the simulation.

Usage: python benchmarks/sim_seeds.py --out DIR [--seeds 601 602 603 604 605 606]
       [--distance-m 6000] [--no-lasers] [--jobs 2]

Each seed also prints its band-edge sensitivity (:func:`_edge_sensitivity`): how much one
event's reading changes from 9 to 11 Hz, and how steep the tail is at the threshold.

``--no-lasers`` simulates without laser scans (the drive and the IMU are the same, so are the
labels): several times faster, for tuning the vehicle.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import polars as pl

from toolkit.config import default_config
from toolkit.stages.ingest import ingest_log
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

STOP_EDGES_HZ = (9.0, 10.0, 11.0)


def label_rates(log: Path) -> dict[str, object]:
    """Events, rough share per stop edge and the positives' kinds for one log."""
    cfg = default_config()
    with tempfile.TemporaryDirectory(prefix="sim_seeds_") as tmp:
        ws = Workspace(Path(tmp) / "ws")
        log_id = ingest_log(log, ws, cfg).log_id
        run_stage(POSE, ws, cfg, log_id=log_id)
        by_edge: dict[str, float] = {}
        kinds_by_edge: dict[str, dict[str, int]] = {}
        ruggedness_by_edge: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for stop in STOP_EDGES_HZ:
            label = dataclasses.replace(cfg.label, fir_stop_hz=stop, fir_pass_hz=stop + 5.0)
            r = run_stage(
                LABEL, ws, dataclasses.replace(cfg, label=label), log_id=log_id, overwrite=True
            )
            by_edge[f"{stop:g}"] = round(100.0 * r.rough / max(r.events, 1), 4)
            edge_events = read_table(ws.log_dir(log_id) / "events.parquet", "events")
            # By event id: the same events at every edge (the edge changes the filter, not
            # which events exist), checked in _edge_sensitivity.
            order = np.argsort(edge_events.column("event_id").to_numpy(), kind="stable")
            ruggedness_by_edge[stop] = (
                edge_events.column("event_id").to_numpy()[order],
                edge_events.column("ruggedness").to_numpy()[order],
            )
            kinds_by_edge[f"{stop:g}"] = dict(
                Counter(
                    str(row.get("truth_feature_kind") or "background")
                    for row in edge_events.filter(edge_events.column("rough")).to_pylist()
                )
            )
        edge_sensitivity = _edge_sensitivity(
            ruggedness_by_edge, cfg.label.rough_threshold_g_per_mph
        )
        result = run_stage(LABEL, ws, cfg, log_id=log_id, overwrite=True)
        events = read_table(ws.log_dir(log_id) / "events.parquet", "events")
        rough = events.filter(events.column("rough")).to_pylist()
        kinds = Counter(str(row.get("truth_feature_kind") or "background") for row in rough)
        # How far each kind is from the threshold: ruggedness quantiles per truth kind.
        frame = pl.from_arrow(events).with_columns(
            pl.col("truth_feature_kind").fill_null("background").alias("kind")
        )
        spread = (
            frame.group_by("kind")
            .agg(
                pl.len().alias("n"),
                pl.col("ruggedness").quantile(0.5).alias("p50"),
                pl.col("ruggedness").quantile(0.9).alias("p90"),
                pl.col("ruggedness").max().alias("max"),
            )
            .sort("kind")
        )
    return {
        "events": result.events,
        "rough": result.rough,
        "rough_percent": round(100.0 * result.rough_rate, 4),
        "rough_percent_by_stop_edge_hz": by_edge,
        "positives_by_kind_by_stop_edge_hz": kinds_by_edge,
        "positives_by_kind": dict(kinds),
        "edge_sensitivity": edge_sensitivity,
        "ruggedness_by_kind": {
            r["kind"]: [r["n"], round(r["p50"], 4), round(r["p90"], 4), round(r["max"], 4)]
            for r in spread.to_dicts()
        },
    }


def _edge_sensitivity(
    ruggedness_by_edge: dict[float, tuple[np.ndarray, np.ndarray]], threshold: float
) -> dict[str, float]:
    """Why the rate moves with the band edge, in two numbers and their product.

    ``ruggedness_by_edge``: per stop edge, the event ids (E,) and their ruggedness (E,),
    sorted by id.

    ``gain_9_over_11``: the median over events near or above the threshold (ruggedness at
    10 Hz at least half of it) of ruggedness with the 9 Hz edge over that with the 11 Hz one:
    how much one event's shock reading changes with the edge. ``tail_exponent``: the local
    slope ``k = -d log(rate) / d log(threshold)`` of the 10 Hz ruggedness's upper tail,
    from the rates at threshold / 1.2 and threshold x 1.2: how much the rate changes for a
    given change of every reading. If every event's reading scaled alike, the rate would
    move by ``gain ** k`` from 9 to 11 Hz (``expected_ratio``).
    """
    ids = [ruggedness_by_edge[e][0] for e in STOP_EDGES_HZ]
    if not all(np.array_equal(ids[0], other) for other in ids[1:]):
        raise SystemExit("sim_seeds: the stop edges labelled different events")
    r9, r10, r11 = (ruggedness_by_edge[e][1] for e in STOP_EDGES_HZ)
    near = np.isfinite(r9) & np.isfinite(r10) & np.isfinite(r11) & (r10 >= threshold / 2)
    near &= r11 > 0
    gain = float(np.median(r9[near] / r11[near])) if near.any() else float("nan")
    lo = float(np.mean(r10 >= threshold / 1.2))
    hi = float(np.mean(r10 >= threshold * 1.2))
    k = float(np.log(lo / hi) / np.log(1.2**2)) if lo > 0 and hi > 0 else float("nan")
    return {
        "gain_9_over_11": round(gain, 3),
        "tail_exponent": round(k, 2),
        "expected_ratio": round(gain**k, 2),
    }


def one_seed(job: tuple[int, Path, float, bool]) -> dict[str, object]:
    """Simulates (unless the log exists) and labels one seed."""
    seed, out, distance_m, no_lasers = job
    log = out / f"race_{seed}_{distance_m:g}m{'_nolasers' if no_lasers else ''}.mcap"
    sim_s = None
    if not log.exists():
        t = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "toolkit", "sim", str(log), "--profile", "race",
             "--distance-m", str(distance_m), "--seed", str(seed),
             *(["--no-lasers"] if no_lasers else [])],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        sim_s = round(time.perf_counter() - t, 1)
    row = label_rates(log)
    row["sim_seconds"] = sim_s
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[601, 602, 603, 604, 605, 606])
    ap.add_argument("--distance-m", type=float, default=6000.0)
    ap.add_argument("--no-lasers", action="store_true")
    ap.add_argument("--jobs", type=int, default=1, help="seeds run in parallel")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"load average {os.getloadavg()}")
    results: dict[str, object] = {}
    jobs = [(seed, args.out, args.distance_m, args.no_lasers) for seed in args.seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for seed, row in zip(args.seeds, pool.map(one_seed, jobs), strict=True):
            results[str(seed)] = row
            edges = row["rough_percent_by_stop_edge_hz"]
            print(
                f"seed {seed}: {row['events']} events, rough {row['rough_percent']} % "
                f"(stop edge 9/10/11 Hz: {edges}), positives {row['positives_by_kind']}, "
                f"sim {row['sim_seconds']} s",
                flush=True,
            )
            print(f"  ruggedness [n, p50, p90, max] by kind: {row['ruggedness_by_kind']}")
            print(f"  band-edge sensitivity: {row['edge_sensitivity']}")
            print(
                f"  positives by kind at stop edge 9/10/11 Hz: {row['positives_by_kind_by_stop_edge_hz']}"
            )
    pooled = pooled_ratio_noise(results)
    print(f"pooled over the seeds: {pooled}")
    results["pooled"] = pooled
    (args.out / "seeds.json").write_text(json.dumps(results, indent=2) + "\n")


def pooled_ratio_noise(
    results: dict[str, object], draws: int = 200_000, seed: int = 0
) -> dict[str, object]:
    """The 9 Hz / 11 Hz ratio pooled over all seeds, and what counting noise alone does to
    it on one seed.

    The pooled rates at 9 and 11 Hz estimate the model's expected ratio with the seeds'
    counts summed. For one seed of the mean event count, the positives at 11 Hz are drawn
    Poisson with the pooled 11 Hz rate, and those 9 Hz adds Poisson with the difference (the
    11 Hz positives are, near enough, among the 9 Hz ones): ``p_seed_below_3`` is how often
    such a seed shows a ratio below 3 (and has an 11 Hz positive at all), ``p_six_of_six``
    that to the sixth, the chance the issue's six seeds all pass if the expected ratio is
    the pooled one.
    """
    rows = [r for r in results.values() if isinstance(r, dict) and "events" in r]
    events = np.array([r["events"] for r in rows], dtype=np.float64)
    by_edge = {
        e: np.array([r["rough_percent_by_stop_edge_hz"][e] for r in rows]) / 100.0
        for e in ("9", "10", "11")
    }
    rate = {e: float((v * events).sum() / events.sum()) for e, v in by_edge.items()}
    lam11 = rate["11"] * float(events.mean())
    lam_extra = max(rate["9"] - rate["11"], 0.0) * float(events.mean())
    rng = np.random.default_rng(seed)
    n11 = rng.poisson(lam11, draws)
    n9 = n11 + rng.poisson(lam_extra, draws)
    below = float(np.mean((n11 > 0) & (n9 < 3 * n11)))
    return {
        "rough_percent_9_10_11": [round(100 * rate[e], 3) for e in ("9", "10", "11")],
        "ratio_9_over_11": round(rate["9"] / rate["11"], 2) if rate["11"] > 0 else float("nan"),
        "p_seed_below_3": round(below, 3),
        "p_six_of_six": round(below**6, 3),
    }


if __name__ == "__main__":
    main()
