"""Label stage: the IMU's shock along the posed path -> ``events.parquet`` (sect. 5).

Inputs ``WS/logs/<id>/{imu,pose}.parquet``, ``tf_static.json`` (the IMU's mount) and, on
simulated logs, the truth ingest wrote. Output ``events.parquet`` (schema ``events``):

* **Events** (:mod:`toolkit.model.events`): the rear-axle path (pose x, y; base_link is on the
  ground below the rear-axle centre) cut by distance ``s`` into consecutive stretches of
  ``label.event_length_m``; event ``k`` is ``s`` in ``[k L, (k+1) L)``, entered and left at the
  times the path reaches those distances (linear between pose samples). Its ``event_id`` is
  ``k``: rejected events leave gaps.
* **Speed** (:mod:`toolkit.model.ruggedness`): the mean speed over the event, ``L / (t_end -
  t_start)`` (the time mean of the path speed), in mph (1 mph = 0.44704 m/s exactly). Events
  slower than ``label.min_speed_mps`` are rejected (``too_slow``) before anything is divided
  by their speed; a stop lies inside one long slow event, so it makes none.
* **Shock** (:mod:`toolkit.model.shock`): the z axis of the IMU's specific force turned
  into base_link by the mount (``a_z = R[2, :] a_imu``), filtered by the type-IV FIR designed
  for the IMU's measured rate, each output stamped at its window's centre (the 19.5-sample
  delay compensated exactly); ``shock_g`` = the ``label.shock_statistic`` over the event's
  time span / ``label.gravity_mps2``. For ``max_abs``, ``label.attribution`` says which
  impacts are the event's (issue 26; :mod:`toolkit.model.shock`, "Attribution"):
  ``impact`` (default), the largest crest of the band-limited |filtered| whose compensated time
  lies in the event's span and that no larger crest of another event explains as the filter's
  response to it (its quadrature twin, its taps' ringing): one impact labels one event, not
  every event its filtered response reaches; ``span_peak``, the band-limited peak over the
  span (the rule before, bit for bit), under which the flank of a neighbour's impact at the
  boundary was the event's shock (7 of 56 positives on three simulated race logs). An
  event left with no crest of its own keeps the unexplained rest of its span, or 0.0: it is
  covered, so it is labelled, not rejected. An event the filtered IMU does not cover (before
  the filter has 40 inputs, after the IMU ends, across an IMU gap of more than 1.5 periods) is
  rejected (``no_imu``).
* **Ruggedness** ``shock_g / speed_mph`` (sect. 5.2); ``rough`` when it reaches
  ``label.rough_threshold_g_per_mph`` (sect. 7: 0.02 G/mph).
* Simulated logs: the tallest true feature under a rear tyre (:mod:`toolkit.stages.label_truth`);
  on a ``calibration`` log also the paper's Fig. 5 (:mod:`toolkit.analysis.fig5`):
  ``fig5_shock_speed.csv`` and ``.png`` beside the events, the fit in the manifest.

Manifest: record ``label`` (inputs, config hash, rows, rejects by reason, timings, warnings)
and a header section ``label`` with the IMU rate, the filter's taps and measured response,
the counts, the attribution (:func:`~toolkit.model.ruggedness.attribution_summary`: under
``impact``, how many events' shock it lowered, how many kept no impact of their own, and the
positives ``span_peak`` would have had against these; in the summary line when the positives
differ), and the truth and Fig. 5 summaries. Idempotent: an up-to-date label is not
recomputed. Memory: the IMU is streamed in batches (:mod:`toolkit.stages.label_inputs`) and
only the filtered samples of the event being labelled (plus the interpolation margin, and
under ``impact`` the filter's reach) are kept; the pose (cut into events run by run,
:func:`~toolkit.model.events.path_events_step`) and the truth (simulated logs) are streamed
too. Only the events' own arrays are held whole (a dozen numbers an event, ~4 MB for an
hour's 28,000 events: 1/14 of the pose's rows at 10 m/s).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from toolkit.analysis.fig5 import LineFit, fit_line, obstacle_passes, write_fig5
from toolkit.arrays import FloatArray, IntArray
from toolkit.config import LabelConfig, VehicleConfig
from toolkit.errors import StageError
from toolkit.geometry.mounts import sensor_mounts
from toolkit.layout import LogFiles, log_file_name
from toolkit.model.events import PathCarry, path_events, path_events_step
from toolkit.model.ruggedness import (
    EventLabels,
    attribution_summary,
    event_speed_mps,
    fast_enough,
    label_events,
)
from toolkit.model.shock import ShockFir, design_shock_fir
from toolkit.model.shock_attribution import impact_envelope
from toolkit.sim.record import SIM_RECORD
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.label_inputs import (
    GAP_PERIODS,
    EventShocks,
    event_shocks,
    imu_period_ns,
    streamed_path_events,
)
from toolkit.stages.label_truth import TruthUnder, truth_under_events
from toolkit.tableio import TableWriter, table_num_rows

_log = logging.getLogger(__name__)


STAGE = "label"
OUTPUT = log_file_name("events")
FIG5_CSV = log_file_name("fig5_csv")
FIG5_PNG = log_file_name("fig5_png")
#: Files ingest writes that label reads when present (besides imu.parquet).
INGEST_EXTRAS = ("tf_static", "mcap_metadata", "truth_pose", "truth_features")
REJECT_REASONS = ("too_slow", "no_imu")


@dataclass(frozen=True)
class LabelResult:
    """What the label stage did for one log."""

    log_id: str
    status: str  # "labelled" or "up_to_date"
    events: int
    rough: int
    rejects: dict[str, int]
    imu_rate_hz: float
    seconds: float
    warnings: tuple[str, ...] = ()
    #: Simulated logs: events / rough events with a true feature under a rear tyre and without.
    truth: dict[str, int] | None = None
    #: Calibration logs: Fig. 5's fit (slope_g_per_mph, intercept_g, r2, passes).
    fig5: dict[str, Any] | None = None
    outputs: tuple[str, ...] = field(default=(OUTPUT,))
    #: What the attribution rule changed (:func:`~toolkit.model.ruggedness.attribution_summary`);
    #: None on old manifests.
    attribution: dict[str, Any] | None = None

    @property
    def rough_rate(self) -> float:
        """Rough events per labelled event (0 with none)."""
        return self.rough / self.events if self.events else 0.0

    def summary(self) -> str:
        """One line for people: events, rough count and rate, rejects, IMU rate, and on
        simulated logs what the truth says, on calibration logs Fig. 5's r^2."""
        parts = [
            f"{self.events} events, {self.rough} rough ({100 * self.rough_rate:.2f} %)",
            f"rejected {self.rejects.get('too_slow', 0)} too slow, "
            f"{self.rejects.get('no_imu', 0)} without IMU",
        ]
        if self.imu_rate_hz:
            parts.append(f"IMU {self.imu_rate_hz:.2f} Hz")
        if self.truth:
            t = self.truth
            parts.append(
                f"truth: rough {t['rough_with_feature']}/{t['with_feature']} with a feature "
                f"under a tyre, {t['rough_without_feature']}/{t['without_feature']} without"
            )
        if self.fig5:
            f = self.fig5
            parts.append(
                f"Fig. 5: {f['slope_g_per_mph']:.4f} G/mph, r^2 {f['r2']:.3f} over "
                f"{f['passes']} passes"
            )
        changed = _attribution_line(self.attribution)
        if changed:
            parts.append(changed)
        if self.warnings:
            parts.append(f"{len(self.warnings)} warning(s)")
        return f"{self.log_id}: label {self.status.replace('_', ' ')} ({'; '.join(parts)})"


