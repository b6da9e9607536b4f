"""Benchmark: where the oracle reads the truth (``benchmarks/README.md``, "The oracle where
the beams hit").

    python benchmarks/oracle_probe.py WS [CONFIG]

On a workspace of simulated logs with tables (the tuning seeds 801/802 in the README), the
test AUC and the share of test events at R = 0 of the default model's search, unlearned (the
initial guess) and learned, on three sets of heights for the same points: as the lasers
measured them; the true terrain under each point's *estimated* position (the oracle before
the fix); the true terrain where each beam truly hit (``oracle_patches`` now).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from toolkit.analysis.oracle import oracle_patches
from toolkit.analysis.truth_terrain import true_ground
from toolkit.config import load_config
from toolkit.model.ascent import coordinate_ascent
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import RoughnessParams, model_pairs, score_events
from toolkit.model.search import ascent_config
from toolkit.stages import training_data
from toolkit.workspace import Workspace


def under_estimated_positions(ws: Workspace, log_ids: np.ndarray, p: TyrePatches) -> TyrePatches:
    """The oracle before the fix: the truth read under each point's estimated position."""
    z, valid = p.z.copy(), p.valid.copy()
    for log_id in sorted(set(log_ids.tolist())):
        ground = true_ground(ws.log_dir(log_id))
        assert ground is not None, "a simulated log"
        rows = np.flatnonzero(log_ids == log_id)
        mask = p.valid[rows]
        h, _ = ground.height_m(np.c_[p.x[rows][mask], p.y[rows][mask], p.z[rows][mask]])
        sub, sub_valid = z[rows], valid[rows]
        sub[mask], sub_valid[mask] = h, np.isfinite(h)
        z[rows], valid[rows] = sub, sub_valid
    z[~valid] = 0.0
    return dataclasses.replace(p, z=z, valid=valid, count=valid.sum(axis=1))


def main() -> None:
    ws = Workspace(Path(sys.argv[1]))
    cfg = load_config(Path(sys.argv[2]) if len(sys.argv) > 2 else ws.config_path)
    events = training_data.split_events(ws, None)
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    train, test = split == "train", split == "test"
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    patches = training_data.patches_of(
        ws, events, cfg.model, order=training_data.laser_order(ws, cfg.model)
    )
    log_ids = np.repeat(np.asarray(events.column("log_id").to_pylist(), dtype=object), 2)
    start = RoughnessParams.from_vector(ascent_config(cfg.learn).initial, 0.0)
    beam_hits = oracle_patches(ws, events, patches)
    assert beam_hits is not None, "every log simulated"
    for name, p in (
        ("laser heights", patches),
        ("truth under the estimated position", under_estimated_positions(ws, log_ids, patches)),
        ("truth where the beam hit", beam_hits),
    ):
        everything = model_pairs(p)
        r0 = score_events(everything, start).r_combined
        pairs = training_data.pair_table(p.take(np.repeat(train, 2)), cfg.model, ws.root)
        fitted = coordinate_ascent(pairs, rough[train], ascent_config(cfg.learn))
        r = score_events(everything, fitted.params).r_combined
        print(
            f"{name}: unlearned {roc_auc_score(rough[test], r0[test]):.3f} "
            f"(at 0: {np.mean(r0[test] == 0):.0%}); learned {roc_auc_score(rough[test], r[test]):.3f} "
            f"(at 0: {np.mean(r[test] == 0):.0%})",
            flush=True,
        )


if __name__ == "__main__":
    main()
