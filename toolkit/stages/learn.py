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
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toolkit import __version__
from toolkit.atomic import atomic_write_json
from toolkit.config import LearnConfig, ModelConfig
from toolkit.errors import ConfigError, StageError
from toolkit.layout import workspace_file_name
from toolkit.model.ascent import AscentConfig, AscentResult, b_names, coordinate_ascent
from toolkit.model.search import ascent_config
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.training_data import (
    laser_order,
    pair_table,
    patches_of,
    split_events,
)

_log = logging.getLogger(__name__)

STAGE = "learn"
MODEL_FORMAT = "terrain.roughness_model"
MODEL_FORMAT_VERSION = 1


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
        "step_rule": config.step_rule,
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


@dataclass(frozen=True)
class LearnSettings:
    """What learning reads of the configuration: the model's form and the search."""

    model: ModelConfig
    learn: LearnConfig


def _recall(last: Recalled[LearnSettings]) -> LearnResult:
    """The outcome of an up-to-date model: the model as written."""
    doc = json.loads(last.workspace.model_path.read_text())
    return LearnResult("up_to_date", doc, last.seconds)


def _compute(call: Call[LearnSettings]) -> Made[LearnResult]:
    """Learn and write ``model.json`` (the module docstring); the runner records it."""
    config = call.settings
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
        # Keyed by the tables' paths in the workspace, as a reader of model.json finds them.
        inputs={
            workspace.path(n).relative_to(workspace.root).as_posix(): h for n, h in inputs.items()
        },
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
    settings=LearnSettings,
    compute=_compute,
    recall=_recall,
    rows=("train_events", "points", "pairs"),
    unit="rotation",
    progress_total=lambda config: config.learn.iterations,
)


__all__ = ["SPEC", "STAGE", "LearnResult", "require_both_classes"]
