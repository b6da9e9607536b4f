"""Learning the model's parameters by coordinate ascent (sect. 6, eqs. 6 and 7).

The objective, maximised::

    J = Tp - lambda Fp                                                              (eq. 6)

with Tp and Fp the true- and false-positive rates of ``R_combined > mu`` against the labels
(ruggedness at or above the user's threshold, sect. 5.2). The search::

    B = (alpha_1..alpha_10, upsilon, omega, zeta)        the 13-vector, an initial guess
    I = initial increments,  S = signs
    T = B + S I                                                                     (eq. 7)

Each element of S in turn takes -1 then +1 (all others zero); for each T every value of
R_combined is a candidate mu (:func:`best_threshold`); if T improves J, ``B = T``, mu is
saved, and the search moves to the next element. After a full rotation I is halved; this
repeats a fixed number of times. Decisions the paper leaves open:

- *Improvement* (``accept``, :data:`ACCEPTANCE`) is judged on the training split by one of:

  ``"objective"`` (the paper's): a strictly larger J, or on a tie in J a strictly larger
  area under the ROC curve (AUC) of R_combined. J is piecewise constant, and with rare
  positives and lambda = 5 it is 0 (nothing predicted rough beats any cut) over wide regions
  of parameter space: measured on a 6.4 km race log (2,284 training events, 9 rough), every
  single step from the default initial guess left J at 0 and the plain search never moved,
  although parameters with J = 0.22 exist. The AUC tie-break lets the search climb such
  plateaus. With 20-60 training positives J is decided by the top few events, and the
  search buys them by driving 90-99 % of all events to R = 0 (W >= 0): the ranking of
  everything else is given up (``benchmarks/README.md``, "What the search does").

  ``"auc"``: a strictly larger training AUC (ties counted half), then a larger J. The
  whole ranking is what is climbed, so events are not sacrificed to eq. (6)'s corner.

  ``"pauc"``: a strictly larger partial AUC up to FPR :data:`PAUC_MAX_FPR` (the region
  sect. 7.1 calls the most important), then the AUC, then J.

  Whichever decides the steps, mu is always eq. (6)'s best threshold for the parameters
  reached (lambda as configured): the paper's objective still picks the operating point.
  Acceptance is strict, so the search never ends below its starting point on the measure
  it climbs, and it stays deterministic.

- *Early stopping* (``validation_share`` > 0, beyond the paper): with a few dozen training
  positives every measure can be climbed far past what holds on unseen road. A share of
  the training events (whole stretches: :func:`validation_events`) is then held out: the
  steps are judged on the rest, and the search returns the parameters of the rotation (the
  start included) that ranked the held-out events best by the same measure. mu is then
  chosen by eq. (6) on every training event.
- *omega stays a positive integer*: its step is ``max(1, round(I_omega))``, so it keeps moving
  by at least one pair after its increment has halved below 1. Any T outside the model's
  domain (an exponent, upsilon or zeta not positive, omega below 1:
  :meth:`RoughnessParams.admissible`) is skipped, as is one whose scores overflow.
- *mu between two adjacent R_combined values* is their midpoint; on a tie in J between
  thresholds, the one predicting fewer events rough (lambda > 0 prefers few false alarms).
- *The step sizes* (``step_rule``, :data:`STEP_RULES`): ``"halve"`` is the paper's, every
  increment halved after each full rotation, so element j can move at most about
  ``2 I_j`` from its start in all: the initial increments decide which scales the search can
  reach, and a start far from the optimum (a penalty at zero whose useful weight is ten
  increments away) stays there. ``"adapt"`` (beyond the paper; a compass search with
  expansion, Kolda, Lewis and Torczon 2003, sect. 3): each element keeps its own increment,
  doubled after a step along it is accepted and halved after both signs fail, so a
  penalty that helps keeps growing geometrically until it overshoots, and one that does not
  narrows in as the paper's does. The number of rotations is the same either way.
- *Frozen parameters*: ``free`` names the elements of B the search may change; the others
  keep their initial value (the baseline of Fig. 6 learns upsilon, omega and zeta only; the
  ablations fix the time or the rate terms at zero).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from toolkit.arrays import BoolArray, FloatArray
from toolkit.model.roughness import (
    N_ALPHA,
    N_ALPHA_LEAD,
    RoughnessParams,
    TopScores,
    combine,
    total_score,
)

#: Names of the 13 elements of B, in order.
B_NAMES = tuple(f"alpha_{i}" for i in range(1, N_ALPHA + 1)) + ("upsilon", "omega", "zeta")
#: With the look-ahead term (:mod:`toolkit.model.roughness`), B has 15 elements.
B_NAMES_LEAD = tuple(f"alpha_{i}" for i in range(1, N_ALPHA_LEAD + 1)) + (
    "upsilon",
    "omega",
    "zeta",
)
OMEGA = 11


def b_names(size: int) -> tuple[str, ...]:
    """The names of B's elements for a B of ``size`` (13, or 15 with the look-ahead term)."""
    return B_NAMES if size == len(B_NAMES) else B_NAMES_LEAD


