"""Learn stage: the training tables -> ``model.json``, the roughness model's 14 parameters
(paper sect. 6).

Inputs: ``tables/events.parquet`` (the training split's events and their ``rough`` labels)
and ``tables/event_points.parquet`` (the points under each tyre), as the last finished
``terrain tables`` wrote them. Each training event's tyre patches
(:mod:`toolkit.model.patches`, at most ``[model] max_points_per_wheel`` points a tyre) are
turned into their pairs once (:class:`toolkit.model.roughness.PairTable`); coordinate ascent
(:mod:`toolkit.model.ascent`) then searches B = (alpha_1..alpha_10, upsilon, omega, zeta)
and mu for the largest ``Tp - lambda Fp`` (eq. 6).

``model.json`` holds the parameters, lambda, the objective with its true- and false-positive
rates, the iterations and the objective after each, the accepted steps, the initial guess
and increments, what it was trained on (events, positives, points, the tables' sha256) and
the toolkit's version. The same tables and configuration give the same file, byte for byte.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from toolkit import __version__
from toolkit.atomic import atomic_write_json
from toolkit.config import LearnConfig, ModelConfig, PipelineConfig
from toolkit.errors import ConfigError, StageError
from toolkit.layout import workspace_file_name
from toolkit.manifest import (
    file_sha256,
    require_finished,
)
from toolkit.model.ascent import AscentConfig, AscentResult, b_names, coordinate_ascent
from toolkit.model.patches import POINT_COLUMNS, TyrePatches, build_patches, lead_order
from toolkit.model.roughness import PairTable, RoughnessParams
from toolkit.stages import tables as tables_stage
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.tableio import iter_table_batches, read_table
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

STAGE = "learn"
CONFIG_SECTIONS = ("model", "learn")
MODEL_FORMAT = "terrain.roughness_model"
MODEL_FORMAT_VERSION = 1
#: Rows per batch when streaming the event points.
POINT_BATCH = 1_048_576
#: Largest pair table learning builds, bytes (13 bytes a pair: three float32 logarithms of
#: differences and a validity flag; the search's cache adds up to 16 a pair, up to
#: :data:`toolkit.model.roughness.CACHE_BYTES`): a quarter of the project machine's 24 GiB.
#: Evaluate holds the training split's pairs too (and the oracle's, one after the other).
MAX_PAIR_BYTES = 6 << 30
#: String columns of the event points read as dictionaries (a few distinct values each).
DICTIONARY_COLUMNS = ("log_id", "wheel", "laser")


def table_inputs(workspace: Workspace, config: PipelineConfig) -> dict[str, str]:
    """sha256 of the two tables (keyed ``tables/<name>``), refused unless they are what the
    last finished ``terrain tables`` wrote (WorkspaceError naming the file), and made with
    ``config``, the configuration in force (StageError): tables of another configuration
    (a ``run -c B --from tables`` whose learn failed leaves B's tables under A's
    ``config.toml``) would be learned from, scored and reported as this one's."""
    paths = (workspace.events_table, workspace.event_points_table)
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise StageError("no training tables; run `terrain tables` first", path=missing[0])
    hashes = {p.name: file_sha256(p) for p in paths}
    record = workspace.manifest().stage(tables_stage.STAGE)
    require_finished(record, tables_stage.STAGE, hashes, workspace.tables_dir)
    if record is not None and record.config_hash != tables_stage.stage_config_hash(config):
        raise StageError(
            "the tables were made with another configuration than the workspace's "
            f"({workspace.config_path.name}); run `terrain tables` again",
            path=workspace.tables_dir,
        )
    return {f"tables/{name}": sha for name, sha in hashes.items()}


def split_events(workspace: Workspace, split: str | None) -> pa.Table:
    """The events of one split (``"train"``, ``"test"``) or all (None), in table order."""
    events = read_table(workspace.events_table, "tables_events")
    # A (log, event) listed twice is the events table's fault: said of it here, before the
    # points are matched to events and the duplicate would look like theirs.
    keys = pa.table({"log_id": events.column("log_id"), "event_id": events.column("event_id")})
    counts = keys.group_by(["log_id", "event_id"]).aggregate([([], "count_all")])
    twice = counts.filter(pc.greater(counts.column("count_all"), 1))
    if twice.num_rows:
        first = twice.slice(0, 1).to_pylist()[0]
        raise StageError(
            f"log {first['log_id']!r} lists event {first['event_id']} "
            f"{first['count_all']} times ({twice.num_rows} duplicated event(s))",
            path=workspace.events_table,
        )
    if split is None:
        return events
    return events.filter(pc.equal(events.column("split"), split))


