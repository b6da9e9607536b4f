"""The paper's Fig. 7 (Sect. 7.2): shock experienced against completion time when the speed
is lowered reactively (after a measured rough event, the race software) or proactively
(before an event the roughness model flags ahead, the paper's method).

**What is replayed.** A route is one log's test events in driving order: consecutive
stretches ``[s_start_m, s_end_m]`` of the rear-axle path, each with the speed the log drove
over it (``speed_mps``, the *nominal* speed: what "no speed change" means), its ruggedness
coefficient (G per mph, Sect. 5.2), its measured label ``rough`` (ruggedness at or above the
threshold of Sect. 7) and the model's verdict ``predicted``. Sect. 7.2 states that "the only
software change is the mechanism that triggers speed reduction", so both controllers share
one speed profile (slow to a fraction of the nominal speed, hold, recover) and differ only in
*where* it is triggered and *what* triggers it. Events dropped by the label stage leave gaps
in ``s``; a gap costs no time (nothing is known about it) but the speed caps run across it,
since they are functions of the position ``s``.

**Shock at another speed.** Sect. 5.2 finds the shock over an obstacle "approximated tightly
by a linear function" of speed and defines the ruggedness coefficient as shock / speed. So an
event driven at ``v`` instead of the logged speed is replayed with shock
``ruggedness * v / MPS_PER_MPH`` G (1 mph = 0.44704 m/s exactly): proportional to speed,
through the origin, which is what the coefficient assumes.

**Speed over an event.** Each slowdown (one per trigger) is a speed *cap* ``c(s)`` along the
path; the vehicle's speed at ``s`` is ``min(nominal, every active cap)``. An event is driven
at that speed evaluated at its middle ``m = (s_start + s_end) / 2`` (events are ~1.4 m, the
speed changes little within one), taking ``(s_end - s_start) / v`` seconds. Completion time
is the sum over the events. A cap is a fraction of the nominal speed *at its trigger*, not of
the speed the vehicle has there: overlapping slowdowns take the lowest cap rather than
compounding (a second rough event while slowed does not halve the speed again), as a speed
limit set by the controller would.

**One slowdown.** With ``v0`` the nominal speed of the trigger event, ``v_slow =
slow_fraction * v0``, braking limit ``a = decel_mps2``, recovery rate ``r = recovery_mps2``,
and the slowdown known from ``s_know`` on, the vehicle wants to be at ``v_slow`` on a *hold*
interval ``[s_lo, s_hi]``. Under constant acceleration ``v^2`` is linear in distance
(``v^2 = v_1^2 + 2 a d``), so the *plan* is::

    P(s)^2 = v_slow^2 + 2 a max(0, s_lo - s) + 2 r max(0, s - s_hi)

the latest braking that reaches ``v_slow`` at ``s_lo`` (the braking envelope), the hold,
then a recovery at ``r`` whose cap grows until the nominal speed ends it. The vehicle cannot
start braking before it knows: at ``s_know`` it is at ``v0`` and can at best brake from there,

    B(s)^2 = max(0, v0^2 - 2 a (s - s_know))

so the cap is ``c(s) = max(P(s), B(s))`` for ``s >= s_know`` and no cap before ``s_know``.
``P^2 - B^2`` is constant before ``s_lo``: ``2 a (s_lo - s_know) - (v0^2 - v_slow^2)``. With
enough warning (``s_lo - s_know`` at least the braking distance ``(v0^2 - v_slow^2) / 2a``)
the envelope governs and the vehicle is at ``v_slow`` on the whole hold interval; with less,
``B`` governs: it brakes from ``s_know`` and reaches ``s_lo`` at
``sqrt(max(v_slow^2, v0^2 - 2 a (s_lo - s_know)))``, still braking into the hold interval
until ``v_slow`` (or until the recovery cap passes it).

- *Reactive* (Sect. 7.2: "the vehicle slowed after an onset of rough terrain was detected by
  the accelerometers"): every event with ``rough`` True triggers at its end,
  ``s_know = s_end`` (the IMU has measured the whole event only once it is over). The
  vehicle brakes from ``v0`` at once, ``s_lo = s_know + (v0^2 - v_slow^2) / 2a`` (where it
  reaches ``v_slow``; here ``P = B`` before it), ``s_hi = s_lo + hold_distance_m``. The
  triggering event itself is not slowed (its middle is before ``s_know``); the next ones are.
- *Proactive* (the paper's method): every event ``j`` with ``predicted`` True is flagged and
  known ``lookahead_m`` before it, ``s_know = s_start_j - lookahead_m``; ``s_lo = s_start_j``,
  ``s_hi = s_end_j + hold_distance_m``. ``v0`` (nominal speed of event ``j``) stands for the
  speed at ``s_know``: the log's speed changes little over a lookahead of tens of metres.
  ``lookahead_m = inf`` means the verdict is known arbitrarily early.
- *No change*: the nominal speeds.

**Shock experienced.** The Fig. 7 y-axis is ``sum over events of max(0, shock_g -
shock_floor_g)``. Slowing lowers *every* shock in proportion, so a plain sum
(``shock_floor_g = 0``) rewards slowing anywhere, rough or not; a floor counts only the part
of each shock above a level worth avoiding, so slowing on smooth ground buys nothing. The
plain sum and the count of events above the floor are reported too. Both axes are normalised
by the no-change run over the same routes (Sect. 7.2); a no-change shock of zero gives NaN.

**Comparing curves.** A sweep of the controller parameters traces a cloud of (time, shock)
points per method; its Pareto front (:func:`pareto_front`) is the curve of Fig. 7: the
lowest shock reachable for each completion time. The paper's "the reduction is as much as
50%" is read at equal completion time (:func:`shock_reduction_at_equal_time`): at the
normalised time of each reactive front point inside the proactive front's time range, the
proactive shock is interpolated linearly along its front (drawn as a line, as in Fig. 7) and
the reduction is ``1 - proactive / reactive``.

Arrays are float64 (E,) over a route's E events; (E, K) in the cap computation over K
slowdowns, evaluated in blocks of at most :data:`BLOCK` x :data:`BLOCK` and only over the
slowdowns whose caps can reach each block of events (no loop per event).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import BoolArray, FloatArray
from toolkit.errors import ConfigError, StageError
from toolkit.model.shock import MPS_PER_MPH

Method = Literal["no_change", "reactive", "proactive"]
METHODS: tuple[Method, ...] = ("no_change", "reactive", "proactive")

#: Names of the methods in Fig. 7's legend (the paper's labels).
METHOD_LABELS: dict[str, str] = {
    "no_change": "no speed change",
    "reactive": "reactive only (race)",
    "proactive": "self-supervised (proactive)",
}

#: Side of the blocks of the (events x slowdowns) cap array: 1024 x 1024 float64 is 8 MiB
#: per temporary, small enough for two shared cores, large enough that numpy dominates.
BLOCK = 1024


@dataclass(frozen=True)
class SpeedControlParams:
    """The speed controller (shared by both triggers, Sect. 7.2) and the shock floor.

    ``slow_fraction`` in (0, 1]: slow speed / nominal speed of the trigger event.
    ``decel_mps2`` > 0: braking limit. ``recovery_mps2`` > 0: acceleration back to nominal.
    ``hold_distance_m`` >= 0: distance held at the slow speed (reactive: after reaching it;
    proactive: after the flagged event's end). ``lookahead_m`` >= 0 (may be inf, proactive
    only): how far before a flagged event the model's verdict is known. ``shock_floor_g``
    >= 0: the part of each event's shock that is not counted (0: the plain sum).

    The defaults are placeholders of plausible magnitude, not the race's values (the paper
    says only that they "were set by machine learning to match human driving"): a caller
    sweeps ``slow_fraction`` and ``recovery_mps2`` and sets the rest.
    """

    slow_fraction: float = 0.5
    decel_mps2: float = 1.5
    recovery_mps2: float = 0.5
    hold_distance_m: float = 20.0
    lookahead_m: float = 20.0
    shock_floor_g: float = 0.0

    def __post_init__(self) -> None:
        checks: tuple[tuple[str, float, bool, str], ...] = (
            ("slow_fraction", self.slow_fraction, 0.0 < self.slow_fraction <= 1.0, "in (0, 1]"),
            ("decel_mps2", self.decel_mps2, 0.0 < self.decel_mps2 < math.inf, "finite, > 0"),
            (
                "recovery_mps2",
                self.recovery_mps2,
                0.0 < self.recovery_mps2 < math.inf,
                "finite, > 0",
            ),
            (
                "hold_distance_m",
                self.hold_distance_m,
                0.0 <= self.hold_distance_m < math.inf,
                "finite, >= 0",
            ),
            ("lookahead_m", self.lookahead_m, self.lookahead_m >= 0.0, ">= 0 (inf allowed)"),
            (
                "shock_floor_g",
                self.shock_floor_g,
                0.0 <= self.shock_floor_g < math.inf,
                "finite, >= 0",
            ),
        )
        for name, value, ok, want in checks:
            # NaN fails every comparison above, so it lands here too.
            if not ok:
                raise ConfigError(f"speed control: {name} = {value!r}, expected {want}")


@dataclass(frozen=True, eq=False)
class Route:
    """One log's test events in driving order, all arrays (E,).

    ``s_start_m``, ``s_end_m``: each strictly increasing, ``s_end_m >= s_start_m``.
    ``speed_mps`` > 0: the logged (nominal) speed. ``ruggedness`` >= 0, G per mph.
    ``rough``, ``predicted``: bool, measured label and model verdict. ``source`` names the
    log in errors. Invalid input raises :class:`~toolkit.errors.StageError`.
    """

    s_start_m: FloatArray
    s_end_m: FloatArray
    speed_mps: FloatArray
    ruggedness: FloatArray
    rough: BoolArray
    predicted: BoolArray
    source: str | Path | None = None

    def __post_init__(self) -> None:
        floats = ("s_start_m", "s_end_m", "speed_mps", "ruggedness")
        bools = ("rough", "predicted")
        arrays = {name: np.asarray(getattr(self, name)) for name in floats + bools}
        lengths = {name: a.shape for name, a in arrays.items()}
        if any(a.ndim != 1 for a in arrays.values()) or len(set(lengths.values())) != 1:
            raise StageError(
                f"route arrays must be 1-D of equal length, got shapes {lengths}", self.source
            )
        for name in bools:
            if arrays[name].dtype != np.bool_:
                raise StageError(
                    f"route column {name} must be bool, got dtype {arrays[name].dtype}",
                    self.source,
                )
        for name in floats:
            a = arrays[name]
            if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
                raise StageError(
                    f"route column {name} must be numeric, got dtype {a.dtype}", self.source
                )
            a = a.astype(np.float64)
            arrays[name] = a
            self._require(name, a, np.isfinite(a), "is not finite")
        self._require("speed_mps", arrays["speed_mps"], arrays["speed_mps"] > 0, "is not > 0")
        self._require("ruggedness", arrays["ruggedness"], arrays["ruggedness"] >= 0, "is < 0")
        length = arrays["s_end_m"] - arrays["s_start_m"]
        self._require("s_end_m", arrays["s_end_m"], length >= 0, "is before s_start_m")
        for name in ("s_start_m", "s_end_m"):
            a = arrays[name]
            # Element i + 1 is compared with element i; the message names i + 1.
            ok = np.concatenate([[True], np.diff(a) > 0])
            self._require(name, a, ok, "does not increase (strictly) from the previous event")
        for name, a in arrays.items():
            object.__setattr__(self, name, a)

    def _require(self, name: str, values: NDArray[np.generic], ok: BoolArray, what: str) -> None:
        """StageError naming the first element of ``values`` (column ``name``) where ``ok`` is
        False, and its value."""
        if not bool(np.all(ok)):
            i = int(np.flatnonzero(~ok)[0])
            raise StageError(f"route column {name}[{i}] = {values[i].item()!r} {what}", self.source)

    @property
    def events(self) -> int:
        """E, the number of events."""
        return int(self.s_start_m.size)


@dataclass(frozen=True)
class DriveResult:
    """A replayed drive: ``time_s`` completion time, ``shock_g`` the shock experienced (sum
    of the shocks above the floor, less the floor), ``shock_sum_g`` the plain sum,
    ``shocks_over_floor`` the events whose shock exceeds the floor, ``events`` driven."""

    time_s: float
    shock_g: float
    shock_sum_g: float
    shocks_over_floor: int
    events: int

    def __add__(self, other: DriveResult) -> DriveResult:
        return DriveResult(
            self.time_s + other.time_s,
            self.shock_g + other.shock_g,
            self.shock_sum_g + other.shock_sum_g,
            self.shocks_over_floor + other.shocks_over_floor,
            self.events + other.events,
        )


@dataclass(frozen=True)
class TradeoffPoint:
    """One point of Fig. 7: a method and its parameters, the summed time and shock over the
    routes, and both normalised by the no-change run (NaN where that is zero)."""

    method: str
    params: SpeedControlParams
    time_s: float
    shock_g: float
    time_norm: float
    shock_norm: float
    shock_sum_g: float
    shocks_over_floor: int


@dataclass(frozen=True)
class ShockReduction:
    """:func:`shock_reduction_at_equal_time`: ``max_reduction`` the largest of
    ``reductions`` (NaN if none is defined); ``time_norm`` (M,) the reactive front's
    normalised times inside the proactive front's range, ``reductions`` (M,) ``1 -
    proactive / reactive`` shock there (NaN where the reactive shock is zero)."""

    max_reduction: float
    time_norm: FloatArray
    reductions: FloatArray


@dataclass(frozen=True)
class _Slowdowns:
    """K slowdowns (see the module docstring), arrays (K,) with ``s_know_m`` increasing."""

    s_know_m: FloatArray
    v0_mps: FloatArray
    v_slow_mps: FloatArray
    s_lo_m: FloatArray
    s_hi_m: FloatArray


def _slowdowns(route: Route, params: SpeedControlParams, method: Method) -> _Slowdowns:
    """The slowdowns ``method`` triggers on ``route``."""
    a = params.decel_mps2
    if method == "reactive":
        idx = np.flatnonzero(route.rough)
        s_know = route.s_end_m[idx]
        v0 = route.speed_mps[idx]
        v_slow = params.slow_fraction * v0
        s_lo = s_know + (v0**2 - v_slow**2) / (2.0 * a)
        s_hi = s_lo + params.hold_distance_m
    else:
        idx = np.flatnonzero(route.predicted)
        s_lo = route.s_start_m[idx]
        s_know = s_lo - params.lookahead_m
        v0 = route.speed_mps[idx]
        v_slow = params.slow_fraction * v0
        s_hi = route.s_end_m[idx] + params.hold_distance_m
    return _Slowdowns(s_know, v0, v_slow, s_lo, s_hi)


def _cap_block(
    mid_m: FloatArray, sd: _Slowdowns, k: slice, params: SpeedControlParams
) -> FloatArray:
    """Lowest cap (B,) at the ``mid_m`` (B,) over slowdowns ``k``: ``max(P, B)`` of the
    module docstring where known, inf before ``s_know``; an (B, K) array."""
    s = mid_m[:, None]
    a, r = params.decel_mps2, params.recovery_mps2
    since_know = s - sd.s_know_m[None, k]
    brake2 = np.maximum(sd.v0_mps[None, k] ** 2 - 2.0 * a * since_know, 0.0)
    plan2 = (
        sd.v_slow_mps[None, k] ** 2
        + 2.0 * a * np.maximum(sd.s_lo_m[None, k] - s, 0.0)
        + 2.0 * r * np.maximum(s - sd.s_hi_m[None, k], 0.0)
    )
    cap = np.where(since_know >= 0.0, np.sqrt(np.maximum(brake2, plan2)), np.inf)
    return np.asarray(cap.min(axis=1), np.float64)


def _caps(
    mid_m: FloatArray, nominal_mps: FloatArray, sd: _Slowdowns, params: SpeedControlParams
) -> FloatArray:
    """Lowest cap (E,) at the event middles ``mid_m`` (E,, increasing) over all slowdowns."""
    cap = np.full(mid_m.shape, np.inf)
    if sd.s_know_m.size == 0 or mid_m.size == 0:
        return cap
    # Past s_gone the recovery cap exceeds every nominal speed of the route (and B <= v0 is
    # below it), so the slowdown no longer binds. Its running maximum is increasing, so the
    # slowdowns that can reach a block of events are one contiguous index range.
    v_top = float(nominal_mps.max())
    s_gone = sd.s_hi_m + np.maximum(v_top**2 - sd.v_slow_mps**2, 0.0) / (2.0 * params.recovery_mps2)
    reach = np.maximum.accumulate(s_gone)
    for i0 in range(0, mid_m.size, BLOCK):
        block = mid_m[i0 : i0 + BLOCK]
        k_lo = int(np.searchsorted(reach, block[0], side="left"))
        k_hi = int(np.searchsorted(sd.s_know_m, block[-1], side="right"))
        for k0 in range(k_lo, k_hi, BLOCK):
            k = slice(k0, min(k0 + BLOCK, k_hi))
            cap[i0 : i0 + BLOCK] = np.minimum(
                cap[i0 : i0 + BLOCK], _cap_block(block, sd, k, params)
            )
    return cap


def _check_method(method: str) -> Method:
    if method not in METHODS:
        raise ValueError(f"unknown speed control method {method!r}, expected one of {METHODS}")
    return method


def event_speeds(route: Route, params: SpeedControlParams, method: Method) -> FloatArray:
    """Speed (E,) m/s over each event of ``route`` under ``method``: ``min(nominal, caps)`` at
    the event's middle (module docstring)."""
    method = _check_method(method)
    if method == "no_change":
        return route.speed_mps.copy()
    mid = 0.5 * (route.s_start_m + route.s_end_m)
    cap = _caps(mid, route.speed_mps, _slowdowns(route, params, method), params)
    return np.minimum(route.speed_mps, cap)