#: What decides whether a step improves (module docstring): eq. (6) first, the AUC first,
#: or the partial AUC first.
ACCEPTANCE = ("objective", "auc", "pauc")
#: How the increments change (module docstring): after every rotation, all halved (the
#: paper's), or each by its own element's success (doubled) and failure (halved).
STEP_RULES = ("halve", "adapt")
#: The partial AUC's upper FPR: sect. 7.1, "the most important region (0-20% false
#: positive rate)".
PAUC_MAX_FPR = 0.2


@dataclass(frozen=True)
class Threshold:
    """The best mu for a set of scores and its rates: J = tpr - lambda fpr (eq. 6)."""

    mu: float
    objective: float
    tpr: float
    fpr: float
    auc: float = 0.5
    #: Area under the ROC curve from FPR 0 to :data:`PAUC_MAX_FPR`, divided by that width
    #: (1 for a perfect ranking, 0.1 for a random one).
    pauc: float = 0.1

    def key(self, accept: str = "objective") -> tuple[float, ...]:
        """What a step is judged by, compared lexicographically (module docstring)."""
        if accept == "objective":
            return (self.objective, self.auc)
        if accept == "auc":
            return (self.auc, self.objective)
        if accept == "pauc":
            return (self.pauc, self.auc, self.objective)
        raise ValueError(f"accept must be one of {ACCEPTANCE}, not {accept!r}")

    def beats(self, other: Threshold, accept: str = "objective", margin: float = 0.0) -> bool:
        """Strictly better by :meth:`key` (the paper's: a larger J, on a tie a larger AUC);
        with a ``margin``, better by more than it in the first measure."""
        if margin > 0.0:
            return self.key(accept)[0] > other.key(accept)[0] + margin
        return self.key(accept) > other.key(accept)


