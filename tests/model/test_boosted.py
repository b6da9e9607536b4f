"""Beyond the paper (issue 26): the gradient-boosted learner on the patches' features."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.metrics import roc_auc_score

from toolkit.model.boosted import (
    ALL_FEATURES,
    LASER_FEATURES,
    LEAD_FEATURES,
    BoostedConfig,
    patch_features,
    train_and_score,
)
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import CHUNK_GROUPS

#: One point: (x, y, z, tau, gamma, psi, laser index into the patches' lasers).
LPoint = tuple[float, float, float, float, float, float, int]

LASERS = ("/laser/a", "/laser/b", "/laser/c")


def _patches(groups: Sequence[Sequence[LPoint]], lasers: Sequence[str] = LASERS) -> TyrePatches:
    """TyrePatches straight from numpy: ``groups[2 e + w]`` the points of event e's wheel w."""
    G = len(groups)
    n = max(2, max((len(g) for g in groups), default=0))
    cols = np.zeros((6, G, n))
    laser = np.full((G, n), -1, np.int16)
    valid = np.zeros((G, n), bool)
    for g, pts in enumerate(groups):
        for j, p in enumerate(pts):
            cols[:, g, j] = p[:6]
            laser[g, j] = p[6]
            valid[g, j] = True
    x, y, z, tau, gamma, psi = cols
    count = valid.sum(axis=1).astype(np.int64)
    return TyrePatches(x, y, z, tau, gamma, psi, valid, count, laser, tuple(sorted(lasers)))


def _random(rng: np.random.Generator, events: int, n: int, n_lasers: int = 3) -> TyrePatches:
    """Dense random patches (G = 2 events, n points each, some padding), vectorised."""
    G = 2 * events
    count = rng.integers(0, n + 1, G)
    valid = np.arange(n)[None, :] < count[:, None]
    laser = np.where(valid, rng.integers(0, n_lasers, (G, n)), -1).astype(np.int16)

    def col(v: np.ndarray) -> np.ndarray:
        return np.where(valid, v, 0.0)

    return TyrePatches(
        x=col(rng.uniform(0, 1.4, (G, n))),
        y=col(rng.uniform(-0.3, 0.3, (G, n))),
        z=col(rng.normal(0, 0.05, (G, n))),
        tau=col(1000.0 + rng.uniform(0, 3, (G, n))),
        gamma=col(rng.normal(0, 0.1, (G, n))),
        psi=col(rng.normal(0, 0.1, (G, n))),
        valid=valid,
        count=count.astype(np.int64),
        laser=laser,
        lasers=tuple(f"/laser/{chr(97 + i)}" for i in range(n_lasers)),
    )


def _col(names: tuple[str, ...], name: str) -> int:
    return names.index(name)


def test_names_and_shape_follow_the_lasers_given() -> None:
    p = _patches([[(0.1, 0.1, 0.0, 5.0, 0.0, 0.0, 0)], []], lasers=("/laser/a",))
    lasers = ["/laser/z", "/laser/a"]  # any order, and one the patches never saw
    f, names = patch_features(p, lasers)
    tyre = [f"{k}[{laser}]" for laser in lasers for k in LASER_FEATURES] + list(ALL_FEATURES)
    assert names == tuple(f"{n}.tyre_max" for n in tyre) + tuple(f"{n}.tyre_min" for n in tyre)
    assert f.shape == (1, len(names)) and f.dtype == np.float64
    f2, names2 = patch_features(p, lasers, event_time_s=np.array([6.0]))
    assert names2 == tuple(f"{n}.tyre_max" for n in tyre + list(LEAD_FEATURES)) + tuple(
        f"{n}.tyre_min" for n in tyre + list(LEAD_FEATURES)
    )
    assert f2.shape == (1, len(names2))


