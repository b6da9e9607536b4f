"""Beyond the paper: a gradient-boosted classifier on the same tyre patches (issue 26).

Stavens and Thrun score a patch with a form they built by hand: every pair's height
difference, less penalties for the time between the scans, their distance and the roll and
pitch rates (eq. 4), the omega largest pair scores weighted by upsilon (eqs. 2-3), the two
tyres combined by a signed power (eq. 5); only its 14 numbers are learned (sect. 6). This
module is *not* in the paper. It asks how far that form is from what the same points allow: a
modern, flexible learner (scikit-learn's ``HistGradientBoostingClassifier``) is given
summaries of exactly the points eqs. (2)-(7) see, and the same labels and training split. Its
test-split ROC is one more row of the evaluation: a gap above the paper's model says the
hand-built form leaves information in the points unused; no gap says the form is as good as
a generic learner gets from them.

**Features** (:func:`patch_features`). Per tyre, from its points alone:

- per laser, in the order of the ``lasers`` given (so every split has the same columns, even
  where a laser saw nothing): ``dz_cell[l]``, the largest ``|z_i - z_j|`` between two of that
  laser's points in the same ``cell_m`` grid cell (the race's obstacle test's pairs,
  :mod:`toolkit.model.baseline`); ``dz_near[l]``, the same over pairs within ``cell_m`` of
  each other in x-y (no grid edges); ``count[l]``, its points; ``tau_span[l]``, the time
  between its first and last point;
- over all points, whatever the laser: ``dz_cell`` and ``dz_near`` (pairs of two lasers
  included: where the lasers' pose errors disagree), ``dtau_at_dz_cell`` (the time between
  the two scans of that largest same-cell difference: a large one seconds apart may be pose
  drift, eq. 4's time term), ``count``, ``tau_span``, ``gamma_abs_max`` and ``psi_abs_max``
  (the largest roll and pitch rates when the points were seen, eq. 4's last terms),
  ``z_std`` and ``z_range``;
- with the events' times (``event_time_s``): ``lead_min`` and ``lead_max``, the time from
  the freshest and the oldest point to the event.

A height difference with no pair to take it from (no points, or none in one cell) is NaN,
"not seen", not 0, which would claim flat ground; ``HistGradientBoostingClassifier`` learns
where missing values go at each split. Absolute positions and times are never features
(they would identify a place or a moment of the log, not roughness).

**Two tyres.** Each tyre feature enters the event twice: its larger value over the two tyres
(``.tyre_max``, NaN only when both tyres lack it) and its smaller (``.tyre_min``, NaN when
either lacks it). That pair is the two values without their order: lossless but for which
tyre was which, which eq. (5) also discards (it is symmetric in left and right, as a shock
is). Side-by-side left and right columns would make the learner find every rule twice with
the few rough events there are (~0.4 %); a maximum alone would lose whether both tyres or one
met the bump.

**No test event is seen.** Each event's features are a function of its own points only (no
statistic across events: no scaling, no imputation, no binning here), so computing them for
all events at once leaks nothing; :func:`train_and_score` passes the learner the training
rows alone (its feature binning is fitted in ``fit``, on those rows) and only then scores
every event.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import sklearn
from numpy.typing import NDArray
from sklearn.ensemble import HistGradientBoostingClassifier
from threadpoolctl import threadpool_limits

from toolkit.arrays import BoolArray, FloatArray
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import CHUNK_GROUPS

#: OpenMP threads of the fit and the scores: one, so that the sums of gradients are added in
#: one order whatever the machine (bit-for-bit the same scores on 2 cores or 64).
THREADS = 1

#: Per-laser features of a tyre, in column order (see the module docstring).
LASER_FEATURES = ("dz_cell", "dz_near", "count", "tau_span")
#: Features of a tyre over all its points, in column order.
ALL_FEATURES = (
    "dz_cell",
    "dz_near",
    "dtau_at_dz_cell",
    "count",
    "tau_span",
    "gamma_abs_max",
    "psi_abs_max",
    "z_std",
    "z_range",
)
#: With the events' times.
LEAD_FEATURES = ("lead_min", "lead_max")


def _tyre_feature_names(lasers: Sequence[str], lead: bool) -> list[str]:
    names = [f"{f}[{laser}]" for laser in lasers for f in LASER_FEATURES]
    names += list(ALL_FEATURES)
    if lead:
        names += list(LEAD_FEATURES)
    return names


def _max_or_nan(values: FloatArray, mask: BoolArray) -> FloatArray:
    """(rows,) the largest of ``values`` (rows, k) where ``mask``, NaN where none is."""
    out: FloatArray = np.max(np.where(mask, values, -np.inf), axis=1, initial=-np.inf)
    out[np.isneginf(out)] = np.nan
    return out


def _span_or_nan(values: FloatArray, mask: BoolArray) -> FloatArray:
    """(rows,) max - min of ``values`` (rows, k) where ``mask``, NaN where none is."""
    hi = np.max(np.where(mask, values, -np.inf), axis=1, initial=-np.inf)
    lo = np.min(np.where(mask, values, np.inf), axis=1, initial=np.inf)
    out: FloatArray = hi - lo
    out[~mask.any(axis=1)] = np.nan
    return out


def _tyre_features(
    patches: TyrePatches,
    column: NDArray[np.int64],
    n_lasers: int,
    cell_m: float,
    event_time_s: FloatArray | None,
) -> FloatArray:
    """(G, F_tyre) the per-tyre features (column order of :func:`_tyre_feature_names`).

    ``column``: (len(patches.lasers),) each of the patches' lasers' index in the caller's
    ``lasers``, -1 for one not listed (its points count only in the all-laser features)."""
    G, n = patches.groups, patches.n_max
    n_lead = 0 if event_time_s is None else len(LEAD_FEATURES)
    n_feat = len(LASER_FEATURES) * n_lasers + len(ALL_FEATURES) + n_lead
    out = np.empty((G, n_feat), np.float64)
    r, c = np.tril_indices(n, -1)
    # Laser column of every point; -2 in the padding, so that it matches no listed laser.
    to_col = np.append(column, -2)  # index -1 (the padding) -> -2
    lab_all = to_col[patches.laser.astype(np.int64)]
    # A chunk of patches at a time: about a dozen (chunk, n (n - 1) / 2) temporaries, 3 MB
    # each at 40 points, whatever the number of events.
    for lo in range(0, G, CHUNK_GROUPS):
        rows = slice(lo, min(lo + CHUNK_GROUPS, G))
        x, y, z = patches.x[rows], patches.y[rows], patches.z[rows]
        tau, valid, lab = patches.tau[rows], patches.valid[rows], lab_all[rows]
        pair = valid[:, r] & valid[:, c]
        dz = np.abs(z[:, r] - z[:, c])
        cx, cy = np.floor(x / cell_m), np.floor(y / cell_m)
        same = pair & (cx[:, r] == cx[:, c]) & (cy[:, r] == cy[:, c])
        near = pair & ((x[:, r] - x[:, c]) ** 2 + (y[:, r] - y[:, c]) ** 2 <= cell_m**2)
        same_laser = lab[:, r] == lab[:, c]
        lab_r = lab[:, r]
        k = 0
        for li in range(n_lasers):
            mine = same_laser & (lab_r == li)
            on = valid & (lab == li)
            out[rows, k] = _max_or_nan(dz, same & mine)
            out[rows, k + 1] = _max_or_nan(dz, near & mine)
            out[rows, k + 2] = np.count_nonzero(on, axis=1)
            out[rows, k + 3] = _span_or_nan(tau, on)
            k += len(LASER_FEATURES)
        dz_same = np.where(same, dz, -np.inf)
        at = np.argmax(dz_same, axis=1) if r.size else np.zeros(valid.shape[0], np.int64)
        has_pair = same.any(axis=1)
        out[rows, k] = _max_or_nan(dz, same)
        out[rows, k + 1] = _max_or_nan(dz, near)
        i = np.arange(valid.shape[0])
        dtau_at = np.abs(tau[i, r[at]] - tau[i, c[at]]) if r.size else np.zeros(i.size)
        out[rows, k + 2] = np.where(has_pair, dtau_at, np.nan)
        count = np.count_nonzero(valid, axis=1)
        out[rows, k + 3] = count
        out[rows, k + 4] = _span_or_nan(tau, valid)
        out[rows, k + 5] = _max_or_nan(np.abs(patches.gamma[rows]), valid)
        out[rows, k + 6] = _max_or_nan(np.abs(patches.psi[rows]), valid)
        safe = np.maximum(count, 1)
        mean = np.where(valid, z, 0.0).sum(axis=1) / safe
        var = np.where(valid, (z - mean[:, None]) ** 2, 0.0).sum(axis=1) / safe
        out[rows, k + 7] = np.where(count > 0, np.sqrt(var), np.nan)
        out[rows, k + 8] = _span_or_nan(z, valid)
        if event_time_s is not None:
            g = np.arange(rows.start, rows.stop)
            t_event = event_time_s[g // 2]
            newest = np.max(np.where(valid, tau, -np.inf), axis=1, initial=-np.inf)
            oldest = np.min(np.where(valid, tau, np.inf), axis=1, initial=np.inf)
            none = count == 0
            out[rows, k + 9] = np.where(none, np.nan, t_event - newest)
            out[rows, k + 10] = np.where(none, np.nan, t_event - oldest)
    return out


def patch_features(
    patches: TyrePatches,
    lasers: Sequence[str],
    cell_m: float = 0.25,
    *,
    event_time_s: FloatArray | None = None,
) -> tuple[FloatArray, tuple[str, ...]]:
    """Per-event features of the points under both rear tyres (module docstring).

    Args:
        patches: E events' patches (G = 2 E groups).
        lasers: the per-laser columns, in this order (use the same list for every split; a
            laser of ``patches`` not listed enters only the all-laser features).
        cell_m: the grid cell of ``dz_cell`` and the radius of ``dz_near``, m (the race's
            test's 25 cm by default, :class:`toolkit.model.baseline.BaselineParams`).
        event_time_s: (E,) each event's time on the points' ``tau`` clock, s (e.g. the
            events' ``t_start_ns`` / 1e9), for the lead-time features; None omits them.

    Returns:
        features: (E, F) float64, NaN where a feature has nothing to take it from.
        names: (F,) the column names: ``<tyre feature>.tyre_max`` for all tyre features, then
            ``<tyre feature>.tyre_min`` in the same order.

    Vectorised a chunk of :data:`toolkit.model.roughness.CHUNK_GROUPS` patches at a time over
    the pairs ``np.tril_indices(n_max, -1)`` (memory bounded by the chunk, not by E).
    """
    lasers = list(lasers)
    if len(set(lasers)) != len(lasers):
        raise ValueError(f"lasers must be distinct: {lasers}")
    if cell_m <= 0:
        raise ValueError(f"cell_m must be positive, not {cell_m}")
    E = patches.events
    if event_time_s is not None:
        event_time_s = np.asarray(event_time_s, np.float64)
        if event_time_s.shape != (E,):
            raise ValueError(f"event_time_s has shape {event_time_s.shape}, not ({E},)")
    index = {name: i for i, name in enumerate(lasers)}
    column = np.array([index.get(name, -1) for name in patches.lasers], np.int64)
    tyre = _tyre_features(patches, column, len(lasers), cell_m, event_time_s)
    tyre_names = _tyre_feature_names(lasers, event_time_s is not None)
    left, right = tyre[0 : 2 * E : 2], tyre[1 : 2 * E : 2]
    # fmax ignores a NaN (the tyre that has the feature), minimum keeps it: together the
    # unordered pair of the two values, missing ones included.
    features = np.concatenate([np.fmax(left, right), np.minimum(left, right)], axis=1)
    names = tuple(f"{n}.tyre_max" for n in tyre_names) + tuple(f"{n}.tyre_min" for n in tyre_names)
    return np.ascontiguousarray(features, np.float64), names


@dataclass(frozen=True)
class BoostedConfig:
    """The learner's settings, fixed a priori (never tuned on the test split).

    - ``max_iter`` 200 trees at ``learning_rate`` 0.05: a slow rate with enough trees to use
      it; with early stopping off, all of them are grown.
    - ``max_leaf_nodes`` 15 (scikit-learn's default 31 halved) and ``min_samples_leaf`` 20:
      small trees, since a training split holds only some tens of rough events (~0.4 %).
    - ``l2_regularization`` 1.0: shrinks leaves backed by few events' gradients.
    - ``class_weight`` "balanced": each rough event weighs as much as ~250 smooth ones, so
      the splits separate rough from smooth instead of refining the base rate, and the sums
      of hessians in a leaf (~p(1 - p) per event, ~0.004 unweighted) are not swamped by
      ``l2_regularization`` and ``min_hessian_to_split``. The weighted model's
      probabilities are not calibrated; the evaluation only ranks events by the score.
    - ``early_stopping`` False: scikit-learn's "auto" turns it on above 10,000 rows and
      would hold back 10 % of the training split (and of its few rough events) to
      validate; off, every training event is fitted and nothing random is drawn.
    - ``random_state`` 0: fixed, for whatever scikit-learn draws (binning subsample above
      200,000 rows; a validation split if early stopping is turned on).
    """

    max_iter: int = 200
    learning_rate: float = 0.05
    max_leaf_nodes: int = 15
    min_samples_leaf: int = 20
    l2_regularization: float = 1.0
    class_weight: str | None = "balanced"
    early_stopping: bool = False
    random_state: int = 0

    def classifier(self) -> Any:
        """An unfitted ``HistGradientBoostingClassifier`` with these settings."""
        return HistGradientBoostingClassifier(
            loss="log_loss",
            max_iter=self.max_iter,
            learning_rate=self.learning_rate,
            max_leaf_nodes=self.max_leaf_nodes,
            min_samples_leaf=self.min_samples_leaf,
            l2_regularization=self.l2_regularization,
            class_weight=self.class_weight,
            early_stopping=self.early_stopping,
            random_state=self.random_state,
        )


def train_and_score(
    features: FloatArray,
    rough: BoolArray,
    train_mask: BoolArray,
    config: BoostedConfig = BoostedConfig(),  # noqa: B008 (frozen: shared safely)
) -> tuple[FloatArray, dict[str, Any]]:
    """Fit the learner on the training events alone, then score every event.

    Args:
        features: (E, F) from :func:`patch_features`.
        rough: (E,) bool, the events' labels.
        train_mask: (E,) bool, True for the training split. Only these rows (features and
            labels) reach ``fit``; the other rows are used only after it, to be scored.
        config: the learner's settings.

    Returns:
        scores: (E,) float64, the fitted model's decision function (log-odds of rough under
            the class weighting: higher is rougher; no saturation at 0 or 1, so no ties made
            by rounding) for every event, training and test.
        summary: JSON-ready facts of the fit (settings, rows, rough rows, iterations,
            scikit-learn's version, threads, features used and left out: a feature no
            training event has is left out).

    ValueError if the shapes disagree or the training split lacks a class.
    """
    X = np.asarray(features, np.float64)
    y = np.asarray(rough, bool)
    train = np.asarray(train_mask, bool)
    if X.ndim != 2 or y.shape != (X.shape[0],) or train.shape != (X.shape[0],):
        raise ValueError(
            f"features {X.shape}, rough {y.shape} and train_mask {train.shape} disagree"
        )
    X_train, y_train = X[train], y[train]  # copies: nothing of another row is reachable
    n_rough = int(np.count_nonzero(y_train))
    if n_rough == 0 or n_rough == y_train.size:
        raise ValueError(
            f"the training split needs rough and smooth events ({n_rough} of {y_train.size} rough)"
        )
    # A feature no training event has (a laser none of the model's points came from: with
    # the nearest laser first, the far lasers' columns) tells the trees nothing, and
    # scikit-learn's binning cannot bin a column without one finite value: left out.
    seen = np.isfinite(X_train).any(axis=0)
    X, X_train = X[:, seen], X_train[:, seen]
    model = config.classifier()
    with threadpool_limits(limits=THREADS, user_api="openmp"):
        model.fit(X_train, y_train)
        scores = np.asarray(model.decision_function(X), np.float64)
    summary: dict[str, Any] = {
        "learner": "sklearn.ensemble.HistGradientBoostingClassifier",
        "sklearn_version": sklearn.__version__,
        "config": asdict(config),
        "threads": THREADS,
        "features": int(X.shape[1]),
        "features_left_out": int(np.count_nonzero(~seen)),
        "train_events": int(y_train.size),
        "train_rough": n_rough,
        "iterations": int(model.n_iter_),
    }
    return scores, summary


__all__ = [
    "ALL_FEATURES",
    "LASER_FEATURES",
    "LEAD_FEATURES",
    "BoostedConfig",
    "patch_features",
    "train_and_score",
]
