"""What the report is made of: each method's ROC on the test split (sect. 7.1,
:mod:`toolkit.model.roc`), the speed-control trade-off (sect. 7.2,
:mod:`toolkit.model.speed_control`), ``summary.json``'s contents and ``scores.parquet``'s
table.

Speed control: each log's test events in driving order, the reactive controller swept over
``slow_fractions`` x ``recovery_rates_mps2`` and the proactive one over ``slow_fractions``,
triggered by the model's verdicts.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit import __version__
from toolkit.analysis import fig7
from toolkit.analysis.method_registry import ABLATION_NAMES, MAIN_METHODS, SCORE_COLUMNS
from toolkit.analysis.methods import MethodScores, Rows
from toolkit.arrays import BoolArray, FloatArray
from toolkit.config import EvaluateConfig
from toolkit.model import speed_control as sc
from toolkit.model.baseline import BaselineParams
from toolkit.model.roc import RocSummary, auc, summarise
from toolkit.model.shock import MPS_PER_MPH

#: model.json's keys the summary repeats, as learn wrote them.
MODEL_KEYS = (
    "alpha",
    "upsilon",
    "omega",
    "zeta",
    "mu",
    "lambda",
    "objective",
    "tp_rate",
    "fp_rate",
    "iterations",
)


def method_rocs(
    methods: Mapping[str, MethodScores | None],
    test: BoolArray,
    rough: BoolArray,
    ruggedness: FloatArray,
    ev: EvaluateConfig,
    testable: bool,
) -> dict[str, RocSummary | None]:
    """Each method's ROC on the test split with bootstrap intervals (None for a method not
    run, or for every method when the test split lacks a class)."""
    return {
        name: (
            summarise(
                m.scores.r_combined[test],
                rough[test],
                ruggedness[test],
                ev.fpr_points,
                resamples=ev.bootstrap_resamples,
                seed=ev.bootstrap_seed,
            )
            if m is not None and testable
            else None
        )
        for name, m in methods.items()
    }


def start_aucs(
    methods: Mapping[str, MethodScores | None], test: BoolArray, rough: BoolArray, testable: bool
) -> dict[str, float]:
    """The test AUC of each learned method's start, unlearned (its search's initial
    parameters; only methods that have one, and none when the test split lacks a class)."""
    if not testable:
        return {}
    return {
        name: auc(m.start[test], rough[test])
        for name, m in methods.items()
        if m is not None and m.start is not None
    }


def method_entry(
    roc: RocSummary | None,
    m: MethodScores | None,
    points: dict[str, Any] | None,
    start_auc: float | None = None,
) -> dict[str, Any] | None:
    """A method's summary entry: its ROC, parameters and points, how its training went,
    and its start's test AUC (None for a method without an ROC)."""
    if roc is None or m is None:
        return None
    out = roc.to_json()
    out["params"] = m.params.to_json()
    out["points"] = points
    if start_auc is not None:
        out["start_auc"] = start_auc
    if m.trained is not None:
        t = m.trained
        out["train_objective"] = t.objective
        out["train_auc"] = t.auc
        out["accepted_by"] = t.accepted_by
        if t.start is not None:
            out["train_start"] = {"objective": t.start.objective, "auc": t.start.auc}
    return out


def split_counts(train: BoolArray, test: BoolArray, rough: BoolArray) -> dict[str, int]:
    """Events and rough events of each split (``train_events``, ``train_positives``...)."""
    return {
        f"{side}_{k}": int(v)
        for side, mask in (("train", train), ("test", test))
        for k, v in (("events", mask.sum()), ("positives", (rough & mask).sum()))
    }


def summary_json(
    rows: Rows,
    rocs: Mapping[str, RocSummary | None],
    starts: Mapping[str, float],
    speed: dict[str, Any],
    counts: dict[str, int],
    closest: str | None,
    model: dict[str, Any],
    bp: BaselineParams,
    warnings: list[str],
) -> dict[str, Any]:
    """``summary.json``'s contents; ``model`` is the summary's model entry
    (:func:`model_entry`), ``starts`` the learned methods' starts' test AUCs
    (:func:`start_aucs`)."""

    def entry(name: str) -> dict[str, Any] | None:
        m, points = rows.methods.get(name), rows.points.get(name)
        return method_entry(rocs.get(name), m, points, starts.get(name))

    return {
        **{name: entry(name) for name in MAIN_METHODS},
        "ablations": {name: entry(name) for name in ABLATION_NAMES},
        "speed_control": speed,
        "not_run": rows.not_run,
        **counts,
        "closest_laser": closest,
        "model": model,
        "baseline_test": {
            "cell_m": bp.cell_m,
            "delta_m": bp.delta_m,
            "sigma0_m": bp.sigma0_m,
            "growth_m2_per_s": bp.growth_m2_per_s,
            "confidence": bp.confidence,
        },
        "warnings": warnings,
        "toolkit_version": __version__,
    }


def model_entry(
    model_doc: dict[str, Any], point_sample: str, order: tuple[str, ...]
) -> dict[str, Any]:
    """The summary's model entry: ``model.json``'s parameters and rates, and the points
    the model scored."""
    return (
        {k: model_doc[k] for k in MODEL_KEYS}
        | {k: model_doc.get(k) for k in ("accepted_by", "train_auc", "start")}
        | {"point_sample": point_sample, "laser_order": list(order)}
    )


