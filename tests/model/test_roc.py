"""ROC curves, operating points, bootstrap intervals (Fig. 6)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import spearmanr

from toolkit.model.roc import auc, roc, summarise, tpr_at_fpr


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
    assert a.to_json()["tpr_at_fpr"].keys() == {"0.05", "0.1", "0.2"}
