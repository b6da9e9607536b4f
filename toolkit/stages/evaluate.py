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

Methods (sect. 7.1 and beyond); each summary entry says which points it scored:

- ``self_supervised``: the learned model (``model.json``), on the configured points.
- ``paper_exact``: the paper's method as written, trained here: a uniform sample of every
  laser's points (``point_sample = "hash"``) and steps accepted by eq. (6) itself
  (``accept = "objective"``), from the configured initial guess. The same row as
  ``self_supervised`` when the configuration already is the paper's.
- ``baseline_all_lasers`` / ``baseline_closest_laser``: the race's obstacle test
  (:mod:`toolkit.model.baseline`) generating W, with upsilon, omega, zeta and mu trained
  separately on the training split, as sect. 7.1 did; once on a uniform sample of all lasers'
  points and once on the closest laser's alone. The closest laser is ``[evaluate]
  baseline_closest_laser``, or by default the one whose points under the tyres were seen the
  shortest time before the rear axle got there (the nearest beams: at any speed they land
  closest to the vehicle).
- ``baseline_model_points``: the race test on the model's own points, and
  ``model_closest_laser``: the model learned on the closest laser's points, so that the model
  and the race test are compared on the same points as well as each on its own. When the
  model's points are the closest laser's (the nearest-laser sample usually keeps nothing
  else), each is the same computation as its twin and is reported with ``same_as``.
- ``boosted`` (beyond the paper): gradient-boosted trees over per-patch features of the
  model's points (:mod:`toolkit.model.boosted`), fitted on the training split alone.
