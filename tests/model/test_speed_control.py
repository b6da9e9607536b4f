"""Fig. 7 (Sect. 7.2): the reactive and proactive speed controllers replayed over hand-made
routes whose speeds, times and shocks are worked out by hand."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from toolkit.analysis.fig7 import CSV_HEADER, CSV_NAME, PNG_NAME, tradeoff_png, write_tradeoff_csv
from toolkit.errors import ConfigError, StageError
from toolkit.model import speed_control as sc
from toolkit.model.speed_control import (
    Route,
    SpeedControlParams,
    TradeoffPoint,
    drive,
    drive_routes,
    event_shocks_g,
    event_speeds,
    no_change_point,
    pareto_front,
    proactive_curve,
    reactive_curve,
    shock_reduction_at_equal_time,
)

MPH = 0.44704


def route(
    n: int = 20,
    *,
    length_m: float = 10.0,
    speed_mps: float = 10.0,
    rough_at: Sequence[int] = (),
    predicted_at: Sequence[int] = (),
    rugged: float = 0.03,
    smooth: float = 0.0,
) -> Route:
    """``n`` contiguous events of ``length_m`` at ``speed_mps`` from s = 0; the events in
    ``rough_at`` have ruggedness ``rugged`` (the others ``smooth``) and are labelled rough;
    those in ``predicted_at`` are flagged by the model."""
    s0 = np.arange(n, dtype=np.float64) * length_m
    rough = np.zeros(n, bool)
    rough[list(rough_at)] = True
    predicted = np.zeros(n, bool)
    predicted[list(predicted_at)] = True
    return Route(
        s_start_m=s0,
        s_end_m=s0 + length_m,
        speed_mps=np.full(n, speed_mps),
        ruggedness=np.where(rough, rugged, smooth),
        rough=rough,
        predicted=predicted,
    )


def point(t: float, s: float, method: str = "reactive") -> TradeoffPoint:
    """A hand-made Fig. 7 point whose raw and normalised values are equal."""
    return TradeoffPoint(method, SpeedControlParams(), t, s, t, s, s, 0)


# --- no change -----------------------------------------------------------------------------


def test_no_change_is_nominal_and_normalises_to_one() -> None:
    r = route(5, rough_at=[2], smooth=0.001)
    params = SpeedControlParams()
    res = drive(r, params, "no_change")
    assert res.time_s == pytest.approx(5.0)  # 5 x 10 m at 10 m/s
    assert res.shock_g == pytest.approx((0.03 + 4 * 0.001) * 10 / MPH)
    assert res.shock_sum_g == res.shock_g
    assert res.events == 5
    p = no_change_point([r], params)
    assert (p.time_norm, p.shock_norm) == (1.0, 1.0)


def test_empty_route_gives_zero() -> None:
    r = route(0)
    for method in sc.METHODS:
        res = drive(r, SpeedControlParams(), method)
        assert (res.time_s, res.shock_g, res.shock_sum_g, res.shocks_over_floor) == (0, 0, 0, 0)
    p = no_change_point([r], SpeedControlParams())
    assert math.isnan(p.time_norm) and math.isnan(p.shock_norm)


def test_routes_are_summed() -> None:
    a, b = route(10, rough_at=[3], predicted_at=[3]), route(7, rough_at=[1, 5], predicted_at=[5])
    params = SpeedControlParams(decel_mps2=2.0, hold_distance_m=5.0)
    for method in sc.METHODS:
        both = drive_routes([a, b], params, method)
        one, two = drive(a, params, method), drive(b, params, method)
        assert both.time_s == pytest.approx(one.time_s + two.time_s)
        assert both.shock_g == pytest.approx(one.shock_g + two.shock_g)
        assert both.events == 17


# --- proactive -----------------------------------------------------------------------------

PRO = SpeedControlParams(
    slow_fraction=0.5, decel_mps2=2.0, recovery_mps2=1.0, hold_distance_m=10.0, lookahead_m=math.inf
)


def test_proactive_halves_the_flagged_event_and_costs_the_computed_time() -> None:
    # Event 10 (s 100-110) flagged; v0 = 10, v_slow = 5, a = 2, r = 1, hold until s = 120.
    r = route(20, rough_at=[10], predicted_at=[10])
    v = event_speeds(r, PRO, "proactive")
    expected = np.full(20, 10.0)
    expected[8] = math.sqrt(25 + 2 * 2 * 15)  # mid 85, 15 m before the event
    expected[9] = math.sqrt(25 + 2 * 2 * 5)  # mid 95
    expected[10] = expected[11] = 5.0  # on the event, then held to s = 120
    for i, mid in zip(range(12, 16), (125, 135, 145, 155), strict=True):
        expected[i] = math.sqrt(25 + 2 * 1 * (mid - 120))  # recovering at 1 m/s^2
    # mid 75 is 25 m before: sqrt(125) > 10, and mid 165: sqrt(115) > 10, both nominal.
    np.testing.assert_allclose(v, expected, rtol=1e-12)

    base = drive(r, PRO, "no_change")
    pro = drive(r, PRO, "proactive")
    assert pro.shock_g == base.shock_g / 2  # the only rough event, at half speed
    assert event_shocks_g(r, v)[10] == event_shocks_g(r, r.speed_mps)[10] / 2
    assert pro.time_s - base.time_s == pytest.approx(float(np.sum(10.0 / expected - 1.0)))
    assert pro.time_s - base.time_s > 2.0  # 2 s on the two held events alone


def test_braking_envelope_respects_decel() -> None:
    # 1 m events: the vehicle is at sqrt(v_slow^2 + 2 a d) a distance d before the event.
    r = route(200, length_m=1.0, rough_at=[150], predicted_at=[150])
    params = SpeedControlParams(slow_fraction=0.5, decel_mps2=1.5, lookahead_m=math.inf)
    v = event_speeds(r, params, "proactive")
    d = 150.0 - (np.arange(150) + 0.5)
    envelope = np.sqrt(25.0 + 2 * 1.5 * d)
    braking = envelope < 10.0
    assert 20 < braking.sum() < 30  # (100 - 25) / 3 = 25 m of braking
    np.testing.assert_allclose(v[:150][braking], envelope[braking], rtol=1e-12)
    assert np.all(v[:150][~braking] == 10.0)
    # Between consecutive events never more than a = 1.5 m/s^2: (v1^2 - v2^2) / 2 ds <= a.
    decel = -np.diff(v[:151] ** 2) / 2.0
    assert decel.max() == pytest.approx(1.5)
    assert np.all(decel <= 1.5 + 1e-9)


def test_short_lookahead_limits_how_slow_the_vehicle_gets() -> None:
    r = route(20, rough_at=[10], predicted_at=[10])
    short = SpeedControlParams(
        slow_fraction=0.5, decel_mps2=2.0, hold_distance_m=10.0, lookahead_m=1.0
    )
    v = event_speeds(r, short, "proactive")
    # Known at s = 99, braking from 10 m/s: at the event's middle (6 m on) sqrt(100 - 24).
    assert v[10] == pytest.approx(math.sqrt(100 - 2 * 2 * 6))
    assert v[10] > 5.0
    assert v[9] == 10.0  # mid 95 is before the vehicle knows
    # Still braking into the hold: mid 115 is 16 m after s_know, sqrt(100 - 64) = 6.
    assert v[11] == pytest.approx(6.0)
    # The speed reachable at the event's start is sqrt(max(v_slow^2, v0^2 - 2 a lookahead)).
    speeds = [
        event_speeds(r, SpeedControlParams(decel_mps2=2.0, lookahead_m=la), "proactive")[10]
        for la in (0.0, 5.0, 10.0, 15.0, 30.0)
    ]
    assert speeds == sorted(speeds, reverse=True)
    assert speeds[0] == pytest.approx(math.sqrt(100 - 2 * 2 * 5))
    assert speeds[-1] == 5.0


def test_proactive_ignores_the_measured_label() -> None:
    r = route(20, rough_at=[10], predicted_at=[])
    assert np.all(event_speeds(r, PRO, "proactive") == 10.0)
    assert drive(r, PRO, "proactive").shock_g == drive(r, PRO, "no_change").shock_g


# --- reactive ------------------------------------------------------------------------------

REA = SpeedControlParams(slow_fraction=0.5, decel_mps2=5.0, recovery_mps2=1.0, hold_distance_m=20.0)


def test_reactive_slows_after_the_trigger_holds_and_recovers() -> None:
    # Event 5 (s 50-60) rough: braking from s = 60 at 5 m/s^2 reaches 5 m/s at 67.5; held
    # to 87.5; then v^2 = 25 + 2 (s - 87.5).
    r = route(20, rough_at=[5])
    v = event_speeds(r, REA, "reactive")
    expected = np.full(20, 10.0)
    expected[6] = math.sqrt(100 - 2 * 5 * 5)  # mid 65, braking
    expected[7] = expected[8] = 5.0  # mid 75, 85: held
    expected[9] = math.sqrt(40)  # mid 95
    expected[10] = math.sqrt(60)
    expected[11] = math.sqrt(80)
    np.testing.assert_allclose(v, expected, rtol=1e-12)
    assert v[5] == 10.0  # the trigger itself is measured, not avoided
    base, rea = drive(r, REA, "no_change"), drive(r, REA, "reactive")
    assert rea.shock_g == base.shock_g  # the only rough event is the trigger
    assert rea.time_s > base.time_s
    # Recovery at exactly the given rate: (v2^2 - v1^2) / 2 ds = 1 m/s^2.
    # (7.5 of the first 10 m are past the hold.)
    np.testing.assert_allclose(np.diff(v[8:12] ** 2) / (2 * 10.0), [0.75, 1.0, 1.0])


def test_reactive_slows_the_next_rough_event_and_does_not_compound() -> None:
    r = route(20, rough_at=[5, 6, 7])
    v = event_speeds(r, REA, "reactive")
    # Event 6 is capped by trigger 5 (sqrt 50); event 7 by trigger 5 (5 m/s) - the caps of
    # triggers 6 (braking from s = 70) do not halve it again.
    assert v[6] == pytest.approx(math.sqrt(50))
    assert v[7] == 5.0
    assert v.min() == 5.0
    shocks = event_shocks_g(r, v)
    nominal = event_shocks_g(r, r.speed_mps)
    assert shocks[5] == nominal[5]
    assert shocks[7] == nominal[7] / 2
    # Hold measured from the last trigger: trigger 7 at s = 80 reaches 5 m/s at 87.5.
    assert v[9] == 5.0 and v[10] == 5.0
    assert v[11] == pytest.approx(math.sqrt(25 + 2 * (115 - 107.5)))


def test_reactive_ignores_predictions() -> None:
    r = route(20, predicted_at=[5])
    assert np.all(event_speeds(r, REA, "reactive") == 10.0)


# --- blocks and windows against a per-trigger reference -------------------------------------


def reference_speeds(r: Route, p: SpeedControlParams, method: str) -> np.ndarray:
    """Per-trigger loop over the piecewise profile written out phase by phase."""
    mid = 0.5 * (r.s_start_m + r.s_end_m)
    cap = np.full(mid.size, np.inf)
    a, rec = p.decel_mps2, p.recovery_mps2
    flags = r.rough if method == "reactive" else r.predicted
    for j in np.flatnonzero(flags):
        v0 = r.speed_mps[j]
        vs = p.slow_fraction * v0
        for i, s in enumerate(mid):
            if method == "reactive":
                st = r.s_end_m[j]
                s_reach = st + (v0**2 - vs**2) / (2 * a)
                s_hold = s_reach + p.hold_distance_m
                if s < st:
                    continue
                if s <= s_reach:
                    c = math.sqrt(max(vs**2, v0**2 - 2 * a * (s - st)))
                elif s <= s_hold:
                    c = vs
                else:
                    c = math.sqrt(vs**2 + 2 * rec * (s - s_hold))
            else:
                s0, s_hold = r.s_start_m[j], r.s_end_m[j] + p.hold_distance_m
                s_know = s0 - p.lookahead_m
                if s < s_know:
                    continue
                brake = math.sqrt(max(0.0, v0**2 - 2 * a * (s - s_know)))
                if s < s0:
                    plan = math.sqrt(vs**2 + 2 * a * (s0 - s))
                elif s <= s_hold:
                    plan = vs
                else:
                    plan = math.sqrt(vs**2 + 2 * rec * (s - s_hold))
                c = max(brake, plan)
            cap[i] = min(cap[i], c)
    out: np.ndarray = np.minimum(r.speed_mps, cap)
    return out


def random_route(seed: int, n: int = 300) -> Route:
    rng = np.random.default_rng(seed)
    length = rng.uniform(0.5, 2.0, n)
    gaps = np.where(rng.random(n) < 0.1, rng.uniform(0.0, 5.0, n), 0.0)
    s0 = np.cumsum(np.concatenate([[0.0], (length + gaps)[:-1]]))
    rug = rng.uniform(0.0, 0.04, n)
    return Route(
        s_start_m=s0,
        s_end_m=s0 + length,
        speed_mps=rng.uniform(4.0, 15.0, n),
        ruggedness=rug,
        rough=rug >= 0.035,
        predicted=rng.random(n) < 0.15,
    )


@pytest.mark.parametrize("method", ["reactive", "proactive"])
@pytest.mark.parametrize("lookahead_m", [3.0, 25.0])
def test_blocked_caps_match_the_per_trigger_reference(
    monkeypatch: pytest.MonkeyPatch, method: sc.Method, lookahead_m: float
) -> None:
    r = random_route(7)
    params = SpeedControlParams(
        slow_fraction=0.4, decel_mps2=1.0, recovery_mps2=0.3, hold_distance_m=8.0,
        lookahead_m=lookahead_m,
    )  # fmt: skip
    want = reference_speeds(r, params, method)
    assert np.any(want < r.speed_mps)
    monkeypatch.setattr(sc, "BLOCK", 16)  # many blocks, windows that skip slowdowns
    np.testing.assert_allclose(event_speeds(r, params, method), want, rtol=1e-12)


# --- shock floor ---------------------------------------------------------------------------


def test_shock_floor_counts_only_the_excess() -> None:
    r = route(4, rough_at=[1, 2], rugged=0.03, smooth=0.01)
    # Shocks at 10 m/s: 0.01 * 22.37 = 0.2237 G smooth, 0.6711 G rough.
    res = drive(r, SpeedControlParams(shock_floor_g=0.5), "no_change")
    rough_g, smooth_g = 0.03 * 10 / MPH, 0.01 * 10 / MPH
    assert res.shock_g == pytest.approx(2 * (rough_g - 0.5))
    assert res.shock_sum_g == pytest.approx(2 * rough_g + 2 * smooth_g)
    assert res.shocks_over_floor == 2


def test_floor_removes_the_reward_for_slowing_on_smooth_ground() -> None:
    # Flagging every event halves every shock: a plain sum calls that a halving, the floor
    # (above the slowed rough shock, below nothing smooth ever reaches) sees the rough one.
    r = route(20, rough_at=[10], rugged=0.03, smooth=0.01, predicted_at=range(20))
    plain = SpeedControlParams(lookahead_m=math.inf)
    floored = SpeedControlParams(lookahead_m=math.inf, shock_floor_g=0.3)
    assert no_change_point([r], plain).shock_norm == 1.0
    p_plain = proactive_curve([r], plain, [0.5])[0]
    p_floor = proactive_curve([r], floored, [0.5])[0]
    assert p_plain.shock_norm == pytest.approx(0.5)
    assert p_floor.shock_norm == pytest.approx((0.03 * 5 / MPH - 0.3) / (0.03 * 10 / MPH - 0.3))
    assert p_floor.shocks_over_floor == 1


# --- sweeps, fronts, reduction ---------------------------------------------------------------


def test_curves_sweep_every_combination_normalised_by_no_change() -> None:
    r = route(30, rough_at=[5, 6, 20], predicted_at=[5, 6, 20], smooth=0.001)
    base = SpeedControlParams(decel_mps2=2.0, hold_distance_m=10.0, lookahead_m=30.0)
    rea = reactive_curve([r], base, [0.3, 0.6, 1.0], [0.2, 1.0])
    assert [(p.params.slow_fraction, p.params.recovery_mps2) for p in rea] == [
        (f, rr) for f in (0.3, 0.6, 1.0) for rr in (0.2, 1.0)
    ]
    ref = drive(r, base, "no_change")
    for p in rea:
        assert p.method == "reactive" and p.params.decel_mps2 == 2.0
        assert p.time_norm == pytest.approx(p.time_s / ref.time_s)
        assert p.shock_norm == pytest.approx(p.shock_g / ref.shock_g)
    # Slowing to 100 % changes nothing.
    assert (rea[-1].time_norm, rea[-1].shock_norm) == pytest.approx((1.0, 1.0))
    # Slower recovery costs time and saves shock.
    assert rea[0].time_s > rea[1].time_s and rea[0].shock_g < rea[1].shock_g
    pro = proactive_curve([r], base, [0.3, 0.6, 1.0])
    assert [p.params.slow_fraction for p in pro] == [0.3, 0.6, 1.0]
    assert all(p.method == "proactive" for p in pro)
    # A perfect predictor removes shock the reactive controller cannot (the triggers).
    assert pro[0].shock_norm < rea[0].shock_norm


def test_pareto_front_known_answer() -> None:
    a, b, c = point(1.0, 1.0), point(1.1, 0.7), point(1.2, 0.8)
    d, e, f = point(1.3, 0.4), point(1.1, 0.9), point(1.5, 0.4)
    g = point(1.3, 0.4)  # equal to d: the first given is kept
    front = pareto_front([f, c, e, d, a, g, b])
    assert front == [a, b, d]
    assert front[2] is d
    assert pareto_front([]) == []
    assert pareto_front([point(1.0, math.nan), a]) == [a]


def test_shock_reduction_at_equal_time_known_answer() -> None:
    reactive = [point(0.8, 0.6), point(0.9, 0.5), point(1.0, 0.4)]
    proactive = [point(0.95, 0.2, "proactive"), point(0.85, 0.3, "proactive")]
    red = shock_reduction_at_equal_time(reactive, proactive)
    # Only t = 0.9 lies in [0.85, 0.95]; proactive there 0.25 against 0.5.
    np.testing.assert_allclose(red.time_norm, [0.9])
    np.testing.assert_allclose(red.reductions, [0.5])
    assert red.max_reduction == pytest.approx(0.5)
    # Two points inside: the larger reduction is reported, endpoints included.
    red2 = shock_reduction_at_equal_time(
        [point(0.85, 0.4), point(0.95, 0.8)], [point(0.85, 0.3), point(0.95, 0.2)]
    )
    np.testing.assert_allclose(red2.reductions, [0.25, 0.75])
    assert red2.max_reduction == pytest.approx(0.75)


def test_shock_reduction_nan_without_overlap_or_reactive_shock() -> None:
    none = shock_reduction_at_equal_time([point(1.2, 0.5)], [point(0.8, 0.3), point(1.0, 0.2)])
    assert math.isnan(none.max_reduction) and none.reductions.size == 0
    assert math.isnan(shock_reduction_at_equal_time([point(1.0, 0.5)], []).max_reduction)
    zero = shock_reduction_at_equal_time([point(0.9, 0.0)], [point(0.8, 0.3), point(1.0, 0.2)])
    assert zero.reductions.size == 1 and math.isnan(zero.reductions[0])
    assert math.isnan(zero.max_reduction)


# --- validation ----------------------------------------------------------------------------


def columns(**changes: object) -> dict[str, object]:
    s0 = np.array([0.0, 1.0, 2.0])
    cols: dict[str, object] = {
        "s_start_m": s0,
        "s_end_m": s0 + 1.0,
        "speed_mps": np.array([5.0, 6.0, 7.0]),
        "ruggedness": np.array([0.01, 0.02, 0.0]),
        "rough": np.array([False, True, False]),
        "predicted": np.array([False, False, True]),
    }
    cols.update(changes)
    return cols


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"speed_mps": np.array([5.0, 6.0])}, "equal length"),
        ({"speed_mps": np.array([5.0, 0.0, 7.0])}, "speed_mps[1] = 0.0 is not > 0"),
        ({"speed_mps": np.array([5.0, 6.0, -1.0])}, "speed_mps[2] = -1.0"),
        ({"ruggedness": np.array([0.01, np.nan, 0.0])}, "ruggedness[1] = nan is not finite"),
        ({"s_end_m": np.array([1.0, 2.0, np.inf])}, "s_end_m[2] = inf is not finite"),
        ({"ruggedness": np.array([0.01, -0.02, 0.0])}, "ruggedness[1] = -0.02 is < 0"),
        ({"s_start_m": np.array([0.0, 2.0, 1.5])}, "s_start_m[2] = 1.5 does not increase"),
        ({"s_end_m": np.array([1.0, 0.5, 3.0])}, "s_end_m[1] = 0.5 is before s_start_m"),
        ({"rough": np.array([0, 1, 0])}, "rough must be bool"),
        ({"s_start_m": np.array(["a", "b", "c"])}, "s_start_m must be numeric"),
    ],
)
def test_bad_route_raises_stage_error(changes: dict[str, object], message: str) -> None:
    with pytest.raises(StageError, match=message.replace("[", r"\[").replace("]", r"\]")) as err:
        Route(**columns(**changes), source="logs/a/events.parquet")  # type: ignore[arg-type]
    assert "logs/a/events.parquet" in str(err.value)


@pytest.mark.parametrize(
    "changes",
    [
        {"slow_fraction": 0.0},
        {"slow_fraction": 1.5},
        {"decel_mps2": 0.0},
        {"recovery_mps2": math.inf},
        {"hold_distance_m": -1.0},
        {"lookahead_m": math.nan},
        {"shock_floor_g": -0.1},
    ],
)
def test_bad_params_raise_config_error(changes: dict[str, float]) -> None:
    ((name, value),) = changes.items()
    with pytest.raises(ConfigError, match=f"{name} = {value!r}"):
        SpeedControlParams(**changes)


def test_unknown_method_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="'fast'"):
        drive(route(3), SpeedControlParams(), "fast")  # type: ignore[arg-type]


def test_integer_columns_are_accepted_as_float64() -> None:
    r = Route(**columns(speed_mps=np.array([5, 6, 7])))  # type: ignore[arg-type]
    assert r.speed_mps.dtype == np.float64


# --- outputs and determinism -----------------------------------------------------------------


def sweep() -> list[list[TradeoffPoint]]:
    routes = [random_route(1), random_route(2, n=150)]
    base = SpeedControlParams(decel_mps2=1.0, hold_distance_m=8.0, lookahead_m=15.0)
    return [
        reactive_curve(routes, base, [0.3, 0.5, 0.8], [0.2, 0.6]),
        proactive_curve(routes, base, [0.3, 0.5, 0.8]),
        [no_change_point(routes, base)],
    ]


def test_outputs_are_deterministic(tmp_path: Path) -> None:
    one, two = sweep(), sweep()
    assert [[(p.time_s, p.shock_g) for p in c] for c in one] == [
        [(p.time_s, p.shock_g) for p in c] for c in two
    ]
    paths = []
    for name, curves in (("a", one), ("b", two)):
        paths.append(
            (write_tradeoff_csv(tmp_path / name, curves), tradeoff_png(tmp_path / name, curves))
        )
    (csv_a, png_a), (csv_b, png_b) = paths
    assert csv_a.name == CSV_NAME and png_a.name == PNG_NAME
    assert csv_a.read_bytes() == csv_b.read_bytes()
    assert png_a.read_bytes() == png_b.read_bytes()
    assert png_a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    rows = list(csv.DictReader(csv_a.open()))
    assert tuple(rows[0]) == CSV_HEADER
    assert len(rows) == 6 + 3 + 1
    assert [r["method"] for r in rows] == ["reactive"] * 6 + ["proactive"] * 3 + ["no_change"]
    on_front = [r for r in rows if r["on_front"] == "true"]
    fronts = [pareto_front(c) for c in one]
    assert len(on_front) == sum(len(f) for f in fronts)
    assert rows[-1]["slow_fraction"] == "" and float(rows[-1]["time_norm"]) == 1.0
    assert float(rows[0]["slow_fraction"]) == 0.3 and float(rows[0]["recovery_mps2"]) == 0.2
