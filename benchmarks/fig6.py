"""Fig. 6 on enough data to tell: pooled unseen race logs, every method's ROC with intervals.

Simulates (or reuses) one ``race`` log per seed (20 miles each by default), runs ``terrain
run`` on all of them in one workspace with ``[tables] split_scope = "per_log"`` (the first
half of each log trains, the second tests, as the paper's miles 60-70 and 70-80), then reads
``report/scores.parquet`` and writes, per method, on the pooled test events:

- the ROC (``fig6.png``, drawn as scikit-learn draws it: ties as one diagonal step);
- the AUC with a 95 % stratified-bootstrap interval (rough and smooth events resampled
  apart, so every resample holds as many of each as the test split);
- TPR at FPR 5, 10 and 20 % (the ROC's interpolated value at that FPR);
- the share of events scored exactly 0 (eq. 3's W >= 0 ties) and unscored (NaN);
- the paired AUC difference to the race test on the closest laser, with its interval
  (the same resamples for both methods, so the shared noise of the test events cancels);
- per seed, the AUC of each method (its own test half), to show the spread.

The workspace's configuration is the toolkit's default with ``split_scope = "per_log"``;
``--set SECTION.KEY=VALUE`` overrides a key (a TOML value) to measure a variant.

``--lidar`` runs the same on the simulator's spinning 3-D lidar instead of its five lasers
(``terrain sim --lidar --no-lasers``; logs ``race-SEED-lidar.mcap``) with
``pipelines/lidar.toml``'s keys over the default; the race test's "closest laser" is then the
lidar's ring nearest the vehicle. ``--jobs N`` simulates N logs at once (one core each).

Usage: python benchmarks/fig6.py --keep DIR [--seeds 901 902 903 904] [--distance-m 32187]
       [--resamples 1000] [--set learn.accept='"objective"'] [--from STAGE] [--lidar]
       [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from sklearn.metrics import roc_auc_score, roc_curve

from toolkit.analysis.method_registry import METHOD_KEYS, RACE_TEST

REPO = Path(__file__).resolve().parent.parent
#: Every method of the report, in its order (``scores.parquet`` names each one's column).
METHODS = METHOD_KEYS
REFERENCE = RACE_TEST
FPRS = (0.05, 0.10, 0.20)
#: ``pipelines/lidar.toml``'s keys, as overrides of the default (``--lidar``).
LIDAR_OVERRIDES = (
    "topics.lasers=[]",
    'topics.lidars=["/ouster/points"]',
    'lidar.time="ouster"',
    'project.keep="near_path"',
    'evaluate.baseline_closest_laser=""',
)


def workspace_config(overrides: list[str]) -> str:
    """The default configuration's text with per-log splits and ``overrides`` applied."""
    text = (REPO / "toolkit" / "default_config.toml").read_text()
    overrides = ['tables.split_scope="per_log"', *overrides]
    for item in overrides:
        dotted, value = item.split("=", 1)
        section, key = dotted.split(".", 1)
        block = re.search(rf"^\[{re.escape(section)}\]$.*?(?=^\[|\Z)", text, re.M | re.S)
        if block is None:
            raise SystemExit(f"no section [{section}] in the default configuration")
        body, n = re.subn(
            rf"^{re.escape(key)}\s*=.*$", f"{key} = {value}", block.group(0), count=1, flags=re.M
        )
        if n == 0:
            raise SystemExit(f"no key {key} in [{section}]")
        text = text[: block.start()] + body + text[block.end() :]
    return text


def simulate(logs: Path, seeds: list[int], distance_m: float, lidar: bool, jobs: int) -> list[Path]:
    """One race log per seed in ``logs`` (kept when already there), ``jobs`` at a time."""
    outs = [logs / (f"race-{s}-lidar.mcap" if lidar else f"race-{s}.mcap") for s in seeds]
    todo = [(s, o) for s, o in zip(seeds, outs, strict=True) if not o.exists()]
    running: list[tuple[int, float, subprocess.Popen[bytes]]] = []
    while todo or running:
        while todo and len(running) < jobs:
            seed, out = todo.pop(0)
            cmd = [sys.executable, "-m", "toolkit", "sim", str(out), "--profile", "race",
                   "--distance-m", str(distance_m), "--seed", str(seed)]  # fmt: skip
            if lidar:
                cmd += ["--lidar", "--no-lasers"]
            if jobs > 1:
                cmd += ["--workers", "0"]
            running.append((seed, time.perf_counter(), subprocess.Popen(cmd)))
        seed, t0, proc = running.pop(0)
        if proc.wait() != 0:
            raise SystemExit(f"simulating seed {seed} failed")
        print(f"simulated seed {seed} in {time.perf_counter() - t0:.0f} s", flush=True)
    return outs