def _attribution_line(attribution: dict[str, Any] | None) -> str:
    """The summary's words on the attribution, or "" when it changed no positive."""
    if not attribution or attribution.get("rule") != "impact":
        return ""
    before, lost = attribution["rough_span_peak"], attribution["rough_lost"]
    if not lost:
        return ""
    return (
        f"impact attribution: {lost} of span_peak's {before} rough events were a neighbour's "
        f"impact ({attribution['events_reduced']} events' shock lowered)"
    )


@dataclass(frozen=True)
class LabelSettings:
    """What label reads of the configuration: its section and the vehicle (the IMU's mount,
    the track and wheelbase)."""

    label: LabelConfig
    vehicle: VehicleConfig


def _recall(last: Recalled[LabelSettings]) -> LabelResult:
    """The outcome of an up-to-date label, from its record and the manifest's header."""
    header = last.header.get("label") or {}
    return LabelResult(
        last.log_id,
        "up_to_date",
        int(last.record.row_counts.get("events", 0)),
        int(header.get("rough", 0)),
        dict(last.record.rejects),
        float(header.get("imu_rate_hz", 0.0)),
        last.seconds,
        truth=header.get("truth"),
        fig5=header.get("fig5"),
        outputs=tuple(last.record.outputs),
        attribution=header.get("attribution"),
    )


