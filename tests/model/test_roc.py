"""ROC curves, operating points, bootstrap intervals (Fig. 6)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import spearmanr
from sklearn.metrics import roc_auc_score

from toolkit.model.roc import (
    MIN_ROUGH_EVENTS,
    auc,
    auc_half_width,
    bootstrap,
    roc,
    small_sample_warnings,
    summarise,
    tpr_at_fpr,
)


@pytest.mark.parametrize("seed", range(4))
def test_bootstrap_equals_each_resample_curve_built_anew(seed: int) -> None:
    """The bootstrap's counted curves give, resample by resample, the AUC and operating
    points of the resample's own curve (``roc`` on the drawn events, the draws made as the
    bootstrap makes them), under heavy ties, NaN and infinite scores."""
    rng = np.random.default_rng(seed)
    n = 400
    y = rng.random(n) < 0.1
    s = np.round(rng.normal(size=n) + y, 1)
    s[rng.random(n) < 0.3] = 0.0
    s[rng.random(n) < 0.05] = np.nan
    s[rng.random(n) < 0.02] = np.inf
    rates = (0.05, 0.1, 0.2)
    aucs, tprs = bootstrap(s, y, rates, resamples=150, seed=seed)

    draw = np.random.default_rng(seed)
    pos, neg = np.flatnonzero(y), np.flatnonzero(~y)
    for b in range(150):
        idx = np.concatenate([draw.choice(pos, pos.size), draw.choice(neg, neg.size)])
        curve = roc(s[idx], y[idx])
        assert aucs[b] == pytest.approx(auc(s[idx], y[idx]), abs=1e-12)
        assert list(tprs[b]) == [tpr_at_fpr(curve, f) for f in rates]


@pytest.mark.parametrize("seed", range(5))
def test_roc_points_equal_a_brute_force_count(seed: int) -> None:
    """Every point of the curve is (FP/N, TP/P) of ``score >= threshold``, counted by hand,
    and every distinct score is a threshold (ties rounded in)."""
    rng = np.random.default_rng(seed)
    s = np.round(rng.normal(size=300), 1)
    y = rng.random(300) < 0.2
    c = roc(s, y)
    for f, t, thr in zip(c.fpr, c.tpr, c.thresholds, strict=True):
        pred = s >= thr
        assert t == (pred & y).sum() / y.sum()
        assert f == (pred & ~y).sum() / (~y).sum()
    assert set(np.unique(s)) <= set(c.thresholds[np.isfinite(c.thresholds)])


def test_tpr_at_fpr_takes_the_best_point_not_above_the_rate() -> None:
    """Scores 4 3 2 1 0 for labels P N P N N: points (0, .5) (1/3, .5) (1/3, 1) ...; at FPR
    0.2 the best TPR is 0.5 (no interpolation), at 1/3 it is 1."""
    c = roc(np.array([4.0, 3.0, 2.0, 1.0, 0.0]), np.array([True, False, True, False, False]))
    assert tpr_at_fpr(c, 0.2) == 0.5
    assert tpr_at_fpr(c, 1 / 3) == 1.0


def test_unscored_events_rank_below_every_scored_one() -> None:
    s = np.array([np.nan, 0.5, 0.2, np.nan])
    y = np.array([True, True, False, False])
    # Pairs (positive, negative): (0.5, 0.2) and (0.5, NaN) won, (NaN, 0.2) lost, (NaN, NaN)
    # tied (half): 2.5 of 4.
    assert auc(s, y) == pytest.approx(0.625)


def test_summary_intervals_and_correlation() -> None:
    """Perfectly separated scores: AUC 1 with interval [1, 1]; noisy ones: a proper interval,
    the same for the same seed; Spearman's rho as scipy's."""
    rng = np.random.default_rng(2)
    y = rng.random(400) < 0.1
    y[:2] = [True, False]
    perfect = summarise(y.astype(float), y, y.astype(float), resamples=50)
    assert perfect.auc == 1.0 and perfect.auc_ci == (1.0, 1.0)
    assert perfect.tpr_at_fpr == {"0.05": 1.0, "0.1": 1.0, "0.2": 1.0}
    s = y + rng.normal(0, 0.8, 400)
    rug = s + rng.normal(0, 1, 400)
    a = summarise(s, y, rug, resamples=200, seed=4)
    b = summarise(s, y, rug, resamples=200, seed=4)
    assert a.auc_ci == b.auc_ci and a.auc_ci[0] < a.auc < a.auc_ci[1]
    assert a.spearman == pytest.approx(spearmanr(s, rug).statistic)
    tprs = a.to_json()["tpr_at_fpr"]
    assert isinstance(tprs, dict) and tprs.keys() == {"0.05", "0.1", "0.2"}


def heavy_ties(seed: int, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Scores (n,) that are exactly 0 for about 95 % of the events, rough ones among them,
    a few unscored (NaN), and labels (n,) with about 5 % rough: the shape of a method that
    sees no evidence on most of the route."""
    rng = np.random.default_rng(seed)
    y = rng.random(n) < 0.05
    s = np.where(rng.random(n) < 0.95, 0.0, rng.random(n))
    s[y] = np.where(rng.random(y.sum()) < 0.5, 0.0, rng.random(y.sum()) + 0.3)
    s[rng.random(n) < 0.02] = np.nan
    y[:2] = [True, False]
    return s, y