def test_a_planted_step_shows_in_its_lasers_dz_and_an_absent_laser_is_nan() -> None:
    """Laser b sees a 30 cm step in one 25 cm cell (x 0.10 and 0.12); laser a sees flat
    ground in another cell; laser c saw nothing. The other tyre has no points."""
    left = [
        (0.10, 0.10, 0.00, 5.0, 0.0, 0.0, 1),
        (0.12, 0.10, 0.30, 5.1, 0.0, 0.0, 1),
        (0.60, 0.10, 0.01, 5.2, 0.2, -0.4, 0),
        (0.62, 0.10, 0.02, 5.6, 0.0, 0.0, 0),
    ]
    f, names = patch_features(_patches([left, []]), LASERS)
    row = dict(zip(names, f[0], strict=True))
    assert row["dz_cell[/laser/b].tyre_max"] == pytest.approx(0.30)
    assert row["dz_near[/laser/b].tyre_max"] == pytest.approx(0.30)
    assert row["dz_cell[/laser/a].tyre_max"] == pytest.approx(0.01)
    assert row["dz_cell.tyre_max"] == pytest.approx(0.30)
    assert row["dtau_at_dz_cell.tyre_max"] == pytest.approx(0.1)
    assert row["count[/laser/a].tyre_max"] == 2 and row["count[/laser/c].tyre_max"] == 0
    assert row["tau_span[/laser/a].tyre_max"] == pytest.approx(0.4)
    assert row["tau_span.tyre_max"] == pytest.approx(0.6)
    assert row["gamma_abs_max.tyre_max"] == pytest.approx(0.2)
    assert row["psi_abs_max.tyre_max"] == pytest.approx(0.4)
    assert row["z_range.tyre_max"] == pytest.approx(0.30)
    assert row["z_std.tyre_max"] == pytest.approx(np.std([0.0, 0.3, 0.01, 0.02]))
    for k in ("dz_cell", "dz_near", "tau_span"):
        assert math.isnan(row[f"{k}[/laser/c].tyre_max"])  # laser c: no points
        assert math.isnan(row[f"{k}[/laser/a].tyre_min"])  # the right tyre: no points
    assert row["count.tyre_max"] == 4 and row["count.tyre_min"] == 0


def test_cell_and_near_pairs_differ_across_a_cell_edge() -> None:
    """x = 0.24 and 0.26: different cells (no dz_cell pair) but 2 cm apart (a dz_near one)."""
    pts = [(0.24, 0.1, 0.0, 5.0, 0.0, 0.0, 0), (0.26, 0.1, 0.2, 5.0, 0.0, 0.0, 0)]
    f, names = patch_features(_patches([pts, pts]), LASERS)
    row = dict(zip(names, f[0], strict=True))
    assert math.isnan(row["dz_cell[/laser/a].tyre_max"]) and math.isnan(row["dz_cell.tyre_min"])
    assert math.isnan(row["dtau_at_dz_cell.tyre_max"])
    assert row["dz_near[/laser/a].tyre_min"] == pytest.approx(0.2)


def test_two_tyres_enter_as_their_larger_and_smaller_value() -> None:
    a = [(0.1, 0.1, 0.0, 5.0, 0.0, 0.0, 0), (0.12, 0.1, 0.05, 5.0, 0.0, 0.0, 0)]
    b = [(0.1, 0.1, 0.0, 5.0, 0.0, 0.0, 0), (0.12, 0.1, 0.20, 5.0, 0.0, 0.0, 0)]
    f, names = patch_features(_patches([a, b, b, a]), LASERS)
    i, j = _col(names, "dz_cell[/laser/a].tyre_max"), _col(names, "dz_cell[/laser/a].tyre_min")
    np.testing.assert_allclose(f[:, [i, j]], [[0.20, 0.05], [0.20, 0.05]])  # no left/right
    np.testing.assert_array_equal(f[0], f[1])


def test_a_laser_not_listed_counts_only_in_the_all_laser_features() -> None:
    pts = [(0.1, 0.1, 0.0, 5.0, 0.0, 0.0, 2), (0.12, 0.1, 0.3, 5.0, 0.0, 0.0, 2)]
    f, names = patch_features(_patches([pts, []]), LASERS[:2])
    row = dict(zip(names, f[0], strict=True))
    assert row["dz_cell.tyre_max"] == pytest.approx(0.3) and row["count.tyre_max"] == 2
    assert row["count[/laser/a].tyre_max"] == row["count[/laser/b].tyre_max"] == 0


def test_lead_times_count_from_the_event() -> None:
    pts = [(0.1, 0.1, 0.0, 5.0, 0.0, 0.0, 0), (0.5, 0.1, 0.0, 6.5, 0.0, 0.0, 1)]
    f, names = patch_features(_patches([pts, pts[:1]]), LASERS, event_time_s=np.array([7.0]))
    row = dict(zip(names, f[0], strict=True))
    assert row["lead_min.tyre_max"] == pytest.approx(2.0)  # right tyre: freshest at 5.0
    assert row["lead_min.tyre_min"] == pytest.approx(0.5)
    assert row["lead_max.tyre_max"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="event_time_s"):
        patch_features(_patches([pts, pts]), LASERS, event_time_s=np.zeros(2))