def _sim_profile(log_dir: Path) -> str | None:
    """The simulator profile the log says it was made with, or None (a real log)."""
    path = LogFiles(log_dir).mcap_metadata
    if not path.is_file():
        return None
    try:
        sim = json.loads(path.read_text(encoding="utf-8")).get(SIM_RECORD) or {}
        profile = sim.get("profile")
    except (ValueError, AttributeError) as exc:
        raise StageError(f"unreadable MCAP metadata: {exc}", path=path) from exc
    return str(profile) if profile is not None else None


@dataclass(frozen=True)
class _Events:
    """What label read of a log: the IMU's rate and filter, the events' boundaries
    (E + 1,) (times ns, distances m), their mean speeds (E,) m/s and which are fast enough."""

    row_z: FloatArray
    period_ns: int
    rate_hz: float
    fir: ShockFir
    bounds_ns: IntArray
    s_b: FloatArray
    speed_mps: FloatArray
    fast: NDArray[np.bool_]


def _read_events(call: Call[LabelSettings], warnings: list[str]) -> _Events:
    """The IMU's mount, rate and filter, and the posed path cut into events (sect. 5)."""
    config = call.settings
    cfg, imu_path = config.label, call.files.imu
    mounts = sensor_mounts(call.files.tf_static, config.vehicle, gps=False)
    warnings += mounts.warnings
    row_z = np.asarray(mounts.imu.rotation[2], np.float64)
    period_ns = imu_period_ns(imu_path)
    rate_hz = 1e9 / period_ns
    fir = design_shock_fir(rate_hz, cfg.fir_taps, cfg.fir_stop_hz, cfg.fir_pass_hz, where=imu_path)
    bounds_ns, s_b = streamed_path_events(call.files.pose, cfg.event_length_m)
    speed_mps = event_speed_mps(bounds_ns, cfg.event_length_m)
    fast = fast_enough(speed_mps, cfg.min_speed_mps)
    return _Events(row_z, period_ns, rate_hz, fir, bounds_ns, s_b, speed_mps, fast)


def _filter_shocks(
    call: Call[LabelSettings], ev: _Events, warnings: list[str]
) -> tuple[EventShocks, NDArray[np.bool_], dict[str, int]]:
    """The shock of every fast event (sect. 5.1), which are covered by the filtered IMU,
    and the rejects by reason."""
    cfg = call.settings.label
    envelope = impact_envelope(ev.fir) if cfg.attribution == "impact" else None
    shocks = event_shocks(
        call.files.imu,
        ev.row_z,
        ev.fir,
        ev.period_ns,
        ev.bounds_ns,
        ev.fast,
        cfg.shock_statistic,
        envelope,
    )
    covered = ev.fast & np.isfinite(shocks.shock_mps2)
    rejects = {"too_slow": int((~ev.fast).sum()), "no_imu": int((ev.fast & ~covered).sum())}
    if shocks.runs > 1:
        warnings.append(
            f"the IMU has {shocks.runs - 1} gap(s) longer than {GAP_PERIODS} periods: the "
            f"shock filter restarted after each"
        )
    if max(ev.bounds_ns.size - 1, 0) == 0:
        warnings.append(
            f"the posed path is shorter than one event ({cfg.event_length_m} m): no events"
        )
    return shocks, covered, rejects