@pytest.mark.parametrize("seed", range(3))
def test_the_curve_encloses_the_auc_under_heavy_ties(seed: int) -> None:
    """Joined by straight lines, the curve's points enclose exactly the AUC (ties counted
    half), however many events tie at 0: a tie is one diagonal segment of the curve."""
    s, y = heavy_ties(seed)
    summary = summarise(s, y, np.abs(np.nan_to_num(s)), resamples=20)
    c = summary.curve
    assert c.fpr[0] == 0.0 and c.tpr[0] == 0.0 and c.fpr[-1] == 1.0 and c.tpr[-1] == 1.0
    assert float(np.trapezoid(c.tpr, c.fpr)) == pytest.approx(summary.auc, abs=1e-9)
    assert float(np.trapezoid(c.tpr, c.fpr)) == pytest.approx(
        roc_auc_score(y, np.where(np.isnan(s), -1.0, s)), abs=1e-9
    )


def test_zero_and_unscored_shares() -> None:
    """Scores 0 0 0 .5 NaN 2 for labels P N N P P N: of the 5 scored events 3 score 0, of
    the 2 scored rough ones 1; 1 of 6 events and 1 of 3 rough ones is unscored. An exact
    0 only: -0.0 counts, 1e-300 does not."""
    s = np.array([0.0, -0.0, 0.0, 0.5, np.nan, 2.0])
    y = np.array([True, False, False, True, True, False])
    r = summarise(s, y, np.arange(6.0), resamples=5)
    assert r.zero_share == pytest.approx(3 / 5) and r.zero_share_rough == pytest.approx(1 / 2)
    assert r.unscored_share == pytest.approx(1 / 6)
    assert r.unscored_share_rough == pytest.approx(1 / 3)
    doc = r.to_json()
    assert doc["zero_share"] == 0.6 and doc["zero_share_rough"] == 0.5
    assert doc["unscored_share"] == round(1 / 6, 6)
    assert doc["unscored_share_rough"] == round(1 / 3, 6)
    tiny = summarise(
        np.array([1e-300, 0.0, 1.0]), np.array([True, False, True]), np.arange(3.0), resamples=5
    )
    assert tiny.zero_share == pytest.approx(1 / 3) and tiny.zero_share_rough == 0.0


