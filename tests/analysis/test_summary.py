"""The evaluate stage's summary, scores table and speed-control entry on crafted inputs."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from toolkit import __version__
from toolkit.analysis import fig7
from toolkit.analysis.method_registry import ABLATION_NAMES, MAIN_METHODS, SCORE_COLUMNS
from toolkit.analysis.methods import MethodScores, Rows
from toolkit.analysis.summary import (
    MODEL_KEYS,
    _routes,
    method_entry,
    method_rocs,
    model_entry,
    scores_table,
    speed_control,
    split_counts,
    start_aucs,
    summary_json,
)
from toolkit.config import EvaluateConfig, default_config
from toolkit.model.ascent import AscentResult, Threshold
from toolkit.model.baseline import BaselineParams
from toolkit.model.roc import RocSummary
from toolkit.model.roughness import EventScores, RoughnessParams
from toolkit.model.shock import MPS_PER_MPH

PARAMS = RoughnessParams((1.0,) * 10, 2.0, 3, 0.5, 0.25)


def _method(r_combined: list[float], trained: AscentResult | None = None) -> MethodScores:
    """A method whose R_left is R_combined, R_right half of it, verdict R_combined > 0.5."""
    r = np.asarray(r_combined, np.float64)
    return MethodScores(EventScores(r, r / 2, r, r > 0.5), trained, PARAMS)


def _evaluate(**changes: object) -> EvaluateConfig:
    """The default [evaluate], few bootstrap resamples, with ``changes``."""
    ev = default_config().evaluate
    return dataclasses.replace(ev, **{"bootstrap_resamples": 20, **changes})  # type: ignore[arg-type]


# Seven events: the first two are training events whose scores would spoil the test
# split's ranking; the test split's five rank two rough events among three smooth ones.
SCORES = [0.0, 1.0, 0.9, 0.8, 0.7, 0.3, 0.1]
ROUGH = np.array([True, False, True, False, True, False, False])
TEST = np.array([False, False, True, True, True, True, True])
# Ruggedness rising with the score on the test split, against it on the training split.
RUGGEDNESS = np.array([9.0, 0.0, 0.5, 0.4, 0.3, 0.2, 0.1])


def test_method_rocs_rank_the_test_events_only() -> None:
    """Rough 0.9 and 0.7 against smooth 0.8, 0.3, 0.1: 5 of the 6 pairs ordered, AUC 5/6;
    at FPR 0.2 the best TPR is 1/2 (0.9 alone), at FPR 0.5 it is 1 (0.8 let in)."""
    ev = _evaluate(fpr_points=(0.2, 0.5))
    rocs = method_rocs({"a": _method(SCORES), "b": None}, TEST, ROUGH, RUGGEDNESS, ev, True)
    assert list(rocs) == ["a", "b"] and rocs["b"] is None
    roc = rocs["a"]
    assert isinstance(roc, RocSummary)
    assert roc.auc == pytest.approx(5 / 6, abs=1e-12)
    assert roc.tpr_at_fpr == {"0.2": 0.5, "0.5": 1.0}
    assert (roc.events, roc.positives) == (5, 2)
    assert roc.spearman == pytest.approx(1.0)  # the test split's ruggedness, not the train's
    assert roc.zero_share == 0.0 and roc.unscored_share == 0.0
    lo, hi = roc.auc_ci
    assert 0.0 <= lo <= hi <= 1.0


def test_method_rocs_are_none_when_the_test_split_lacks_a_class() -> None:
    rocs = method_rocs(
        {"a": _method(SCORES), "b": None}, TEST, ROUGH, RUGGEDNESS, _evaluate(), False
    )
    assert rocs == {"a": None, "b": None}


def test_method_entry_holds_the_roc_params_points_and_training() -> None:
    roc = method_rocs({"a": _method(SCORES)}, TEST, ROUGH, RUGGEDNESS, _evaluate(), True)["a"]
    assert roc is not None
    trained = AscentResult(
        params=PARAMS,
        objective=0.4,
        tpr=0.6,
        fpr=0.2,
        auc=0.75,
        iterations=3,
        evaluations=100,
        history=(0.1, 0.3, 0.4),
        start=Threshold(mu=0.1, objective=0.2, tpr=0.5, fpr=0.3, auc=0.6),
        accepted_by="auc",
    )
    points = {"sample": "hash"}
    entry = method_entry(roc, _method(SCORES, trained), points)
    assert entry is not None
    assert entry["auc"] == round(5 / 6, 6)
    assert entry["events"] == 5 and entry["positives"] == 2
    assert entry["params"] == PARAMS.to_json()
    assert entry["points"] == points
    assert entry["train_objective"] == 0.4 and entry["train_auc"] == 0.75
    assert entry["accepted_by"] == "auc"
    assert entry["train_start"] == {"objective": 0.2, "auc": 0.6}
    # Untrained (the learned model, trained by `terrain learn`): no training keys.
    plain = method_entry(roc, _method(SCORES), None)
    assert plain is not None and plain["points"] is None
    assert not {"train_objective", "train_auc", "accepted_by", "train_start"} & set(plain)
    assert plain == {k: v for k, v in entry.items() if not k.startswith(("train", "accepted"))} | {
        "points": None
    }
    assert method_entry(None, _method(SCORES), points) is None
    assert method_entry(roc, None, points) is None


def test_split_counts_count_events_and_rough_events_per_split() -> None:
    train = np.array([True, True, False, False, False, False])
    test = np.array([False, False, True, True, True, False])
    rough = np.array([True, False, True, True, False, True])  # the last is in neither split
    counts = split_counts(train, test, rough)
    assert counts == {
        "train_events": 2,
        "train_positives": 1,
        "test_events": 3,
        "test_positives": 2,
    }
    assert list(counts) == ["train_events", "train_positives", "test_events", "test_positives"]
    assert all(type(v) is int for v in counts.values())  # JSON-ready, not numpy integers


def test_model_entry_repeats_model_json_and_names_the_points() -> None:
    doc = {k: float(i) for i, k in enumerate(MODEL_KEYS)} | {"train_auc": 0.7, "other": 1}
    entry = model_entry(doc, "nearest_laser", ("/laser_2", "/laser_1"))
    assert list(entry) == [
        *MODEL_KEYS,
        "accepted_by",
        "train_auc",
        "start",
        "point_sample",
        "laser_order",
    ]
    assert all(entry[k] == doc[k] for k in MODEL_KEYS)
    assert entry["accepted_by"] is None and entry["start"] is None  # absent from model.json
    assert entry["train_auc"] == 0.7
    assert entry["point_sample"] == "nearest_laser"
    assert entry["laser_order"] == ["/laser_2", "/laser_1"]
    with pytest.raises(KeyError):
        model_entry({k: v for k, v in doc.items() if k != "mu"}, "hash", ())


def test_start_aucs_are_each_learned_rows_start_on_the_test_split() -> None:
    """The start's AUC on the test events alone (the two training events, scored to spoil
    it, do not count); rows without a start have none; nothing when the test is untestable."""
    start = np.array([9.0, -9.0, 0.1, 0.9, 0.2, 0.8, 0.7])  # test: rough events lowest
    learned = dataclasses.replace(_method(SCORES), start=start)
    methods = {"self_supervised": learned, "boosted": _method(SCORES), "oracle": None}
    assert start_aucs(methods, TEST, ROUGH, True) == {"self_supervised": 0.0}
    assert start_aucs(methods, TEST, ROUGH, False) == {}


def test_summary_json_lists_every_method_the_counts_and_the_baseline_test() -> None:
    rows = Rows()
    learned, ablated = _method(SCORES), _method([-v for v in SCORES])
    rows.add("self_supervised", learned, {"sample": "nearest_laser"})
    rows.add("no_time_term", ablated, {"sample": "nearest_laser"})
    rows.add("boosted", _method(SCORES), {"sample": "hash"})  # scored, but no ROC below
    rows.not_run["model_closest_laser"] = "off ([evaluate] model_on_closest_laser)"
    ev = _evaluate()
    rocs = method_rocs(
        {"self_supervised": learned, "no_time_term": ablated}, TEST, ROUGH, RUGGEDNESS, ev, True
    )
    speed = {"shock_reduction_at_equal_time": 0.25}
    counts = split_counts(~TEST, TEST, ROUGH)
    model = {"mu": 0.25}
    bp = BaselineParams(cell_m=0.5, delta_m=0.2, sigma0_m=0.04, growth_m2_per_s=0.001)
    starts = {"self_supervised": 0.5}
    summary = summary_json(rows, rocs, starts, speed, counts, "/laser_1", model, bp, ["careful"])
    assert list(summary) == [
        *MAIN_METHODS,
        "ablations",
        "speed_control",
        "not_run",
        "train_events",
        "train_positives",
        "test_events",
        "test_positives",
        "closest_laser",
        "model",
        "baseline_test",
        "warnings",
        "toolkit_version",
    ]
    assert summary["self_supervised"] == method_entry(
        rocs["self_supervised"], learned, {"sample": "nearest_laser"}, 0.5
    )
    assert summary["self_supervised"]["auc"] == round(5 / 6, 6)
    assert summary["self_supervised"]["start_auc"] == 0.5
    assert "start_auc" not in summary["ablations"]["no_time_term"]
    assert all(summary[name] is None for name in MAIN_METHODS if name != "self_supervised")
    assert list(summary["ablations"]) == list(ABLATION_NAMES)
    assert summary["ablations"]["no_time_term"]["auc"] == round(1 / 6, 6)  # negated scores
    assert summary["ablations"]["no_rate_terms"] is None
    assert summary["ablations"]["no_learning"] is None
    assert summary["speed_control"] is speed and summary["model"] is model
    assert summary["not_run"] == {"model_closest_laser": "off ([evaluate] model_on_closest_laser)"}
    assert (summary["train_events"], summary["train_positives"]) == (2, 1)
    assert (summary["test_events"], summary["test_positives"]) == (5, 2)
    assert summary["closest_laser"] == "/laser_1"
    assert summary["baseline_test"] == {
        "cell_m": 0.5,
        "delta_m": 0.2,
        "sigma0_m": 0.04,
        "growth_m2_per_s": 0.001,
        "confidence": 0.95,
    }
    assert summary["warnings"] == ["careful"]
    assert summary["toolkit_version"] == __version__
    json.dumps(summary, allow_nan=False)  # what atomic_write_json will be given


def _events(log_ids: list[str], split: list[str]) -> pa.Table:
    """An events table as evaluate reads it (both splits), event ids 10, 11, ..."""
    n = len(log_ids)
    return pa.table(
        {
            "log_id": log_ids,
            "event_id": pa.array(np.arange(10, 10 + n), pa.int64()),
            "split": split,
        }
    )


def test_scores_table_holds_every_event_in_order_and_nulls_where_unscored() -> None:
    events = _events(["b", "a", "b", "a"], ["test", "train", "train", "test"])
    learned = _method([0.9, 0.2, 0.6, 0.4])
    rows = Rows()
    rows.add("baseline_all_lasers", _method([0.5, np.nan, 0.25, 1.5]), {})
    rows.add("oracle", None, {})  # not run
    rough = np.array([True, False, True, False])
    ruggedness = np.array([1.0, 0.1, 0.8, 0.2])
    table = scores_table(events, learned, rows, rough, ruggedness)
    assert table.column_names == [
        "log_id",
        "event_id",
        "split",
        "r_left",
        "r_right",
        "r_combined",
        "predicted",
        "rough",
        "ruggedness",
        *SCORE_COLUMNS,
    ]
    assert table.num_rows == 4
    # The events' rows, in the events table's order (not sorted by log or split).
    assert table.column("log_id").to_pylist() == ["b", "a", "b", "a"]
    assert table.column("event_id").to_pylist() == [10, 11, 12, 13]
    assert table.column("split").to_pylist() == ["test", "train", "train", "test"]
    assert table.column("r_left").to_pylist() == [0.9, 0.2, 0.6, 0.4]
    assert table.column("r_right").to_pylist() == [0.45, 0.1, 0.3, 0.2]
    assert table.column("r_combined").to_pylist() == [0.9, 0.2, 0.6, 0.4]
    assert table.column("predicted").to_pylist() == [True, False, True, False]
    assert table.column("rough").to_pylist() == [True, False, True, False]
    assert table.column("ruggedness").to_pylist() == [1.0, 0.1, 0.8, 0.2]
    assert table.column("baseline_all_lasers").to_pylist() == [0.5, None, 0.25, 1.5]
    for name in SCORE_COLUMNS:
        column = table.column(name)
        assert column.type == pa.float64(), name
        if name != "baseline_all_lasers":
            assert column.null_count == 4, name  # not run, or never added to the rows


def _route_events() -> pa.Table:
    """Seven events of two logs, out of driving order; log "c" has only training events."""
    return pa.table(
        {
            "log_id": ["b", "a", "b", "a", "c", "a", "b"],
            "s_start_m": [20.0, 5.0, 10.0, 1.0, 0.0, 3.0, 30.0],
            "s_end_m": [21.0, 6.0, 11.0, 2.0, 1.0, 4.0, 31.0],
            "speed_mph": [10.0, 20.0, 10.0, 20.0, 5.0, 20.0, 10.0],
            "ruggedness": [0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07],
            "rough": [False, True, False, True, False, True, False],
        }
    )


def test_routes_are_each_logs_test_events_in_driving_order() -> None:
    events = _route_events()
    test = np.array([True, True, True, True, False, True, False])  # row 6 of "b" is training
    predicted = np.array([True, False, False, True, True, False, True])
    routes = _routes(events, predicted, test)
    assert [r.source for r in routes] == ["a", "b"]
    a, b = routes
    # Log a: rows 3, 5, 1 (s 1, 3, 5); log b: rows 2, 0 (s 10, 20).
    np.testing.assert_array_equal(a.s_start_m, [1.0, 3.0, 5.0])
    np.testing.assert_array_equal(a.s_end_m, [2.0, 4.0, 6.0])
    np.testing.assert_allclose(a.speed_mps, np.full(3, 20.0 * MPS_PER_MPH), rtol=1e-15)
    np.testing.assert_array_equal(a.ruggedness, [0.04, 0.06, 0.02])
    np.testing.assert_array_equal(a.rough, [True, True, True])
    np.testing.assert_array_equal(a.predicted, [True, False, False])
    np.testing.assert_array_equal(b.s_start_m, [10.0, 20.0])
    np.testing.assert_array_equal(b.ruggedness, [0.03, 0.01])
    np.testing.assert_array_equal(b.predicted, [False, True])
    assert _routes(events, predicted, np.zeros(7, bool)) == []


def test_speed_control_without_triggers_changes_nothing(tmp_path: Path) -> None:
    """No event rough or flagged: every controller drives the nominal speeds, so the reactive
    and proactive fronts are the no-change point (1, 1) and the reduction there is 0. The
    no-change time and shock are the hand-computed sums over the test events."""
    events = _route_events().set_column(5, "rough", pa.array([False] * 7))
    test = np.array([True, True, True, True, False, True, False])
    ev = _evaluate(slow_fractions=(0.5, 0.8), recovery_rates_mps2=(0.5,), shock_floor_g=0.3)
    entry, files = speed_control(events, np.zeros(7, bool), test, ev, tmp_path)
    assert files == [tmp_path / fig7.CSV_NAME, tmp_path / fig7.PNG_NAME]
    assert all(f.is_file() and f.stat().st_size > 0 for f in files)
    assert entry["shock_reduction_at_equal_time"] == 0.0
    assert entry["reductions_along_reactive_front"] == [{"time_norm": 1.0, "reduction": 0.0}]
    assert entry["curves"] == fig7.CSV_NAME and entry["shock_floor_g"] == 0.3
    # 1 m each: three events at 20 mph (log a) and two at 10 mph (log b).
    time_s = 3 / (20 * MPS_PER_MPH) + 2 / (10 * MPS_PER_MPH)
    # Shock = ruggedness x mph: a 0.8, 1.2, 0.4 (over the 0.3 G floor: 0.5, 0.9, 0.1);
    # b 0.3, 0.1 (none over).
    assert entry["no_change"] == {
        "time_s": round(time_s, 3),
        "shock_g": pytest.approx(1.5, abs=1e-6),
        "shocks_over_floor": 3,
    }
    json.dumps(entry, allow_nan=False)


def test_speed_control_flagging_rough_events_ahead_reduces_shock(tmp_path: Path) -> None:
    """Five rough events in a row of smooth ones, all flagged by the model: the reactive
    controller slows only after the first, the proactive one before it, so along the
    reactive front (where the proactive front reaches) the proactive shock is lower."""
    n = 40
    rough = np.zeros(n, bool)
    rough[10:15] = True
    events = pa.table(
        {
            "log_id": ["a"] * n,
            "s_start_m": np.arange(n) * 10.0,
            "s_end_m": np.arange(n) * 10.0 + 2.0,
            "speed_mph": np.full(n, 20.0),
            "ruggedness": np.where(rough, 0.1, 0.001),
            "rough": rough,
        }
    )
    ev = _evaluate(slow_fractions=(0.3, 0.5, 0.7, 0.9), recovery_rates_mps2=(0.5, 1.0))
    entry, _ = speed_control(events, rough.copy(), np.ones(n, bool), ev, tmp_path)
    # Rough: 0.1 x 20 mph = 2 G, 1.7 over the floor; smooth 0.02 G, under it.
    assert entry["no_change"]["shocks_over_floor"] == 5
    assert entry["no_change"]["shock_g"] == pytest.approx(8.5, abs=1e-6)
    along = entry["reductions_along_reactive_front"]
    assert len(along) >= 2
    assert all(p["time_norm"] > 1.0 and p["reduction"] > 0.0 for p in along)
    assert entry["shock_reduction_at_equal_time"] == max(p["reduction"] for p in along)