- ``oracle`` (simulated logs only): the model's own search, trained and tested on the true
  terrain height under each point instead of the measured z (pose, laser and range errors
  removed; the points' places and times kept). It bounds what better z alone could buy.
- ``ablations``: the model learned again with the time term (alpha_3 = 0) or the roll- and
  pitch-rate terms (alpha_7 = alpha_9 = 0) removed, what each part of eq. (4) buys; and
  ``no_learning``, the search's initial guess as it stands (mu from the training split),
  what the learning itself buys.

Every entry also gives the share of test events a method scored exactly 0 (eq. 3's W >= 0
ties them) and the warnings say when a split has fewer than 30 rough events.

Speed control (sect. 7.2, :mod:`toolkit.model.speed_control`): each log's test events in
driving order, the reactive controller swept over ``slow_fractions`` x
``recovery_rates_mps2`` and the proactive one over ``slow_fractions``, triggered by the
model's verdicts.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import scipy.fft
from numpy.typing import NDArray

from toolkit import __version__
from toolkit.analysis import fig7
from toolkit.analysis.fig4 import PNG_NAME as FIG4_PNG
from toolkit.analysis.figures import write_bytes_atomic
from toolkit.analysis.report import ReportInputs, roc_png, write_index_html
from toolkit.analysis.truth_terrain import true_ground, where_beams_hit
from toolkit.atomic import atomic_write_json
from toolkit.config import EvaluateConfig, LearnConfig, ModelConfig, PipelineConfig
from toolkit.errors import StageError
from toolkit.generations import open_generation
from toolkit.layout import workspace_file_name
from toolkit.manifest import (
    file_sha256,
    require_finished,
)
from toolkit.model import boosted
from toolkit.model import speed_control as sc
from toolkit.model.ascent import AscentResult, best_threshold, coordinate_ascent
from toolkit.model.baseline import BaselineParams, FixedScores, baseline_pairs, pair_scores
from toolkit.model.patches import TyrePatches
from toolkit.model.roc import RocSummary, caveats, small_sample_warnings, summarise
from toolkit.model.roughness import (
    THREADS,
    EventScores,
    RoughnessParams,
    TopScores,
    model_pairs,
    score_events,
)
from toolkit.model.search import ascent_config
from toolkit.model.shock import MPS_PER_MPH
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.label import FIG5_PNG
from toolkit.stages.learn import stage_config_hash as learn_config_hash
from toolkit.stages.runner import run_stage
from toolkit.stages.training_data import (
    laser_order,
    lasers_nearest_first,
    load_model,
    pair_table,
    patches_of,
    split_events,
    table_inputs,
)
from toolkit.tableio import write_table
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

STAGE = "evaluate"
CONFIG_SECTIONS = ("model", "learn", "evaluate")
SCORES_NAME = workspace_file_name("scores")
SUMMARY_NAME = workspace_file_name("summary")
INDEX_NAME = workspace_file_name("index")
MODEL_NAME = workspace_file_name("model")
ROC_PNG = "roc.png"

BoolArray = NDArray[np.bool_]
FloatArray = NDArray[np.float64]

#: Elements of B an ablation fixes at zero (0-based: alpha_3; alpha_7 and alpha_9), and the
#: exponents that then have nothing to weigh (kept at their initial value).
ABLATIONS: dict[str, tuple[dict[int, float], tuple[int, ...]]] = {
    "no_time_term": ({2: 0.0}, (2, 3)),
    "no_rate_terms": ({6: 0.0, 8: 0.0}, (6, 7, 8, 9)),
}
#: The ablations' names in the summary and in scores.parquet: the two above, and the
#: initial guess itself, unlearned (mu chosen on the training split), what learning buys.
ABLATION_NAMES = (*ABLATIONS, "no_learning")
#: The baseline learns only upsilon, omega and zeta (and mu): sect. 7.1.
BASELINE_FREE = (False,) * 10 + (True, True, True)
#: Every method, in the report's order (its table and the ROC figure's curves); a method a
#: run cannot train (no oracle off the simulator, no closest laser) is left out.
METHOD_NAMES = (
    "self_supervised",
    "paper_exact",
    "baseline_all_lasers",
    "baseline_closest_laser",
    "baseline_model_points",
    "model_closest_laser",
    "boosted",
    "oracle",
    *ABLATION_NAMES,
)
#: The methods beside the ablations that the summary lists at its top level.
MAIN_METHODS = METHOD_NAMES[: -len(ABLATION_NAMES)]


@dataclass(frozen=True)
class MethodScores:
    """One method's verdicts on every event (E,), and how it was trained (None for the
    learned model, trained by ``terrain learn``)."""

    scores: EventScores
    trained: AscentResult | None
    params: RoughnessParams


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


def _train_groups(train: BoolArray) -> BoolArray:
    """Event mask (E,) -> patch mask (2E,): both tyres of each event."""
    return np.repeat(train, 2)


def _train_and_score(
    training: TopScores,
    everything: TopScores,
    train: BoolArray,
    rough: BoolArray,
    learn: LearnConfig,
    free: tuple[bool, ...] | None = None,
    fixed: dict[int, float] | None = None,
) -> MethodScores:
    """Coordinate ascent on ``training`` (the training events' patches, held whole: the
    search scores them hundreds of times), then every event scored by ``everything`` (block
    by block: once)."""
    result = coordinate_ascent(training, rough[train], ascent_config(learn, free, fixed))
    return MethodScores(score_events(everything, result.params), result, result.params)


def _baseline(
    p: TyrePatches, bp: BaselineParams, train: BoolArray, rough: BoolArray, learn: LearnConfig
) -> MethodScores:
    """The race test on the points ``p``: its W from :func:`pair_scores`, upsilon, omega,
    zeta and mu trained on the training split (sect. 7.1); an event without two points of
    ``p`` under either tyre has nothing to score (NaN, never predicted rough)."""
    got = _train_and_score(
        FixedScores(pair_scores(p.take(_train_groups(train)), bp)),
        baseline_pairs(p, bp),
        train,
        rough,
        # The race test's W has no alphas, so no look-ahead term either: B is the 13-vector
        # of which BASELINE_FREE moves upsilon, omega and zeta.
        dataclasses.replace(learn, lead_term=False),
        BASELINE_FREE,
    )
    none = (p.count.reshape(-1, 2) < 2).all(axis=1)
    s = got.scores
    r_comb = np.where(none, np.nan, s.r_combined)
    return MethodScores(
        EventScores(s.r_left, s.r_right, r_comb, s.predicted & ~none), got.trained, got.params
    )


def _same_points(a: TyrePatches, b: TyrePatches) -> bool:
    """Whether two patch sets hold the same points in the same places (every feature)."""
    if a.valid.shape != b.valid.shape or not np.array_equal(a.valid, b.valid):
        return False
    v = a.valid
    return all(
        np.array_equal(getattr(a, k)[v], getattr(b, k)[v])
        for k in ("x", "y", "z", "tau", "gamma", "psi")
    )


def _paper_exact(config: EvaluateSettings) -> tuple[ModelConfig, LearnConfig]:
    """The paper's method as written, with the configured initial guess: every laser's
    points alike (the uniform sample, sect. 7: "data from all lasers is used"), eq. (4)
    without the look-ahead term, and steps accepted by eq. (6) itself with no early stopping
    (sect. 6)."""
    return (
        dataclasses.replace(config.model, point_sample="hash"),
        dataclasses.replace(
            config.learn, accept="objective", lead_term=False, validation_share=0.0
        ),
    )


def _boosted(
    patches: TyrePatches,
    order: tuple[str, ...],
    event_time_s: FloatArray,
    train: BoolArray,
    rough: BoolArray,
    config: EvaluateSettings,
) -> MethodScores:
    """The gradient-boosted classifier (beyond the paper, :mod:`toolkit.model.boosted`) on
    the model's points, fitted on the training split alone; its score is the log-odds of
    rough, and mu eq. (6)'s best threshold on the training split."""
    lasers = tuple(order) or patches.lasers
    features, _ = boosted.patch_features(
        patches, lasers, config.evaluate.baseline_cell_m, event_time_s=event_time_s
    )
    scores, _ = boosted.train_and_score(features, rough, train, boosted.BoostedConfig())
    mu = best_threshold(scores[train], rough[train], config.learn.lambda_fp).mu
    nan = np.full(scores.size, np.nan)
    params = RoughnessParams((0.0,) * 10, 1.0, 1, 1.0, mu)
    return MethodScores(EventScores(nan, nan, scores, scores > mu), None, params)


def closest_laser(
    workspace: Workspace, order: tuple[str, ...], configured: str | None
) -> str | None:
    """The configured closest laser, or the nearest of the training split's lasers
    (:func:`~toolkit.stages.training_data.lasers_nearest_first`; ``order`` when the model already
    ranked them), None without points. Ranked on every point of the training events: the
    model's patches are a sample that keeps the nearest laser first, so the few other points
    in them come from unusual patches and would rank the lasers wrongly (on five 20-mile
    races their median look-ahead put the second laser first)."""
    if configured:
        return configured
    ranked = order or lasers_nearest_first(workspace)
    return ranked[0] if ranked else None


def oracle_patches(
    workspace: Workspace, events: pa.Table, patches: TyrePatches
) -> TyrePatches | None:
    """``patches`` with each point's z replaced by the true terrain height where its beam
    truly hit (:func:`~toolkit.analysis.truth_terrain.where_beams_hit`: the point moved by
    the pose's error at its time), or None unless every log is simulated. Points off the
    modelled terrain are dropped.

    The points stay where they are (the same points, under the same tyres, as the model
    scores): only their heights change. Looking the truth up under the point's *estimated*
    position instead read the ground 16 cm (median) beside what the laser saw, and cost the
    oracle its lead (on tuning seeds 801/802, learned test AUC 0.887 there against 0.900 where
    the beams hit; the laser model 0.880: ``benchmarks/README.md``, "The oracle")."""
    log_of_group = np.repeat(np.asarray(events.column("log_id").to_pylist(), dtype=object), 2)
    z = patches.z.copy()
    valid = patches.valid.copy()
    for log_id in sorted(set(log_of_group.tolist())):
        ground = true_ground(workspace.log_dir(log_id))
        if ground is None:
            return None
        rows = np.flatnonzero(log_of_group == log_id)
        mask = patches.valid[rows]
        xyz = np.c_[patches.x[rows][mask], patches.y[rows][mask], patches.z[rows][mask]]
        t_ns = np.round(patches.tau[rows][mask] * 1e9).astype(np.int64)
        hit = where_beams_hit(workspace.log_dir(log_id), xyz, t_ns)
        placed = np.isfinite(hit).all(axis=1)  # the true pose covers the point's time
        h = np.full(hit.shape[0], np.nan)
        # The terrain's tiles are synthesised by FFT (most of this lookup's time: ~30 s for
        # an hour's route); pocketfft splits each transform's independent lines over the
        # threads, so the heights are the same with one thread or two.
        with scipy.fft.set_workers(THREADS):
            h[placed], _ = ground.height_m(hit[placed])
        sub = z[rows]
        sub[mask] = h
        z[rows] = sub
        sub_valid = valid[rows]
        sub_valid[mask] = np.isfinite(h)
        valid[rows] = sub_valid
    z[~valid] = 0.0
    return TyrePatches(
        patches.x,
        patches.y,
        z,
        patches.tau,
        patches.gamma,
        patches.psi,
        valid,
        valid.sum(axis=1),
        patches.laser,
        patches.lasers,
        patches.lead,
    )


def _routes(events: pa.Table, predicted: BoolArray, test: BoolArray) -> list[sc.Route]:
    """Each log's test events, in driving order, as speed-control routes."""
    routes = []
    log_ids = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    col = {
        n: events.column(n).to_numpy(zero_copy_only=False)
        for n in ("s_start_m", "s_end_m", "speed_mph", "ruggedness", "rough")
    }
    for log_id in sorted(set(log_ids[test].tolist())):
        rows = np.flatnonzero(test & (log_ids == log_id))
        rows = rows[np.argsort(col["s_start_m"][rows], kind="stable")]
        routes.append(
            sc.Route(
                s_start_m=col["s_start_m"][rows].astype(np.float64),
                s_end_m=col["s_end_m"][rows].astype(np.float64),
                speed_mps=col["speed_mph"][rows].astype(np.float64) * MPS_PER_MPH,
                ruggedness=col["ruggedness"][rows].astype(np.float64),
                rough=col["rough"][rows].astype(bool),
                predicted=predicted[rows].astype(bool),
                source=str(log_id),
            )
        )
    return routes


def speed_control(
    events: pa.Table, predicted: BoolArray, test: BoolArray, config: EvaluateSettings, out_dir: Path
) -> tuple[dict[str, Any], list[Path]]:
    """Fig. 7: the curves, the CSV and PNG, and the summary entry."""
    ev = config.evaluate
    base = sc.SpeedControlParams(
        slow_fraction=ev.slow_fractions[0],
        decel_mps2=ev.decel_mps2,
        recovery_mps2=ev.recovery_mps2,
        hold_distance_m=ev.hold_distance_m,
        lookahead_m=ev.lookahead_m,
        shock_floor_g=ev.shock_floor_g,
    )
    routes = _routes(events, predicted, test)
    reactive = sc.reactive_curve(routes, base, ev.slow_fractions, ev.recovery_rates_mps2)
    proactive = sc.proactive_curve(routes, base, ev.slow_fractions)
    none = sc.no_change_point(routes, base)
    reduction = sc.shock_reduction_at_equal_time(
        sc.pareto_front(reactive), sc.pareto_front(proactive)
    )
    curves = [reactive, proactive, [none]]
    files = [
        fig7.write_tradeoff_csv(out_dir, curves),
        fig7.tradeoff_png(out_dir, curves, "Fig. 7 analogue"),
    ]
    best = reduction.max_reduction
    return {
        "shock_reduction_at_equal_time": None if not np.isfinite(best) else round(float(best), 6),
        "reductions_along_reactive_front": [
            {
                "time_norm": round(float(t), 6),
                "reduction": None if not np.isfinite(r) else round(float(r), 6),
            }
            for t, r in zip(reduction.time_norm, reduction.reductions, strict=True)
        ],
        "curves": fig7.CSV_NAME,
        "shock_floor_g": ev.shock_floor_g,
        "no_change": {
            "time_s": round(none.time_s, 3),
            "shock_g": round(none.shock_g, 6),
            "shocks_over_floor": none.shocks_over_floor,
        },
    }, files


@dataclass(frozen=True)
class EvaluateSettings:
    """What evaluation reads of the configuration: the model's form and the search (the
    baselines and ablations learn as learn does), and its own section."""

    model: ModelConfig
    learn: LearnConfig
    evaluate: EvaluateConfig


def run_evaluate(
    workspace: Workspace,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    step: Callable[[str], None] | None = None,
) -> EvaluateResult:
    """Score every event by every method, compare them on the test split, write the report
    (module docstring)."""
    result = run_stage(SPEC, workspace, config, overwrite=overwrite, step=step)
    return cast(EvaluateResult, result)


def _gather(workspace: Workspace, config: PipelineConfig) -> tuple[dict[str, str], None]:
    """The tables' and the model's hashes, refused unless the model was learned from these
    tables with this configuration."""
    inputs = table_inputs(workspace, config)
    model_path = workspace.model_path
    if not model_path.is_file():
        raise StageError("no model; run `terrain learn` first", path=model_path)
    model_sha = file_sha256(model_path)
    learned_from = workspace.manifest().stage("learn")
    require_finished(learned_from, "learn", {MODEL_NAME: model_sha}, workspace.root)
    # The model must come from these tables: one learned before a relabelling or a new split
    # would be scored on events it may have trained on, and its rates would not be these.
    if learned_from is not None and dict(learned_from.inputs) != inputs:
        raise StageError(
            "the model was learned from other training tables than the ones here; run "
            "`terrain learn` again",
            path=model_path,
        )
    # ... and with this configuration: the patches evaluate builds ([model]) must be the
    # ones the model was learned on, and the ablations search as [learn] now says.
    if learned_from is not None and learned_from.config_hash != learn_config_hash(config):
        raise StageError(
            "the model was learned with another [model] or [learn] configuration than the "
            "one in force; run `terrain learn` again",
            path=model_path,
        )
    inputs[MODEL_NAME] = model_sha
    return inputs, None


def _recall(last: Recalled) -> EvaluateResult:
    """The outcome of an up-to-date report: its summary as written."""
    report = last.workspace.report_dir
    done = json.loads((report / SUMMARY_NAME).read_text())
    return EvaluateResult("up_to_date", done, report / INDEX_NAME, (), last.seconds)


def _compute(call: Call) -> Made:
    """Score, compare and write the report (the module docstring); the runner records it."""
    config: EvaluateSettings = call.settings
    workspace, inputs, cfg_hash, start = call.workspace, call.inputs, call.config_hash, call.start
    # Each step's time, for the manifest (where an evaluation spends its minutes).
    step_s: dict[str, float] = {}
    current: list[Any] = [None, start]

    def tell(what: str | None) -> None:
        now = time.perf_counter()
        if current[0] is not None:
            step_s[current[0]] = step_s.get(current[0], 0.0) + now - current[1]
        current[:] = [what, now]
        if what is not None:
            call.step(what)

    warnings: list[str] = []
    timings: dict[str, float] = {}
    params, model_doc = load_model(workspace)
    t0 = time.perf_counter()
    tell("reading the tables")
    events = split_events(workspace, None)
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    train, test = split == "train", split == "test"
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    ruggedness = events.column("ruggedness").to_numpy(zero_copy_only=False).astype(np.float64)
    order = laser_order(workspace, config.model)
    patches = patches_of(workspace, events, config.model, order=order)
    train_groups = _train_groups(train)
    timings["read"] = time.perf_counter() - t0

    # The report's order (its table and the ROC figure's curves).
    methods: dict[str, MethodScores | None] = dict.fromkeys(METHOD_NAMES)
    points: dict[str, dict[str, Any]] = {}
    # Rows left out on purpose, and why (the report says so on their line).
    not_run: dict[str, str] = {}
    model_points = {"sample": config.model.point_sample, "only_laser": None}
    t0 = time.perf_counter()
    # Only the training split's pairs are held: each search scores them hundreds of times.
    # Every event is scored once per method, a block of pairs at a time, so memory follows
    # the training split, not the whole log (an hour's log: ~280 MB of pairs a split).
    tell("scoring the learned model")
    everything = model_pairs(patches)
    learned = MethodScores(score_events(everything, params), None, params)
    methods["self_supervised"] = learned
    points["self_supervised"] = model_points
    learnable = bool(rough[train].any() and (~rough[train]).any())
    if not learnable:
        warnings.append(
            "the training split lacks rough or smooth events: baselines, oracle and "
            "ablations not trained"
        )
    ev = config.evaluate
    bp = BaselineParams(
        ev.baseline_cell_m,
        ev.baseline_delta_m,
        ev.baseline_sigma0_m,
        ev.baseline_growth_m2_per_s,
        ev.baseline_confidence,
    )
    tell("reading the baselines' points")
    t_start_s = events.column("t_start_ns").to_numpy().astype(np.float64) * 1e-9
    # Chosen on the training split's patches alone: the choice feeds trained rows.
    closest = closest_laser(workspace, order, ev.baseline_closest_laser)
    # Sect. 7.1's two readings of the race test: all lasers' points equally (the uniform
    # sample), and the closest laser's alone. Then the race test on the model's own points,
    # so that the two are also compared on the same points.
    uniform = (
        patches
        if config.model.point_sample == "hash"
        else patches_of(workspace, events, dataclasses.replace(config.model, point_sample="hash"))
    )
    nearest = (
        patches_of(workspace, events, config.model, only_laser=closest, order=order)
        if closest is not None and learnable
        else None
    )
    # With the nearest laser first, a patch usually holds that laser's points alone (it
    # puts ~130 under a tyre): then the rows on "the model's points" and on "the closest
    # laser's points" are the same computation, done once and reported under both names.
    same = nearest is not None and _same_points(patches, nearest)
    point_sets: dict[str, tuple[TyrePatches | None, dict[str, Any]]] = {
        "baseline_all_lasers": (uniform, {"sample": "hash", "only_laser": None}),
        "baseline_closest_laser": (
            nearest,
            {"sample": config.model.point_sample, "only_laser": closest},
        ),
        "baseline_model_points": (
            patches if config.model.point_sample != "hash" and not same else None,
            model_points,
        ),
    }
    for name, (p, where) in point_sets.items():
        tell(f"training {name}")
        if not learnable or p is None:
            continue
        methods[name] = _baseline(p, bp, train, rough, config.learn)
        points[name] = where
    if same and learnable and config.model.point_sample != "hash":
        methods["baseline_model_points"] = methods["baseline_closest_laser"]
        points["baseline_model_points"] = {**model_points, "same_as": "baseline_closest_laser"}
    if learnable:
        tell("training the paper-exact model")
        paper = _paper_exact(config)
        if paper == (config.model, config.learn):
            methods["paper_exact"] = learned
        else:
            methods["paper_exact"] = _train_and_score(
                pair_table(uniform.take(train_groups), paper[0], workspace.config_path),
                model_pairs(uniform),
                train,
                rough,
                paper[1],
            )
        points["paper_exact"] = {"sample": "hash", "only_laser": None}
        if same:
            methods["model_closest_laser"] = learned
            points["model_closest_laser"] = {
                **points["baseline_closest_laser"],
                "same_as": "self_supervised",
            }
        elif nearest is not None and not ev.model_on_closest_laser:
            not_run["model_closest_laser"] = "off ([evaluate] model_on_closest_laser)"
        elif nearest is not None:
            tell("training the model on the closest laser's points")
            methods["model_closest_laser"] = _train_and_score(
                pair_table(nearest.take(train_groups), config.model, workspace.config_path),
                model_pairs(nearest),
                train,
                rough,
                config.learn,
            )
            points["model_closest_laser"] = points["baseline_closest_laser"]
        tell("training the gradient-boosted learner")
        methods["boosted"] = _boosted(patches, order, t_start_s, train, rough, config)
        points["boosted"] = model_points
    train_pairs = pair_table(patches.take(train_groups), config.model, workspace.config_path)
    for name, (fixed_values, frozen) in ABLATIONS.items():
        tell(f"training the ablation {name}")
        if not learnable:
            continue
        free = tuple(j not in frozen for j in range(len(ascent_config(config.learn).initial)))
        methods[name] = _train_and_score(
            train_pairs, everything, train, rough, config.learn, free, fixed_values
        )
        points[name] = model_points
    tell("scoring the initial guess")
    if learnable:
        start_params = RoughnessParams.from_vector(ascent_config(config.learn).initial, 0.0)
        initial = score_events(everything, start_params)
        mu = best_threshold(initial.r_combined[train], rough[train], config.learn.lambda_fp).mu
        start_params = dataclasses.replace(start_params, mu=mu)
        methods["no_learning"] = MethodScores(
            dataclasses.replace(initial, predicted=initial.r_combined > mu), None, start_params
        )
        points["no_learning"] = model_points
    # The model's training pairs go before the oracle builds its own.
    del train_pairs, uniform, nearest
    tell("training the oracle")
    truth = oracle_patches(workspace, events, patches) if learnable else None
    if truth is None:
        if learnable:
            warnings.append("not every log is simulated: no oracle")
    else:
        oracle_pairs = pair_table(truth.take(train_groups), config.model, workspace.config_path)
        methods["oracle"] = _train_and_score(
            oracle_pairs, model_pairs(truth), train, rough, config.learn
        )
        points["oracle"] = {**model_points, "z": "true terrain height where each beam hit"}
        del oracle_pairs, truth
    timings["methods"] = time.perf_counter() - t0

    tell("ROC and speed control")
    t0 = time.perf_counter()
    # The report is replaced as a whole, as a log is: written into a new generation of
    # WS/report (WS/.report.<host>-<pid>-<hex>.gen) and switched to by one rename, so a
    # reader, or an evaluate killed while writing, sees the old report or the new one.
    with open_generation(workspace.root, REPORT_NAME, carry_files=False) as gen:
        report = gen.path  # made from nothing: a figure no longer drawn does not linger
        testable = bool(rough[test].any() and (~rough[test]).any())
        if not testable:
            warnings.append("the test split lacks rough or smooth events: no ROC")
        rocs: dict[str, RocSummary | None] = {}
        for name, m in methods.items():
            rocs[name] = (
                summarise(
                    m.scores.r_combined[test],
                    rough[test],
                    ruggedness[test],
                    ev.fpr_points,
                    resamples=ev.bootstrap_resamples,
                    seed=ev.bootstrap_seed,
                )
                if m is not None and testable
                else None
            )
        speed, speed_files = speed_control(events, learned.scores.predicted, test, config, report)
        timings["evaluate"] = time.perf_counter() - t0
        tell(None)

        def entry(name: str) -> dict[str, Any] | None:
            r, m = rocs.get(name), methods.get(name)
            if r is None or m is None:
                return None
            out = r.to_json()
            out["params"] = m.params.to_json()
            out["points"] = points.get(name)
            if m.trained is not None:
                t = m.trained
                out["train_objective"] = t.objective
                out["train_auc"] = t.auc
                out["accepted_by"] = t.accepted_by
                if t.start is not None:
                    out["train_start"] = {"objective": t.start.objective, "auc": t.start.auc}
            return out

        counts = {
            f"{side}_{k}": int(v)
            for side, mask in (("train", train), ("test", test))
            for k, v in (("events", mask.sum()), ("positives", (rough & mask).sum()))
        }
        # What a reader must know of the learned row (and of an oracle below it).
        warnings += caveats(
            rocs.get("self_supervised"),
            rocs.get("oracle"),
            int(learned.scores.predicted[test].sum()),
            float(model_doc.get("objective", 0.0)),
        )
        # Too few rough events to tell methods apart: said on the page and on the terminal.
        warnings += small_sample_warnings(
            {"train": counts["train_positives"], "test": counts["test_positives"]}
            if testable
            else {"train": counts["train_positives"]}
        )
        summary: dict[str, Any] = {
            **{name: entry(name) for name in MAIN_METHODS},
            "ablations": {name: entry(name) for name in ABLATION_NAMES},
            "speed_control": speed,
            "not_run": not_run,
            **counts,
            "closest_laser": closest,
            "model": {
                k: model_doc[k]
                for k in (
                    "alpha",
                    "upsilon",
                    "omega",
                    "zeta",
                    "mu",
                    "lambda",
                    "objective",
                    "tp_rate",
                    "fp_rate",
                    "iterations",
                )
            }
            | {k: model_doc.get(k) for k in ("accepted_by", "train_auc", "start")}
            | {"point_sample": config.model.point_sample, "laser_order": list(order)},
            "baseline_test": {
                "cell_m": bp.cell_m,
                "delta_m": bp.delta_m,
                "sigma0_m": bp.sigma0_m,
                "growth_m2_per_s": bp.growth_m2_per_s,
                "confidence": bp.confidence,
            },
            "warnings": warnings,
            "toolkit_version": __version__,
        }

        def column(name: str) -> pa.Array:
            m = methods.get(name)
            if m is None:
                return pa.nulls(events.num_rows, pa.float64())
            v = m.scores.r_combined
            return pa.array(v, pa.float64(), mask=~np.isfinite(v))

        s = learned.scores
        scores = pa.table(
            {
                "log_id": events.column("log_id"),
                "event_id": events.column("event_id"),
                "split": events.column("split"),
                "r_left": s.r_left,
                "r_right": s.r_right,
                "r_combined": s.r_combined,
                "predicted": s.predicted,
                "rough": rough,
                "ruggedness": ruggedness,
                **{
                    name: column(name)
                    for name in (
                        "baseline_all_lasers",
                        "baseline_closest_laser",
                        "paper_exact",
                        "baseline_model_points",
                        "model_closest_laser",
                        "boosted",
                        "oracle",
                        *ABLATION_NAMES,
                    )
                },
            }
        )
        write_table(
            report / SCORES_NAME,
            scores,
            "scores",
            source_sha256=sorted(inputs.values()),
            config_hash=cfg_hash,
        )
        figures = [
            roc_png(report / ROC_PNG, {n: r.curve for n, r in rocs.items() if r is not None})
        ]
        copied = _copy_log_figures(workspace, events, report)
        atomic_write_json(report / SUMMARY_NAME, summary)
        write_index_html(
            report / INDEX_NAME,
            ReportInputs(
                summary, model_doc, [p.name for p in figures], [p.name for p in speed_files], copied
            ),
        )
        names = [SCORES_NAME, SUMMARY_NAME, INDEX_NAME]
        gen.commit()
    report = workspace.report_dir
    outcome = EvaluateResult(
        "written", summary, report / INDEX_NAME, tuple(warnings), time.perf_counter() - start
    )
    return Made(
        outcome,
        tuple(f"{REPORT_NAME}/{n}" for n in names),
        row_counts={**counts, "scores": events.num_rows},
        timings_s={
            **timings,
            **{f"step: {k}": v for k, v in step_s.items()},
            "total": time.perf_counter() - start,
        },
        warnings=tuple(warnings),
    )


#: The report's folder under the workspace (a link to its current generation).
REPORT_NAME = "report"


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
    sections=CONFIG_SECTIONS,
    settings=EvaluateSettings,
    gather=_gather,
    compute=_compute,
    recall=_recall,
    rows=("scores",),
    describe=EvaluateResult.text,
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = ["SPEC", "STAGE", "EvaluateResult", "closest_laser", "oracle_patches", "run_evaluate"]
