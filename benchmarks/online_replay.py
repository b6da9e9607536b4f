"""Learning while driving, measured: ``terrain online``'s replay on a workspace, any variant.

For a workspace made with ``terrain run LOGS -w WS`` (``[tables] split_scope = "per_log"``:
each log's first half trains, its second tests; ``model.json`` learned), the replay of
:mod:`toolkit.stages.online` runs as the stage runs it, with ``[online]`` keys overridden
(``--set online.update_every_m=150``), and writes nothing into the workspace. Printed:

- on the test split (each log's second half): the online scores as they were when each
  event was seen, the offline model (``model.json``), the frozen early model, the online
  model at its drive's end, and the start unlearned: AUC and TPR at FPR 5 / 10 / 20 %;
- per stretch of ``[online] stretch_m`` driven (pooled over the drives): the online AUC as it
  came, the offline model's and the final online model's (forgetting), and the distance from
  which every stretch stays within 0.02 of the offline model;
- the update time (p50, p95, max; the loop's work, without a refit), a refit's time, the
  replay's speed against the drive's duration, the process's peak memory.

``--cut-into WS2 --minutes M --logs N`` makes workspace WS2 of the first M minutes of each
of WS's first N logs (both tables cut, so that every pass over the points reads only
theirs, as in a workspace of logs that long) and stops: replayed in a fresh process, what
the peak memory is measured against, the patches being read a window at a
time (:mod:`toolkit.stages.online_patches`).

``--speed-control`` also drives Fig. 7's proactive controller on the test split by the online
flags as they were (each event's verdict when seen) and by the offline model's, each against
the reactive race controller at equal time, as the report's ``online_learning`` entry does
(:func:`toolkit.analysis.summary.shock_reduction`), without running ``terrain evaluate``.

``--start-from WS2`` starts every drive from the model the offline search (``[learn]`` of
this workspace) learns on WS2's training split: a model learned on other logs. WS2's tables
are read as they are (their freshness is not checked).

Usage: python benchmarks/online_replay.py WS [--set online.KEY=VALUE ...] [--start-from WS2]
       [--speed-control]
       python benchmarks/online_replay.py WS --cut-into WS2 [--minutes M] [--logs N]
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import shutil
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.analysis.summary import shock_reduction
from toolkit.config import PipelineConfig, load_config
from toolkit.model.ascent import coordinate_ascent
from toolkit.model.online import start
from toolkit.model.search import ascent_config
from toolkit.stages.online import OnlineSettings, run_online, start_state
from toolkit.stages.online_replay import ReplayLog
from toolkit.stages.online_stream import drive_stream
from toolkit.stages.training_data import load_model, pair_table, patches_of, split_events
from toolkit.tableio import (
    TableWriter,
    iter_table_batches,
    read_table,
    read_table_metadata,
    write_table,
)
from toolkit.workspace import Workspace


def with_overrides(cfg: PipelineConfig, overrides: list[str]) -> PipelineConfig:
    """``cfg`` with ``online.KEY=VALUE`` items applied (VALUE a TOML value)."""
    changes = {}
    for item in overrides:
        dotted, value = item.split("=", 1)
        section, key = dotted.split(".", 1)
        if section != "online":
            raise SystemExit(f"only [online] keys vary here, not {dotted}")
        changes[key] = tomllib.loads(f"v = {value}")["v"]
    return dataclasses.replace(cfg, online=dataclasses.replace(cfg.online, **changes))


def learned_elsewhere(other: Path, cfg: PipelineConfig) -> tuple[tuple[float, ...], float]:
    """B and mu of ``[learn]``'s search on the training split of workspace ``other``."""
    ws = Workspace(other)
    train = split_events(ws, "train")
    rough = train.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    patches = patches_of(ws, train, cfg.model)
    result = coordinate_ascent(
        pair_table(patches, cfg.model, ws.config_path), rough, ascent_config(cfg.learn)
    )
    return result.params.vector(), result.params.mu