def event_shocks_g(route: Route, speed_mps: FloatArray) -> FloatArray:
    """Shock (E,) G of each event driven at ``speed_mps`` (E,): ruggedness times speed in mph,
    the linear model of Sect. 5.2."""
    return np.asarray(route.ruggedness * (speed_mps / MPS_PER_MPH), np.float64)


def drive(route: Route, params: SpeedControlParams, method: Method) -> DriveResult:
    """Replay ``route`` under ``method``: completion time and shock (an empty route gives
    zeros)."""
    v = event_speeds(route, params, method)
    shock = event_shocks_g(route, v)
    over = shock - params.shock_floor_g
    return DriveResult(
        time_s=float(np.sum((route.s_end_m - route.s_start_m) / v)),
        shock_g=float(np.sum(np.maximum(over, 0.0))),
        shock_sum_g=float(np.sum(shock)),
        shocks_over_floor=int(np.count_nonzero(over > 0.0)),
        events=route.events,
    )


def drive_routes(
    routes: Iterable[Route], params: SpeedControlParams, method: Method
) -> DriveResult:
    """Each route (one log) replayed separately, times and shocks summed."""
    total = DriveResult(0.0, 0.0, 0.0, 0, 0)
    for route in routes:
        total = total + drive(route, params, method)
    return total


