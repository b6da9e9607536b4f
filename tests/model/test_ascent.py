"""Sect. 6: the threshold search, and coordinate ascent on a planted problem."""

from __future__ import annotations

import itertools

import numpy as np
import pyarrow as pa
import pytest
from sklearn.metrics import auc, roc_auc_score, roc_curve

from tests.model.helpers import make_patches, planted, points_table
from toolkit.model.ascent import (
    ACCEPTANCE,
    PAUC_MAX_FPR,
    AscentConfig,
    Threshold,
    best_threshold,
    coordinate_ascent,
    partial_auc,
    validation_events,
)
from toolkit.model.patches import build_patches, lead_order
from toolkit.model.roughness import PairTable, RoughnessParams, score_events


def _brute_force_best(r: np.ndarray, y: np.ndarray, lam: float) -> float:
    """max over every mu of eq. (6): each distinct value, each midpoint, and below all."""
    values = np.unique(r)
    candidates = list(values) + list((values[1:] + values[:-1]) / 2) + [values[0] - 1.0]
    best = 0.0
    for mu in candidates:
        pred = r > mu
        best = max(best, (pred & y).sum() / y.sum() - lam * (pred & ~y).sum() / (~y).sum())
    return float(best)


@pytest.mark.parametrize("seed", range(8))
def test_best_threshold_is_the_best_of_every_candidate(seed: int) -> None:
    """Every R_combined value a candidate mu (ties included: scores rounded to a grid): the
    objective found equals a brute-force maximum, and ``r > mu`` reproduces its rates."""
    rng = np.random.default_rng(seed)
    r = np.round(rng.normal(size=200), 1)
    y = rng.random(200) < 0.1 + 0.3 * (r > 1)
    y[0], y[1] = True, False
    for lam in (0.0, 1.0, 5.0):
        t = best_threshold(r, y, lam)
        assert t.objective == pytest.approx(_brute_force_best(r, y, lam), abs=1e-12)
        pred = r > t.mu
        if t.objective > 0:
            assert (pred & y).sum() / y.sum() == pytest.approx(t.tpr)
            assert (pred & ~y).sum() / (~y).sum() == pytest.approx(t.fpr)


def test_mu_sits_midway_between_adjacent_scores() -> None:
    """Decision 6: mu halfway between the lowest score called rough and the next one."""
    t = best_threshold(np.array([0.0, 1.0, 3.0, 5.0]), np.array([False, False, True, True]), 5.0)
    assert (t.mu, t.objective, t.tpr, t.fpr) == (2.0, 1.0, 1.0, 0.0)


def _config(**kw: object) -> AscentConfig:
    base = dict(
        initial=(1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 2.0, 1.0),
        increments=(0.5, 0.5, 0.02, 0.5, 0.05, 0.5, 0.02, 0.5, 0.02, 0.5, 0.1, 2.0, 0.25),
        lambda_fp=5.0,
        iterations=8,
    )
    base.update(kw)
    return AscentConfig(**base)  # type: ignore[arg-type]


def test_a_planted_problem_is_learned() -> None:
    """From alpha_3 = 0 (J at 0: the drift outscores the step), the search finds the time
    penalty and separates the training events perfectly (J = 1), and the learned model
    classifies fresh events from the same process without error."""
    rng = np.random.default_rng(3)
    train, y_train = planted(rng, 60)
    source = PairTable(make_patches(train))
    start = _config().initial
    r0 = score_events(source, RoughnessParams.from_vector(start, 0.0)).r_combined
    assert best_threshold(r0, y_train, 5.0).objective == 0.0  # the premise: J starts at 0
    result = coordinate_ascent(source, y_train, _config())
    assert result.objective == 1.0 and result.tpr == 1.0 and result.fpr == 0.0
    assert result.params.alpha[2] > 0.0  # the time term was needed
    test, y_test = planted(rng, 40)
    got = score_events(PairTable(make_patches(test)), result.params)
    np.testing.assert_array_equal(got.predicted, y_test)