def scores_table(
    events: pa.Table, learned: MethodScores, rows: Rows, rough: BoolArray, ruggedness: FloatArray
) -> pa.Table:
    """``scores.parquet``: per event the learned model's R_left, R_right, R_combined and
    verdict, the label and the ruggedness, and every other method's R_combined (null where
    it scored nothing or was not run)."""

    def column(name: str) -> pa.Array:
        m = rows.methods.get(name)
        if m is None:
            return pa.nulls(events.num_rows, pa.float64())
        v = m.scores.r_combined
        return pa.array(v, pa.float64(), mask=~np.isfinite(v))

    s = learned.scores
    return pa.table(
        {
            "log_id": events.column("log_id"),
            "event_id": events.column("event_id"),
            "split": events.column("split"),
            "r_left": s.r_left,
            "r_right": s.r_right,
            "r_combined": s.r_combined,
            "predicted": s.predicted,
            "rough": rough,
            "ruggedness": ruggedness,
            **{name: column(name) for name in SCORE_COLUMNS},
        }
    )


def _routes(events: pa.Table, predicted: BoolArray, test: BoolArray) -> list[sc.Route]:
    """Each log's test events, in driving order, as speed-control routes."""
    routes = []
    log_ids = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    col = {
        n: events.column(n).to_numpy(zero_copy_only=False)
        for n in ("s_start_m", "s_end_m", "speed_mph", "ruggedness", "rough")
    }
    for log_id in sorted(set(log_ids[test].tolist())):
        rows = np.flatnonzero(test & (log_ids == log_id))
        rows = rows[np.argsort(col["s_start_m"][rows], kind="stable")]
        routes.append(
            sc.Route(
                s_start_m=col["s_start_m"][rows].astype(np.float64),
                s_end_m=col["s_end_m"][rows].astype(np.float64),
                speed_mps=col["speed_mph"][rows].astype(np.float64) * MPS_PER_MPH,
                ruggedness=col["ruggedness"][rows].astype(np.float64),
                rough=col["rough"][rows].astype(bool),
                predicted=predicted[rows].astype(bool),
                source=str(log_id),
            )
        )
    return routes


def _speed_params(ev: EvaluateConfig) -> sc.SpeedControlParams:
    """The controller of ``[evaluate]``, at its first slowing fraction."""
    return sc.SpeedControlParams(
        slow_fraction=ev.slow_fractions[0],
        decel_mps2=ev.decel_mps2,
        recovery_mps2=ev.recovery_mps2,
        hold_distance_m=ev.hold_distance_m,
        lookahead_m=ev.lookahead_m,
        shock_floor_g=ev.shock_floor_g,
    )


def shock_reduction(
    events: pa.Table, predicted: BoolArray, test: BoolArray, ev: EvaluateConfig
) -> float | None:
    """Fig. 7's headline for any flags (E,) on the test events: the largest shock
    reduction of the proactive controller driven by them against the reactive race
    controller, at equal time (None where the fronts never meet)."""
    base = _speed_params(ev)
    routes = _routes(events, predicted, test)
    reactive = sc.reactive_curve(routes, base, ev.slow_fractions, ev.recovery_rates_mps2)
    proactive = sc.proactive_curve(routes, base, ev.slow_fractions)
    best = sc.shock_reduction_at_equal_time(
        sc.pareto_front(reactive), sc.pareto_front(proactive)
    ).max_reduction
    return None if not np.isfinite(best) else round(float(best), 6)


def speed_control(
    events: pa.Table, predicted: BoolArray, test: BoolArray, ev: EvaluateConfig, out_dir: Path
) -> tuple[dict[str, Any], list[Path]]:
    """Fig. 7: the curves, the CSV and PNG, and the summary entry."""
    base = _speed_params(ev)
    routes = _routes(events, predicted, test)
    reactive = sc.reactive_curve(routes, base, ev.slow_fractions, ev.recovery_rates_mps2)
    proactive = sc.proactive_curve(routes, base, ev.slow_fractions)
    none = sc.no_change_point(routes, base)
    reduction = sc.shock_reduction_at_equal_time(
        sc.pareto_front(reactive), sc.pareto_front(proactive)
    )
    curves = [reactive, proactive, [none]]
    files = [
        fig7.write_tradeoff_csv(out_dir, curves),
        fig7.tradeoff_png(out_dir, curves, "Fig. 7 analogue"),
    ]
    best = reduction.max_reduction
    return {
        "shock_reduction_at_equal_time": None if not np.isfinite(best) else round(float(best), 6),
        "reductions_along_reactive_front": [
            {
                "time_norm": round(float(t), 6),
                "reduction": None if not np.isfinite(r) else round(float(r), 6),
            }
            for t, r in zip(reduction.time_norm, reduction.reductions, strict=True)
        ],
        "curves": fig7.CSV_NAME,
        "shock_floor_g": ev.shock_floor_g,
        "no_change": {
            "time_s": round(none.time_s, 3),
            "shock_g": round(none.shock_g, 6),
            "shocks_over_floor": none.shocks_over_floor,
        },
    }, files


__all__ = [
    "shock_reduction",
    "MODEL_KEYS",
    "method_entry",
    "method_rocs",
    "model_entry",
    "scores_table",
    "speed_control",
    "split_counts",
    "start_aucs",
    "summary_json",
]
