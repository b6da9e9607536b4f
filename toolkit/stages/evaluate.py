"""Evaluate stage: the learned model against the race's method, on the test split (sect. 7).

Inputs: the training tables (as ``terrain tables`` wrote them) and ``model.json`` (as
``terrain learn`` wrote it). Outputs under ``WS/report/``:

- ``scores.parquet``: per event (both splits) the model's R_left, R_right, R_combined and
  verdict, the label and the ruggedness, and every other method's R_combined.
- ``summary.json``: per method, on the test split, AUC and TPR at the configured FPRs with
  bootstrap intervals, and the rank correlation with ruggedness; the speed-control result;
  the counts per split.
- ``index.html`` with ``roc.png``, ``speed_tradeoff.png`` (and ``speed_tradeoff.csv``), and
  copies of each log's Fig. 4 and, for calibration logs, Fig. 5.

The methods (sect. 7.1 and beyond: the learned model, the paper's method as written, the
race's obstacle test on all lasers', the closest laser's and the model's points, the model
on the closest laser's points, gradient-boosted trees, the oracle on simulated logs, the
ablations of eq. (4) and the unlearned initial guess) are trained and scored in
:mod:`toolkit.analysis.methods`; which points each scores, and when two rows are one
computation, is ``docs/evaluate.md``. ROC, speed control (sect. 7.2), the summary and the
scores table are :mod:`toolkit.analysis.summary`'s. This module reads the tables and the
model, picks each method's points, and writes the report as a whole (a new generation).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.analysis.fig4 import PNG_NAME as FIG4_PNG
from toolkit.analysis.figures import write_bytes_atomic
from toolkit.analysis.method_registry import HEADLINE, MAIN_METHODS, UNLEARNED_START
from toolkit.analysis.methods import (
    ABLATIONS,
    MethodScores,
    Rows,
    Trainer,
    ablation,
    baseline,
    boosted_row,
    no_learning,
    paper_exact,
    same_points,
)
from toolkit.analysis.oracle import oracle_patches
from toolkit.analysis.report import ReportInputs, roc_png, write_index_html
from toolkit.analysis.summary import (
    method_rocs,
    model_entry,
    scores_table,
    speed_control,
    split_counts,
    summary_json,
)
from toolkit.arrays import BoolArray, FloatArray
from toolkit.atomic import atomic_write_json
from toolkit.config import EvaluateConfig, LearnConfig, ModelConfig
from toolkit.generations import open_generation
from toolkit.layout import workspace_file_name
from toolkit.manifest import Manifest
from toolkit.model.baseline import BaselineParams
from toolkit.model.patches import TyrePatches
from toolkit.model.roc import caveats, small_sample_warnings
from toolkit.model.roughness import Blockwise, RoughnessParams, model_pairs, score_events
from toolkit.sim.record import SIM_RECORD
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.label import FIG5_PNG
from toolkit.stages.training_data import (
    closest_laser,
    laser_order,
    load_model,
    pair_table,
    patches_of,
    split_events,
)
from toolkit.tableio import write_table
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

STAGE = "evaluate"
SCORES_NAME = workspace_file_name("scores")
SUMMARY_NAME = workspace_file_name("summary")
INDEX_NAME = workspace_file_name("index")
MODEL_NAME = workspace_file_name("model")
ROC_PNG = "roc.png"
#: The report's folder under the workspace (a link to its current generation).
REPORT_NAME = "report"


@dataclass(frozen=True)
class EvaluateResult:
    status: str
    summary: dict[str, Any]
    report: Path
    warnings: tuple[str, ...]
    seconds: float

    def text(self) -> str:
        if self.status == "up_to_date":
            return f"report up to date: {self.report}"
        s = self.summary
        lines = [f"report written in {self.seconds:.1f} s: {self.report}"]
        for name in MAIN_METHODS:
            m = s.get(name)
            if isinstance(m, dict) and m.get("auc") is not None:
                tpr = ", ".join(
                    f"{k}: {v:.2f}" for k, v in m["tpr_at_fpr"].items() if v is not None
                )
                lines.append(f"  {name}: AUC {m['auc']:.3f}; TPR at FPR {tpr}")
        red = s["speed_control"]["shock_reduction_at_equal_time"]
        if red is not None:
            lines.append(
                f"  speed control: proactive shock {100 * red:.0f} % below reactive at equal time"
            )
        return "\n".join(lines)


@dataclass(frozen=True)
class EvaluateSettings:
    """What evaluation reads of the configuration: the model's form and the search (the
    baselines and ablations learn as learn does), and its own section."""

    model: ModelConfig
    learn: LearnConfig
    evaluate: EvaluateConfig


def _recall(last: Recalled[EvaluateSettings]) -> EvaluateResult:
    """The outcome of an up-to-date report: its summary as written."""
    report = last.workspace.report_dir
    done = json.loads((report / SUMMARY_NAME).read_text())
    return EvaluateResult("up_to_date", done, report / INDEX_NAME, (), last.seconds)


@dataclass(frozen=True)
class _Tables:
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


def _read_tables(workspace: Workspace, model: ModelConfig) -> _Tables:
    """The events of both splits and the model's patches of them."""
    events = split_events(workspace, None)
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    ruggedness = events.column("ruggedness").to_numpy(zero_copy_only=False).astype(np.float64)
    order = laser_order(workspace, model)
    patches = patches_of(workspace, events, model, order=order)
    return _Tables(events, split == "train", split == "test", rough, ruggedness, order, patches)