def _point_batches(workspace: Workspace, columns: Sequence[str]) -> Iterator[pa.RecordBatch]:
    return iter_table_batches(
        workspace.event_points_table,
        "event_points",
        columns=list(columns),
        batch_rows=POINT_BATCH,
        as_dictionary=[c for c in DICTIONARY_COLUMNS if c in columns],
    )


def lasers_nearest_first(workspace: Workspace) -> tuple[str, ...]:
    """Every laser of the training split's event points, nearest first
    (:func:`toolkit.model.patches.lead_order`: the shortest mean time between a point's scan
    and its event), over all their points, not a sample of them: the one ranking both the
    model's nearest-laser sample and the race test's closest laser use. Measured on the
    training split only, so no test event informs a trained row."""
    train = split_events(workspace, "train")
    columns = ("log_id", "event_id", "laser", "t_ns")
    return lead_order(train, _point_batches(workspace, columns), workspace.event_points_table)


def laser_order(workspace: Workspace, model: ModelConfig) -> tuple[str, ...]:
    """The lasers nearest first when ``[model] point_sample = "nearest_laser"``
    (:func:`lasers_nearest_first`); () for any other sample."""
    if model.point_sample != "nearest_laser":
        return ()
    return lasers_nearest_first(workspace)


def patches_of(
    workspace: Workspace,
    events: pa.Table,
    model: ModelConfig,
    *,
    only_laser: str | None = None,
    order: Sequence[str] | None = None,
) -> TyrePatches:
    """The tyre patches of ``events``, streamed from ``tables/event_points.parquet``, sampled
    as ``model`` says (``order``: the lasers nearest first, :func:`laser_order` when None)."""
    if order is None:
        order = laser_order(workspace, model)
    return build_patches(
        events,
        _point_batches(workspace, POINT_COLUMNS),
        model.max_points_per_wheel,
        only_laser=only_laser,
        sample=model.point_sample,
        laser_order=order,
        source=workspace.event_points_table,
    )


def ascent_config(
    lc: LearnConfig,
    free: tuple[bool, ...] | None = None,
    fixed: dict[int, float] | None = None,
) -> AscentConfig:
    """The search of sect. 6 from ``[learn]``: B is the 13-vector (alpha_1..alpha_10,
    upsilon, omega, zeta), or with ``lead_term`` the 15-vector whose alpha_11, alpha_12 weigh
    the look-ahead (:mod:`toolkit.model.roughness`); ``free`` (one flag per element, for the
    13 or 15 elements) says which elements move, ``fixed`` overrides initial values by index
    (an ablation's zeroed terms)."""
    alpha = [*lc.initial_alpha, *(lc.initial_lead if lc.lead_term else ())]
    steps = [*lc.increment_alpha, *(lc.increment_lead if lc.lead_term else ())]
    initial = [*alpha, lc.initial_upsilon, float(lc.initial_omega), lc.initial_zeta]
    for j, v in (fixed or {}).items():
        initial[j] = v
    increments = (*steps, lc.increment_upsilon, lc.increment_omega, lc.increment_zeta)
    return AscentConfig(
        initial=tuple(float(v) for v in initial),
        increments=tuple(float(v) for v in increments),
        lambda_fp=lc.lambda_fp,
        iterations=lc.iterations,
        free=free if free is not None else (),
        accept=lc.accept,
        validation_share=lc.validation_share,
    )