def cut(ws: Workspace, aside: Path, minutes: float | None, logs: int | None) -> Workspace:
    """A workspace at ``aside`` whose tables are ``ws``'s first ``logs`` logs' first
    ``minutes`` each (both tables cut, so that every pass over the points reads only
    theirs, as in a workspace of logs that long), model and configuration copied."""
    events = read_table(ws.events_table, "tables_events")
    log_id = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    t = events.column("t_start_ns").to_numpy().astype(np.int64)
    keep = np.zeros(log_id.size, bool)
    for k, log in enumerate(dict.fromkeys(log_id.tolist())):
        mine = log_id == log
        if logs is not None and k >= logs:
            break
        span = np.inf if minutes is None else minutes * 60e9
        keep |= mine & (t - t[mine].min() < span)
    out = Workspace(aside)
    out.events_table.parent.mkdir(parents=True)
    meta = read_table_metadata(ws.events_table)
    provenance = {
        "source_sha256": meta["source_sha256"].split(","),
        "config_hash": meta["config_hash"],
    }
    kept = events.filter(pa.array(keep))
    write_table(out.events_table, kept, "tables_events", **provenance)
    kept_log = np.asarray(kept.column("log_id").to_pylist(), dtype=object)
    kept_id = kept.column("event_id").to_numpy()
    wanted = {log: kept_id[kept_log == log] for log in dict.fromkeys(kept_log.tolist())}
    columns = pq.read_schema(ws.event_points_table).names
    with TableWriter(out.event_points_table, "event_points", **provenance) as writer:
        for batch in iter_table_batches(
            ws.event_points_table, "event_points", columns=columns, batch_rows=1 << 20
        ):
            logs_in = np.asarray(batch.column("log_id").to_pylist(), dtype=object)
            ids = batch.column("event_id").to_numpy()
            mask = np.zeros(batch.num_rows, bool)
            for log, chosen in wanted.items():
                mine = logs_in == log
                mask[mine] = np.isin(ids[mine], chosen)
            if mask.any():
                writer.write(pa.table(batch).filter(pa.array(mask)))
    shutil.copy(ws.model_path, out.model_path)
    shutil.copy(ws.config_path, out.config_path)
    return out


def line(name: str, m: dict | None) -> str:
    if m is None:
        return f"  {name:34s} (one class only)"
    tpr = " / ".join(f"{v:.2f}" for v in m["tpr_at_fpr"].values())
    return f"  {name:34s} AUC {m['auc']:.3f}  TPR {tpr}  ({m['rough']} rough of {m['events']})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--start-from", type=Path, default=None)
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--logs", type=int, default=None)
    ap.add_argument("--cut-into", type=Path, default=None)
    ap.add_argument("--speed-control", action="store_true")
    args = ap.parse_args()
    ws = Workspace(args.workspace)
    if not ws.model_path.exists():
        raise SystemExit(f"{ws.model_path}: no learned model yet (run `terrain learn -w WS`)")
    if args.cut_into is not None:
        cut(ws, args.cut_into, args.minutes, args.logs)
        print(f"cut into {args.cut_into}: replay it in a fresh process to measure its memory")
        return
    replay(ws, args)