def best_threshold(r_combined: FloatArray, rough: BoolArray, lambda_fp: float) -> Threshold:
    """Every distinct R_combined value as a threshold (sect. 6): the mu maximising eq. (6).

    Scores (E,), labels (E,), at least one positive and one negative. Cutting below the
    k-th largest distinct value predicts rough the events scoring at least it; mu is put
    midway to the next lower value, so ``R_combined > mu`` reproduces that cut. Predicting
    nothing rough (J = 0) is a candidate too. Also returns the area under the ROC curve
    these cuts trace (ties count half, as in the Mann-Whitney statistic).
    """
    r = np.asarray(r_combined, np.float64)
    y = np.asarray(rough, bool)
    n_pos = int(y.sum())
    n_neg = int(y.size - n_pos)
    order = np.argsort(-r, kind="stable")
    r_sorted = r[order]
    tp = np.cumsum(y[order])
    fp = np.arange(1, r.size + 1) - tp
    # A cut may only fall where the score changes (ties go together).
    last_of_tie = np.r_[r_sorted[1:] != r_sorted[:-1], True]
    tpr = tp[last_of_tie] / n_pos
    fpr = fp[last_of_tie] / n_neg
    j = tpr - lambda_fp * fpr
    cut_at = np.flatnonzero(last_of_tie)
    # Trapezoids between consecutive cuts, from (0, 0): a tie spanning both classes is
    # a diagonal step, which counts its pairs half.
    f = np.r_[0.0, fpr]
    t = np.r_[0.0, tpr]
    auc = float(np.sum(np.diff(f) * (t[1:] + t[:-1]) * 0.5))
    pauc = partial_auc(f, t, PAUC_MAX_FPR)
    best = int(np.argmax(j))  # argmax takes the first maximum: the fewest predicted rough
    if j[best] <= 0.0:
        # Nothing called rough beats calling nothing rough: mu just above the highest score.
        return Threshold(float(np.nextafter(r_sorted[0], np.inf)), 0.0, 0.0, 0.0, auc, pauc)
    i = cut_at[best]
    if i + 1 < r.size:
        mu = 0.5 * (r_sorted[i] + r_sorted[i + 1])
        if not mu < r_sorted[i]:  # adjacent floats: no midpoint between them
            mu = r_sorted[i + 1]
    else:
        mu = float(np.nextafter(r_sorted[i], -np.inf))
    return Threshold(float(mu), float(j[best]), float(tpr[best]), float(fpr[best]), auc, pauc)


def partial_auc(fpr: FloatArray, tpr: FloatArray, max_fpr: float) -> float:
    """The area under the ROC polyline (F,) from FPR 0 to ``max_fpr``, divided by
    ``max_fpr``; the polyline's points run from (0, 0) with FPR non-decreasing, and the
    segment crossing ``max_fpr`` is cut there (linear, as the trapezoids count ties)."""
    inside = fpr <= max_fpr
    f = fpr[inside]
    t = tpr[inside]
    k = int(np.count_nonzero(inside))
    if k < fpr.size and fpr[k] > f[-1]:
        # The cut point on the segment from the last point inside to the first outside.
        t_cut = t[-1] + (tpr[k] - t[-1]) * (max_fpr - f[-1]) / (fpr[k] - f[-1])
        f = np.r_[f, max_fpr]
        t = np.r_[t, t_cut]
    return float(np.sum(np.diff(f) * (t[1:] + t[:-1]) * 0.5) / max_fpr)


@dataclass(frozen=True)
class AscentConfig:
    """The search of sect. 6: initial B (13 elements, 15 with the look-ahead term),
    increments I (as many), which elements move, lambda of eq. (6), the number of full
    rotations, what a step must improve, and early stopping."""

    initial: tuple[float, ...]
    increments: tuple[float, ...]
    lambda_fp: float = 5.0
    iterations: int = 20
    #: Which elements of B move (one flag each; empty: all).
    free: tuple[bool, ...] = ()
    #: What a step must improve (:data:`ACCEPTANCE`); mu is eq. (6)'s either way.
    accept: str = "objective"
    #: Early stopping: the share of training events held out (0: none), in blocks of
    #: ``validation_block`` consecutive events (:func:`validation_events`).
    validation_share: float = 0.0
    validation_block: int = 50
    #: How the increments change (:data:`STEP_RULES`).
    step_rule: str = "halve"
    #: A step must raise the accepted measure by more than this (0: any rise, the paper's).
    margin: float = 0.0

    def __post_init__(self) -> None:
        if self.accept not in ACCEPTANCE:
            raise ValueError(f"accept must be one of {ACCEPTANCE}, not {self.accept!r}")
        if self.step_rule not in STEP_RULES:
            raise ValueError(f"step_rule must be one of {STEP_RULES}, not {self.step_rule!r}")
        n = len(self.initial)
        if n not in (len(B_NAMES), len(B_NAMES_LEAD)) or len(self.increments) != n:
            raise ValueError(
                f"B and its increments need 13 or 15 elements each, not {n} and "
                f"{len(self.increments)}"
            )
        if self.free and len(self.free) != n:
            raise ValueError(f"free needs {n} flags, not {len(self.free)}")

    def moves(self, j: int) -> bool:
        """Whether element ``j`` of B may change."""
        return not self.free or self.free[j]


