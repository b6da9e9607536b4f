"""The search's choices measured on tuning logs: point sample x step acceptance x initial guess.

For each workspace given (made with ``terrain run LOG -w WS --to tables``; logs of seeds that
no evaluation uses), each combination of ``[model] point_sample``, ``[learn] accept`` and an
initial guess is learned on the training split and scored on both splits: AUC, partial AUC
to FPR 0.2 and TPR at FPR 5 / 10 / 20 %, the share of test events at R = 0, and the
initial guess's own test AUC. What the defaults were chosen from (``benchmarks/README.md``).

Usage: python benchmarks/tune_search.py WS [WS ...] [--samples ...] [--accept ...]
       [--initial ...] [--step-rule halve adapt] [--increments config flat] [--iterations N ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import time
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score, roc_curve

from toolkit.analysis.methods import Trainer, baseline
from toolkit.config import load_config
from toolkit.model.ascent import coordinate_ascent
from toolkit.model.baseline import BaselineParams
from toolkit.model.roughness import RoughnessParams, model_pairs, score_events
from toolkit.model.search import ascent_config
from toolkit.stages import training_data
from toolkit.workspace import Workspace

#: Initial guesses tried (alpha_1..alpha_10, upsilon, omega, zeta).
INITIAL = {
    # Squared height, 0.05 per second apart, 0.01 per metre: the default until issue 26.
    "squared": ((1.0, 2.0, 0.05, 1.0, 0.01, 1.0, 0.0, 1.0, 0.0, 1.0), 1.05, 3, 1.0),
    # |dz| - 0.01 |dtau| - 0.1 |dxy|: linear in every difference.
    "linear": ((1.0, 1.0, 0.01, 1.0, 0.1, 1.0, 0.0, 1.0, 0.0, 1.0), 1.05, 3, 1.0),
    # Height alone: what the learner must discover every penalty from.
    "height_only": ((1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0), 1.05, 3, 1.0),
    # No tuning at all: the largest height difference of a patch (omega 1, so upsilon has
    # nothing to weigh), every penalty at zero, the two tyres summed.
    "uninformed": ((1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0), 1.0, 1, 1.0),
}
#: Increments tried: the configuration's, or one size for every weight and one for every
#: exponent (no scale chosen per term).
INCREMENTS = {
    "config": None,
    "flat": ((0.05, 0.25) * 5, 0.05, 2.0, 0.25),
    # The hand-set increments of the tuned default until issue 38 (with "linear", "halve").
    "tuned": ((0.5, 0.5, 0.02, 0.5, 0.005, 0.5, 0.02, 0.5, 0.02, 0.5), 0.05, 2.0, 0.25),
}


def rates(y: np.ndarray, r: np.ndarray) -> tuple[float, list[float]]:
    fpr, tpr, _ = roc_curve(y, r, drop_intermediate=False)
    return float(roc_auc_score(y, r)), [float(np.interp(a, fpr, tpr)) for a in (0.05, 0.1, 0.2)]


def per_log(
    log_ids: np.ndarray, test: np.ndarray, y: np.ndarray, r: np.ndarray, r0: np.ndarray
) -> str:
    """Each log's test AUC, learned and (in brackets) unlearned: whether learning helped on
    every seed, not only pooled."""
    out = []
    for log_id in sorted(set(log_ids.tolist())):
        mine = test & (log_ids == log_id)
        if 0 < y[mine].sum() < mine.sum():
            learned, _ = rates(y[mine], r[mine])
            start, _ = rates(y[mine], r0[mine])
            out.append(f"{log_id.rsplit('-', 1)[0]} {learned:.3f} ({start:.3f})")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("workspaces", type=Path, nargs="+")
    ap.add_argument("--samples", nargs="+", default=["hash", "nearest_laser"])
    ap.add_argument("--accept", nargs="+", default=["objective", "auc", "pauc"])
    ap.add_argument("--initial", nargs="+", default=list(INITIAL))
    ap.add_argument("--validation", type=float, nargs="+", default=[0.0])
    ap.add_argument("--lead", type=int, nargs="+", default=[0], help="look-ahead term: 0 off, 1 on")
    ap.add_argument("--baseline", action="store_true", help="also the closest-laser race test")
    ap.add_argument("--step-rule", nargs="+", default=["halve"], choices=["halve", "adapt"])
    ap.add_argument("--increments", nargs="+", default=["config"], choices=list(INCREMENTS))
    ap.add_argument("--iterations", type=int, nargs="+", default=[20])
    ap.add_argument("--per-log", action="store_true", help="also each log's test AUC")
    args = ap.parse_args()
    for root in args.workspaces:
        ws = Workspace(root)
        config = load_config(ws.config_path)
        events = training_data.split_events(ws, None)
        split = np.asarray(events.column("split").to_pylist(), dtype=object)
        train, test = split == "train", split == "test"
        y = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
        log_ids = np.asarray(events.column("log_id").to_pylist(), dtype=object)
        print(f"{root}: train {y[train].sum()} rough of {train.sum()}, test {y[test].sum()} "
              f"of {test.sum()}")  # fmt: skip
        if args.baseline:
            # The race test on the closest laser (sect. 7.1), as evaluate trains it.
            model = dataclasses.replace(config.model, point_sample="nearest_laser")
            order = training_data.laser_order(ws, model)
            near = training_data.patches_of(
                ws, events, config.model, only_laser=order[0], order=order
            )
            ev = config.evaluate
            bp = BaselineParams(ev.baseline_cell_m, ev.baseline_delta_m, ev.baseline_sigma0_m,
                                ev.baseline_growth_m2_per_s, ev.baseline_confidence)  # fmt: skip
            pairs_of = functools.partial(training_data.pair_table, model=config.model, path=root)
            got = baseline(Trainer(train, y, config.learn, pairs_of), near, bp)
            r = np.nan_to_num(got.scores.r_combined, nan=-np.inf)
            auc_te, tpr = rates(y[test], r[test])
            print(f"  race test, closest laser {order[0]}: test AUC {auc_te:.3f} TPR "
                  f"{tpr[0]:.2f}/{tpr[1]:.2f}/{tpr[2]:.2f}", flush=True)  # fmt: skip
        for sample in args.samples:
            model = dataclasses.replace(config.model, point_sample=sample)
            order = training_data.laser_order(ws, model)
            patches = training_data.patches_of(ws, events, model, order=order)
            pairs = training_data.pair_table(patches.take(np.repeat(train, 2)), model, root)
            everything = model_pairs(patches)
            for init, accept, val, lead, rule, incs, its in itertools.product(
                args.initial, args.accept, args.validation, args.lead, args.step_rule,
                args.increments, args.iterations,
            ):  # fmt: skip
                alpha, ups, om, zeta = INITIAL[init]
                lc = dataclasses.replace(
                    config.learn, initial_alpha=alpha, initial_upsilon=ups, initial_omega=om,
                    initial_zeta=zeta, accept=accept, validation_share=val, lead_term=bool(lead),
                    step_rule=rule, iterations=its,
                )  # fmt: skip
                if INCREMENTS[incs] is not None:
                    ia, iu, io, iz = INCREMENTS[incs]
                    lc = dataclasses.replace(lc, increment_alpha=ia, increment_upsilon=iu,
                                             increment_omega=io, increment_zeta=iz)  # fmt: skip
                t0 = time.perf_counter()
                res = coordinate_ascent(pairs, y[train], ascent_config(lc))
                r = score_events(everything, res.params).r_combined
                r0 = score_events(everything, RoughnessParams.from_vector(
                    ascent_config(lc).initial, 0.0)).r_combined  # fmt: skip
                auc0, _ = rates(y[test], r0[test])
                auc_tr, _ = rates(y[train], r[train])
                auc_te, tpr = rates(y[test], r[test])
                zero = float(np.mean(r[test] == 0.0))
                print(
                    f"  {sample:13s} {init:11s} {accept:9s} val {val:.2f} lead {lead} {rule} "
                    f"{incs} x{its} "
                    f"train AUC {auc_tr:.3f} | test AUC "
                    f"{auc_te:.3f} (start {auc0:.3f}) TPR {tpr[0]:.2f}/{tpr[1]:.2f}/{tpr[2]:.2f} "
                    f"at0 {100 * zero:.0f}% J {res.objective:.3f} ({time.perf_counter() - t0:.0f} s)",
                    flush=True,
                )
                if args.per_log:
                    print(
                        "    per log, test AUC learned (start):", per_log(log_ids, test, y, r, r0)
                    )


if __name__ == "__main__":
    main()
