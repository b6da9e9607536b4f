"""The methods evaluate compares (paper sect. 7.1 and beyond), each trained on the training
split and scored on every event, over tyre patches and their pairs.

- the paper's model, searched by coordinate ascent (sect. 6) on any points: the
  paper-exact row (:func:`paper_exact`), the model on the closest laser's points, the oracle
  (:meth:`Trainer.model_on`), and the ablations of eq. (4)'s terms (:func:`ablation`);
- the race's obstacle test generating W, with upsilon, omega, zeta and mu trained as
  sect. 7.1 did (:func:`baseline`);
- gradient-boosted trees over per-patch features, beyond the paper (:func:`boosted_row`);
- the search's initial guess, unlearned (:func:`no_learning`).

Which points each row scores, and when two rows are the same computation, is the stage's
choice (:mod:`toolkit.stages.evaluate`; ``docs/evaluate.md``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from toolkit.analysis.method_registry import METHOD_KEYS, method
from toolkit.arrays import BoolArray, FloatArray
from toolkit.config import LearnConfig, ModelConfig
from toolkit.model import boosted
from toolkit.model.ascent import AscentResult, best_threshold, coordinate_ascent
from toolkit.model.baseline import BaselineParams, FixedScores, baseline_pairs, pair_scores
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import (
    EventScores,
    RoughnessParams,
    TopScores,
    model_pairs,
    score_events,
)
from toolkit.model.search import ascent_config

#: Elements of B an ablation fixes at zero (0-based: alpha_3; alpha_7 and alpha_9), and the
#: exponents that then have nothing to weigh (kept at their initial value).
ABLATIONS: dict[str, tuple[dict[int, float], tuple[int, ...]]] = {
    "no_time_term": ({2: 0.0}, (2, 3)),
    "no_rate_terms": ({6: 0.0, 8: 0.0}, (6, 7, 8, 9)),
}
#: The baseline learns only upsilon, omega and zeta (and mu): sect. 7.1.
BASELINE_FREE = (False,) * 10 + (True, True, True)


@dataclass(frozen=True)
class MethodScores:
    """One method's verdicts on every event (E,), how it was trained (None for the learned
    model, trained by ``terrain learn``), and the R_combined (E,) of its search's start,
    unlearned (None for a method without one: the trees, the start itself): what learning
    bought is the difference."""

    scores: EventScores
    trained: AscentResult | None
    params: RoughnessParams
    start: FloatArray | None = None


@dataclass(frozen=True)
class Rows:
    """The methods' rows as a run fills them: each method's scores (None until trained,
    in the report's order), which points it scored, and the rows left out on purpose with
    why (the report says so on their line)."""

    methods: dict[str, MethodScores | None] = field(
        default_factory=lambda: dict.fromkeys(METHOD_KEYS)
    )
    points: dict[str, dict[str, Any]] = field(default_factory=dict)
    not_run: dict[str, str] = field(default_factory=dict)

    def add(self, name: str, scores: MethodScores | None, points: dict[str, Any]) -> None:
        """Row ``name``: its scores, and the points it scored (a name no method declares:
        :class:`~toolkit.analysis.method_registry.UnknownMethodError`)."""
        method(name)
        self.methods[name] = scores
        self.points[name] = points


@dataclass(frozen=True)
class Trainer:
    """What every trained row shares: the events' training split and labels (E,), the
    search as ``[learn]`` sets it, and how training patches become their pairs (the
    stage's :func:`~toolkit.stages.training_data.pair_table`, which refuses too many)."""

    train: BoolArray
    rough: BoolArray
    learn: LearnConfig
    pairs: Callable[[TyrePatches], TopScores]

    @property
    def learnable(self) -> bool:
        """Whether the training split holds rough and smooth events (eq. 6 needs both)."""
        return bool(self.rough[self.train].any() and (~self.rough[self.train]).any())

    @property
    def groups(self) -> BoolArray:
        """Event mask (E,) -> patch mask (2E,): both tyres of each training event."""
        return np.repeat(self.train, 2)

    def fit(
        self,
        training: TopScores,
        everything: TopScores,
        learn: LearnConfig | None = None,
        free: tuple[bool, ...] | None = None,
        fixed: dict[int, float] | None = None,
    ) -> MethodScores:
        """Coordinate ascent on ``training`` (the training events' patches, held whole: the
        search scores them hundreds of times), then every event scored by ``everything``
        (block by block: once)."""
        search = ascent_config(self.learn if learn is None else learn, free, fixed)
        result = coordinate_ascent(training, self.rough[self.train], search)
        start = score_events(everything, RoughnessParams.from_vector(search.initial, 0.0))
        return MethodScores(
            score_events(everything, result.params), result, result.params, start.r_combined
        )

    def model_on(self, patches: TyrePatches, learn: LearnConfig | None = None) -> MethodScores:
        """The paper's model searched on ``patches``' training events (their pairs), every
        event of ``patches`` then scored."""
        return self.fit(self.pairs(patches.take(self.groups)), model_pairs(patches), learn)


def baseline(trainer: Trainer, p: TyrePatches, bp: BaselineParams) -> MethodScores:
    """The race test on the points ``p``: its W from :func:`pair_scores`, upsilon, omega,
    zeta and mu trained on the training split (sect. 7.1); an event without two points of
    ``p`` under either tyre has nothing to score (NaN, never predicted rough)."""
    got = trainer.fit(
        FixedScores(pair_scores(p.take(trainer.groups), bp)),
        baseline_pairs(p, bp),
        # The race test's W has no alphas, so no look-ahead term either: B is the 13-vector
        # of which BASELINE_FREE moves upsilon, omega and zeta.
        dataclasses.replace(trainer.learn, lead_term=False),
        BASELINE_FREE,
    )
    none = (p.count.reshape(-1, 2) < 2).all(axis=1)
    s = got.scores
    r_comb = np.where(none, np.nan, s.r_combined)
    start = None if got.start is None else np.where(none, np.nan, got.start)
    return MethodScores(
        EventScores(s.r_left, s.r_right, r_comb, s.predicted & ~none),
        got.trained,
        got.params,
        start,
    )


def same_points(a: TyrePatches, b: TyrePatches) -> bool:
    """Whether two patch sets hold the same points in the same places (every feature)."""
    if a.valid.shape != b.valid.shape or not np.array_equal(a.valid, b.valid):
        return False
    v = a.valid
    return all(
        np.array_equal(getattr(a, k)[v], getattr(b, k)[v])
        for k in ("x", "y", "z", "tau", "gamma", "psi")
    )


def paper_exact(model: ModelConfig, learn: LearnConfig) -> tuple[ModelConfig, LearnConfig]:
    """The paper's method as written, with the configured initial guess: every laser's
    points alike (the uniform sample, sect. 7: "data from all lasers is used"), eq. (4)
    without the look-ahead term, and steps accepted by eq. (6) itself, every increment
    halved after each rotation, with no early stopping (sect. 6)."""
    return (
        dataclasses.replace(model, point_sample="hash"),
        dataclasses.replace(
            learn, accept="objective", lead_term=False, validation_share=0.0, step_rule="halve"
        ),
    )


def boosted_row(
    trainer: Trainer,
    patches: TyrePatches,
    order: tuple[str, ...],
    event_time_s: FloatArray,
    cell_m: float,
) -> MethodScores:
    """The gradient-boosted classifier (beyond the paper, :mod:`toolkit.model.boosted`) on
    the model's points, fitted on the training split alone; its score is the log-odds of
    rough, and mu eq. (6)'s best threshold on the training split."""
    train, rough = trainer.train, trainer.rough
    lasers = tuple(order) or patches.lasers
    features, _ = boosted.patch_features(patches, lasers, cell_m, event_time_s=event_time_s)
    scores, _ = boosted.train_and_score(features, rough, train, boosted.BoostedConfig())
    mu = best_threshold(scores[train], rough[train], trainer.learn.lambda_fp).mu
    nan = np.full(scores.size, np.nan)
    params = RoughnessParams((0.0,) * 10, 1.0, 1, 1.0, mu)
    return MethodScores(EventScores(nan, nan, scores, scores > mu), None, params)


def ablation(
    trainer: Trainer, name: str, training: TopScores, everything: TopScores
) -> MethodScores:
    """The model searched again with the terms of :data:`ABLATIONS` ``[name]`` fixed at
    zero and their exponents held at the initial guess."""
    fixed_values, frozen = ABLATIONS[name]
    free = tuple(j not in frozen for j in range(len(ascent_config(trainer.learn).initial)))
    return trainer.fit(training, everything, None, free, fixed_values)


def initial_guess(learn: LearnConfig, everything: TopScores) -> EventScores:
    """Every event scored by the search's initial guess as ``learn`` sets it (mu 0)."""
    return score_events(everything, RoughnessParams.from_vector(ascent_config(learn).initial, 0.0))


def no_learning(trainer: Trainer, initial: EventScores) -> MethodScores:
    """The search's initial guess as it stands (its scores of every event, ``initial``),
    with mu eq. (6)'s best threshold on the training split: what the learning itself
    buys."""
    train, rough = trainer.train, trainer.rough
    start_params = RoughnessParams.from_vector(ascent_config(trainer.learn).initial, 0.0)
    mu = best_threshold(initial.r_combined[train], rough[train], trainer.learn.lambda_fp).mu
    start_params = dataclasses.replace(start_params, mu=mu)
    return MethodScores(
        dataclasses.replace(initial, predicted=initial.r_combined > mu), None, start_params
    )


__all__ = [
    "ABLATIONS",
    "BASELINE_FREE",
    "MethodScores",
    "Rows",
    "Trainer",
    "ablation",
    "baseline",
    "boosted_row",
    "initial_guess",
    "no_learning",
    "paper_exact",
    "same_points",
]