@dataclass(frozen=True)
class AscentResult:
    """Learned parameters and how the search went.

    ``history`` holds J after each full rotation (``iterations`` entries), ``steps`` the
    accepted moves (rotation, element name, new value, J), ``evaluations`` the number of
    candidate vectors scored, ``start`` the initial guess's own result on the training split
    and ``accepted_by`` what the steps had to improve."""

    params: RoughnessParams
    objective: float
    tpr: float
    fpr: float
    auc: float
    iterations: int
    evaluations: int
    history: tuple[float, ...]
    steps: tuple[tuple[int, str, float, float], ...] = field(default=())
    pauc: float = 0.1
    start: Threshold | None = None
    accepted_by: str = "objective"
    #: The measure the steps climb (the first of :meth:`Threshold.key`) after each rotation.
    measure_history: tuple[float, ...] = ()
    #: With early stopping: the best held-out measure so far, after each rotation; the share
    #: of training events actually held out (0: none, also when a part lacked a class) and
    #: the rotation whose parameters were kept (0: the start). ``history``, ``steps`` and
    #: ``measure_history`` are then on the fitted events and run past the kept rotation.
    validation_history: tuple[float, ...] = ()
    held_out_share: float = 0.0
    kept_rotation: int | None = None
    #: The increments after the last rotation (where a search continued later would go on).
    increments: tuple[float, ...] = ()


class _Evaluator:
    """J of a vector B (13 or 15 elements), reusing each patch's sorted top scores while the
    alphas stay put (changing upsilon, omega or zeta then costs a weighted sum, not Delta
    again)."""

    def __init__(self, source: TopScores, rough: BoolArray, lambda_fp: float) -> None:
        self.source = source
        self.rough = rough
        self.lambda_fp = lambda_fp
        self._alpha: tuple[float, ...] | None = None
        self._top: FloatArray = np.zeros((0, 0))
        self.evaluations = 0

    def top(self, alpha: tuple[float, ...], k: int) -> FloatArray:
        if alpha != self._alpha or self._top.shape[1] < k:
            # A little more than asked, so omega's next step needs no new Delta.
            self._top = self.source.top_scores(alpha, k + 8)
            self._alpha = alpha
        return self._top

    def scores(self, params: RoughnessParams) -> FloatArray | None:
        """R_combined (E,) of every training event, None if one is not finite."""
        self.evaluations += 1
        top = self.top(params.alpha, params.omega)
        with np.errstate(over="ignore", invalid="ignore"):
            _, _, r_comb = combine(total_score(top, params.upsilon, params.omega), params.zeta)
        if not np.isfinite(r_comb).all():
            return None
        return r_comb

    def judge(self, r_comb: FloatArray, rows: BoolArray | None = None) -> Threshold:
        """Eq. (6)'s best threshold and the ROC areas on the events ``rows`` (all: None)."""
        if rows is None:
            return best_threshold(r_comb, self.rough, self.lambda_fp)
        return best_threshold(r_comb[rows], self.rough[rows], self.lambda_fp)