@dataclass
class _Steps:
    """The progress steps, each told to the user and timed for the manifest (where an
    evaluation spends its minutes)."""

    step: Callable[[str], None]
    since: float
    current: str | None = None
    seconds: dict[str, float] = field(default_factory=dict)

    def tell(self, what: str | None) -> None:
        """The step ``what`` begins (None: the last one ends)."""
        now = time.perf_counter()
        if self.current is not None:
            self.seconds[self.current] = self.seconds.get(self.current, 0.0) + now - self.since
        self.current, self.since = what, now
        if what is not None:
            self.step(what)


@dataclass(frozen=True)
class _PointSets:
    """The baselines' points: sect. 7.1's two readings of the race test, all lasers' points
    equally (the uniform sample) and the closest laser's alone (None when there is none or
    nothing is trained), and whether the latter are the model's own points."""

    closest: str | None
    uniform: TyrePatches
    nearest: TyrePatches | None
    same: bool


def _baseline_params(ev: EvaluateConfig) -> BaselineParams:
    """The race's obstacle test as ``[evaluate]`` sets it."""
    return BaselineParams(
        ev.baseline_cell_m,
        ev.baseline_delta_m,
        ev.baseline_sigma0_m,
        ev.baseline_growth_m2_per_s,
        ev.baseline_confidence,
    )


