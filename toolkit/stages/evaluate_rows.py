"""Evaluate's rows trained: which points each method scores, and the trainings run on both
cores.

The learned model is scored first, then the baselines' points are read; every other row is
then a :class:`Job`, a training that reads what the parent holds (the events, their
patches, every event's pairs) and gives back the row's scores. Rows that are one
computation with another (``same_as``, ``docs/evaluate.md``) are no job: they take the
other's scores. The jobs are independent of each other, so :func:`run_jobs` runs them
:data:`ROW_WORKERS` at a time in processes forked from this one (they read the parent's
arrays as they are, copy-on-write, without pickling them), and collects the scores in the
jobs' order. Each job computes exactly what it would alone, with the same code, data and
thread count, so the report is byte-identical whatever the number of workers (tested).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Generic, TypeVar

import numpy as np
import pyarrow as pa

from toolkit.analysis.method_registry import HEADLINE, UNLEARNED_START
from toolkit.analysis.methods import (
    ABLATIONS,
    MethodScores,
    Rows,
    Trainer,
    ablation,
    baseline,
    boosted_row,
    initial_guess,
    no_learning,
    paper_exact,
    same_points,
)
from toolkit.analysis.oracle import oracle_patches
from toolkit.arrays import BoolArray, FloatArray
from toolkit.config import EvaluateConfig, LearnConfig, ModelConfig
from toolkit.model.baseline import BaselineParams
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import (
    Blockwise,
    EventScores,
    RoughnessParams,
    TopScores,
    model_pairs,
    score_events,
)
from toolkit.pools import process_pool
from toolkit.stages.training_data import (
    closest_laser,
    laser_order,
    patches_of,
    split_events,
)
from toolkit.workspace import Workspace

#: Rows trained at once: the machine's two cores. Each training scores its pairs on
#: :data:`toolkit.model.roughness.THREADS` threads too, but its candidates' bookkeeping,
#: the threshold search and the boosted trees run on one; two rows at once keep both cores
#: busy through those.
ROW_WORKERS = 2

T = TypeVar("T")


@dataclass(frozen=True)
class EvaluateSettings:
    """What evaluation reads of the configuration: the model's form and the search (the
    baselines and ablations learn as learn does), and its own section."""

    model: ModelConfig
    learn: LearnConfig
    evaluate: EvaluateConfig


@dataclass(frozen=True)
class Tables:
    """Every event (both splits, in table order) with its split, label and ruggedness, and
    the model's patches of them (``order``: the lasers nearest first, when the model's
    sample ranks them)."""

    events: pa.Table
    train: BoolArray
    test: BoolArray
    rough: BoolArray
    ruggedness: FloatArray
    order: tuple[str, ...]
    patches: TyrePatches


def read_tables(workspace: Workspace, model: ModelConfig) -> Tables:
    """The events of both splits and the model's patches of them."""
    events = split_events(workspace, None)
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    ruggedness = events.column("ruggedness").to_numpy(zero_copy_only=False).astype(np.float64)
    order = laser_order(workspace, model)
    patches = patches_of(workspace, events, model, order=order)
    return Tables(events, split == "train", split == "test", rough, ruggedness, order, patches)


@dataclass(frozen=True)
class PointSets:
    """The baselines' points: sect. 7.1's two readings of the race test, all lasers' points
    equally (the uniform sample) and the closest laser's alone (None when there is none or
    nothing is trained), and whether the latter are the model's own points."""

    closest: str | None
    uniform: TyrePatches
    nearest: TyrePatches | None
    same: bool


def baseline_params(ev: EvaluateConfig) -> BaselineParams:
    """The race's obstacle test as ``[evaluate]`` sets it."""
    return BaselineParams(
        ev.baseline_cell_m,
        ev.baseline_delta_m,
        ev.baseline_sigma0_m,
        ev.baseline_growth_m2_per_s,
        ev.baseline_confidence,
    )


@dataclass(frozen=True)
class Job:
    """One row's training: the row, the step told while it runs, what trains it (None: the
    row has nothing to train on, e.g. no oracle off the simulator), and the points the
    summary says it scored."""

    name: str
    told: str
    train: Callable[[], MethodScores | None]
    points: dict[str, Any]
    #: The warning said when it has nothing to train on.
    absent: str = ""


class PerProcess(Generic[T]):
    """A value made on first use in each process: rows trained in one process share it
    (the ablations' training pairs), and a forked child makes its own rather than copy a
    half-used one."""

    def __init__(self, make: Callable[[], T]) -> None:
        self._make = make
        self._made: tuple[int, T] | None = None

    def get(self) -> T:
        if self._made is None or self._made[0] != os.getpid():
            self._made = (os.getpid(), self._make())
        return self._made[1]