def test_adapted_steps_reach_a_penalty_the_halved_ones_cannot() -> None:
    """The planted problem with drifts of 5-9 cm over 2 s: every larger alpha_3 ranks a few
    more drifts below the 5 cm step, and all of them from about 0.021. From alpha_3 = 0 with
    an increment of 0.005, the paper's halving can move it by less than 0.01 in all, so it
    stops partway; the adapted increments double while the steps are taken and get there.
    Only alpha_3 moves (with every element free the search finds other ways round)."""
    rng = np.random.default_rng(3)
    train, y_train = planted(rng, 60, drift_m=(0.05, 0.09))
    small = list(_config().increments)
    small[2] = 0.005
    only_time = tuple(j == 2 for j in range(13))
    got = {}
    for rule in ("halve", "adapt"):
        config = _config(increments=tuple(small), step_rule=rule, free=only_time)
        got[rule] = coordinate_ascent(PairTable(make_patches(train)), y_train, config)
    assert got["halve"].params.alpha[2] < 0.01 and got["halve"].objective < 1.0
    assert got["adapt"].objective == 1.0 and got["adapt"].params.alpha[2] > 0.015
    test, y_test = planted(rng, 40, drift_m=(0.05, 0.09))
    fresh = score_events(PairTable(make_patches(test)), got["adapt"].params)
    np.testing.assert_array_equal(fresh.predicted, y_test)


def test_an_unknown_step_rule_is_refused() -> None:
    with pytest.raises(ValueError, match="step_rule"):
        _config(step_rule="double")


def test_without_the_time_term_the_planted_problem_is_not_learned() -> None:
    """The same problem with alpha_3 frozen at 0: no parameter separates it (J < 1): the
    planted problem needs what the first test says it found."""
    rng = np.random.default_rng(3)
    train, y_train = planted(rng, 60)
    free = tuple(j not in (2, 3) for j in range(13))
    result = coordinate_ascent(PairTable(make_patches(train)), y_train, _config(free=free))
    assert result.objective < 1.0
    assert result.params.alpha[2] == 0.0 and result.params.alpha[3] == 1.0


def test_objective_never_decreases_and_omega_stays_a_positive_integer() -> None:
    """On noisy random labels (hard to learn): the objective after each rotation and at each
    accepted step never falls; omega is an integer >= 1 throughout."""
    rng = np.random.default_rng(11)
    raw, _ = planted(rng, 50)
    y = rng.random(50) < 0.3
    y[:2] = [True, False]
    result = coordinate_ascent(PairTable(make_patches(raw)), y, _config(iterations=6))
    hist = np.array(result.history)
    assert np.all(np.diff(hist) >= 0) and hist[-1] == result.objective
    step_j = [s[3] for s in result.steps]
    assert all(b >= a for a, b in itertools.pairwise(step_j))
    assert isinstance(result.params.omega, int) and result.params.omega >= 1
    assert all(
        float(v).is_integer() and v >= 1 for _, name, v, _ in result.steps if name == "omega"
    )


def test_the_search_is_deterministic() -> None:
    rng = np.random.default_rng(5)
    raw, y = planted(rng, 30)
    a = coordinate_ascent(PairTable(make_patches(raw)), y, _config(iterations=4))
    b = coordinate_ascent(PairTable(make_patches(raw)), y, _config(iterations=4))
    assert a == b


