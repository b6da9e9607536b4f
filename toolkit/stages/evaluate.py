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
scores table are :mod:`toolkit.analysis.summary`'s. :mod:`toolkit.stages.evaluate_rows`
reads the tables, picks each method's points and trains the rows, two at a time on the
machine's two cores; this module reads the model and writes the report as a whole (a new
generation).
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from toolkit.analysis.fig4 import PNG_NAME as FIG4_PNG
from toolkit.analysis.figures import write_bytes_atomic
from toolkit.analysis.method_registry import HEADLINE, MAIN_METHODS
from toolkit.analysis.methods import (
    MethodScores,
    Rows,
    Trainer,
)
from toolkit.analysis.oracle import oracle_patches
from toolkit.analysis.report import ReportInputs, roc_png, write_index_html
from toolkit.analysis.summary import (
    method_rocs,
    model_entry,
    scores_table,
    speed_control,
    split_counts,
    start_aucs,
    summary_json,
)
from toolkit.atomic import atomic_write_json
from toolkit.generations import open_generation
from toolkit.layout import workspace_file_name
from toolkit.manifest import Manifest
from toolkit.model.roc import caveats, small_sample_warnings
from toolkit.sim.record import SIM_RECORD
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.evaluate_online import online_entry, online_row
from toolkit.stages.evaluate_rows import (
    EvaluateSettings,
    RowsRun,
    baseline_params,
    read_tables,
    train_methods,
)
from toolkit.stages.label import FIG5_PNG
from toolkit.stages.training_data import (
    closest_laser,
    load_model,
    pair_table,
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


def _recall(last: Recalled[EvaluateSettings]) -> EvaluateResult:
    """The outcome of an up-to-date report: its summary as written."""
    report = last.workspace.report_dir
    done = json.loads((report / SUMMARY_NAME).read_text())
    return EvaluateResult("up_to_date", done, report / INDEX_NAME, (), last.seconds)


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


def _write_report(
    run: RowsRun,
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
        starts = start_aucs(run.rows.methods, t.test, t.rough, testable)
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
        bp = baseline_params(ev)
        summary = summary_json(run.rows, rocs, starts, speed, counts, closest, model, bp, warnings)
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
        online, online_figures = online_entry(
            run.workspace, t.events, t.test, ev, speed["shock_reduction_at_equal_time"], report
        )
        if online is not None:
            summary["online_learning"] = online
        copied = _copy_log_figures(run.workspace, t.events, report)
        atomic_write_json(report / SUMMARY_NAME, summary)
        write_index_html(
            report / INDEX_NAME,
            ReportInputs(
                summary,
                model_doc,
                [p.name for p in figures],
                [p.name for p in speed_files],
                copied,
                online_figures[0].name if online_figures else None,
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
    tables = read_tables(workspace, config.model)
    timings["read"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    trainer = Trainer(
        tables.train,
        tables.rough,
        config.learn,
        lambda p: pair_table(p, config.model, workspace.config_path),
    )
    run = RowsRun(workspace, config, tables, trainer, steps.tell, Rows(), warnings)
    learned, closest = train_methods(run, params)
    online = online_row(workspace, tables.events)
    if online is not None:
        run.rows.add("online", online, run.model_points)
    else:
        run.rows.not_run["online"] = "not replayed: run `terrain online` (or `terrain run`)"
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
        # Learning while driving, when it has run: its section of the report.
        Need("online_summary", "online", optional=True),
        Need("online_scores", "online", optional=True),
    ),
    makes=("scores", "summary", "index"),
    settings=EvaluateSettings,
    compute=_compute,
    recall=_recall,
    rows=("scores",),
    describe=EvaluateResult.text,
)


__all__ = ["SPEC", "STAGE", "EvaluateResult", "closest_laser", "oracle_patches"]