#: The jobs a forked worker reads by index (set before the pool forks; never pickled).
_JOBS: Sequence[Job] = ()


def _train_job(index: int) -> MethodScores | None:
    """In a forked worker: job ``index`` of :data:`_JOBS`, trained."""
    return _JOBS[index].train()


def run_jobs(
    jobs: Sequence[Job], tell: Callable[[str | None], None], workers: int | None = None
) -> list[MethodScores | None]:
    """Every job trained, in their order: ``workers`` (default :data:`ROW_WORKERS`) at a
    time in forked processes (the jobs' closures and the arrays they read are inherited,
    not pickled), or one after the other in this process with one worker, one job, or no
    ``fork`` on this platform. Each job's step is told while its result is awaited. An
    interrupt or error stops the workers at once (:func:`toolkit.pools.process_pool`)."""
    global _JOBS
    workers = ROW_WORKERS if workers is None else workers
    if workers <= 1 or len(jobs) < 2 or "fork" not in multiprocessing.get_all_start_methods():
        out = []
        for job in jobs:
            tell(job.told)
            out.append(job.train())
        return out
    _JOBS = jobs
    try:
        with process_pool(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            futures = [pool.submit(_train_job, i) for i in range(len(jobs))]
            results = []
            for job, future in zip(jobs, futures, strict=True):
                tell(job.told)
                results.append(future.result())
            return results
    finally:
        _JOBS = ()


@dataclass(frozen=True)
class RowsRun:
    """One evaluation's methods as they are trained, in the report's order of steps: what
    they read, and the rows they fill."""

    workspace: Workspace
    config: EvaluateSettings
    tables: Tables
    trainer: Trainer
    tell: Callable[[str | None], None]
    rows: Rows
    warnings: list[str]

    @property
    def model_points(self) -> dict[str, Any]:
        """The points the model scores, as the summary says them."""
        return {"sample": self.config.model.point_sample, "only_laser": None}

    def learned(self, params: RoughnessParams) -> tuple[MethodScores, Blockwise, EventScores]:
        """The learned model's scores (with its start's), every event's pairs (the other
        rows on the model's points score them too), and every event scored by the search's
        initial guess."""
        # Only the training split's pairs are held: each search scores them hundreds of
        # times. Every event is scored once per method, a block of pairs at a time, so
        # memory follows the training split, not the whole log (an hour's log: ~280 MB of
        # pairs a split).
        self.tell("scoring the learned model and its start")
        everything = model_pairs(self.tables.patches)
        # Learn searched from [learn]'s initial guess, and the runner holds evaluate to the
        # configuration learn ran with: this is the learned model's own start.
        initial = initial_guess(self.config.learn, everything)
        learned = MethodScores(score_events(everything, params), None, params, initial.r_combined)
        self.rows.add(HEADLINE, learned, self.model_points)
        if not self.trainer.learnable:
            self.warnings.append(
                "the training split lacks rough or smooth events: baselines, oracle and "
                "ablations not trained"
            )
        return learned, everything, initial

    def point_sets(self) -> PointSets:
        """The baselines' points (:class:`PointSets`)."""
        self.tell("reading the baselines' points")
        ws, model, t = self.workspace, self.config.model, self.tables
        # Chosen on the training split's patches alone: the choice feeds trained rows.
        closest = closest_laser(ws, t.order, self.config.evaluate.baseline_closest_laser)
        uniform = (
            t.patches
            if model.point_sample == "hash"
            else patches_of(ws, t.events, dataclasses.replace(model, point_sample="hash"))
        )
        nearest = (
            patches_of(ws, t.events, model, only_laser=closest, order=t.order)
            if closest is not None and self.trainer.learnable
            else None
        )
        # With the nearest laser first, a patch usually holds that laser's points alone (it
        # puts ~130 under a tyre): then the rows on "the model's points" and on "the closest
        # laser's points" are the same computation, done once and reported under both names.
        same = nearest is not None and same_points(t.patches, nearest)
        return PointSets(closest, uniform, nearest, same)

    def baseline_jobs(self, sets: PointSets) -> list[Job]:
        """The race test on all lasers' points, the closest laser's, and the model's own
        (sect. 7.1), so that it is also compared with the model on the same points."""
        model, bp = self.config.model, baseline_params(self.config.evaluate)
        hashed = model.point_sample == "hash"
        point_sets: dict[str, tuple[TyrePatches | None, dict[str, Any]]] = {
            "baseline_all_lasers": (sets.uniform, {"sample": "hash", "only_laser": None}),
            "baseline_closest_laser": (
                sets.nearest,
                {"sample": model.point_sample, "only_laser": sets.closest},
            ),
            "baseline_model_points": (
                self.tables.patches if not hashed and not sets.same else None,
                self.model_points,
            ),
        }
        trainer = self.trainer
        return [
            Job(name, f"training {name}", partial(baseline, trainer, p, bp), where)
            for name, (p, where) in point_sets.items()
            if p is not None
        ]

    def model_jobs(self, learned: MethodScores, sets: PointSets) -> list[Job]:
        """The paper's method as written, the model on the closest laser's points, and the
        gradient-boosted learner; a row that is the learned model's own computation takes
        its scores here (no job)."""
        config, t, trainer = self.config, self.tables, self.trainer
        jobs = []
        paper = paper_exact(config.model, config.learn)
        paper_points = {"sample": "hash", "only_laser": None}
        if paper == (config.model, config.learn):
            self.rows.add("paper_exact", learned, paper_points)
        else:
            train = lambda: trainer.model_on(sets.uniform, paper[1])  # noqa: E731
            jobs.append(Job("paper_exact", "training the paper-exact model", train, paper_points))
        if sets.nearest is not None:
            closest_points = {"sample": config.model.point_sample, "only_laser": sets.closest}
            if sets.same:
                points = {**closest_points, "same_as": HEADLINE}
                self.rows.add("model_closest_laser", learned, points)
            elif not config.evaluate.model_on_closest_laser:
                why = "off ([evaluate] model_on_closest_laser)"
                self.rows.not_run["model_closest_laser"] = why
            else:
                nearest = sets.nearest
                jobs.append(
                    Job(
                        "model_closest_laser",
                        "training the model on the closest laser's points",
                        lambda: trainer.model_on(nearest),
                        closest_points,
                    )
                )
        t_start_s = t.events.column("t_start_ns").to_numpy().astype(np.float64) * 1e-9
        cell_m = config.evaluate.baseline_cell_m

        def boosted() -> MethodScores:
            return boosted_row(trainer, t.patches, t.order, t_start_s, cell_m)

        told = "training the gradient-boosted learner"
        jobs.append(Job("boosted", told, boosted, self.model_points))
        return jobs

    def ablation_jobs(self, everything: Blockwise) -> list[Job]:
        """The model learned again without the time or the rate terms."""
        patches, trainer = self.tables.patches, self.trainer
        train_pairs: PerProcess[TopScores] = PerProcess(
            lambda: trainer.pairs(patches.take(trainer.groups))
        )

        def without(name: str) -> MethodScores:
            return ablation(trainer, name, train_pairs.get(), everything)

        told = "training the ablation"
        return [
            Job(name, f"{told} {name}", partial(without, name), self.model_points)
            for name in ABLATIONS
        ]

    def oracle_job(self) -> Job:
        """The model's search on the true terrain heights (simulated logs only: None
        elsewhere)."""
        ws, t, trainer = self.workspace, self.tables, self.trainer

        def train() -> MethodScores | None:
            truth = oracle_patches(ws, t.events, t.patches)
            return None if truth is None else trainer.model_on(truth)

        points = {**self.model_points, "z": "true terrain height where each beam hit"}
        return Job(
            "oracle", "training the oracle", train, points, "not every log is simulated: no oracle"
        )


def train_methods(run: RowsRun, params: RoughnessParams) -> tuple[MethodScores, str | None]:
    """Every method trained and scored into ``run.rows``; the learned model's scores and
    the closest laser."""
    learned, everything, initial = run.learned(params)
    sets = run.point_sets()
    if not run.trainer.learnable:
        return learned, sets.closest
    # The initial guess unlearned, with mu on the training split: no training, no job.
    run.rows.add(UNLEARNED_START, no_learning(run.trainer, initial), run.model_points)
    jobs = [
        *run.baseline_jobs(sets),
        *run.model_jobs(learned, sets),
        *run.ablation_jobs(everything),
        run.oracle_job(),
    ]
    for job, scores in zip(jobs, run_jobs(jobs, run.tell), strict=True):
        if scores is None:
            run.warnings.append(job.absent)
        else:
            run.rows.add(job.name, scores, job.points)
    hashed = run.config.model.point_sample == "hash"
    if sets.same and not hashed:
        run.rows.add(
            "baseline_model_points",
            run.rows.methods["baseline_closest_laser"],
            {**run.model_points, "same_as": "baseline_closest_laser"},
        )
    return learned, sets.closest


__all__ = [
    "ROW_WORKERS",
    "EvaluateSettings",
    "Job",
    "PerProcess",
    "PointSets",
    "RowsRun",
    "Tables",
    "baseline_params",
    "read_tables",
    "run_jobs",
    "train_methods",
]