def test_features_in_chunks_equal_a_loop_and_each_event_depends_on_its_points_alone() -> None:
    """More groups than one chunk; per-laser dz_cell, all-laser dz_near, counts and z_std
    against a loop over points and pairs; the features of a slice of the events are the
    slice of the features (no statistic across events: computing them for both splits at
    once leaks nothing)."""
    rng = np.random.default_rng(3)
    p = _random(rng, CHUNK_GROUPS // 2 + 30, 9)
    assert p.groups > CHUNK_GROUPS
    f, names = patch_features(p, LASERS)
    n_tyre = len(names) // 2
    for e in range(0, p.events, 5):
        per_tyre = []
        for g in (2 * e, 2 * e + 1):
            pts = np.flatnonzero(p.valid[g])
            ref = {}
            for li, laser in enumerate(LASERS):
                dz = [
                    abs(p.z[g, i] - p.z[g, j])
                    for i in pts
                    for j in pts
                    if i < j
                    and p.laser[g, i] == p.laser[g, j] == li
                    and math.floor(p.x[g, i] / 0.25) == math.floor(p.x[g, j] / 0.25)
                    and math.floor(p.y[g, i] / 0.25) == math.floor(p.y[g, j] / 0.25)
                ]
                ref[f"dz_cell[{laser}]"] = max(dz) if dz else math.nan
                ref[f"count[{laser}]"] = float(np.count_nonzero(p.laser[g, pts] == li))
            near = [
                abs(p.z[g, i] - p.z[g, j])
                for i in pts
                for j in pts
                if i < j and math.hypot(p.x[g, i] - p.x[g, j], p.y[g, i] - p.y[g, j]) <= 0.25
            ]
            ref["dz_near"] = max(near) if near else math.nan
            ref["z_std"] = float(np.std(p.z[g, pts])) if pts.size else math.nan
            per_tyre.append(ref)
        for key in per_tyre[0]:
            a, b = per_tyre[0][key], per_tyre[1][key]
            hi = b if math.isnan(a) else a if math.isnan(b) else max(a, b)
            lo = math.nan if math.isnan(a) or math.isnan(b) else min(a, b)
            np.testing.assert_allclose(f[e, _col(names, f"{key}.tyre_max")], hi, rtol=1e-12)
            np.testing.assert_allclose(f[e, _col(names, f"{key}.tyre_min")], lo, rtol=1e-12)
    assert n_tyre == 4 * len(LASERS) + len(ALL_FEATURES)
    part, _ = patch_features(p.take(slice(2 * 7, 2 * 300)), LASERS)
    np.testing.assert_array_equal(part, f[7:300])


def _planted(rng: np.random.Generator, events: int, share: float = 0.05) -> tuple[Any, Any]:
    """Events whose roughness one laser sees: under one tyre of a rough event, laser a's two
    points in one cell differ by a 12-30 cm step (1 cm of noise elsewhere); lasers b and c
    carry 10 cm of pose noise on every event, larger than most steps."""
    n = 12
    G = 2 * events
    rough = rng.random(events) < share
    laser = np.tile(np.repeat(np.arange(3), 4), (G, 1)).astype(np.int16)
    x = rng.uniform(0, 1.4, (G, n))
    y = rng.uniform(-0.3, 0.3, (G, n))
    # Laser a's first two points: 2 cm apart in one cell.
    cell = np.floor(x[:, :1] / 0.25) * 0.25
    x[:, :2], y[:, 1] = cell + np.array([0.10, 0.12]), y[:, 0]
    z = np.where(laser == 0, rng.normal(0, 0.01, (G, n)), rng.normal(0, 0.10, (G, n)))
    wheel = rng.integers(0, 2, events)
    g = 2 * np.flatnonzero(rough) + wheel[rough]
    z[g, 1] += rng.uniform(0.12, 0.30, g.size)
    tau = 100.0 + rng.uniform(0, 2, (G, n))
    p = TyrePatches(
        x=x,
        y=y,
        z=z,
        tau=tau,
        gamma=rng.normal(0, 0.1, (G, n)),
        psi=rng.normal(0, 0.1, (G, n)),
        valid=np.ones((G, n), bool),
        count=np.full(G, n, np.int64),
        laser=laser,
        lasers=LASERS,
    )
    return p, rough


def test_the_learner_never_sees_a_test_event(monkeypatch: pytest.MonkeyPatch) -> None:
    """``fit`` gets exactly the training rows; changing test events' features and labels
    leaves every other event's score the same, bit for bit."""
    rng = np.random.default_rng(11)
    p, rough = _planted(rng, 1500, share=0.1)
    f, _ = patch_features(p, LASERS)
    train = rng.random(rough.size) < 0.5
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    fit = HistGradientBoostingClassifier.fit

    def spy(self: Any, X: Any, y: Any, *args: Any, **kwargs: Any) -> Any:
        seen.append((np.array(X, copy=True), np.array(y, copy=True)))
        return fit(self, X, y, *args, **kwargs)

    monkeypatch.setattr(HistGradientBoostingClassifier, "fit", spy)
    config = BoostedConfig(max_iter=30)
    scores, summary = train_and_score(f, rough, train, config)
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0][0], f[train])
    np.testing.assert_array_equal(seen[0][1], rough[train])
    assert summary["train_events"] == train.sum() and summary["train_rough"] == rough[train].sum()
    assert scores.shape == (rough.size,) and np.isfinite(scores).all()

    # Half the test events get other features and flipped labels.
    changed = ~train & (rng.random(rough.size) < 0.5)
    f2, rough2 = f.copy(), rough.copy()
    f2[changed] = rng.normal(0, 1, (int(changed.sum()), f.shape[1]))
    rough2[changed] = ~rough2[changed]
    scores2, _ = train_and_score(f2, rough2, train, config)
    np.testing.assert_array_equal(scores2[~changed], scores[~changed])


