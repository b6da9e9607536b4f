"""Is it the buffer? The offline search of sect. 6 run per log on what the online learner
would hold at mid-drive, against the same search on the log's whole first half.

For each log of a workspace made with ``[tables] split_scope = "per_log"`` (each log's
first half trains, its second tests), ``[learn]``'s search (its start, increments and
rotations) runs on:

- the log's first half alone (every smooth event of it, its rough ones);
- the online buffer as it would stand at the end of that half: the latest
  ``buffer_rough`` rough events and the latest N smooth ones known by then, N = 256 (the
  ``[online]`` default), 1,024 and 4,096;

and each model's raw scores rank the log's second half (one model per log, so raw scores
compare). Printed beside them: the workspace's ``model.json`` (learned on every log's
first half pooled). Same rough events, fewer smooth ones: what the buffer's size alone
costs the search.

Usage: python benchmarks/online_buffer_search.py WS [--smooth 256 1024 4096]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pyarrow as pa

from toolkit.config import load_config
from toolkit.model.ascent import coordinate_ascent
from toolkit.model.roc import auc
from toolkit.model.roughness import RoughnessParams, model_pairs, score_events
from toolkit.model.search import ascent_config
from toolkit.stages.training_data import (
    laser_order,
    load_model,
    pair_table,
    patches_of,
    split_events,
)
from toolkit.workspace import Workspace


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspace", type=Path)
    ap.add_argument("--smooth", type=int, nargs="+", default=[256, 1024, 4096])
    args = ap.parse_args()
    ws = Workspace(args.workspace)
    cfg = load_config(ws.config_path)
    events = split_events(ws, None)
    order = laser_order(ws, cfg.model)
    offline, _ = load_model(ws)
    log_id = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    t_end = events.column("t_end_ns").to_numpy()
    search = ascent_config(cfg.learn)

    def fit(rows: np.ndarray) -> RoughnessParams:
        patches = patches_of(ws, events.take(pa.array(rows)), cfg.model, order=order)
        pairs = pair_table(patches, cfg.model, ws.config_path)
        return coordinate_ascent(pairs, rough[rows], search).params

    for log in dict.fromkeys(log_id.tolist()):
        t0 = time.perf_counter()
        rows = np.flatnonzero(log_id == log)
        train, test = rows[split[rows] == "train"], rows[split[rows] == "test"]
        known = train[np.argsort(t_end[train], kind="stable")]  # in the order labels came
        latest_rough = known[rough[known]][-cfg.online.buffer_rough :]
        pairs = model_pairs(patches_of(ws, events.take(pa.array(test)), cfg.model, order=order))
        models = {"model.json": offline, "first half alone": fit(train)}
        for n in args.smooth:
            buffer = np.r_[latest_rough, known[~rough[known]][-n:]]
            models[f"buffer {latest_rough.size} + {n}"] = fit(buffer)
        cells = [
            f"{name} {auc(score_events(pairs, params).r_combined, rough[test]):.3f}"
            for name, params in models.items()
        ]
        print(
            f"{log}: second half {int(rough[test].sum())} rough of {test.size}; "
            f"first half {int(rough[train].sum())} rough of {train.size}: "
            + "; ".join(cells)
            + f" ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