def pair_table(patches: TyrePatches, model: ModelConfig, path: Path) -> PairTable:
    """The pairs of ``patches``; StageError, before allocating, when they would take more
    than :data:`MAX_PAIR_BYTES` (an uncapped ``[model] max_points_per_wheel`` on dense
    lasers: N points a tyre make N (N - 1) / 2 pairs)."""
    n = patches.n_max
    need = patches.groups * (n * (n - 1) // 2) * 13
    if need > MAX_PAIR_BYTES:
        raise StageError(
            f"{patches.groups} tyre patches of up to {n} points make {need / 2**30:.1f} GiB of "
            f"pairs (limit {MAX_PAIR_BYTES / 2**30:.0f} GiB); set [model] max_points_per_wheel "
            f"(now {model.max_points_per_wheel}) to 40 or so",
            path=path,
        )
    return PairTable(patches)


def require_both_classes(rough: np.ndarray, what: str, path: Path) -> None:
    """StageError unless the labels (E,) hold at least one rough and one smooth event: the
    rates of eq. (6) are undefined otherwise."""
    n_pos = int(np.count_nonzero(rough))
    if n_pos == 0 or n_pos == rough.size:
        kind = "rough" if n_pos == 0 else "smooth"
        raise StageError(
            f"the {what} has {rough.size} events and no {kind} one: nothing to learn from "
            "(more driving, or another [label] rough_threshold_g_per_mph)",
            path=path,
        )


@dataclass(frozen=True)
class LearnResult:
    """What ``terrain learn`` did, for the command line."""

    status: str  # "written" or "up_to_date"
    model: dict[str, Any]
    seconds: float

    def summary(self) -> str:
        m = self.model
        if self.status == "up_to_date":
            return f"model up to date (objective {m['objective']:.4f})"
        t = m["training"]
        return (
            f"model learned on {t['events']} training events ({t['positives']} rough) in "
            f"{self.seconds:.1f} s: Tp - {m['lambda']:g} Fp = {m['objective']:.4f} (Tp "
            f"{m['tp_rate']:.3f}, Fp {m['fp_rate']:.4f}) after {m['iterations']} iterations"
        )


def model_json(
    result: AscentResult,
    config: AscentConfig,
    *,
    events: int,
    positives: int,
    points: int,
    model: ModelConfig,
    laser_order: Sequence[str],
    inputs: dict[str, str],
    cfg_hash: str,
) -> dict[str, Any]:
    """The contents of ``model.json`` (module docstring)."""
    p = result.params
    return {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        **p.to_json(),
        "lambda": config.lambda_fp,
        "objective": result.objective,
        "tp_rate": result.tpr,
        "fp_rate": result.fpr,
        "train_auc": result.auc,
        "train_pauc": result.pauc,
        "accepted_by": result.accepted_by,
        "start": None
        if result.start is None
        else {
            "objective": result.start.objective,
            "auc": result.start.auc,
            "pauc": result.start.pauc,
        },
        "iterations": result.iterations,
        "evaluations": result.evaluations,
        "objective_by_iteration": list(result.history),
        "accepted_measure_by_iteration": list(result.measure_history),
        "validation_share": config.validation_share,
        "held_out_share": result.held_out_share,
        "kept_rotation": result.kept_rotation,
        "validation_measure_by_iteration": list(result.validation_history),
        "steps": [
            {"iteration": i, "parameter": n, "value": v, "objective": j}
            for i, n, v, j in result.steps
        ],
        "initial": dict(zip(b_names(len(config.initial)), config.initial, strict=True)),
        "increments": dict(zip(b_names(len(config.initial)), config.increments, strict=True)),
        "training": {
            "events": events,
            "positives": positives,
            "points": points,
            "max_points_per_wheel": model.max_points_per_wheel,
            "point_sample": model.point_sample,
            "laser_order": list(laser_order),
            "tables_sha256": inputs,
        },
        "config_hash": cfg_hash,
        "toolkit_version": __version__,
    }


def load_model(workspace: Workspace) -> tuple[RoughnessParams, dict[str, Any]]:
    """The learned parameters and the whole ``model.json``; StageError if missing or
    malformed."""
    path = workspace.model_path
    if not path.is_file():
        raise StageError("no model; run `terrain learn` first", path=path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise StageError(f"unreadable model: {exc}", path=path) from exc
    if not isinstance(doc, dict):
        raise StageError("unreadable model: not a JSON object", path=path)

    def number(key: str, value: Any, integer: bool = False) -> float:
        """A JSON number as written by learn: finite, not a string or a boolean, and for
        omega a whole number (5.9 is not truncated to 5)."""
        ok = isinstance(value, int) if integer else isinstance(value, (int, float))
        if isinstance(value, bool) or not ok or not math.isfinite(value):
            kind = "an integer" if integer else "a finite number"
            raise StageError(f"model key {key!r} must be {kind}, not {value!r}", path=path)
        return float(value)

    for key in ("alpha", "upsilon", "omega", "zeta", "mu"):
        if key not in doc:
            raise StageError(f"unreadable model: no key {key!r}", path=path)
    if not isinstance(doc["alpha"], list):
        raise StageError(f"model key 'alpha' must be a list, not {doc['alpha']!r}", path=path)
    try:
        params = RoughnessParams(
            tuple(number(f"alpha[{i}]", a) for i, a in enumerate(doc["alpha"])),
            number("upsilon", doc["upsilon"]),
            int(number("omega", doc["omega"], integer=True)),
            number("zeta", doc["zeta"]),
            number("mu", doc["mu"]),
        )
    except (ValueError, TypeError) as exc:
        raise StageError(f"unreadable model: {exc}", path=path) from exc
    if not params.admissible():
        raise StageError(f"model parameters outside the model's domain: {params}", path=path)
    return params, doc


@dataclass(frozen=True)
class LearnSettings:
    """What learning reads of the configuration: the model's form and the search."""

    model: ModelConfig
    learn: LearnConfig


def run_learn(
    workspace: Workspace,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
) -> LearnResult:
    """Learn the model from the training split and write ``model.json`` (module docstring);
    ``progress`` is told each rotation of the search."""
    step = (lambda _: progress(1)) if progress is not None else None
    return cast(LearnResult, run_stage(SPEC, workspace, config, overwrite=overwrite, step=step))


def _gather(workspace: Workspace, config: PipelineConfig) -> tuple[dict[str, str], None]:
    """The tables' hashes (:func:`table_inputs`)."""
    return table_inputs(workspace, config), None


def _recall(last: Recalled) -> LearnResult:
    """The outcome of an up-to-date model: the model as written."""
    doc = json.loads(last.workspace.model_path.read_text())
    return LearnResult("up_to_date", doc, last.seconds)


def _compute(call: Call) -> Made:
    """Learn and write ``model.json`` (the module docstring); the runner records it."""
    config: LearnSettings = call.settings
    workspace, inputs, cfg_hash, start = call.workspace, call.inputs, call.config_hash, call.start
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    train = split_events(workspace, "train")
    rough = train.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    require_both_classes(rough, "training split", workspace.events_table)
    order = laser_order(workspace, config.model)
    patches = patches_of(workspace, train, config.model, order=order)
    pairs = pair_table(patches, config.model, workspace.config_path)
    timings["pairs"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    search = ascent_config(config.learn)
    try:
        result = coordinate_ascent(pairs, rough, search, lambda _: call.step(""))
    except ValueError as exc:  # an initial guess whose scores overflow: the configuration's
        raise ConfigError(
            f"learn.initial_alpha / initial_upsilon / initial_omega / initial_zeta: {exc}",
            path=workspace.config_path,
        ) from exc
    timings["ascent"] = time.perf_counter() - t0
    doc = model_json(
        result,
        search,
        events=train.num_rows,
        positives=int(rough.sum()),
        points=int(patches.count.sum()),
        model=config.model,
        laser_order=order,
        inputs=dict(inputs),
        cfg_hash=cfg_hash,
    )
    atomic_write_json(workspace.model_path, doc)
    outcome = LearnResult("written", doc, time.perf_counter() - start)
    return Made(
        outcome,
        (workspace_file_name("model"),),
        row_counts={
            "train_events": train.num_rows,
            "train_positives": int(rough.sum()),
            "points": int(patches.count.sum()),
            "pairs": pairs.pairs * pairs.groups,
        },
        timings_s={**timings, "total": time.perf_counter() - start},
    )


SPEC = Stage(
    STAGE,
    "workspace",
    needs=(Need("events_table", "tables"), Need("event_points_table", "tables")),
    makes=("model",),
    sections=CONFIG_SECTIONS,
    settings=LearnSettings,
    gather=_gather,
    compute=_compute,
    recall=_recall,
    rows=("train_events", "points", "pairs"),
    unit="rotation",
    progress_total=lambda config: config.learn.iterations,
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "STAGE",
    "LearnResult",
    "ascent_config",
    "laser_order",
    "load_model",
    "pair_table",
    "patches_of",
    "require_both_classes",
    "run_learn",
    "split_events",
    "table_inputs",
]