def replay(ws: Workspace, args: argparse.Namespace) -> None:
    """The replay of ``ws``, measured and printed (module docstring)."""
    cfg = with_overrides(load_config(ws.config_path), args.overrides)
    settings = OnlineSettings(cfg.model, cfg.label, cfg.learn, cfg.online)
    t0 = time.perf_counter()
    stream = drive_stream(ws, cfg.model, cfg.label)
    s = stream.stream
    print(f"stream: {s.events} events, {s.rough.sum()} rough, {len(set(stream.log_id))} logs; "
          f"read in {time.perf_counter() - t0:.0f} s; [online] {cfg.online}", flush=True)  # fmt: skip
    offline, _ = load_model(ws)
    first, _ = start_state(ws, settings)
    if args.start_from is not None:
        t0 = time.perf_counter()
        b, mu = learned_elsewhere(args.start_from, cfg)
        first = start(b, ascent_config(cfg.learn).increments, mu)
        print(f"start: learned on {args.start_from} in {time.perf_counter() - t0:.0f} s")
    with tempfile.TemporaryDirectory() as tmp:
        log = ReplayLog(Path(tmp) / "checkpoint.npz", "benchmark", cfg.online)
        run = run_online(stream, offline, first, settings, log, lambda: None)
    t, summary = run.timings, run.summary
    print(f"replay: {t['replay']:.1f} s for {t['driven']:.0f} s of driving "
          f"({t['real_time_factor']:.0f}x real time); {summary['updates']} updates, p50 "
          f"{1e3 * t['update_p50']:.0f} ms, p95 {1e3 * t['update_p95']:.0f} ms, max "
          f"{1e3 * t['update_max']:.0f} ms; refits {t['refits']:.0f}, the longest "
          f"{t['refit_max']:.1f} s; peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")  # fmt: skip
    print("test split (each log's second half):")
    names = {
        "online": "online, standing as it came",
        "online_raw": "online, raw score as it came",
        "offline": "offline (model.json)",
        "offline_as_met": "offline, standing as the online",
        "frozen": f"frozen after {cfg.online.frozen_after_m / 1000:g} km",
        "final": "online model at its drive's end",
        "start": "the start, unlearned",
    }
    for key, name in names.items():
        print(line(name, summary["test"][key]))
    print(f"per {cfg.online.stretch_m / 1000:g} km: online as it came | offline | offline "
          "as met | final")  # fmt: skip
    for row in summary["stretches"]:
        cells = " | ".join("  -  " if row[k] is None else f"{row[k]:.3f}"
                           for k in ("online", "offline", "offline_as_met", "final"))  # fmt: skip
        print(f"  {row['from_m'] / 1000:5.1f} km: {cells}  [{row['rough']} rough]")
    within = summary["within_0_02_from_m"]
    print(f"within 0.02 of the offline model on every later stretch from: "
          f"{'never' if within is None else f'{within / 1000:.1f} km'} (measured alike: "
          f"{summary['within_0_02_as_met_from_m']}); label latency p50 "
          f"{summary['label_latency_s']['p50']:.2f} s, p95 {summary['label_latency_s']['p95']:.2f} s;"
          f" first update per drive (m): {summary['first_update_m']}")  # fmt: skip
    if args.speed_control:
        speed_control(ws, cfg, run.scores, offline.mu)
    print(f"final B per drive: {[np.round(d['b'] or [], 3).tolist() for d in run.done.state_doc(stream.log_id, stream.event_id)['drives']]}")  # fmt: skip


def speed_control(ws: Workspace, cfg: PipelineConfig, scores: pa.Table, mu: float) -> None:
    """Fig. 7's shock reduction at equal time on the test split, driven by the online flags
    as they were and by the offline model's (``r_offline > mu``), printed."""
    t0 = time.perf_counter()
    events = split_events(ws, None)
    keys = pl.DataFrame(events.select(["log_id", "event_id"])).with_row_index("row")
    got = keys.join(
        pl.DataFrame(scores.select(["log_id", "event_id", "predicted", "r_offline"])),
        on=["log_id", "event_id"],
        how="left",
    ).sort("row")
    test = np.asarray(events.column("split").to_pylist(), dtype=object) == "test"
    online = got["predicted"].fill_null(False).to_numpy().astype(bool)
    offline = got["r_offline"].fill_null(-np.inf).to_numpy() > mu
    red = {n: shock_reduction(events, f, test, cfg.evaluate) for n, f in
           (("online", online), ("offline", offline))}  # fmt: skip
    share = (
        f"{100 * red['online'] / red['offline']:.0f} %"
        if red["online"] is not None and red["offline"]
        else "n/a"
    )
    print(f"speed control, shock reduction at equal time: online flags {red['online']}, "
          f"offline model {red['offline']} ({share} of it; {time.perf_counter() - t0:.0f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