def lowest_for_nan(v: np.ndarray) -> np.ndarray:
    """``v`` with its unscored (non-finite) events ranked below every scored one, by a finite
    value (scikit-learn refuses infinities)."""
    finite = np.isfinite(v)
    floor = float(v[finite].min()) - 1.0 if finite.any() else 0.0
    return np.where(finite, v, floor)


def tpr_at(fpr: np.ndarray, tpr: np.ndarray, at: float) -> float:
    """The ROC polyline's TPR at FPR ``at`` (linear between its points: ties are diagonal)."""
    return float(np.interp(at, fpr, tpr))


def stratified_indices(
    rng: np.random.Generator, rough: np.ndarray, resamples: int
) -> list[np.ndarray]:
    pos, neg = np.flatnonzero(rough), np.flatnonzero(~rough)
    return [
        np.concatenate([rng.choice(pos, pos.size), rng.choice(neg, neg.size)])
        for _ in range(resamples)
    ]


def summarise(scores: dict[str, np.ndarray], rough: np.ndarray, resamples: int) -> dict:
    """Per method: AUC, its interval, TPR at FPRS, zero and unscored shares, and the paired
    difference to :data:`REFERENCE`. An unscored event (NaN) ranks lowest."""
    rng = np.random.default_rng(0)
    draws = stratified_indices(rng, rough, resamples)
    ranked = {n: lowest_for_nan(v) for n, v in scores.items()}
    boot = {n: np.array([roc_auc_score(rough[i], v[i]) for i in draws]) for n, v in ranked.items()}
    out: dict[str, dict] = {}
    for name, v in ranked.items():
        fpr, tpr, _ = roc_curve(rough, v, drop_intermediate=False)
        finite = np.isfinite(scores[name])
        entry = {
            "auc": float(roc_auc_score(rough, v)),
            "auc_ci95": [float(np.quantile(boot[name], q)) for q in (0.025, 0.975)],
            "tpr_at_fpr": {f"{a:.2f}": tpr_at(fpr, tpr, a) for a in FPRS},
            "zero_share": float(np.mean(scores[name][finite] == 0.0)) if finite.any() else None,
            "unscored_share": float(np.mean(~finite)),
        }
        if REFERENCE in boot and name != REFERENCE:
            d = boot[name] - boot[REFERENCE]
            entry["auc_minus_closest_laser"] = entry["auc"] - float(
                roc_auc_score(rough, ranked[REFERENCE])
            )
            entry["auc_minus_closest_laser_ci95"] = [
                float(np.quantile(d, q)) for q in (0.025, 0.975)
            ]
            entry["share_of_resamples_above"] = float(np.mean(d > 0))
        out[name] = entry
    return out


