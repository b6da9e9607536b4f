"""Learning while driving, measured: test-then-train replay of a workspace's tables.

For a workspace made with ``terrain run LOGS -w WS --to tables`` (``split_scope =
"per_log"``: each log's first half trains, its second tests), the drive is replayed in time
order (:mod:`toolkit.model.online`) from an uninformed start (height alone) and, with
``--from-offline``, from the model searched offline on the training split. Printed:

- prequential AUC and TPR at FPR 5 / 10 / 20 % (of the events' standings, which compare
  across model versions: :mod:`toolkit.model.online`) per stretch of ``--window-km`` driven (each
  event scored by the model as it stood when the event was seen);
- on the test split (each log's second half): the online scores as they were, the offline
  model (the search of ``[learn]`` on the training split), the start unlearned, and a
  frozen early model (the online one after ``--frozen-km``);
- the distance after which the online model's AUC on a stretch stays within 0.02 of the
  offline model's on the test split;
- forgetting: the final online model's AUC on each earlier stretch against the AUC those
  stretches got as they came;
- the update time (p50, p95, max), the replay's speed against the drive's duration.

Usage: python benchmarks/online_replay.py WS [--update-every-m 100] [--buffer-rough 64]
       [--buffer-smooth 1024] [--coordinates 3] [--min-rough 1] [--step-rule adapt] [--average]
       [--validation 0.5]
       [--window-km 2] [--frozen-km 3] [--from-offline]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score, roc_curve

from toolkit.config import load_config
from toolkit.model.ascent import coordinate_ascent
from toolkit.model.online import OnlineConfig, RoughnessParams, replay, start
from toolkit.model.roughness import PairTable, model_pairs, score_events
from toolkit.model.search import ascent_config
from toolkit.stages.online_stream import drive_stream
from toolkit.workspace import Workspace

UNINFORMED = ((1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0), 1.0, 1, 1.0)


def rates(y: np.ndarray, r: np.ndarray) -> tuple[float, list[float]]:
    r = np.where(np.isfinite(r), r, np.nanmin(r[np.isfinite(r)]) - 1.0)
    fpr, tpr, _ = roc_curve(y, r, drop_intermediate=False)
    return float(roc_auc_score(y, r)), [float(np.interp(a, fpr, tpr)) for a in (0.05, 0.1, 0.2)]


def line(name: str, y: np.ndarray, r: np.ndarray) -> str:
    if not 0 < y.sum() < y.size:
        return f"  {name:34s} (one class only)"
    auc, tpr = rates(y, r)
    return f"  {name:34s} AUC {auc:.3f}  TPR {tpr[0]:.2f} / {tpr[1]:.2f} / {tpr[2]:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--update-every-m", type=float, default=100.0)
    ap.add_argument("--buffer-rough", type=int, default=64)
    ap.add_argument("--buffer-smooth", type=int, default=1024)
    ap.add_argument("--coordinates", type=int, default=3)
    ap.add_argument("--min-rough", type=int, default=1)
    ap.add_argument("--step-rule", choices=["adapt", "halve"], default="adapt")
    ap.add_argument("--average", action="store_true", help="score with B averaged over versions")
    ap.add_argument("--validation", type=float, default=0.0, help="buffer share held out")
    ap.add_argument("--refit-every-m", type=float, default=0.0, help="whole search on the buffer")
    ap.add_argument("--refit-iterations", type=int, default=20)
    ap.add_argument("--window-km", type=float, default=2.0)
    ap.add_argument("--frozen-km", type=float, default=3.0)
    ap.add_argument("--from-offline", action="store_true")
    args = ap.parse_args()
    ws = Workspace(args.workspace)
    config = load_config(ws.config_path)
    t0 = time.perf_counter()
    drive = drive_stream(ws, config.model, config.label)
    s = drive.stream
    print(f"stream: {s.events} events, {s.rough.sum()} rough, {s.s_start_m[-1] / 1000:.1f} km, "
          f"{(s.t_known_ns[-1] - s.t_start_ns[0]) / 1e9:.0f} s; read in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip
    train, test = drive.split == "train", drive.split == "test"
    lc = dataclasses.replace(
        config.learn,
        initial_alpha=UNINFORMED[0],
        initial_upsilon=UNINFORMED[1],
        initial_omega=UNINFORMED[2],
        initial_zeta=UNINFORMED[3],
        step_rule="adapt",
    )
    search = ascent_config(lc)
    everything = model_pairs(s.patches)
    t0 = time.perf_counter()
    offline = coordinate_ascent(
        PairTable(s.patches.take(np.repeat(train, 2))), s.rough[train], ascent_config(config.learn)
    )
    print(f"offline search ([learn] as configured): {time.perf_counter() - t0:.0f} s", flush=True)
    r_offline = score_events(everything, offline.params).r_combined
    r_start = score_events(everything, RoughnessParams.from_vector(search.initial, 0.0)).r_combined
    oc = OnlineConfig(
        update_every_m=args.update_every_m,
        buffer_rough=args.buffer_rough,
        buffer_smooth=args.buffer_smooth,
        coordinates_per_update=args.coordinates,
        lambda_fp=config.learn.lambda_fp,
        min_rough=args.min_rough,
        step_rule=args.step_rule,
        average=args.average,
        validation_share=args.validation,
        refit_every_m=args.refit_every_m,
        refit_iterations=args.refit_iterations,
    )
    first = (
        start(offline.params.vector(), search.increments, offline.params.mu)
        if args.from_offline
        else start(search.initial, search.increments)
    )
    frozen_steps = int(args.frozen_km * 1000 / oc.update_every_m)
    t0 = time.perf_counter()
    early, part = replay(s, first, oc, stop_after=frozen_steps)
    state, rest = replay(s, early, oc)
    wall = time.perf_counter() - t0
    r_raw = np.where(np.isnan(part.r_combined), rest.r_combined, part.r_combined)
    # Pooled over versions, the standings (each score's share of buffered smooth events
    # below it) are what compare; the raw scores are printed beside them.
    r_online = np.where(np.isnan(part.r_combined), rest.standing, part.standing)
    r_frozen = score_events(everything, early.params).r_combined
    r_final = score_events(everything, state.params).r_combined
    update_s = np.r_[part.update_s, rest.update_s]
    drive_s = (s.t_known_ns[-1] - s.t_start_ns[0]) / 1e9
    print(f"replay: {wall:.1f} s for {drive_s:.0f} s of driving ({drive_s / wall:.1f}x real "
          f"time); {update_s.size} updates, p50 {1e3 * np.percentile(update_s, 50):.0f} ms, "
          f"p95 {1e3 * np.percentile(update_s, 95):.0f} ms, max {1e3 * update_s.max():.0f} ms; "
          f"final version {state.version}", flush=True)  # fmt: skip
    y = s.rough
    print("test split (each log's second half):")
    print(line("online, standing as it came", y[test], r_online[test]))
    print(line("online, raw score as it came", y[test], r_raw[test]))
    print(line("offline, searched on the training split", y[test], r_offline[test]))
    print(line(f"frozen after {args.frozen_km:g} km", y[test], r_frozen[test]))
    print(line("the start, unlearned", y[test], r_start[test]))
    print(line("the online model at the end", y[test], r_final[test]))
    off_auc = rates(y[test], r_offline[test])[0]
    km = s.s_start_m / 1000.0
    edges = np.arange(0.0, km[-1] + args.window_km, args.window_km)
    print(f"per {args.window_km:g} km: prequential AUC (TPR 5/10/20 %) | final model's AUC")
    within = None
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        rows = (km >= lo) & (km < hi)
        if not 0 < y[rows].sum() < rows.sum():
            print(f"  {lo:5.1f}-{hi:5.1f} km: {y[rows].sum()} rough of {rows.sum()}")
            continue
        auc, tpr = rates(y[rows], r_online[rows])
        final, _ = rates(y[rows], r_final[rows])
        # The stretch from which every later one stays within 0.02 of the offline model.
        within = (lo if within is None else within) if auc >= off_auc - 0.02 else None
        print(f"  {lo:5.1f}-{hi:5.1f} km: {auc:.3f} ({tpr[0]:.2f} / {tpr[1]:.2f} / {tpr[2]:.2f}) "
              f"| {final:.3f}  [{y[rows].sum()} rough]")  # fmt: skip
    print(f"within 0.02 of the offline test AUC ({off_auc:.3f}) from km "
          f"{'never' if within is None else f'{within:.1f}'} on")  # fmt: skip
    print(f"final online parameters: {tuple(round(v, 4) for v in state.b)}, mu {state.mu:.4f}")


if __name__ == "__main__":
    main()
