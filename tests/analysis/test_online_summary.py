"""What the report states of a replay: stretches, the distance to the offline model, labels
out of order, stretches without events."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.analysis.online_summary import (
    comparable,
    gaps,
    learning_verdict,
    online_summary,
    out_of_order,
    rates,
    stretches,
    within_from_m,
)


def test_within_is_the_first_stretch_from_which_every_later_one_holds() -> None:
    rows = [
        {"from_m": 0.0, "online": 0.70, "offline": 0.90},
        {"from_m": 1.0, "online": 0.89, "offline": 0.90},  # within, but the next is not
        {"from_m": 2.0, "online": 0.80, "offline": 0.90},
        {"from_m": 3.0, "online": None, "offline": 0.90},  # one class only: no verdict
        {"from_m": 4.0, "online": 0.88, "offline": 0.90},
        {"from_m": 5.0, "online": 0.95, "offline": 0.90},
    ]
    assert within_from_m(rows) == 4.0
    assert within_from_m(rows[:3]) is None


def test_stretches_pool_events_by_distance_and_skip_one_class() -> None:
    s_m = np.array([10.0, 20.0, 30.0, 1010.0, 1020.0])
    rough = np.array([True, False, False, False, False])
    score = np.array([3.0, 1.0, 2.0, 1.0, 2.0])
    rows = stretches(s_m, rough, {"online": score}, 1000.0)
    assert [r["events"] for r in rows] == [3, 2]
    assert rows[0]["online"] == 1.0 and rows[1]["online"] is None


def test_labels_known_before_those_of_earlier_events_are_counted() -> None:
    drive = np.array([0, 0, 0, 1, 1])
    t_seen = np.array([1, 2, 3, 1, 2])
    t_known = np.array([10, 9, 11, 5, 6])  # the second event's label came first
    assert out_of_order(drive, t_seen, t_known) == 1


def test_a_stretch_without_events_is_a_gap() -> None:
    drive = np.array([0, 0, 0, 1])
    s_m = np.array([0.0, 1.4, 2500.0, 0.0])
    assert gaps(drive, s_m, 1000.0) == [{"drive": 0, "from_m": 1.4, "to_m": 2500.0}]


def test_rates_rank_unscored_events_last() -> None:
    rough = np.array([True, False, False])
    got = rates(np.array([np.nan, 1.0, 2.0]), rough, (0.5,))
    assert got is not None and got["auc"] == 0.0
    assert rates(np.array([1.0, 2.0]), np.array([False, False]), (0.5,)) is None


def test_the_summary_compares_on_the_test_split() -> None:
    n = 8
    scores = {
        "rough": np.array([1, 0, 0, 0, 1, 0, 0, 0], bool),
        "split": np.array(["train"] * 4 + ["test"] * 4, dtype=object),
        "drive": np.zeros(n, np.int64),
        "s_m": np.arange(n) * 100.0,
        "t_seen_ns": np.arange(n, dtype=np.int64),
        "t_known_ns": np.arange(n, dtype=np.int64) + 5,
        "version": np.r_[np.zeros(4), np.ones(4)].astype(np.int64),
        "standing": np.array([np.nan, 0, 0, 0, 0.9, 0.1, 0.2, 0.95]),
        "r_online": np.arange(n, dtype=float),
        "r_offline": np.array([0, 0, 0, 0, 9.0, 1, 2, 3]),
        "r_start": np.zeros(n),
        "standing_offline": np.zeros(n),
        "standing_frozen": np.zeros(n),
        "standing_final": np.zeros(n),
        "r_frozen": np.zeros(n),
        "r_final": np.zeros(n),
    }
    steps = {
        "drive": np.zeros(2, np.int64),
        "step": np.arange(2),
        "end_m": np.array([400.0, 800.0]),
        "version": np.array([0, 1]),
    }
    got = online_summary(
        scores, steps, fprs=(0.1,), stretch_m=400.0, update_every_m=400.0, frozen_after_m=400.0
    )
    assert got["test"]["offline"]["auc"] == 1.0
    assert got["test"]["online"]["auc"] == pytest.approx(2.0 / 3.0)
    assert got["first_update_m"] == {"0": 800.0}
    assert got["label_latency_s"]["p50"] == 5e-9
    assert got["gaps"] == [] and got["out_of_order_labels"] == 0


def test_standings_tied_are_ranked_by_their_raw_scores() -> None:
    """Two events both above every buffered smooth event stand at 1; their raw scores
    decide between them, and no standing's order changes."""
    standing = np.array([1.0, 1.0, 0.5, 0.25])
    raw = np.array([7.0, 9.0, 8.0, 1.0])
    got = comparable(standing, raw)
    assert got[1] > got[0] > got[2] > got[3]
    rough = np.array([False, True, False, False])
    assert rates(got, rough, (0.1,))["auc"] == 1.0  # type: ignore[index]
    assert rates(standing, rough, (0.1,))["auc"] < 1.0  # type: ignore[index]


def test_the_verdict_says_whether_learning_while_driving_beat_its_start() -> None:
    """Above the start's test AUC: helped; equal or below: did not, with the difference;
    without either AUC (one class only): no verdict."""
    helped, said = learning_verdict({"online": {"auc": 0.895}, "start": {"auc": 0.750}}) or ()
    assert helped and "0.145 above its start's, unlearned (0.750)" in said
    tie = learning_verdict({"online": {"auc": 0.8}, "start": {"auc": 0.8}})
    assert tie is not None and not tie[0] and "did not help" in tie[1] and "+0.000" in tie[1]
    assert learning_verdict({"online": None, "start": {"auc": 0.8}}) is None
    assert learning_verdict({"online": {"auc": 0.8}, "start": {"auc": None}}) is None