def test_auc_and_partial_auc_agree_with_scikit_learn() -> None:
    """The search's AUC (ties half) and partial AUC to FPR 0.2 are scikit-learn's, on scores
    with heavy ties at zero (as W >= 0 makes them)."""
    rng = np.random.default_rng(2)
    r = np.where(rng.random(400) < 0.8, 0.0, np.round(rng.exponential(1.0, 400), 1))
    y = rng.random(400) < 0.05 + 0.3 * (r > 1.0)
    t = best_threshold(r, y, 5.0)
    assert t.auc == pytest.approx(roc_auc_score(y, r), abs=1e-12)
    fpr, tpr, _ = roc_curve(y, r, drop_intermediate=False)
    inside = fpr <= PAUC_MAX_FPR
    f = np.r_[fpr[inside], PAUC_MAX_FPR]
    tp = np.r_[tpr[inside], np.interp(PAUC_MAX_FPR, fpr, tpr)]
    assert t.pauc == pytest.approx(auc(f, tp) / PAUC_MAX_FPR, abs=1e-12)
    assert partial_auc(np.array([0.0, 1.0]), np.array([0.0, 1.0]), 0.2) == pytest.approx(0.1)


@pytest.mark.parametrize("accept", ACCEPTANCE)
def test_no_search_ends_below_its_start_on_what_it_climbs(accept: str) -> None:
    """Whatever decides the steps, the measure it climbs never falls from rotation to
    rotation and ends at or above the initial guess's own; mu is eq. (6)'s best threshold
    for the parameters reached."""
    rng = np.random.default_rng(11)
    raw, _ = planted(rng, 50)
    y = rng.random(50) < 0.3
    y[:2] = [True, False]
    source = PairTable(make_patches(raw))
    result = coordinate_ascent(source, y, _config(iterations=5, accept=accept))
    assert result.start is not None and result.accepted_by == accept
    measures = np.array(result.measure_history)
    assert np.all(np.diff(measures) >= 0)
    end = Threshold(result.params.mu, result.objective, result.tpr, result.fpr, result.auc,
                    result.pauc)  # fmt: skip
    assert end.key(accept) >= result.start.key(accept)
    r = score_events(source, result.params).r_combined
    assert result.params.mu == best_threshold(r, y, 5.0).mu


def _near_and_far(
    rng: np.random.Generator, events: int, first_id: int = 0
) -> tuple[pa.Table, pa.Table]:
    """Events seen by two lasers. The near laser (seen 0.5 s ahead, 30 points a tyre) sees
    the ground: flat within 3 mm, and a 6 cm step under the left tyre of every fifth event
    (rough). The far laser (seen 3 s ahead, 60 points a tyre) sees the same ground through
    heavy-tailed range and attitude error (Student t, 3 degrees of freedom, 2 cm scale):
    height differences as large as the step everywhere, and no signal."""
    rows: list[tuple[object, ...]] = []
    rough = np.arange(events) % 5 == 0
    for e in range(events):
        t0 = 100.0 + 2.0 * (first_id + e)
        for w, wheel in enumerate(("left", "right")):
            for laser, n, lead in (("/near", 30, 0.5), ("/far", 60, 3.0)):
                x = rng.uniform(0.0, 1.4, n)
                z = rng.normal(0.0, 0.003, n)
                if laser == "/near" and rough[e] and w == 0:
                    z += np.where(x > 0.7, 0.06, 0.0)
                if laser == "/far":
                    z = 0.02 * rng.standard_t(3, n)
                tau = t0 - lead + rng.uniform(0.0, 0.1, n)
                for k in range(n):
                    rows.append((
                        "log", first_id + e, wheel, float(x[k]), float(0.02 * k % 0.3), float(z[k]),
                        float(tau[k]), 0.0, 0.0, laser, round(float(tau[k]) * 1e9),
                    ))  # fmt: skip
    columns = list(zip(*rows, strict=True))
    points = points_table([]).schema.empty_table().to_pydict()
    for name, col in zip(points, columns, strict=True):
        points[name] = list(col)
    table = pa.table(points, schema=points_table([]).schema)
    ids = pa.array(range(first_id, first_id + events), pa.int64())
    start = pa.array(
        [round((100.0 + 2.0 * (first_id + e)) * 1e9) for e in range(events)], pa.int64()
    )
    ev = pa.table({"log_id": ["log"] * events, "event_id": ids, "t_start_ns": start,
                   "rough": pa.array(rough)})  # fmt: skip
    return ev, table