def validation_events(rough: BoolArray, share: float, block: int) -> BoolArray | None:
    """The training events (E,) held out to stop the search early: every k-th block of
    ``block`` consecutive events (k = round(1 / share)), so the held-out events are whole
    stretches of road, not neighbours of the fitted ones. None when ``share`` is 0 or either
    part would lack a rough or a smooth event."""
    if share <= 0.0:
        return None
    k = max(2, round(1.0 / share))
    held = (np.arange(rough.size) // block) % k == k - 1
    for part in (held, ~held):
        if not (rough[part].any() and (~rough[part]).any()):
            return None
    return np.asarray(held, bool)


#: An accepted move: (rotation, element name, new value, J after it).
Step = tuple[int, str, float, float]


@dataclass(frozen=True)
class _Climb:
    """Where the search stands: B, its judgement on the fitted events (J of eq. (6), the
    ROC areas, mu), its R_combined (E,) on every training event, and the moves accepted."""

    b: list[float]
    best: Threshold
    r_best: FloatArray
    steps: tuple[Step, ...] = ()

    def moved_in(self, rotation: int) -> bool:
        """Whether a move was accepted during ``rotation``."""
        return bool(self.steps) and self.steps[-1][0] == rotation


@dataclass(frozen=True)
class _EarlyStop:
    """Early stopping's state: the held-out events (E,), and the rotation (0: the start)
    whose B ranked them best so far by the measure the steps climb, with that measure."""

    held: BoolArray
    b: list[float]
    value: float
    rotation: int = 0

    def after(self, evaluate: _Evaluator, climb: _Climb, rotation: int, accept: str) -> _EarlyStop:
        """The state after ``rotation``: ``climb``'s B kept if it moved then and ranks the
        held-out events strictly better."""
        if not climb.moved_in(rotation):
            return self
        val = evaluate.judge(climb.r_best, self.held).key(accept)[0]
        if val > self.value:
            return _EarlyStop(self.held, list(climb.b), val, rotation + 1)
        return self


def _step(increment: float, j: int, omega: int) -> float:
    """The magnitude of element ``j`` of S I in eq. (7): I_j, except omega's, which stays a
    whole number of pairs, ``max(1, round(I_omega))``."""
    return max(1.0, float(round(increment))) if j == omega else increment


def _improve(
    evaluate: _Evaluator,
    climb: _Climb,
    j: int,
    step: float,
    fit: BoolArray | None,
    accept: str,
    margin: float = 0.0,
) -> tuple[list[float], RoughnessParams, Threshold, FloatArray] | None:
    """Eq. (7) along element ``j``: ``T = B + S I`` with S_j = -1, then +1 (all others 0).
    The first admissible T whose scores are finite and beat B by ``accept`` on the fitted
    events ``fit`` (all: None), as (T, its parameters, its judgement, its R_combined)."""
    b = climb.b
    for sign in (-1.0, 1.0):
        t = list(b)
        t[j] = b[j] + sign * step
        candidate = RoughnessParams.from_vector(t, 0.0)
        if not candidate.admissible():
            continue
        r = evaluate.scores(candidate)
        got = None if r is None else evaluate.judge(r, fit)
        if r is not None and got is not None and got.beats(climb.best, accept, margin):
            return t, candidate, got, r
    return None


def _rotate(
    evaluate: _Evaluator,
    climb: _Climb,
    rotation: int,
    inc: list[float],
    config: AscentConfig,
    fit: BoolArray | None,
) -> _Climb:
    """One full rotation of sect. 6: each free element of B in turn tries eq. (7)'s two
    signs with increments ``inc``, and B takes the first T that improves. The source then
    keeps the new B's terms (every later candidate differs from it in one element).

    ``inc`` is updated in place for the next rotation by ``config.step_rule``: all halved
    (the paper's), or each element's doubled if its step was taken and halved if not."""
    names = b_names(len(climb.b))
    omega = names.index("omega")
    moved = [False] * len(climb.b)
    for j in range(len(climb.b)):
        if not config.moves(j):
            continue
        step = _step(inc[j], j, omega)
        better = _improve(evaluate, climb, j, step, fit, config.accept, config.margin)
        if better is not None:
            t, candidate, got, r = better
            evaluate.source.hold(candidate.alpha)
            climb = _Climb(t, got, r, (*climb.steps, (rotation, names[j], t[j], got.objective)))
            moved[j] = True
    for j, took in enumerate(moved):
        if config.moves(j):  # a frozen element keeps its increment (an online update's)
            inc[j] *= 2.0 if took and config.step_rule == "adapt" else 0.5
    return climb


def _start(evaluate: _Evaluator, b: list[float], fit: BoolArray | None) -> tuple[_Climb, Threshold]:
    """The search's starting point from the initial B (its judgement on the fitted events),
    and the initial guess's own result on every training event. The source is set to keep
    B's terms. ValueError if B is outside the model's domain."""
    start = RoughnessParams.from_vector(b, 0.0)
    # Every candidate differs from B in one element: the source may keep B's terms.
    evaluate.source.hold(start.alpha)
    r0 = evaluate.scores(start) if start.admissible() else None
    if r0 is None:
        raise ValueError(f"the initial parameters {b} are outside the model's domain")
    return _Climb(b, evaluate.judge(r0, fit), r0), evaluate.judge(r0)


def _judge_kept(evaluate: _Evaluator, b: list[float]) -> Threshold:
    """Early stopping's kept B judged (and mu chosen by eq. (6)) on every training event."""
    r_kept = evaluate.scores(RoughnessParams.from_vector(b, 0.0))
    if r_kept is None:  # scored finite when kept; cannot fail
        raise RuntimeError("kept parameters no longer score")
    return evaluate.judge(r_kept)


def coordinate_ascent(
    source: TopScores,
    rough: BoolArray,
    config: AscentConfig,
    progress: Callable[[int], None] | None = None,
) -> AscentResult:
    """Sect. 6's coordinate ascent on ``source``'s patches (2E groups) and labels (E,):
    maximise ``J = Tp - lambda Fp`` (eq. 6) over B by steps ``T = B + S I`` (eq. 7), I
    halved after each full rotation (module docstring).

    ``progress`` is called with the rotation just finished. Deterministic: the same inputs
    give the same result.
    """
    rough = np.asarray(rough, bool)
    evaluate = _Evaluator(source, rough, config.lambda_fp)
    held = validation_events(rough, config.validation_share, config.validation_block)
    fit = None if held is None else ~held
    inc = list(config.increments)
    history: list[float] = []
    measures: list[float] = []
    val_history: list[float] = []
    try:
        climb, first = _start(evaluate, list(config.initial), fit)
        # Early stopping: the rotation (0: the start) whose parameters rank the held-out
        # events best, by the measure the steps climb.
        stop = None
        if held is not None:
            value = evaluate.judge(climb.r_best, held).key(config.accept)[0]
            stop = _EarlyStop(held, list(climb.b), value)
        for rotation in range(config.iterations):
            climb = _rotate(evaluate, climb, rotation, inc, config, fit)
            history.append(climb.best.objective)
            measures.append(climb.best.key(config.accept)[0])
            if stop is not None:
                stop = stop.after(evaluate, climb, rotation, config.accept)
                val_history.append(stop.value)
            if progress is not None:
                progress(rotation + 1)
        b, best = climb.b, climb.best
        if stop is not None:
            b, best = stop.b, _judge_kept(evaluate, stop.b)
    finally:
        source.hold(None)
    return AscentResult(
        params=RoughnessParams.from_vector(b, best.mu),
        objective=best.objective,
        tpr=best.tpr,
        fpr=best.fpr,
        auc=best.auc,
        iterations=config.iterations,
        evaluations=evaluate.evaluations,
        history=tuple(history),
        steps=climb.steps,
        pauc=best.pauc,
        start=first,
        accepted_by=config.accept,
        measure_history=tuple(measures),
        validation_history=tuple(val_history),
        held_out_share=0.0 if stop is None else float(stop.held.mean()),
        kept_rotation=None if stop is None else stop.rotation,
        increments=tuple(inc),
    )


def initial_vector(
    alpha: Sequence[float], upsilon: float, omega: int, zeta: float
) -> tuple[float, ...]:
    """B from its parts (sect. 6)."""
    return (*(float(a) for a in alpha), float(upsilon), float(omega), float(zeta))


__all__ = [
    "ACCEPTANCE",
    "B_NAMES",
    "B_NAMES_LEAD",
    "PAUC_MAX_FPR",
    "STEP_RULES",
    "AscentConfig",
    "AscentResult",
    "Threshold",
    "b_names",
    "best_threshold",
    "coordinate_ascent",
    "initial_vector",
    "partial_auc",
    "validation_events",
]