def test_shares_of_a_method_that_scores_nothing_are_undefined_not_zero() -> None:
    """Every event unscored: no scored event to take a share of, so the zero shares are
    NaN (null in JSON), and the unscored shares 1."""
    y = np.array([True, False, False])
    r = summarise(np.full(3, np.nan), y, np.ones(3), resamples=5)
    assert np.isnan(r.zero_share) and np.isnan(r.zero_share_rough)
    assert r.unscored_share == 1.0 and r.unscored_share_rough == 1.0
    assert r.to_json()["zero_share"] is None


def test_small_sample_warnings_name_each_small_split_in_order() -> None:
    """A line for each split with fewer than MIN_ROUGH_EVENTS (30) rough events, naming the
    split, its count, the threshold and the AUC difference it cannot resolve; none for 30
    or more; a split without a rough event says it has no ROC."""
    assert MIN_ROUGH_EVENTS == 30
    assert small_sample_warnings({"train": 400, "test": 30}) == []
    lines = small_sample_warnings({"train": 12, "validation": 300, "test": 6, "extra": 0})
    assert len(lines) == 3
    assert lines[0].startswith("the train split has 12 rough events (fewer than 30)")
    assert lines[1].startswith("the test split has 6 rough events (fewer than 30)")
    assert f"~{auc_half_width(6):.2f}" in lines[1] and "noise" in lines[1]
    assert lines[2] == "the extra split has no rough event: no ROC curve or AUC on it"
    assert small_sample_warnings({"test": 1})[0].startswith("the test split has 1 rough event ")
    assert small_sample_warnings({"test": 40}, minimum=50) != []


def test_auc_half_width_is_about_the_bootstrap_interval() -> None:
    """Hanley & McNeil's width: +-0.10 at 30 rough events (why 30 is the threshold), shrinking
    as 1/sqrt(P); the stratified bootstrap of 30 rough among 3000 smooth binormal scores at
    AUC 0.75 gives an interval of about that half-width (a little narrower)."""
    assert auc_half_width(30) == pytest.approx(0.10, abs=0.005)
    assert auc_half_width(120) == pytest.approx(auc_half_width(30) / 2)
    assert auc_half_width(0) == float("inf")
    rng = np.random.default_rng(3)
    y = np.zeros(3030, bool)
    y[:30] = True
    s = rng.normal(size=y.size) + 0.954 * y  # binormal, AUC = Phi(0.954 / sqrt 2) = 0.75
    r = summarise(s, y, s, resamples=200, seed=1)
    half = (r.auc_ci[1] - r.auc_ci[0]) / 2
    assert 0.6 * auc_half_width(30) < half < 1.3 * auc_half_width(30)


def test_the_report_says_what_a_reader_must_know_of_the_learned_row() -> None:
    """A model flagging nothing, a ranking mostly tied at zero, and an oracle below the
    learned model each get a line; a sound run gets none."""
    from toolkit.model.roc import caveats, summarise

    rng = np.random.default_rng(4)
    y = np.zeros(2000, bool)
    y[:40] = True
    good = np.where(y, rng.normal(2, 1, y.size), rng.normal(0, 1, y.size))
    tied = np.where(rng.random(y.size) < 0.8, 0.0, good)
    worse = good + rng.normal(0, 2, y.size)
    s_good = summarise(good, y, good, resamples=20)
    s_tied = summarise(tied, y, good, resamples=20)
    s_worse = summarise(worse, y, good, resamples=20)
    assert caveats(s_good, s_good, flagged_test=12, objective=0.4) == []
    (nothing,) = caveats(s_good, None, flagged_test=0, objective=0.0)
    assert "calling nothing rough" in nothing
    assert caveats(s_good, None, flagged_test=0, objective=0.3) == [
        "the learned model flags no test event rough at its threshold mu"
    ]
    (zeros,) = caveats(s_tied, None, flagged_test=5, objective=0.3)
    assert zeros.startswith(f"{100 * s_tied.zero_share:.0f} % of the test events score exactly 0")
    (below,) = caveats(s_good, s_worse, flagged_test=5, objective=0.3)
    assert below.startswith("the oracle (the model on true heights) ranks below the learned model")
    assert "40 rough test events" in below