def test_far_laser_noise_and_a_near_laser_step() -> None:
    """The planted problem of issue "Fig. 6 for real": far-laser points carry noise, the near
    laser the step. The default model (nearest laser first, steps accepted by the training
    AUC) finds the step and ranks unseen events almost perfectly; the paper-exact one (a
    uniform sample of both lasers, steps accepted by eq. 6) is reported as it is."""
    rng = np.random.default_rng(7)
    train_ev, train_pts = _near_and_far(rng, 100)
    test_ev, test_pts = _near_and_far(rng, 100, first_id=100)
    y_train = train_ev.column("rough").to_numpy(zero_copy_only=False)
    y_test = test_ev.column("rough").to_numpy(zero_copy_only=False)
    results = {}
    for name, sample, accept in (("default", "nearest_laser", "auc"),
                                 ("paper", "hash", "objective")):  # fmt: skip
        order = lead_order(train_ev, train_pts)
        assert order == ("/near", "/far")
        train = build_patches(train_ev, train_pts, 20, sample=sample, laser_order=order)
        test = build_patches(test_ev, test_pts, 20, sample=sample, laser_order=order)
        cfg = _config(
            initial=(1.0, 1.0, 0.01, 1.0, 0.1, 1.0, 0.0, 1.0, 0.0, 1.0, 1.05, 3.0, 1.0),
            accept=accept,
        )
        learned = coordinate_ascent(PairTable(train), y_train, cfg)
        r = score_events(PairTable(test), learned.params).r_combined
        results[name] = roc_auc_score(y_test, r)
    assert results["default"] >= 0.95
    assert results["paper"] < results["default"]


def test_validation_events_are_whole_blocks_and_need_both_classes() -> None:
    rough = np.zeros(600, bool)
    rough[::7] = True
    held = validation_events(rough, 1 / 3, 50)
    assert held is not None and held.sum() == 200
    assert held[100:150].all() and not held[:100].any()  # every third block of 50
    assert validation_events(rough, 0.0, 50) is None
    only_first = np.zeros(600, bool)
    only_first[3] = True
    assert validation_events(only_first, 1 / 3, 50) is None  # nothing rough held out


def test_early_stopping_keeps_the_rotation_that_ranks_held_out_events_best() -> None:
    """With a held-out share, the result's parameters rank the held-out events at least as
    well as the start and as every later rotation the search passed; mu is eq. (6)'s on all
    training events."""
    rng = np.random.default_rng(11)
    raw, _ = planted(rng, 90)
    y = rng.random(90) < 0.3
    source = PairTable(make_patches(raw))
    cfg = _config(iterations=5, accept="auc", validation_share=1 / 3, validation_block=5)
    result = coordinate_ascent(source, y, cfg)
    held = validation_events(y, 1 / 3, 5)
    assert held is not None
    val = np.array(result.validation_history)
    assert val.size == 5 and np.all(np.diff(val) >= 0)
    r = score_events(source, result.params).r_combined
    assert roc_auc_score(y[held], r[held]) == pytest.approx(val[-1], abs=1e-12)
    start = score_events(source, RoughnessParams.from_vector(cfg.initial, 0.0)).r_combined
    assert val[-1] >= roc_auc_score(y[held], start[held])
    assert result.params.mu == best_threshold(r, y, 5.0).mu


