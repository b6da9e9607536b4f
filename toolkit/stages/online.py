"""Online stage: learning while driving (paper sect. 8), a test-then-train replay of the
training tables -> ``WS/online/``.

The workspace's events are replayed as the vehicle drove them (:mod:`toolkit.stages.
online_stream`): each scored by the model as it stood when its last point was seen, its label
learned from once the rear axle has passed and the shock filter has had its samples
(:mod:`toolkit.model.online`). With ``[online] restart_each_log`` each log is a drive of its
own, learned from the start; otherwise the logs are one drive and the model carries over.
The start is ``[learn]``'s initial guess (the uninformed one by default) or, with
``start_model``, a ``model.json`` learned elsewhere.

Outputs:

- ``online/scores.parquet`` (schema ``online_scores``): every event as it was met, beside the
  offline model (``model.json``), the start, the frozen early model and the final one;
- ``online/steps.parquet`` (``online_steps``): every update, with B and mu after it;
- ``online/summary.json``: what the report says of it (:mod:`toolkit.analysis.
  online_summary`);
- ``online/state.json``: each drive's learner at its end, its buffer as (log, event) pairs.

*Stopped and resumed.* Every ``checkpoint_every`` updates the replay so far is saved to
``online/.checkpoint.npz``, keyed by the stage's inputs, configuration and code. A run that
finds a checkpoint with its own key resumes from it (and says so); the replay is
deterministic, so a resumed run writes what an unbroken one writes, byte for byte. The
checkpoint is removed once the outputs are written.

The update times and the replay's speed, which differ from run to run, are in the stage's
manifest record (``timings_s``), not in its outputs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from toolkit.analysis.online_summary import (
    FPRS,
    changed_anywhere,
    learning_verdict,
    online_summary,
)
from toolkit.atomic import atomic_write_json
from toolkit.config import (
    LabelConfig,
    LearnConfig,
    ModelConfig,
    OnlineLearnConfig,
    PipelineConfig,
)
from toolkit.errors import StageError
from toolkit.manifest import Manifest, file_sha256
from toolkit.model.online import (
    LearnerState,
    OnlineConfig,
    event_groups,
    reference_of,
    standing_of,
    start,
)
from toolkit.model.roughness import RoughnessParams, model_pairs, score_events
from toolkit.model.search import ascent_config, online_config
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.online_patches import WINDOW_EVENTS
from toolkit.stages.online_replay import Drive, Replay, ReplayLog, replay_drives
from toolkit.stages.online_stream import DriveStream, drive_stream
from toolkit.stages.training_data import load_model, load_model_file
from toolkit.tableio import write_table
from toolkit.workspace import Workspace

STAGE = "online"
_log = logging.getLogger(__name__)
#: The warning a resumed replay gives (on the terminal, not in the manifest).
RESUMED = "resumed a stopped replay from its checkpoint"
NEEDS = (
    Need("events_table", "tables"),
    Need("event_points_table", "tables"),
    Need("model", "learn"),
)


@dataclass(frozen=True)
class OnlineSettings:
    """What the replay reads of the configuration."""

    model: ModelConfig
    label: LabelConfig
    learn: LearnConfig
    online: OnlineLearnConfig


@dataclass(frozen=True)
class OnlineResult:
    """What ``terrain online`` did, for the command line."""

    status: str  # "written" or "up_to_date"
    summary: dict[str, Any]
    seconds: float
    warnings: tuple[str, ...] = ()
    #: The run's timings (the manifest's): the updates' p50 and p95, the replay's speed.
    timings: dict[str, float] = dataclasses.field(default_factory=dict)

    def text(self) -> str:
        s = self.summary
        if self.status == "up_to_date":
            return "online replay up to date"
        lines = [
            f"online replay of {s['drives']} drive(s) in {self.seconds:.1f} s: {s['events']} "
            f"events ({s['rough']} rough), {s['updates']} updates"
        ]
        for name in ("online", "offline", "frozen", "start"):
            got = s["test"].get(name)
            if got is not None:
                tpr = ", ".join(f"{k}: {v:.2f}" for k, v in got["tpr_at_fpr"].items())
                lines.append(f"  test split, {name}: AUC {got['auc']:.3f}; TPR at FPR {tpr}")
        within = s["within_0_02_from_m"]
        lines.append(
            "  within 0.02 AUC of the offline model: "
            + ("never" if within is None else f"from {within / 1000:.1f} km driven on")
        )
        t = self.timings
        if t:
            lines.append(
                f"  an update took {1000 * t['update_p50']:.0f} ms (p50), "
                f"{1000 * t['update_p95']:.0f} ms (p95); the replay ran at "
                f"{t['real_time_factor']:.0f}x real time"
            )
            if t.get("refits"):
                lines.append(
                    f"  {t['refits']:.0f} refit(s) beside the loop, the longest "
                    f"{t['refit_max']:.1f} s"
                )
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def start_state(
    workspace: Workspace, settings: OnlineSettings
) -> tuple[LearnerState, dict[str, Any]]:
    """The learner each drive starts from, and what the summary says of it: ``[learn]``'s
    initial guess with mu above every score (nothing flagged before a label is seen), or
    ``start_model``'s B and mu; ``[learn]``'s increments either way."""
    search = ascent_config(settings.learn)
    name = settings.online.start_model
    if not name:
        return start(search.initial, search.increments), {"from": "initial_guess"}
    path = workspace.root / name
    params, _ = load_model_file(path)
    b = params.vector()
    if len(b) != len(search.increments):
        raise StageError(
            f"start_model has {len(b)} elements of B and [learn] {len(search.increments)} "
            "(lead_term differs)",
            path=path,
        )
    return start(b, search.increments, params.mu), {"from": name, "sha256": file_sha256(path)}


def _gather(workspace: Workspace, config: PipelineConfig) -> tuple[dict[str, str], None]:
    """The tables and model.json, checked current (as every stage's needs), and the start
    model's file: a new file at the same path replays again."""
    from toolkit.stages.runner import check_needs

    manifest = Manifest(workspace.manifest_path)
    inputs = check_needs(NEEDS, workspace.path, manifest, config, STAGE)
    if config.online.start_model:
        path = workspace.root / config.online.start_model
        if not path.is_file():
            raise StageError("[online] start_model: no such file", path=path)
        inputs["start_model"] = file_sha256(path)
    return inputs, None


def checkpoint_key(call: Call[OnlineSettings]) -> str:
    """What a checkpoint must match to be resumed from: the inputs, configuration and code."""
    from toolkit.stages.registry import code_version_of

    doc = {"inputs": dict(call.inputs), "config": call.config_hash, "code": code_version_of(STAGE)}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class OnlineRun:
    """A replay done: the scores and steps tables, the summary, the replay itself (its
    learners and buffers) and its timings (s; the update's p50 and p95, the speed)."""

    scores: pa.Table
    steps: pa.Table
    summary: dict[str, Any]
    done: Replay
    timings: dict[str, float]


def run_online(
    stream: DriveStream,
    offline: RoughnessParams,
    first: LearnerState,
    settings: OnlineSettings,
    log: ReplayLog,
    step: Callable[[], None],
) -> OnlineRun:
    """Replay ``stream``'s drives from ``first`` (resumed from ``log`` when it holds this
    replay's checkpoint), score every event by the models compared, and summarise."""
    oc = online_config(settings.online, settings.learn)
    drives = split_drives(stream.log_id, stream.stream.s_start_m, settings.online)
    t0 = time.perf_counter()
    done = replay_drives(stream.stream, drives, first, oc, log, step)
    replay_s = time.perf_counter() - t0
    frozen_steps = max(1, math.ceil(settings.online.frozen_after_m / oc.update_every_m))
    models = {"r_offline": [offline] * len(drives)}
    models["r_start"] = [first.params] * len(drives)
    models["r_frozen"] = [done.model_after(d, frozen_steps, first) for d in range(len(drives))]
    models["r_final"] = [done.model_after(d, None, first) for d in range(len(drives))]
    as_of = {
        "r_frozen": [done.step_end_ns(d, frozen_steps) for d in range(len(drives))],
        "r_final": [done.step_end_ns(d, None) for d in range(len(drives))],
    }
    scores = scores_table(stream, drives, done, models, as_of, oc)
    steps = done.steps_table()
    summary = online_summary(
        _columns(scores),
        _columns(steps.drop_columns(["b"])),
        fprs=FPRS,
        stretch_m=settings.online.stretch_m,
        update_every_m=oc.update_every_m,
        frozen_after_m=settings.online.frozen_after_m,
    )
    update_s = np.asarray(done.update_s) if done.update_s else np.zeros(1)
    timings = {
        "replay": replay_s,
        "update_p50": float(np.percentile(update_s, 50)),
        "update_p95": float(np.percentile(update_s, 95)),
        "update_max": float(update_s.max()),
        "refits": float(len(done.refit_s)),
        "refit_max": max(done.refit_s, default=0.0),
        "driven": float(done.driven_s),
        "real_time_factor": float(done.driven_s) / max(replay_s, 1e-9),
    }
    return OnlineRun(scores, steps, summary, done, timings)


def _compute(call: Call[OnlineSettings]) -> Made[OnlineResult]:
    """Replay, score, summarise and write (the module docstring)."""
    ws, settings = call.workspace, call.settings
    t0 = time.perf_counter()
    stream = drive_stream(ws, settings.model, settings.label)
    if stream.stream.events == 0:
        raise StageError("the tables hold no event to replay", path=ws.events_table)
    offline, _ = load_model(ws)
    first, started = start_state(ws, settings)
    read_s = time.perf_counter() - t0
    log = ReplayLog(ws.path("online_checkpoint"), checkpoint_key(call), settings.online)
    run = run_online(stream, offline, first, settings, log, lambda: call.step(""))
    # The start's model, for the report's row (mu None: above every score).
    mu = first.mu if np.isfinite(first.mu) else None
    summary = {**run.summary, "start": {**started, "b": list(first.b), "mu": mu}}
    oc = online_config(settings.online, settings.learn)
    warnings = _warnings(summary, run.done.resumed_at, oc)
    if run.done.resumed_at is not None:  # said on the terminal under `terrain run` too
        _log.warning("%s (%s)", RESUMED, run.done.resumed_at)
    # A fact of this machine, not of the inputs: on the terminal, not in the manifest.
    slow = _slow_refit(run.timings["refit_max"], oc)
    sources = sorted(set(call.inputs.values()))
    for name, table in (("online_scores", run.scores), ("online_steps", run.steps)):
        write_table(ws.path(name), table, name, source_sha256=sources, config_hash=call.config_hash)
    atomic_write_json(ws.path("online_summary"), summary)
    atomic_write_json(ws.path("online_state"), run.done.state_doc(stream.log_id, stream.event_id))
    log.remove()
    timings = {"read": read_s, **run.timings}
    seconds = time.perf_counter() - call.start
    return Made(
        OnlineResult("written", summary, seconds, (*warnings, *slow), timings),
        tuple(
            ws.path(n).relative_to(ws.root).as_posix()
            for n in ("online_scores", "online_steps", "online_summary", "online_state")
        ),
        row_counts={"events": run.scores.num_rows, "updates": run.steps.num_rows},
        timings_s={**timings, "total": seconds},
        # A resumed run is recorded as an unbroken one is (its outputs are the same); the
        # resumption is said on the terminal, in the outcome's text.
        warnings=tuple(w for w in warnings if not w.startswith(RESUMED)),
    )


def split_drives(log_id: np.ndarray, s_m: np.ndarray, online: OnlineLearnConfig) -> list[Drive]:
    """The drives replayed: one per log (in the stream's order) with ``restart_each_log``,
    else one; each with its events' rows in the stream and where its distance starts."""
    if not online.restart_each_log:
        rows = np.arange(log_id.size, dtype=np.int64)
        return [Drive(rows, float(s_m.min()))]
    out = []
    for log in dict.fromkeys(log_id.tolist()):
        rows = np.flatnonzero(log_id == log).astype(np.int64)
        out.append(Drive(rows, float(s_m[rows].min())))
    return out


def scores_table(
    stream: DriveStream,
    drives: list[Drive],
    done: Replay,
    models: dict[str, list[RoughnessParams]],
    as_of: dict[str, list[int]],
    oc: OnlineConfig,
) -> pa.Table:
    """One row per event (stream order): as met online, and each compared model's R.

    ``as_of`` names the models that differ from drive to drive (the frozen and the final
    online models) and, per drive, the time (ns) each stood at: their scores are also given
    as standings (``standing_<name>``), against the reference of the smooth events known by
    then (:func:`~toolkit.model.online.reference_of`), so that they pool over drives as the
    online scores do."""
    s = stream.stream
    n = s.events
    drive_of = np.zeros(n, np.int64)
    s_m = np.zeros(n)
    compared = {name: np.full(n, np.nan) for name in models}
    standings = {f"standing_{name[2:]}": np.full(n, np.nan) for name in as_of}
    for d, drive in enumerate(drives):
        drive_of[drive.rows] = d
        s_m[drive.rows] = s.s_start_m[drive.rows] - drive.s0_m
        for rows in np.array_split(drive.rows, max(1, -(-drive.rows.size // WINDOW_EVENTS))):
            # A window's events at a time: a drive's pairs at once grow with its length.
            pairs = model_pairs(s.patches.take(event_groups(rows)))
            for name, params in models.items():
                compared[name][rows] = score_events(pairs, params[d]).r_combined
        for name, when in as_of.items():
            r = compared[name][drive.rows]
            ref = _smooth_known(s.t_known_ns[drive.rows], s.rough[drive.rows], when[d])
            standings[f"standing_{name[2:]}"][drive.rows] = standing_of(
                r, np.sort(r[reference_of(ref, oc.reference_smooth, oc.buffer_smooth)])
            )
    standings["standing_offline"] = _as_met(stream, drives, done, compared["r_offline"], oc)
    return pa.table(
        {
            "log_id": pa.array(stream.log_id.tolist(), pa.string()),
            "event_id": pa.array(stream.event_id, pa.int64()),
            "split": pa.array(stream.split.tolist(), pa.string()),
            "drive": drive_of,
            "s_m": s_m,
            "t_seen_ns": s.t_seen_ns,
            "t_known_ns": s.t_known_ns,
            "rough": s.rough,
            "version": done.version,
            "r_online": done.r_combined,
            "standing": done.standing,
            "predicted": done.predicted,
            **compared,
            **standings,
        }
    )


def _as_met(
    stream: DriveStream, drives: list[Drive], done: Replay, r: np.ndarray, oc: OnlineConfig
) -> np.ndarray:
    """Scores ``r`` (E,) of one fixed model as standings the way the online scores are:
    each event against the reference as it was when it was seen (of the smooth events known
    by the end of the update before), so that a fixed model and the online one are
    measured alike."""
    s = stream.stream
    out = np.full(s.events, np.nan)
    for d, drive in enumerate(drives):
        ends = np.asarray([done.step_end[k][1] for k, row in enumerate(done.steps) if row[0] == d])
        t_seen, rows = s.t_seen_ns[drive.rows], drive.rows
        before = np.searchsorted(ends, t_seen, side="left") - 1
        for k in np.unique(before):
            mine = before == k
            until = int(ends[k]) if k >= 0 else int(np.iinfo(np.int64).min)
            ref = reference_of(
                _smooth_known(s.t_known_ns[rows], s.rough[rows], until),
                oc.reference_smooth,
                oc.buffer_smooth,
            )
            out[rows[mine]] = standing_of(r[rows[mine]], np.sort(r[rows[ref]]))
    return out


def _smooth_known(t_known_ns: np.ndarray, rough: np.ndarray, until_ns: int) -> np.ndarray:
    """The smooth events (rows of a drive) whose labels were known by ``until_ns``, in the
    order known, as the replay met them."""
    rows = np.flatnonzero(~rough & (t_known_ns <= until_ns))
    return rows[np.argsort(t_known_ns[rows], kind="stable")]


def _columns(table: pa.Table) -> dict[str, np.ndarray]:
    """A table's columns as arrays, by name."""
    return {n: table.column(n).to_numpy(zero_copy_only=False) for n in table.column_names}


def _warnings(summary: dict[str, Any], resumed_at: str | None, oc: OnlineConfig) -> list[str]:
    """What the user must know of this replay, said on the terminal."""
    out = []
    if resumed_at is not None:
        out.append(f"{RESUMED} ({resumed_at})")
    why = f"fewer than {oc.min_rough} rough labels, or no smooth one"
    # When the model may first change: at the first update, or with only refits learning,
    # at the first refit's (its budget of driving later).
    expected_m = oc.update_every_m
    if oc.coordinates_per_update == 0:
        why = (
            f"it learns by refits, every {oc.refit_every_m:g} m driven with {oc.min_rough} "
            f"rough labels known, each ready {oc.refit_budget_s:g} s of driving later: none "
            "was ready before the drive's end"
        )
        expected_m = oc.refit_every_m
    for d, where in summary["first_update_m"].items():
        if where is None:
            out.append(f"drive {d}: the model never learned ({why}): it flagged nothing")
        elif where > 2.0 * expected_m:
            out.append(
                f"drive {d}: the model first changed at {where / 1000:.1f} km (waiting for "
                f"{oc.min_rough} rough labels); nothing was flagged before"
            )
    gaps = summary["gaps"]
    if gaps:
        km = sum(g["to_m"] - g["from_m"] for g in gaps) / 1000.0
        out.append(
            f"{len(gaps)} stretch(es) without events ({km:.1f} km: no pose, IMU or points "
            "there); the model stood still across them"
        )
    # Said when some drive learned (a drive that never did is said so above).
    verdict = learning_verdict(summary["test"])
    if verdict is not None and not verdict[0] and changed_anywhere(summary):
        out.append(verdict[1])
    if summary["out_of_order_labels"]:
        out.append(
            f"{summary['out_of_order_labels']} label(s) known before those of events driven "
            "earlier: each entered the buffer when known"
        )
    return out


def _slow_refit(refit_max_s: float, oc: OnlineConfig) -> tuple[str, ...]:
    """What to say when a refit took longer than its budget of driving (empty: none did):
    on the vehicle its model would have been ready later than the replay took it."""
    if oc.refit_every_m <= 0.0 or refit_max_s <= oc.refit_budget_s:
        return ()
    return (
        f"a refit took {refit_max_s:.1f} s on this machine, longer than its budget of "
        f"{oc.refit_budget_s:g} s of driving ([online] refit_budget_s): on the vehicle its "
        "model would have been ready later than the replay took it",
    )


def _recall(last: Recalled[OnlineSettings]) -> OnlineResult:
    """The outcome of an up-to-date replay: its summary as written."""
    doc = json.loads(last.workspace.path("online_summary").read_text())
    return OnlineResult("up_to_date", doc, last.seconds)


SPEC = Stage(
    STAGE,
    "workspace",
    needs=NEEDS,
    makes=("online_scores", "online_steps", "online_summary", "online_state"),
    settings=OnlineSettings,
    compute=_compute,
    recall=_recall,
    gather=_gather,
    rows=("events", "updates"),
    unit="update",
    describe=OnlineResult.text,
)


__all__ = [
    "SPEC",
    "STAGE",
    "OnlineResult",
    "OnlineRun",
    "OnlineSettings",
    "checkpoint_key",
    "run_online",
    "scores_table",
    "split_drives",
    "start_state",
]