@dataclass(frozen=True)
class _Run:
    """One evaluation's methods as they are trained, in the report's order of steps: what
    they read, and the rows they fill."""

    workspace: Workspace
    config: EvaluateSettings
    tables: _Tables
    trainer: Trainer
    tell: Callable[[str | None], None]
    rows: Rows
    warnings: list[str]

    @property
    def model_points(self) -> dict[str, Any]:
        """The points the model scores, as the summary says them."""
        return {"sample": self.config.model.point_sample, "only_laser": None}

    def learned(self, params: RoughnessParams) -> tuple[MethodScores, Blockwise]:
        """The learned model's scores, and every event's pairs (the other rows on the
        model's points score them too)."""
        # Only the training split's pairs are held: each search scores them hundreds of
        # times. Every event is scored once per method, a block of pairs at a time, so
        # memory follows the training split, not the whole log (an hour's log: ~280 MB of
        # pairs a split).
        self.tell("scoring the learned model")
        everything = model_pairs(self.tables.patches)
        learned = MethodScores(score_events(everything, params), None, params)
        self.rows.add(HEADLINE, learned, self.model_points)
        if not self.trainer.learnable:
            self.warnings.append(
                "the training split lacks rough or smooth events: baselines, oracle and "
                "ablations not trained"
            )
        return learned, everything

    def point_sets(self) -> _PointSets:
        """The baselines' points (:class:`_PointSets`)."""
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
        return _PointSets(closest, uniform, nearest, same)

    def baselines(self, sets: _PointSets) -> None:
        """The race test on all lasers' points, the closest laser's, and the model's own
        (sect. 7.1), so that it is also compared with the model on the same points."""
        model, bp = self.config.model, _baseline_params(self.config.evaluate)
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
        for name, (p, where) in point_sets.items():
            self.tell(f"training {name}")
            if not self.trainer.learnable or p is None:
                continue
            self.rows.add(name, baseline(self.trainer, p, bp), where)
        if sets.same and self.trainer.learnable and not hashed:
            self.rows.add(
                "baseline_model_points",
                self.rows.methods["baseline_closest_laser"],
                {**self.model_points, "same_as": "baseline_closest_laser"},
            )

    def models(self, learned: MethodScores, sets: _PointSets) -> None:
        """The paper's method as written, the model on the closest laser's points, and the
        gradient-boosted learner (trained only when the training split has both classes)."""
        self.tell("training the paper-exact model")
        config, t = self.config, self.tables
        paper = paper_exact(config.model, config.learn)
        same_config = paper == (config.model, config.learn)
        row = learned if same_config else self.trainer.model_on(sets.uniform, paper[1])
        self.rows.add("paper_exact", row, {"sample": "hash", "only_laser": None})
        self.model_closest_laser(learned, sets)
        self.tell("training the gradient-boosted learner")
        t_start_s = t.events.column("t_start_ns").to_numpy().astype(np.float64) * 1e-9
        cell_m = config.evaluate.baseline_cell_m
        self.rows.add(
            "boosted",
            boosted_row(self.trainer, t.patches, t.order, t_start_s, cell_m),
            self.model_points,
        )

    def model_closest_laser(self, learned: MethodScores, sets: _PointSets) -> None:
        """The model on the closest laser's points: the learned model's row when they are
        its own points, trained when ``[evaluate] model_on_closest_laser`` asks."""
        if sets.nearest is None:
            return
        closest_points = self.rows.points["baseline_closest_laser"]
        if sets.same:
            self.rows.add("model_closest_laser", learned, {**closest_points, "same_as": HEADLINE})
        elif not self.config.evaluate.model_on_closest_laser:
            self.rows.not_run["model_closest_laser"] = "off ([evaluate] model_on_closest_laser)"
        else:
            self.tell("training the model on the closest laser's points")
            self.rows.add(
                "model_closest_laser", self.trainer.model_on(sets.nearest), closest_points
            )

    def ablations(self, everything: Blockwise) -> None:
        """The model learned again without the time or the rate terms, and the initial
        guess unlearned."""
        patches, trainer = self.tables.patches, self.trainer
        train_pairs = trainer.pairs(patches.take(trainer.groups))
        for name in ABLATIONS:
            self.tell(f"training the ablation {name}")
            if not trainer.learnable:
                continue
            self.rows.add(name, ablation(trainer, name, train_pairs, everything), self.model_points)
        self.tell("scoring the initial guess")
        if trainer.learnable:
            self.rows.add(UNLEARNED_START, no_learning(trainer, everything), self.model_points)

    def oracle(self) -> None:
        """The model's search on the true terrain heights (simulated logs only)."""
        self.tell("training the oracle")
        t = self.tables
        learnable = self.trainer.learnable
        truth = oracle_patches(self.workspace, t.events, t.patches) if learnable else None
        if truth is None:
            if learnable:
                self.warnings.append("not every log is simulated: no oracle")
            return
        self.rows.add(
            "oracle",
            self.trainer.model_on(truth),
            {**self.model_points, "z": "true terrain height where each beam hit"},
        )