def _event_columns(
    ev: _Events, shocks: EventShocks, keep: IntArray, labels: EventLabels, truth: TruthUnder | None
) -> tuple[dict[str, pa.Array], dict[str, int] | None]:
    """The events table's columns (schema ``events``) and, on simulated logs, the truth's
    counts of events and rough events with a true feature under a tyre and without."""
    bounds_ns, s_b, rough = ev.bounds_ns, ev.s_b, labels.rough
    columns: dict[str, pa.Array] = {
        "event_id": pa.array(keep, pa.int64()),
        "t_start_ns": pa.array(bounds_ns[keep], pa.int64()),
        "t_end_ns": pa.array(bounds_ns[keep + 1], pa.int64()),
        "s_start_m": pa.array(s_b[keep], pa.float64()),
        "s_end_m": pa.array(s_b[keep + 1], pa.float64()),
        "speed_mph": pa.array(labels.speed_mph, pa.float64()),
        "shock_g": pa.array(labels.shock_g, pa.float64()),
        "ruggedness": pa.array(labels.ruggedness, pa.float64()),
        "rough": pa.array(rough, pa.bool_()),
        "shock_t_ns": pa.array(shocks.shock_t_ns[keep], pa.int64()),
        "imu_samples": pa.array(shocks.samples[keep], pa.int32()),
    }
    if truth is None:
        columns["truth_feature_height_m"] = pa.nulls(keep.size, pa.float64())
        columns["truth_feature_kind"] = pa.nulls(keep.size, pa.string())
        return columns, None
    height = truth.height_m[keep]
    kinds = [truth.kind[i] for i in keep.tolist()]
    columns["truth_feature_height_m"] = pa.array(height, pa.float64())
    columns["truth_feature_kind"] = pa.array(kinds, pa.string())
    under = height > 0
    return columns, {
        "with_feature": int(under.sum()),
        "rough_with_feature": int((rough & under).sum()),
        "without_feature": int((~under).sum()),
        "rough_without_feature": int((rough & ~under).sum()),
    }


def _fig5(
    call: Call[LabelSettings],
    ev: _Events,
    keep: IntArray,
    labels: EventLabels,
    truth: TruthUnder | None,
    warnings: list[str],
) -> tuple[LineFit | None, list[str]]:
    """On a calibration log, the paper's Fig. 5 (shock against speed over the obstacle
    passes) written beside the events; the files label wrote. Stale figures of an earlier
    run are removed."""
    log_dir, outputs = call.files.dir, [OUTPUT]
    fig5: LineFit | None = None
    if _sim_profile(log_dir) == "calibration" and truth is not None:
        passes = obstacle_passes(
            ev.s_b[keep],
            ev.s_b[keep + 1],
            labels.speed_mph,
            labels.shock_g,
            [truth.kind[i] for i in keep.tolist()],
            call.settings.vehicle.wheelbase_m,
        )
        if len({round(p.speed_mph, 1) for p in passes}) >= 2:
            fig5 = fit_line(
                np.array([p.speed_mph for p in passes]), np.array([p.peak_g for p in passes])
            )
            title = f"{call.log_id}: Fig. 5"
            write_fig5(log_dir / FIG5_CSV, log_dir / FIG5_PNG, passes, fig5, title)
            outputs += [FIG5_CSV, FIG5_PNG]
        else:
            warnings.append(
                f"calibration log with {len(passes)} obstacle pass(es) at distinct speeds: "
                "no Fig. 5 (needs two)"
            )
    for stale in {FIG5_CSV, FIG5_PNG} - set(outputs):  # from an earlier run's generation
        (log_dir / stale).unlink(missing_ok=True)
    return fig5, outputs


@dataclass(frozen=True)
class _Written:
    """What label wrote: the labels of the kept events, the truth's and the attribution's
    summaries, Fig. 5's fit and the files."""

    labels: EventLabels
    truth: dict[str, int] | None
    attribution: dict[str, Any]
    fig5: LineFit | None
    outputs: list[str]