def _ratio(x: float, ref: float) -> float:
    return x / ref if ref > 0 else math.nan


def tradeoff_point(
    routes: Sequence[Route],
    params: SpeedControlParams,
    method: Method,
    reference: DriveResult | None = None,
) -> TradeoffPoint:
    """The Fig. 7 point of ``method`` with ``params`` over ``routes``, normalised by
    ``reference`` (default: the no-change run with the same floor)."""
    if reference is None:
        reference = drive_routes(routes, params, "no_change")
    res = drive_routes(routes, params, method)
    return TradeoffPoint(
        method=method,
        params=params,
        time_s=res.time_s,
        shock_g=res.shock_g,
        time_norm=_ratio(res.time_s, reference.time_s),
        shock_norm=_ratio(res.shock_g, reference.shock_g),
        shock_sum_g=res.shock_sum_g,
        shocks_over_floor=res.shocks_over_floor,
    )


def reactive_curve(
    routes: Sequence[Route],
    base_params: SpeedControlParams,
    slow_fractions: Sequence[float],
    recovery_rates: Sequence[float],
) -> list[TradeoffPoint]:
    """The reactive controller at every (slow fraction, recovery rate), the other parameters
    from ``base_params``; in that order (fractions outer)."""
    ref = drive_routes(routes, base_params, "no_change")
    return [
        tradeoff_point(
            routes,
            dataclasses.replace(base_params, slow_fraction=f, recovery_mps2=r),
            "reactive",
            ref,
        )
        for f in slow_fractions
        for r in recovery_rates
    ]