def _train_methods(run: _Run, params: RoughnessParams) -> tuple[MethodScores, str | None]:
    """Every method trained and scored into ``run.rows``; the learned model's scores and
    the closest laser."""
    learned, everything = run.learned(params)
    sets = run.point_sets()
    run.baselines(sets)
    if run.trainer.learnable:
        run.models(learned, sets)
    closest = sets.closest
    # The model's training pairs and the baselines' points go before the oracle builds its
    # own.
    del sets
    run.ablations(everything)
    run.oracle()
    return learned, closest


def _write_report(
    run: _Run,
    learned: MethodScores,
    closest: str | None,
    model_doc: dict[str, Any],
    call: Call[EvaluateSettings],
    timings: dict[str, float],
) -> tuple[dict[str, Any], dict[str, int]]:
    """ROC, speed control, the summary and the scores, written into a new generation of the
    report; the summary and the counts per split."""
    run.tell("ROC and speed control")
    t0 = time.perf_counter()
    t, ev, warnings = run.tables, run.config.evaluate, run.warnings
    # The report is replaced as a whole, as a log is: written into a new generation of
    # WS/report (WS/.report.<host>-<pid>-<hex>.gen) and switched to by one rename, so a
    # reader, or an evaluate killed while writing, sees the old report or the new one.
    with open_generation(run.workspace.root, REPORT_NAME, carry_files=False) as gen:
        report = gen.path  # made from nothing: a figure no longer drawn does not linger
        testable = bool(t.rough[t.test].any() and (~t.rough[t.test]).any())
        if not testable:
            warnings.append("the test split lacks rough or smooth events: no ROC")
        rocs = method_rocs(run.rows.methods, t.test, t.rough, t.ruggedness, ev, testable)
        speed, speed_files = speed_control(t.events, learned.scores.predicted, t.test, ev, report)
        timings["evaluate"] = time.perf_counter() - t0
        run.tell(None)
        counts = split_counts(t.train, t.test, t.rough)
        # What a reader must know of the learned row (and of an oracle below it).
        warnings += caveats(
            rocs.get(HEADLINE),
            rocs.get("oracle"),
            int(learned.scores.predicted[t.test].sum()),
            float(model_doc.get("objective", 0.0)),
        )
        # Too few rough events to tell methods apart: said on the page and on the terminal.
        warnings += small_sample_warnings(
            {"train": counts["train_positives"], "test": counts["test_positives"]}
            if testable
            else {"train": counts["train_positives"]}
        )
        model = model_entry(model_doc, run.config.model.point_sample, t.order)
        bp = _baseline_params(ev)
        summary = summary_json(run.rows, rocs, speed, counts, closest, model, bp, warnings)
        summary["provenance"] = provenance(run.workspace, t.events, call.config_hash)
        write_table(
            report / SCORES_NAME,
            scores_table(t.events, learned, run.rows, t.rough, t.ruggedness),
            "scores",
            source_sha256=sorted(call.inputs.values()),
            config_hash=call.config_hash,
        )
        curves = {n: r.curve for n, r in rocs.items() if r is not None}
        aucs = {n: r.auc for n, r in rocs.items() if r is not None}
        figures = [roc_png(report / ROC_PNG, curves, aucs)]
        copied = _copy_log_figures(run.workspace, t.events, report)
        atomic_write_json(report / SUMMARY_NAME, summary)
        write_index_html(
            report / INDEX_NAME,
            ReportInputs(
                summary, model_doc, [p.name for p in figures], [p.name for p in speed_files], copied
            ),
        )
        gen.commit()
    return summary, counts