def _write_events(
    call: Call[LabelSettings], ev: _Events, shocks: EventShocks, keep: IntArray, warnings: list[str]
) -> _Written:
    """Label the covered events (sect. 5.2, sect. 7), write ``events.parquet`` and, on a
    calibration log, Fig. 5."""
    config = call.settings
    cfg = config.label
    labels = label_events(
        shocks.shock_mps2[keep], ev.speed_mps[keep], cfg.gravity_mps2, cfg.rough_threshold_g_per_mph
    )
    truth, truth_warning = truth_under_events(call.files.dir, ev.bounds_ns, config.vehicle.track_m)
    if truth_warning:
        warnings.append(truth_warning)
    columns, truth_summary = _event_columns(ev, shocks, keep, labels, truth)
    attribution = attribution_summary(
        cfg.attribution,
        cfg.shock_statistic,
        shocks.shock_mps2[keep],
        shocks.span_peak_mps2[keep],
        shocks.own_impact[keep],
        labels.speed_mph,
        cfg.gravity_mps2,
        cfg.rough_threshold_g_per_mph,
        ~(truth.height_m[keep] > 0) if truth is not None else None,
    )
    changed = _attribution_line(attribution)
    if changed:
        _log.info("%s: %s", call.log_id, changed)
    sha = str((call.manifest.read().get("source") or {}).get("sha256", ""))
    with TableWriter(
        call.files.events, "events", source_sha256=sha, config_hash=call.config_hash
    ) as writer:
        writer.write(pa.table(columns))
    fig5, outputs = _fig5(call, ev, keep, labels, truth, warnings)
    return _Written(labels, truth_summary, attribution, fig5, outputs)


def _made(
    call: Call[LabelSettings],
    ev: _Events,
    shocks: EventShocks,
    keep: IntArray,
    rejects: dict[str, int],
    written: _Written,
    timings: dict[str, float],
    warnings: list[str],
) -> Made[LabelResult]:
    """The outcome and what the runner records (the header's ``label`` section)."""
    n_rough = int(written.labels.rough.sum())
    detail: dict[str, Any] = {
        "imu_rate_hz": round(ev.rate_hz, 6),
        "fir": ev.fir.to_json(),
        "imu_runs": shocks.runs,
        "events": int(keep.size),
        "rough": n_rough,
        "rough_rate": round(n_rough / keep.size, 6) if keep.size else 0.0,
        "rejects": rejects,
        "attribution": written.attribution,
        "truth": written.truth,
        "fig5": written.fig5.to_json() if written.fig5 is not None else None,
    }
    outcome = LabelResult(
        call.log_id,
        "labelled",
        int(keep.size),
        n_rough,
        rejects,
        ev.rate_hz,
        time.perf_counter() - call.start,
        warnings=tuple(warnings),
        truth=written.truth,
        fig5=detail["fig5"],
        outputs=tuple(written.outputs),
        attribution=written.attribution,
    )
    return Made(
        outcome,
        tuple(written.outputs),
        row_counts={"events": int(keep.size)},
        rejects=rejects,
        timings_s=timings,
        warnings=tuple(warnings),
        header={"label": detail},
    )


def _compute(call: Call[LabelSettings]) -> Made[LabelResult]:
    """Label the log in ``call.files`` (the module docstring); the runner records it."""
    timings: dict[str, float] = {}
    warnings: list[str] = []
    t = time.perf_counter()
    ev = _read_events(call, warnings)
    timings["read"] = time.perf_counter() - t
    t = time.perf_counter()
    shocks, covered, rejects = _filter_shocks(call, ev, warnings)
    timings["filter"] = time.perf_counter() - t
    t = time.perf_counter()
    keep = np.flatnonzero(covered)
    written = _write_events(call, ev, shocks, keep, warnings)
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - call.start
    return _made(call, ev, shocks, keep, rejects, written, timings, warnings)


def _require_shock_band(files: LogFiles, config: LabelSettings) -> None:
    """StageError when the log's IMU samples too slowly for the shock filter's band (a
    30 Hz robot IMU against the 10-15 Hz band): nothing to label, whatever is run before."""
    if files.imu.is_file() and table_num_rows(files.imu, "imu"):
        cfg = config.label
        rate_hz = 1e9 / imu_period_ns(files.imu)
        design_shock_fir(rate_hz, cfg.fir_taps, cfg.fir_stop_hz, cfg.fir_pass_hz, where=files.imu)


SPEC = Stage(
    STAGE,
    "log",
    check=_require_shock_band,
    needs=(
        Need("imu", "ingest"),
        *(Need(name, "ingest", optional=True) for name in INGEST_EXTRAS),
        Need("pose", "pose"),
    ),
    makes=("events",),
    settings=LabelSettings,
    compute=_compute,
    recall=_recall,
    rows=("events",),
)


__all__ = [
    "SPEC",
    "STAGE",
    "LabelResult",
    "LabelSettings",
    "PathCarry",
    "attribution_summary",
    "path_events",
    "path_events_step",
]