def proactive_curve(
    routes: Sequence[Route], base_params: SpeedControlParams, slow_fractions: Sequence[float]
) -> list[TradeoffPoint]:
    """The proactive controller at every slow fraction, the rest from ``base_params``."""
    ref = drive_routes(routes, base_params, "no_change")
    return [
        tradeoff_point(routes, dataclasses.replace(base_params, slow_fraction=f), "proactive", ref)
        for f in slow_fractions
    ]


def no_change_point(routes: Sequence[Route], params: SpeedControlParams) -> TradeoffPoint:
    """The no-change run: (1, 1) once normalised (NaN where its time or shock is zero)."""
    return tradeoff_point(routes, params, "no_change")


def pareto_front(points: Sequence[TradeoffPoint]) -> list[TradeoffPoint]:
    """The non-dominated points (no other point has both less-or-equal ``time_s`` and
    ``shock_g``, one strictly) sorted by time: each point of the front has strictly lower
    shock than every faster one. Of equal points the first given is kept; points with a NaN
    time or shock are left out."""
    ok = [p for p in points if not (math.isnan(p.time_s) or math.isnan(p.shock_g))]
    # Stable sort: equal (time, shock) keep their given order, so the first is kept.
    ordered = sorted(ok, key=lambda p: (p.time_s, p.shock_g))
    front: list[TradeoffPoint] = []
    for p in ordered:
        if not front or p.shock_g < front[-1].shock_g:
            front.append(p)
    return front