def test_the_look_ahead_term_is_each_points_lead_time_and_absent_at_zero_weight() -> None:
    """Eq. (4) with 12 alphas subtracts a11 |lead|^a12 for each point of a pair (lead: the
    event's start less the point's time); with a11 = 0 it scores as the paper's 10 alphas,
    bit for bit."""
    rng = np.random.default_rng(3)
    ev, pts = _near_and_far(rng, 3)
    patches = build_patches(ev, pts, 12, sample="nearest_laser", laser_order=("/far",))
    table = PairTable(patches)
    a10 = (1.0, 1.0, 0.01, 1.0, 0.1, 1.0, 0.0, 1.0, 0.0, 1.0)
    a12 = (*a10, 0.2, 1.5)
    start_ns = ev.column("t_start_ns").to_numpy()
    g = 0  # event 0, left tyre
    lead = np.where(patches.valid[g], start_ns[0] * 1e-9 - patches.tau[g], 0.0)
    np.testing.assert_allclose(patches.lead[g][patches.valid[g]], lead[patches.valid[g]], atol=1e-6)
    d10 = table.delta(a10, slice(g, g + 1))[0]
    d12 = table.delta(a12, slice(g, g + 1))[0]
    r, c = np.tril_indices(patches.n_max, -1)
    ok = patches.valid[g][r] & patches.valid[g][c]
    extra = 0.2 * (np.abs(lead[r]) ** 1.5 + np.abs(lead[c]) ** 1.5)
    np.testing.assert_allclose(d12[ok], (d10 - extra)[ok], rtol=2e-5, atol=2e-5)
    zero = table.delta((*a10, 0.0, 1.5), slice(None))
    np.testing.assert_array_equal(zero, table.delta(a10, slice(None)))


def test_the_look_ahead_term_discounts_far_laser_points() -> None:
    """The planted far-laser problem on the paper's uniform sample of both lasers: the far
    points are seen 3 s ahead, the near ones 0.5 s, within 0.1 s of each other; the time term
    cannot tell them apart, the look-ahead term can, and the search learns it."""
    rng = np.random.default_rng(7)
    train_ev, train_pts = _near_and_far(rng, 100)
    test_ev, test_pts = _near_and_far(rng, 100, first_id=100)
    y_train = train_ev.column("rough").to_numpy(zero_copy_only=False)
    y_test = test_ev.column("rough").to_numpy(zero_copy_only=False)
    train = PairTable(build_patches(train_ev, train_pts, 20))
    test = PairTable(build_patches(test_ev, test_pts, 20))
    base = (1.0, 1.0, 0.01, 1.0, 0.1, 1.0, 0.0, 1.0, 0.0, 1.0)
    aucs = {}
    for name, alpha, steps in (
        ("paper", base, ()),
        ("lead", (*base, 0.01, 1.0), (0.005, 0.5)),
    ):
        cfg = AscentConfig(
            initial=(*alpha, 1.05, 3.0, 1.0),
            increments=(
                0.5,
                0.5,
                0.02,
                0.5,
                0.05,
                0.5,
                0.02,
                0.5,
                0.02,
                0.5,
                *steps,
                0.1,
                2.0,
                0.25,
            ),
            iterations=8,
            accept="auc",
        )
        learned = coordinate_ascent(train, y_train, cfg)
        assert len(learned.params.alpha) == len(alpha)
        aucs[name] = roc_auc_score(y_test, score_events(test, learned.params).r_combined)
    assert aucs["lead"] >= 0.95 and aucs["lead"] > aucs["paper"]


def test_early_stopping_says_what_it_held_out_and_kept() -> None:
    rng = np.random.default_rng(11)
    raw, _ = planted(rng, 90)
    y = rng.random(90) < 0.3
    cfg = _config(iterations=4, accept="auc", validation_share=1 / 3, validation_block=5)
    result = coordinate_ascent(PairTable(make_patches(raw)), y, cfg)
    held = validation_events(y, 1 / 3, 5)
    assert held is not None and result.held_out_share == pytest.approx(held.mean())
    assert result.kept_rotation is not None and 0 <= result.kept_rotation <= 4
    plain = coordinate_ascent(PairTable(make_patches(raw)), y, _config(iterations=2))
    assert plain.held_out_share == 0.0 and plain.kept_rotation is None
