"""Learning while driving (sect. 8): the search of sect. 6 run test-then-train on a replay.

The paper ends on it: the method "can equally be used as an online learning method where the
vehicle learns as it drives". Here the events come in the order the vehicle drove them, and
each one twice:

- at ``t_seen_ns``, when the last laser point under either rear tyre was seen, it is
  *scored* with the model as it stood then: what the vehicle knew before its rear axle got
  there;
- at ``t_known_ns``, when the rear axle has left its stretch and the shock filter has had
  the samples it needs (the event's end plus the filter's delay), its *label* is known, and
  only from then on may it train the model.

The replay moves in steps of ``update_every_m`` metres driven. Step k covers the times
``(T_{k-1}, T_k]``, ``T_k`` being when the vehicle had driven ``k * update_every_m``: every
event seen in it is scored with model version ``k - 1``; every label known by ``T_k`` then
enters the buffer, and the model takes one update on it, which makes version ``k``.

*The buffer* holds the most recent ``buffer_rough`` rough and ``buffer_smooth`` smooth
labelled events, their patches with them, so its memory is bounded whatever the distance.
It is class-balanced by construction; eq. (6)'s Tp and Fp are rates within each class, so
mu chosen on it is not pulled by the classes' shares in it.

*Scores across versions.* Each version scores on its own scale (a step of alpha_1 rescales
every score), so the scores of a drive, pooled, would rank events by when they were seen as
much as by how rough they are. Each event also gets its *standing*: the share of the
*reference*'s smooth events that the same version scores below it (ties half), an estimate
of the false-positive rate a cut just below it would have. Standings compare across
versions; an event scored before a smooth label is known has none (NaN). The reference
(:class:`Reference`, ``reference_smooth`` events) is a sample spread over every smooth
event known so far on the drive: every ``stride``-th in the order known, the stride the
least power of two that leaves at most ``reference_smooth``. Ranked against the buffer's
smooth events instead (``reference_smooth = 0``: the last few hundred metres of terrain),
a standing measures an event against its neighbourhood, and pooled over a drive it ranks
worse than the scores do: a fixed model loses 0.018 AUC on four races that way, 0.002
against the drive-wide sample (``benchmarks/README.md``, "Online: what a standing
measures").

*An update* is a piece of the coordinate ascent of :mod:`toolkit.model.ascent`: the next
``coordinates_per_update`` elements of B (a rotation that runs on across updates) each try
eq. (7)'s two signs with their own increments, adapted as ``step_rule = "adapt"`` does
(doubled after a step is taken, halved after both signs fail); a step is kept when it
raises the buffer's AUC, and mu is then eq. (6)'s best threshold on the buffer. Without a
rough and a smooth event in the buffer, or with fewer than ``min_rough`` rough ones, the
model stays as it is. ``step_rule = "halve"`` halves every increment once per full rotation
instead (the steps shrink as the drive goes on); ``average`` scores with B averaged over
the versions learned (measured in ``benchmarks/README.md``, "Online, test-then-train").

*A refit* (``refit_every_m``) is the whole search of sect. 6 rerun on the buffer from the
start, as offline learning runs on a training split, beside the planner's loop: its model
(with the increments its search ended on) is taken by the first update ``refit_budget_s``
of driving after the refit began. With ``coordinates_per_update = 0`` only refits learn.
The stage's default does that (``benchmarks/README.md``, "Online: refits"): one element at a
time, the updates get less from a large buffer than a search over it does.

Everything here is a function of its inputs: the same stream, start and configuration give
the same scores and models, and a replay stopped after any step and resumed from its
:class:`LearnerState` gives what one replay gives.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.model.ascent import STEP_RULES, AscentConfig, best_threshold, coordinate_ascent
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import PairTable, RoughnessParams, model_pairs, score_events
from toolkit.model.standing import (
    Reference,
    event_groups,
    reference_of,
    reference_stride,
    standing_of,
)


@dataclass(frozen=True)
class OnlineConfig:
    """How the model learns as it drives (module docstring)."""

    #: Metres driven between two updates of the model.
    update_every_m: float = 100.0
    #: The buffer: the most recent rough events kept, and the most recent smooth ones.
    buffer_rough: int = 64
    buffer_smooth: int = 1024
    #: Elements of B each update tries (eq. 7's two signs each).
    coordinates_per_update: int = 3
    #: Rough events the buffer must hold before the model learns from it (with one or two,
    #: any step that puts them on top raises the buffer's AUC).
    min_rough: int = 1
    #: How the increments change (:data:`toolkit.model.ascent.STEP_RULES`): "adapt" (each
    #: element's by its own success) or "halve" (all halved after each full rotation, which
    #: spreads over updates: the steps shrink as the drive goes on).
    step_rule: str = "adapt"
    #: Score with the average of B over the versions learned so far (Polyak averaging), mu
    #: chosen for it on the buffer, instead of the search's latest B: steadier versions.
    average: bool = False
    #: Hold out this share of the buffer (every other event at 0.5) and keep an update's
    #: steps only if they rank the held-out events better (toolkit.model.ascent's early
    #: stopping, one rotation long); 0: every step the fitted events accept is kept.
    validation_share: float = 0.0
    #: Eq. (6)'s lambda, for mu.
    lambda_fp: float = 5.0
    #: Every this many metres (0: never), the whole search of sect. 6 is run again on the
    #: buffer, from the start's B and increments, ``refit_iterations`` rotations with
    #: adapted steps, as offline learning runs on a training split. It runs beside the
    #: planner's loop, not in it: its model is taken at the first update at least
    #: ``refit_budget_s`` of driving after the refit began (a budget in drive time, so the
    #: replay does not depend on the machine's speed; the stage says when a refit took
    #: longer), and the updates then go on from it with the increments its search ended on.
    refit_every_m: float = 0.0
    refit_iterations: int = 20
    refit_budget_s: float = 0.0
    #: The smooth events a refit fits: "buffer" (the latest ``buffer_smooth``) or
    #: "reference" (the standings' sample spread over the whole drive so far, as the rough
    #: side of the buffer spans much of it).
    refit_smooth: str = "buffer"
    #: An update's step must raise the buffer's AUC by more than this (0: any rise).
    accept_margin: float = 0.0
    #: The standings' reference (module docstring): at most this many smooth events spread
    #: over the drive so far; 0: the buffer's smooth events.
    reference_smooth: int = 1024

    def __post_init__(self) -> None:
        if not self.update_every_m > 0.0:
            raise ValueError(f"update_every_m must be positive, not {self.update_every_m}")
        if self.buffer_rough < 1 or self.buffer_smooth < 1:
            raise ValueError("the buffer must hold at least one event of each class")
        if self.coordinates_per_update < 0:
            raise ValueError("coordinates_per_update must be >= 0")
        if self.coordinates_per_update == 0 and self.refit_every_m <= 0.0:
            raise ValueError("with coordinates_per_update = 0 only refits learn: set refit_every_m")
        if self.min_rough < 1:
            raise ValueError("the model needs at least one rough event to learn from")
        if self.step_rule not in STEP_RULES:
            raise ValueError(f"step_rule must be one of {STEP_RULES}, not {self.step_rule!r}")
        if self.refit_every_m < 0.0 or self.refit_iterations < 1 or self.refit_budget_s < 0.0:
            raise ValueError(
                "refit_every_m and refit_budget_s must be >= 0 and refit_iterations >= 1"
            )
        if self.refit_smooth not in ("buffer", "reference"):
            raise ValueError(
                f"refit_smooth must be 'buffer' or 'reference', not {self.refit_smooth!r}"
            )
        if self.reference_smooth < 0:
            raise ValueError(f"reference_smooth must be >= 0, not {self.reference_smooth}")
        if not 0.0 <= self.validation_share <= 0.5:
            raise ValueError(f"validation_share must be in [0, 0.5], not {self.validation_share}")


class PatchSource(Protocol):
    """Where a stream's patches come from: :class:`~toolkit.model.patches.TyrePatches`
    held whole, or read as they are asked for (:class:`toolkit.stages.online_patches.
    PatchWindows`). The replay asks in driven order."""

    def take(self, groups: IntArray) -> TyrePatches:
        """The patches of ``groups`` (group ``2 e + w``: event ``e``'s wheel ``w``)."""
        ...


@dataclass(frozen=True)
class _Part:
    """The patches of some events of a source (``events``: their indices in it)."""

    source: PatchSource
    events: IntArray

    def take(self, groups: IntArray) -> TyrePatches:
        groups = np.asarray(groups, np.int64)
        return self.source.take(2 * self.events[groups // 2] + groups % 2)


@dataclass(frozen=True)
class Stream:
    """The events of a drive in the order driven (E,), with their patches (2E groups, as
    :class:`~toolkit.model.patches.TyrePatches`, from a :class:`PatchSource`): when each
    began (ns) and at what distance driven (m, counted over the whole drive), when it was
    seen and when its label was known (ns, module docstring), and its label."""

    t_start_ns: NDArray[np.int64]
    s_start_m: FloatArray
    t_seen_ns: NDArray[np.int64]
    t_known_ns: NDArray[np.int64]
    rough: BoolArray
    patches: PatchSource

    @property
    def events(self) -> int:
        return int(self.rough.size)

    def take(self, index: IntArray) -> Stream:
        """The events ``index`` (in that order), with their patches."""
        index = np.asarray(index, np.int64)
        return self._rows(index, self.patches.take(event_groups(index)))

    def part(self, index: IntArray) -> Stream:
        """The events ``index`` (in that order), their patches still read as asked for
        (:meth:`take` reads them at once)."""
        index = np.asarray(index, np.int64)
        return self._rows(index, _Part(self.patches, index))

    def _rows(self, index: IntArray, patches: PatchSource) -> Stream:
        return Stream(
            self.t_start_ns[index],
            self.s_start_m[index],
            self.t_seen_ns[index],
            self.t_known_ns[index],
            self.rough[index],
            patches,
        )


@dataclass(frozen=True)
class Buffer:
    """The labelled events the model trains on: their patches (2 groups each), labels
    (N,) and indices in the stream (N,), oldest first; and the patches' pairs, kept from
    one update to the next (each event's pairs are computed once, when it enters)."""

    patches: TyrePatches | None = None
    rough: BoolArray = field(default_factory=lambda: np.zeros(0, bool))
    index: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    pairs: PairTable | None = None

    @classmethod
    def of(cls, patches: TyrePatches, rough: BoolArray, index: IntArray) -> Buffer:
        """A buffer of these events (a resumed replay's), their pairs computed."""
        return cls(patches, rough, index, PairTable(patches))

    def add(
        self, patches: TyrePatches, rough: BoolArray, index: IntArray, config: OnlineConfig
    ) -> Buffer:
        """The buffer with events appended (in the order given), then the oldest of each
        class dropped beyond the configured counts."""
        both = patches if self.patches is None else self.patches.join(patches)
        fresh = PairTable(patches)
        pairs = fresh if self.pairs is None else self.pairs.join(fresh)
        labels = np.r_[self.rough, rough].astype(bool)
        where = np.r_[self.index, index].astype(np.int64)
        keep = _latest(labels, config.buffer_rough) | _latest(~labels, config.buffer_smooth)
        groups = np.flatnonzero(np.repeat(keep, 2))
        return Buffer(both.take(groups), labels[keep], where[keep], pairs.take(groups))

    @property
    def learnable(self) -> bool:
        return bool(self.rough.any() and (~self.rough).any())


def _latest(mask: BoolArray, n: int) -> BoolArray:
    """The last ``n`` True entries of ``mask`` (N,)."""
    out = np.zeros(mask.size, bool)
    where = np.flatnonzero(mask)[-n:]
    out[where] = True
    return out


@dataclass(frozen=True)
class LearnerState:
    """The model as it stands after ``version`` updates: B with mu, each element's
    increment, the element the next update tries first, the buffer, and how far the
    replay has gone (``step``: the steps done)."""

    b: tuple[float, ...]
    mu: float
    increments: tuple[float, ...]
    cursor: int = 0
    version: int = 0
    step: int = 0
    buffer: Buffer = field(default_factory=Buffer)
    #: With ``average``: the sum of B over the versions learned, and the averaged model
    #: the events are scored with (B then mu; empty: score with ``b`` and ``mu``).
    b_sum: tuple[float, ...] = ()
    scoring: tuple[float, ...] = ()
    #: The start's B and increments (a refit searches from them), and a refit's model (B,
    #: mu, then the increments its search ended on) waiting to be taken by the first update
    #: at or after ``pending_ready_ns`` (empty: none).
    origin: tuple[float, ...] = ()
    origin_increments: tuple[float, ...] = ()
    pending: tuple[float, ...] = ()
    pending_ready_ns: int = 0
    #: The standings' reference (empty with ``reference_smooth = 0``: the buffer's).
    reference: Reference = field(default_factory=Reference)

    @property
    def params(self) -> RoughnessParams:
        """The model events are scored with."""
        if self.scoring:
            return RoughnessParams.from_vector(self.scoring[:-1], self.scoring[-1])
        return RoughnessParams.from_vector(self.b, self.mu)


def start(
    initial: tuple[float, ...], increments: tuple[float, ...], mu: float = np.inf
) -> LearnerState:
    """A learner that knows nothing yet: B as given, and mu above every score (nothing is
    called rough before a label has been seen) unless a model learned elsewhere gives one."""
    b, steps = tuple(map(float, initial)), tuple(map(float, increments))
    return LearnerState(b, float(mu), steps, origin=b, origin_increments=steps)


def refit(state: LearnerState, config: OnlineConfig, began_ns: int = 0) -> LearnerState:
    """The state with a refit's model pending (:class:`OnlineConfig`'s ``refit_every_m``):
    the search of sect. 6 on the buffer from the start, begun at ``began_ns`` and ready
    ``refit_budget_s`` later. Unchanged without enough labels to learn from."""
    buf = state.buffer
    if buf.patches is None or not buf.learnable or buf.rough.sum() < config.min_rough:
        return state
    search = AscentConfig(
        initial=state.origin,
        increments=state.origin_increments,
        lambda_fp=config.lambda_fp,
        iterations=config.refit_iterations,
        accept="auc",
        step_rule="adapt",
    )
    pairs, rough = _pairs(buf), buf.rough
    ref = state.reference.pairs
    if config.refit_smooth == "reference" and ref is not None:
        rough_groups = event_groups(np.flatnonzero(buf.rough))
        pairs = pairs.take(rough_groups).join(ref)
        rough = np.r_[np.ones(rough_groups.size // 2, bool), np.zeros(ref.groups // 2, bool)]
    result = coordinate_ascent(pairs, rough, search)
    ready_ns = began_ns + int(round(config.refit_budget_s * 1e9))
    pending = (*result.params.vector(), result.params.mu, *result.increments)
    return _with(state, pending=pending, pending_ready_ns=ready_ns)


def take_pending(state: LearnerState, now_ns: int) -> LearnerState:
    """The state with its pending refit taken as its model (a new version) when it is
    ready by ``now_ns``: the updates go on with the increments the refit's search ended on,
    the rotation from its first element. Unchanged otherwise."""
    if not state.pending or now_ns < state.pending_ready_ns:
        return state
    n = len(state.b)
    return _with(
        state,
        b=state.pending[:n],
        mu=state.pending[n],
        increments=state.pending[n + 1 :],
        cursor=0,
        version=state.version + 1,
        pending=(),
        pending_ready_ns=0,
    )


def update(state: LearnerState, config: OnlineConfig) -> tuple[LearnerState, int]:
    """One update on the buffer (module docstring): the new state, and how many steps of
    eq. (7) were kept. The model stays as it is without both classes in the buffer, and
    with ``coordinates_per_update = 0`` (only refits learn)."""
    buf = state.buffer
    if buf.patches is None or not buf.learnable or buf.rough.sum() < config.min_rough:
        return state, 0
    if config.coordinates_per_update == 0:
        return state, 0
    n = len(state.b)
    tried = {(state.cursor + k) % n for k in range(min(config.coordinates_per_update, n))}
    search = AscentConfig(
        initial=state.b,
        increments=state.increments,
        lambda_fp=config.lambda_fp,
        iterations=1,
        free=tuple(j in tried for j in range(n)),
        accept="auc",
        step_rule="adapt",
        validation_share=config.validation_share,
        validation_block=1,
        margin=config.accept_margin,
    )
    result = coordinate_ascent(_pairs(buf), buf.rough, search)
    increments = result.increments
    # Held out, the update's steps were refused (the start kept): as if none was taken.
    refused = result.kept_rotation == 0
    if refused:
        increments = tuple(v * (0.5 if j in tried else 1.0) for j, v in enumerate(state.increments))
    if config.step_rule == "halve":
        # The paper's halving, once per full rotation however many updates it spans.
        wraps = (state.cursor + len(tried)) >= n
        increments = tuple(v * (0.5 if wraps else 1.0) for v in state.increments)
    b_new = result.params.vector()
    b_sum, scoring = state.b_sum, state.scoring
    if config.average:
        b_sum = tuple(float(v) for v in np.add(b_sum or (0.0,) * n, b_new))
        mean = RoughnessParams.from_vector([v / (state.version + 1) for v in b_sum], 0.0)
        r = score_events(_pairs(buf), mean).r_combined
        mu = best_threshold(r, buf.rough, config.lambda_fp).mu
        scoring = (*mean.vector(), mu)
    return (
        _with(
            state,
            b=b_new,
            mu=result.params.mu,
            increments=increments,
            cursor=(state.cursor + len(tried)) % n,
            version=state.version + 1,
            b_sum=b_sum,
            scoring=scoring,
        ),
        0 if refused else len(result.steps),
    )


@dataclass(frozen=True)
class Replayed:
    """What a replay gave: every event's score when it was seen (E,; NaN for an event not
    reached), its standing then (module docstring), the verdict then, and the model version
    that scored it (-1: not reached); per step, where it ended (m, ns), the version after
    it, the buffer's rough and smooth counts, the steps of eq. (7) kept, the update's
    time and a refit's (s; 0 without one)."""

    r_combined: FloatArray
    standing: FloatArray
    predicted: BoolArray
    version: IntArray
    step_end_m: FloatArray
    step_end_ns: NDArray[np.int64]
    step_version: IntArray
    buffer_rough: IntArray
    buffer_smooth: IntArray
    steps_kept: IntArray
    update_s: FloatArray
    refit_s: FloatArray


def step_ends(stream: Stream, config: OnlineConfig) -> tuple[FloatArray, NDArray[np.int64]]:
    """Where each step ends: ``k * update_every_m`` metres driven (k = 1, 2, ...), the last
    at the drive's end, and when the vehicle got there (interpolated between the events'
    starts), so that every event's seeing and knowing falls in some step."""
    s, t = stream.s_start_m, stream.t_start_ns
    if s.size == 0:
        return np.zeros(0), np.zeros(0, np.int64)
    ends_m = np.arange(1, int(np.floor(s[-1] / config.update_every_m)) + 1) * config.update_every_m
    ends_ns = np.interp(ends_m, s, t.astype(np.float64)).astype(np.int64)
    last = int(max(stream.t_seen_ns.max(), stream.t_known_ns.max()))
    return np.r_[ends_m, s[-1]], np.r_[ends_ns, last].astype(np.int64)


def replay(
    stream: Stream,
    state: LearnerState,
    config: OnlineConfig,
    stop_after: int | None = None,
    progress: Callable[[LearnerState], None] | None = None,
) -> tuple[LearnerState, Replayed]:
    """Test-then-train over ``stream`` from ``state`` (a fresh :func:`start`, or a stopped
    replay's state: it resumes at its ``step``), at most ``stop_after`` steps this call.
    The scores are those of this call's steps (NaN elsewhere)."""
    ends_m, ends_ns = step_ends(stream, config)
    n = stream.events
    r = np.full(n, np.nan)
    standing = np.full(n, np.nan)
    predicted = np.zeros(n, bool)
    reference = _smooth_scores(state)
    version = np.full(n, -1, np.int64)
    rows: list[tuple[float, int, int, int, int, int, float, float]] = []
    last = ends_ns.size if stop_after is None else min(ends_ns.size, state.step + stop_after)
    for k in range(state.step, last):
        lo = ends_ns[k - 1] if k else np.iinfo(np.int64).min
        seen = np.flatnonzero((stream.t_seen_ns > lo) & (stream.t_seen_ns <= ends_ns[k]))
        if seen.size:
            got = score_events(model_pairs(stream.patches.take(event_groups(seen))), state.params)
            r[seen], predicted[seen], version[seen] = got.r_combined, got.predicted, state.version
            standing[seen] = standing_of(got.r_combined, reference)
        known = np.flatnonzero((stream.t_known_ns > lo) & (stream.t_known_ns <= ends_ns[k]))
        known = known[np.argsort(stream.t_known_ns[known], kind="stable")]
        if known.size:
            state = _labelled(state, stream, known, config)
        before = state.version
        t0 = time.perf_counter()
        taken = take_pending(state, int(ends_ns[k]))
        state, kept = (taken, 0) if taken is not state else update(state, config)
        took = time.perf_counter() - t0
        refit_took = 0.0
        if _refits(config, ends_m, k):
            t0 = time.perf_counter()
            state = refit(state, config, int(ends_ns[k]))
            refit_took = time.perf_counter() - t0
        if known.size or state.version != before:  # the buffer or the model changed
            reference = _smooth_scores(state)
        state = _with(state, step=k + 1)
        b = state.buffer
        n_rough = int(b.rough.sum())
        rows.append(
            (
                float(ends_m[k]),
                int(ends_ns[k]),
                state.version,
                n_rough,
                b.rough.size - n_rough,
                kept,
                took,
                refit_took,
            )
        )
        if progress is not None:
            progress(state)
    cols = list(zip(*rows, strict=True)) if rows else [()] * 8
    return state, Replayed(
        r,
        standing,
        predicted,
        version,
        np.asarray(cols[0], np.float64),
        np.asarray(cols[1], np.int64),
        np.asarray(cols[2], np.int64),
        np.asarray(cols[3], np.int64),
        np.asarray(cols[4], np.int64),
        np.asarray(cols[5], np.int64),
        np.asarray(cols[6], np.float64),
        np.asarray(cols[7], np.float64),
    )


def _labelled(
    state: LearnerState, stream: Stream, known: IntArray, config: OnlineConfig
) -> LearnerState:
    """The state once the labels of events ``known`` (in the order known) are: in its
    buffer, and the smooth ones in its reference."""
    patches = stream.patches.take(event_groups(known))
    buf = state.buffer.add(patches, stream.rough[known], known, config)
    ref = state.reference
    if config.reference_smooth:
        smooth = np.flatnonzero(~stream.rough[known])
        ref = ref.add(patches.take(event_groups(smooth)), known[smooth], config.reference_smooth)
    return _with(state, buffer=buf, reference=ref)


def _refits(config: OnlineConfig, ends_m: FloatArray, k: int) -> bool:
    """Whether step ``k`` (ending at ``ends_m[k]``) crossed a multiple of
    ``refit_every_m``."""
    if config.refit_every_m <= 0.0:
        return False
    before = ends_m[k - 1] if k else 0.0
    return bool(
        np.floor(ends_m[k] / config.refit_every_m) > np.floor(before / config.refit_every_m)
    )


def _smooth_scores(state: LearnerState) -> FloatArray:
    """The reference's events scored by the state's model, sorted (empty without any): the
    buffer's smooth events when the state keeps no reference."""
    if state.reference.pairs is not None:
        return np.sort(score_events(state.reference.pairs, state.params).r_combined)
    buf = state.buffer
    if buf.patches is None or buf.rough.all():
        return np.zeros(0)
    return np.sort(score_events(_pairs(buf), state.params).r_combined[~buf.rough])


def _pairs(buf: Buffer) -> PairTable:
    """The buffer's pairs (computed for a buffer made without them)."""
    if buf.patches is None:
        raise ValueError("an empty buffer has no pairs")
    return buf.pairs if buf.pairs is not None else PairTable(buf.patches)


def _with(state: LearnerState, **changes: object) -> LearnerState:
    return dataclasses.replace(state, **changes)  # type: ignore[arg-type]


__all__ = [
    "Buffer",
    "LearnerState",
    "OnlineConfig",
    "PatchSource",
    "Reference",
    "Replayed",
    "Stream",
    "event_groups",
    "reference_of",
    "reference_stride",
    "refit",
    "replay",
    "standing_of",
    "start",
    "step_ends",
    "take_pending",
    "update",
]