def shock_reduction_at_equal_time(
    reactive_front: Sequence[TradeoffPoint], proactive_front: Sequence[TradeoffPoint]
) -> ShockReduction:
    """How much less shock the proactive front has than the reactive one at equal completion
    time (Sect. 7.2's "as much as 50%").

    For each reactive point whose ``time_norm`` lies in ``[min, max]`` of the proactive
    points' ``time_norm``, the proactive ``shock_norm`` is interpolated linearly at that time
    along the proactive points sorted by time (pass :func:`pareto_front` outputs), and the
    reduction is ``1 - proactive / reactive``. No overlap gives NaN (empty arrays), a reactive
    shock of zero a NaN reduction at that point.
    """
    pro = sorted(
        (p for p in proactive_front if not (math.isnan(p.time_norm) or math.isnan(p.shock_norm))),
        key=lambda p: (p.time_norm, p.shock_norm),
    )
    empty = ShockReduction(math.nan, np.zeros(0), np.zeros(0))
    if not pro:
        return empty
    pt = np.array([p.time_norm for p in pro], np.float64)
    ps = np.array([p.shock_norm for p in pro], np.float64)
    rt = np.array([p.time_norm for p in reactive_front], np.float64)
    rs = np.array([p.shock_norm for p in reactive_front], np.float64)
    inside = (rt >= pt[0]) & (rt <= pt[-1])
    if not bool(inside.any()):
        return empty
    t, r = rt[inside], rs[inside]
    p_at = np.interp(t, pt, ps)
    with np.errstate(divide="ignore", invalid="ignore"):
        red = np.where(r > 0, 1.0 - p_at / np.where(r > 0, r, 1.0), np.nan)
    best = float(np.nanmax(red)) if bool(np.isfinite(red).any()) else math.nan
    return ShockReduction(best, t, np.asarray(red, np.float64))


__all__ = [
    "BLOCK",
    "METHODS",
    "METHOD_LABELS",
    "DriveResult",
    "Method",
    "Route",
    "ShockReduction",
    "SpeedControlParams",
    "TradeoffPoint",
    "drive",
    "drive_routes",
    "event_shocks_g",
    "event_speeds",
    "no_change_point",
    "pareto_front",
    "proactive_curve",
    "reactive_curve",
    "shock_reduction_at_equal_time",
    "tradeoff_point",
]