def draw(scores: dict[str, np.ndarray], rough: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 5))
    for name, v in scores.items():
        fpr, tpr, _ = roc_curve(rough, lowest_for_nan(v), drop_intermediate=False)
        ax.plot(fpr, tpr, label=name, lw=2 if name in ("self_supervised", REFERENCE) else 1)
    ax.plot([0, 1], [0, 1], color="0.7", lw=0.5)
    ax.set_xlabel("false-positive rate")
    ax.set_ylabel("true-positive rate")
    ax.set_title("Fig. 6 analogue, pooled test halves")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--keep", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[901, 902, 903, 904])
    ap.add_argument("--distance-m", type=float, default=32187.0)  # 20 miles
    ap.add_argument("--resamples", type=int, default=1000)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--workspace", default="ws", help="the workspace's folder name under DIR")
    ap.add_argument("--from", dest="from_stage", default=None)
    ap.add_argument("--lidar", action="store_true", help="the simulator's 3-D lidar alone")
    ap.add_argument("--jobs", type=int, default=1, help="logs simulated at once")
    args = ap.parse_args()
    root = args.keep
    (root / "logs").mkdir(parents=True, exist_ok=True)
    logs = simulate(root / "logs", args.seeds, args.distance_m, args.lidar, args.jobs)
    ws = root / args.workspace
    cfg = root / f"{args.workspace}.toml"
    overrides = [*(LIDAR_OVERRIDES if args.lidar else ()), *args.overrides]
    cfg.write_text(workspace_config(overrides))
    print(f"load average before: {os.getloadavg()}", flush=True)
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "toolkit", "run", *map(str, logs), "-w", str(ws), "-c", str(cfg)]
    if args.from_stage:
        cmd += ["--from", args.from_stage, "--overwrite"]
    subprocess.run(cmd, check=True)
    print(f"run: {time.perf_counter() - t0:.0f} s; load average {os.getloadavg()}", flush=True)

    table = pq.read_table(ws / "report" / "scores.parquet")
    test = np.asarray(table.column("split").to_pylist()) == "test"
    rough = np.asarray(table.column("rough").to_pylist(), bool)
    log_ids = np.asarray(table.column("log_id").to_pylist(), dtype=object)
    scores = {
        "self_supervised" if m == "self_supervised" else m: np.asarray(
            table.column("r_combined" if m == "self_supervised" else m).to_pylist(), float
        )
        for m in METHODS
        if (m == "self_supervised" or m in table.column_names)
        and table.column("r_combined" if m == "self_supervised" else m).null_count < table.num_rows
    }
    test_scores = {n: v[test] for n, v in scores.items()}
    pooled = summarise(test_scores, rough[test], args.resamples)
    per_seed = {}
    for log_id in sorted(set(log_ids.tolist())):
        mine = test & (log_ids == log_id)
        per_seed[log_id] = {
            "test_events": int(mine.sum()),
            "test_rough": int(rough[mine].sum()),
            "train_rough": int((rough & ~test & (log_ids == log_id)).sum()),
            "rough_rate": float(rough[log_ids == log_id].mean()),
            "auc": {
                n: float(roc_auc_score(rough[mine], lowest_for_nan(v[mine])))
                for n, v in scores.items()
            }
            if 0 < rough[mine].sum() < mine.sum()
            else None,
        }
    summary = json.loads((ws / "report" / "summary.json").read_text())
    result = {
        "seeds": args.seeds,
        "distance_m": args.distance_m,
        "lidar": args.lidar,
        "overrides": args.overrides,
        "test_events": int(test.sum()),
        "test_rough": int(rough[test].sum()),
        "train_events": int((~test).sum()),
        "train_rough": int(rough[~test].sum()),
        "rough_rate": float(rough.mean()),
        "methods": pooled,
        "per_seed": per_seed,
        "model": summary.get("model"),
        "warnings": summary.get("warnings"),
        "online_learning": summary.get("online_learning"),
    }
    (root / f"{args.workspace}_fig6.json").write_text(json.dumps(result, indent=2))
    draw(test_scores, rough[test], root / f"{args.workspace}_fig6.png")
    print(
        f"pooled: train {result['train_rough']} rough of {result['train_events']}, test "
        f"{result['test_rough']} of {result['test_events']} ({100 * result['rough_rate']:.2f} %)"
    )
    print(
        "| method | AUC [95 % CI] | TPR at 5 / 10 / 20 % | at 0 | AUC - closest laser [95 % CI] |"
    )
    print("|---|---|---|---|---|")
    for name, e in pooled.items():
        lo, hi = e["auc_ci95"]
        tprs = " / ".join(f"{v:.2f}" for v in e["tpr_at_fpr"].values())
        zero = "" if e["zero_share"] is None else f"{100 * e['zero_share']:.0f} %"
        diff = ""
        if "auc_minus_closest_laser" in e:
            dlo, dhi = e["auc_minus_closest_laser_ci95"]
            diff = f"{e['auc_minus_closest_laser']:+.3f} [{dlo:+.3f}, {dhi:+.3f}]"
        print(f"| {name} | {e['auc']:.3f} [{lo:.3f}, {hi:.3f}] | {tprs} | {zero} | {diff} |")
    for log_id, s in per_seed.items():
        aucs = ", ".join(f"{n} {v:.3f}" for n, v in (s["auc"] or {}).items())
        print(f"{log_id}: test {s['test_rough']} rough of {s['test_events']}, rate "
              f"{100 * s['rough_rate']:.2f} %; {aucs}")  # fmt: skip
    if result["online_learning"]:
        print_online(result["online_learning"], summary)


def print_online(online: dict, summary: dict) -> None:
    """Learning while driving (``terrain online``), pooled over the races: the test split
    (each race's second half) as scored when seen, against the race test and the offline
    model; the distance to within 0.02 of the offline model; Fig. 7 from the online flags."""
    race = summary.get(REFERENCE) or {}
    print("online, test split (second half of each race), scored as each event was seen:")
    for name in ("online", "offline", "frozen", "final", "start"):
        e = online["test"].get(name)
        if e is not None:
            tprs = " / ".join(f"{v:.2f}" for v in e["tpr_at_fpr"].values())
            print(f"  {name:8s} AUC {e['auc']:.3f}  TPR at 5 / 10 / 20 % {tprs}")
    if race.get("tpr_at_fpr"):
        print(f"  race test, closest laser: TPR at FPR 10 % {race['tpr_at_fpr']['0.1']:.2f}")
    within = online["within_0_02_from_m"]
    print(f"  within 0.02 of the offline model from: "
          f"{'never' if within is None else f'{within / 1609.344:.1f} miles'}")  # fmt: skip
    sc = online.get("speed_control") or {}
    if sc.get("online") is not None and sc.get("offline"):
        print(f"  speed control: online {sc['online']:.3f}, offline {sc['offline']:.3f} "
              f"({100 * sc['online'] / sc['offline']:.0f} %)")  # fmt: skip
    for row in online["stretches"]:
        print(f"    {row['from_m'] / 1000:5.1f} km: online {row['online']}, offline "
              f"{row['offline']}, final {row['final']} ({row['rough']} rough)")  # fmt: skip


if __name__ == "__main__":
    main()