def test_the_learner_ranks_test_events_by_the_laser_that_sees_the_step() -> None:
    rng = np.random.default_rng(7)
    p, rough = _planted(rng, 3000)
    f, names = patch_features(p, LASERS)
    train = rng.random(rough.size) < 0.5
    scores, summary = train_and_score(f, rough, train)
    test = ~train
    assert roc_auc_score(rough[test], scores[test]) > 0.9
    # The all-laser dz alone drowns in lasers b and c's noise: the learner picks laser a.
    alone = np.nan_to_num(f[test, _col(names, "dz_cell.tyre_max")])
    assert roc_auc_score(rough[test], alone) < 0.8
    assert summary["iterations"] == BoostedConfig().max_iter


def test_same_inputs_give_the_same_scores_bit_for_bit() -> None:
    rng = np.random.default_rng(2)
    p, rough = _planted(rng, 800, share=0.1)
    f, _ = patch_features(p, LASERS, event_time_s=np.full(p.events, 103.0))
    train = np.arange(rough.size) % 2 == 0
    a, sa = train_and_score(f, rough, train)
    b, sb = train_and_score(f.copy(), rough.copy(), train.copy())
    np.testing.assert_array_equal(a, b)
    assert sa == sb


def test_bad_inputs_are_refused() -> None:
    f = np.zeros((4, 3))
    with pytest.raises(ValueError, match="disagree"):
        train_and_score(f, np.zeros(3, bool), np.ones(4, bool))
    with pytest.raises(ValueError, match="rough and smooth"):
        train_and_score(f, np.array([True, False, False, False]), np.array([0, 1, 1, 1], bool))
    p = _patches([[], []])
    with pytest.raises(ValueError, match="distinct"):
        patch_features(p, ["/laser/a", "/laser/a"])


def test_a_feature_no_training_event_has_is_left_out() -> None:
    """A column with no finite value on the training rows (a laser the model's points never
    came from) is left out instead of breaking the fit; the scores equal a fit without it."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(300, 3))
    y = x[:, 0] + 0.3 * rng.normal(size=300) > 1.2
    train = np.arange(300) < 200
    with_nan = np.c_[x, np.full(300, np.nan)]
    got, summary = train_and_score(with_nan, y, train)
    want, _ = train_and_score(x, y, train)
    np.testing.assert_array_equal(got, want)
    assert summary["features_left_out"] == 1 and summary["features"] == 3
