"""ROC curves with confidence intervals and rank correlation (sect. 7.1, Fig. 6).

The curve itself is scikit-learn's (``sklearn.metrics.roc_curve``, every threshold kept);
this module adds what the report states about it:

- ``tpr_at_fpr``: the largest true-positive rate among the curve's points whose
  false-positive rate is at most the target. No interpolation between points: a classifier
  with one threshold cannot operate between two of its points (a randomised mix could, but
  that is not what a vehicle runs).
- Bootstrap confidence intervals over events: resampling positives and negatives
  separately (a *stratified* bootstrap), so every resample keeps the split's count of each
  class (with 0.4 % positives, a plain resample of a few thousand events can draw none, and
  the curve is then undefined), with a fixed seed; percentile intervals.
- Spearman's rank correlation between a score and the ruggedness (``scipy.stats``).
- Events a method could not score (NaN, e.g. no point of the closest laser under a tyre)
  rank below every scored event: the method says nothing about them, as a vehicle would
  not slow for them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.stats import spearmanr
from sklearn.metrics import auc as sk_auc
from sklearn.metrics import roc_auc_score, roc_curve

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

DEFAULT_FPR_POINTS = (0.05, 0.1, 0.2)


@dataclass(frozen=True)
class RocCurve:
    """The curve's points (K,), from (0, 0) to (1, 1), and the threshold of each."""

    fpr: FloatArray
    tpr: FloatArray
    thresholds: FloatArray


def _finite_scores(scores: FloatArray) -> FloatArray:
    """Scores sklearn accepts, in the same order: NaN (not scored) below every finite score,
    -inf and +inf just beyond the finite range."""
    s = np.asarray(scores, np.float64)
    if np.isfinite(s).all():
        return s
    finite = s[np.isfinite(s)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    span = hi - lo + 1.0
    s = np.where(np.isposinf(s), hi + span, s)
    s = np.where(np.isneginf(s), lo - span, s)
    return np.where(np.isnan(s), lo - 2.0 * span, s)


def roc(scores: FloatArray, labels: BoolArray) -> RocCurve:
    """The ROC curve of ``scores`` (E,) against ``labels`` (E,): every distinct score a
    threshold (``score >= threshold`` predicts positive)."""
    fpr, tpr, thr = roc_curve(
        np.asarray(labels, bool), _finite_scores(scores), drop_intermediate=False
    )
    return RocCurve(fpr.astype(np.float64), tpr.astype(np.float64), thr.astype(np.float64))


def tpr_at_fpr(curve: RocCurve, fpr: float) -> float:
    """The largest TPR among the points with FPR at most ``fpr`` (module docstring)."""
    ok = curve.fpr <= fpr + 1e-12
    return float(curve.tpr[ok].max()) if ok.any() else 0.0


def auc(scores: FloatArray, labels: BoolArray) -> float:
    return float(roc_auc_score(np.asarray(labels, bool), _finite_scores(scores)))


@dataclass(frozen=True)
class RocSummary:
    """What the report states of one method on one split."""

    auc: float
    tpr_at_fpr: dict[str, float]
    auc_ci: tuple[float, float]
    tpr_at_fpr_ci: dict[str, tuple[float, float]]
    spearman: float
    events: int
    positives: int
    curve: RocCurve = field(repr=False)

    def to_json(self) -> dict[str, object]:
        def clean(v: float) -> float | None:
            return None if not math.isfinite(v) else round(v, 6)

        return {
            "auc": clean(self.auc),
            "tpr_at_fpr": {k: clean(v) for k, v in self.tpr_at_fpr.items()},
            "auc_ci95": [clean(v) for v in self.auc_ci],
            "tpr_at_fpr_ci95": {
                k: [clean(a), clean(b)] for k, (a, b) in self.tpr_at_fpr_ci.items()
            },
            "spearman_vs_ruggedness": clean(self.spearman),
            "events": self.events,
            "positives": self.positives,
        }


def fpr_key(fpr: float) -> str:
    """The key summary.json uses for a false-positive rate: ``"0.05"``, ``"0.1"``, ``"0.2"``."""
    return repr(float(fpr))


def summarise(
    scores: FloatArray,
    labels: BoolArray,
    ruggedness: FloatArray,
    fpr_points: Sequence[float] = DEFAULT_FPR_POINTS,
    *,
    resamples: int = 1000,
    seed: int = 0,
    level: float = 0.95,
) -> RocSummary:
    """AUC and TPR at each FPR with stratified-bootstrap intervals, and Spearman's rho of
    the scores against the ruggedness. Needs at least one event of each class."""
    s = np.asarray(scores, np.float64)
    y = np.asarray(labels, bool)
    curve = roc(s, y)
    keys = [fpr_key(f) for f in fpr_points]
    point = {k: tpr_at_fpr(curve, f) for k, f in zip(keys, fpr_points, strict=True)}
    rng = np.random.default_rng(seed)
    pos, neg = np.flatnonzero(y), np.flatnonzero(~y)
    aucs = np.empty(resamples)
    tprs = np.empty((resamples, len(keys)))
    for b in range(resamples):
        idx = np.concatenate([rng.choice(pos, pos.size), rng.choice(neg, neg.size)])
        c = roc(s[idx], y[idx])
        aucs[b] = float(sk_auc(c.fpr, c.tpr))
        tprs[b] = [tpr_at_fpr(c, f) for f in fpr_points]
    lo, hi = 100 * (1 - level) / 2, 100 * (1 + level) / 2

    def interval(v: FloatArray) -> tuple[float, float]:
        return float(np.percentile(v, lo)), float(np.percentile(v, hi))

    finite = np.isfinite(s)
    rho = (
        float(spearmanr(s[finite], np.asarray(ruggedness)[finite]).statistic)
        if finite.sum() > 2
        else float("nan")
    )
    return RocSummary(
        auc=auc(s, y),
        tpr_at_fpr=point,
        auc_ci=interval(aucs),
        tpr_at_fpr_ci={k: interval(tprs[:, i]) for i, k in enumerate(keys)},
        spearman=rho,
        events=int(y.size),
        positives=int(y.sum()),
        curve=curve,
    )


__all__ = [
    "DEFAULT_FPR_POINTS",
    "RocCurve",
    "RocSummary",
    "auc",
    "fpr_key",
    "roc",
    "summarise",
    "tpr_at_fpr",
]