def _compute(call: Call[EvaluateSettings]) -> Made[EvaluateResult]:
    """Score, compare and write the report (the module docstring); the runner records it."""
    config = call.settings
    workspace, start = call.workspace, call.start
    steps = _Steps(call.step, start)
    warnings: list[str] = []
    timings: dict[str, float] = {}
    params, model_doc = load_model(workspace)
    t0 = time.perf_counter()
    steps.tell("reading the tables")
    tables = _read_tables(workspace, config.model)
    timings["read"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    trainer = Trainer(
        tables.train,
        tables.rough,
        config.learn,
        lambda p: pair_table(p, config.model, workspace.config_path),
    )
    run = _Run(workspace, config, tables, trainer, steps.tell, Rows(), warnings)
    learned, closest = _train_methods(run, params)
    timings["methods"] = time.perf_counter() - t0

    summary, counts = _write_report(run, learned, closest, model_doc, call, timings)
    names = [SCORES_NAME, SUMMARY_NAME, INDEX_NAME]
    report = workspace.report_dir
    outcome = EvaluateResult(
        "written", summary, report / INDEX_NAME, tuple(warnings), time.perf_counter() - start
    )
    return Made(
        outcome,
        tuple(f"{REPORT_NAME}/{n}" for n in names),
        row_counts={**counts, "scores": tables.events.num_rows},
        timings_s={
            **timings,
            **{f"step: {k}": v for k, v in steps.seconds.items()},
            "total": time.perf_counter() - start,
        },
        warnings=tuple(warnings),
    )


def provenance(workspace: Workspace, events: pa.Table, config_hash: str) -> dict[str, Any]:
    """Where the report's numbers come from, as the dataset card says it: each log (its id,
    the file it was ingested from, simulated or recorded), the configuration in force (its
    name and the hash of what evaluate read of it). A log is simulated when its file carries
    the simulator's record (``terrain_sim``)."""
    logs = []
    for log_id in sorted(set(events.column("log_id").to_pylist())):
        files = workspace.log(log_id)
        header = Manifest(files.manifest).read()
        source = header.get("source") if isinstance(header.get("source"), dict) else {}
        metadata: Any = {}
        if files.mcap_metadata.is_file():
            with contextlib.suppress(OSError, ValueError):
                metadata = json.loads(files.mcap_metadata.read_text(encoding="utf-8"))
        simulated = isinstance(metadata, dict) and SIM_RECORD in metadata
        logs.append(
            {
                "log_id": log_id,
                "source": str((source or {}).get("path", "")),
                "kind": "simulated" if simulated else "recorded",
            }
        )
    config = workspace.read_config() if workspace.config_path.is_file() else None
    return {
        "logs": logs,
        "configuration": {
            "name": None if config is None else config.name,
            "evaluate_config_hash": config_hash,
        },
    }


def _copy_log_figures(
    workspace: Workspace, events: pa.Table, report: Path
) -> list[tuple[str, str]]:
    """Each log's Fig. 4 (and Fig. 5, for calibration logs) copied beside the report, as
    (caption, file name) pairs."""
    out: list[tuple[str, str]] = []
    for log_id in sorted(set(events.column("log_id").to_pylist())):
        for src, caption in ((FIG4_PNG, "Fig. 4 analogue"), (FIG5_PNG, "Fig. 5 analogue")):
            path = workspace.log_dir(log_id) / src
            if path.is_file():
                name = f"{log_id}_{src}"
                write_bytes_atomic(report / name, path.read_bytes())
                out.append((f"{caption}: {log_id}", name))
    return out


SPEC = Stage(
    STAGE,
    "workspace",
    needs=(
        Need("events_table", "tables"),
        Need("event_points_table", "tables"),
        Need("model", "learn"),
    ),
    makes=("scores", "summary", "index"),
    settings=EvaluateSettings,
    compute=_compute,
    recall=_recall,
    rows=("scores",),
    describe=EvaluateResult.text,
)


__all__ = ["SPEC", "STAGE", "EvaluateResult", "closest_laser", "oracle_patches"]
