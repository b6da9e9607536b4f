"""Label stage: the IMU's shock along the posed path -> ``events.parquet`` (sect. 5).

Inputs ``WS/logs/<id>/{imu,pose}.parquet``, ``tf_static.json`` (the IMU's mount) and, on
simulated logs, the truth ingest wrote. Output ``events.parquet`` (schema ``events``):

* **Events** (:func:`path_events`): the rear-axle path (pose x, y; base_link is on the
  ground below the rear-axle centre) cut by distance ``s`` into consecutive stretches of
  ``label.event_length_m``; event ``k`` is ``s`` in ``[k L, (k+1) L)``, entered and left at the
  times the path reaches those distances (linear between pose samples). Its ``event_id`` is
  ``k``: rejected events leave gaps.
* **Speed**: the mean speed over the event, ``L / (t_end - t_start)`` (the time mean of the
  path speed), in mph (1 mph = 0.44704 m/s exactly). Events slower than
  ``label.min_speed_mps`` are rejected (``too_slow``) before anything is divided by their
  speed; a stop lies inside one long slow event, so it makes none.
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
the counts, the attribution (:func:`attribution_summary`: under ``impact``, how many events'
shock it lowered, how many kept no impact of their own, and the positives ``span_peak`` would
have had against these; in the summary line when the positives differ), and the truth and
Fig. 5 summaries. Idempotent: an up-to-date label is not recomputed. Memory: the IMU is
streamed in batches of :data:`BATCH_ROWS` and only the filtered samples of the event being
labelled (plus the interpolation margin, and under ``impact`` the filter's reach) are kept; the
pose (cut into events run by run, :func:`path_events_step`) and the truth (simulated logs)
are streamed too. Only the events' own arrays are held whole (a dozen numbers an event,
~4 MB for an hour's 28,000 events: 1/14 of the pose's rows at 10 m/s).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from toolkit.analysis.fig5 import LineFit, fit_line, obstacle_passes, write_fig5
from toolkit.config import LabelConfig, PipelineConfig, VehicleConfig
from toolkit.errors import StageError
from toolkit.layout import LogFiles, log_file_name
from toolkit.model.shock import (
    INTERP_MARGIN,
    MPS_PER_MPH,
    ShockFir,
    design_shock_fir,
    event_shock,
    filter_stream,
)
from toolkit.model.shock_attribution import ImpactEnvelope, event_impact_shock, impact_envelope
from toolkit.mounts import sensor_mounts
from toolkit.sim.record import SIM_RECORD
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.label_truth import truth_under_events
from toolkit.stages.runner import run_stage
from toolkit.tableio import TableWriter, iter_table_batches
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

STAGE = "label"
#: Configuration sections label reads: its own, and the vehicle (IMU mount, track, wheelbase).
CONFIG_SECTIONS = ("label", "vehicle")
OUTPUT = log_file_name("events")
FIG5_CSV = log_file_name("fig5_csv")
FIG5_PNG = log_file_name("fig5_png")
#: Rows per IMU read batch.
BATCH_ROWS = 4_096
IMU_COLUMNS = ["t_ns", "accel_x", "accel_y", "accel_z"]
#: A step between IMU stamps longer than this many nominal periods is a gap (as pose).
GAP_PERIODS = 1.5
#: Files ingest writes that label reads when present (besides imu.parquet).
INGEST_EXTRAS = ("tf_static", "mcap_metadata", "truth_pose", "truth_features")
REJECT_REASONS = ("too_slow", "no_imu")


@dataclass(frozen=True)
class LabelResult:
    """What :func:`run_label` did for one log."""

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
    #: What the attribution rule changed (:func:`attribution_summary`); None on old manifests.
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


def attribution_summary(
    rule: str,
    statistic: str,
    shock_mps2: FloatArray,
    span_peak_mps2: FloatArray,
    own_impact: NDArray[np.bool_],
    speed_mph: FloatArray,
    gravity_mps2: float,
    threshold_g_per_mph: float,
    featureless: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """What the attribution changed over the labelled events (E,), for the manifest.

    ``rule`` the configured ``label.attribution``; ``applied`` False (and nothing counted)
    under ``span_peak`` or the ``rms`` statistic. Under ``impact``: ``events_reduced`` (the
    shock below the span peak), ``events_without_own_impact`` (no crest of their own left),
    ``rough_span_peak`` (the positives ``span_peak`` gives: its ruggedness computed as the
    stage computes it, so the same count bit for bit), ``rough`` and ``rough_lost`` (the
    attribution only lowers shocks: no event becomes rough) and, with the truth
    (``featureless``: no true feature under a tyre), ``rough_lost_featureless``."""
    applied = rule == "impact" and statistic == "max_abs"
    out: dict[str, Any] = {"rule": rule, "applied": applied}
    if not applied:
        return out
    rough = (shock_mps2 / gravity_mps2) / speed_mph >= threshold_g_per_mph
    rough_before = (span_peak_mps2 / gravity_mps2) / speed_mph >= threshold_g_per_mph
    lost = rough_before & ~rough
    out.update(
        events_reduced=int((shock_mps2 < span_peak_mps2).sum()),
        events_without_own_impact=int((~own_impact).sum()),
        rough_span_peak=int(rough_before.sum()),
        rough=int(rough.sum()),
        rough_lost=int(lost.sum()),
    )
    if featureless is not None:
        out["rough_lost_featureless"] = int((lost & featureless).sum())
    return out


@dataclass(frozen=True)
class PathCarry:
    """Where the rear-axle path stood after the pose rows seen so far: what
    :func:`path_events_step` needs of them to go on with the next rows."""

    #: The path's first pose time (the origin of the interpolation's float times), ns.
    t0_ns: int
    #: The last row: time (ns), position (m) and distance along the path (m).
    t_ns: int
    x_m: float
    y_m: float
    s_m: float
    #: The index of the next boundary to find (boundaries ``< next_k`` were returned).
    next_k: int


def path_events_step(
    t_ns: IntArray, x: FloatArray, y: FloatArray, length_m: float, carry: PathCarry | None
) -> tuple[IntArray, FloatArray, PathCarry | None]:
    """The event boundaries a run of the path's pose rows holds, for a path fed in
    consecutive runs: (times (B,) ns, distances (B,) m, the carry for the next run).

    The boundaries are where the path ``(t_ns, x, y)`` (K,) reaches ``s = k * length_m``;
    boundary 0 is the path's first row. Between rows the time is linear in s; where s
    stands still (a stop) the boundary is the first time it is reached. ``carry`` is None for
    the first run. The distances are summed in the order of the rows (``np.cumsum`` with the
    last distance prepended), so any split of the path into runs gives, bit for bit, the
    boundaries of the whole path at once (:func:`path_events`), while only a run of the pose
    is held: the label stage's memory does not grow with the log."""
    empty = (np.zeros(0, np.int64), np.zeros(0))
    if t_ns.size == 0:
        return *empty, carry
    if carry is None:
        t, xs, ys, s_first, next_k = t_ns, x, y, 0.0, 0
        t0 = int(t_ns[0])
    else:
        t = np.concatenate([[carry.t_ns], t_ns])
        xs, ys = np.concatenate([[carry.x_m], x]), np.concatenate([[carry.y_m], y])
        s_first, next_k, t0 = carry.s_m, carry.next_k, carry.t0_ns
    s = np.cumsum(np.concatenate([[s_first], np.hypot(np.diff(xs), np.diff(ys))]))
    # The last boundary the run reaches, k L <= s: decided on the products themselves (the
    # quotient s / L may round up to k while k L > s), so each run's boundaries (but the
    # path's boundary 0) lie strictly after its first row and at or before its last.
    last_k = int(np.floor(s[-1] / length_m))
    while last_k * length_m > s[-1]:
        last_k -= 1
    while (last_k + 1) * length_m <= s[-1]:
        last_k += 1
    k = np.arange(next_k, last_k + 1)
    s_b = k * length_m
    t_b = np.empty(k.size, np.int64)
    # Boundaries after the run's first row: s[i-1] < s_b <= s[i], time linear in s between.
    after = k > 0
    if after.any():
        i = np.searchsorted(s, s_b[after], side="left")
        ds = s[i] - s[i - 1]
        frac = np.where(ds > 0, (s_b[after] - s[i - 1]) / np.where(ds > 0, ds, 1.0), 1.0)
        rel = (t - t0).astype(np.float64)
        t_b[after] = t0 + np.round(rel[i - 1] + frac * (rel[i] - rel[i - 1])).astype(np.int64)
    t_b[~after] = t0  # boundary 0: the path's first row
    new_carry = PathCarry(t0, int(t[-1]), float(xs[-1]), float(ys[-1]), float(s[-1]), last_k + 1)
    return t_b, np.asarray(s_b, np.float64), new_carry


def path_events(
    t_ns: IntArray, x: FloatArray, y: FloatArray, length_m: float
) -> tuple[IntArray, FloatArray]:
    """Event boundaries along a whole path: (times (E + 1,) ns, distances (E + 1,) m) where
    the path ``(t_ns, x, y)`` (K,) reaches ``s = k * length_m``, k = 0..E, E the whole events
    it holds (none, and no boundary, when it is shorter than one event). See
    :func:`path_events_step`, which the stage feeds the pose a batch at a time."""
    t_b, s_b, _ = path_events_step(t_ns, x, y, length_m, None)
    return (t_b, s_b) if t_b.size >= 2 else (np.zeros(0, np.int64), np.zeros(0))


def _imu_period_ns(imu_path: Path) -> int:
    """The IMU's nominal sampling period (ns): the mean step of the first batch, over the
    steps within half a median of the median (gaps and duplicates left out). The mean, not
    the median: stamps jitter, so steps are spread, but their mean is the clock's period. The
    window is symmetric so that trimming does not bias it (a window of [median / 1.5,
    median x 1.5] cut jittered short steps but not long ones: 99.35 Hz for a 100 Hz IMU
    with +-2 ms jitter)."""
    first = next(
        iter_table_batches(imu_path, "imu", columns=["t_ns"], batch_rows=BATCH_ROWS, lean=True),
        None,
    )
    t = np.asarray(first.column(0).to_numpy(), np.int64) if first is not None else np.zeros(0)
    dt = np.diff(t)
    dt = dt[dt > 0]
    if dt.size < 1:
        raise StageError(f"the IMU has {t.size} usable row(s): no rate to filter at", path=imu_path)
    med = float(np.median(dt))
    regular = dt[np.abs(dt - med) < 0.5 * med]
    return int(round(float(regular.mean())))


def _vertical_accel(imu_path: Path, row_z: FloatArray) -> Iterator[tuple[IntArray, FloatArray]]:
    """(t_ns (M,), base_link z specific force (M,) m/s^2) batch by batch: ``row_z`` (3,) is
    the mount rotation's last row, so ``a_z = row_z . a_imu``."""
    for b in iter_table_batches(
        imu_path, "imu", columns=IMU_COLUMNS, batch_rows=BATCH_ROWS, lean=True
    ):
        t = np.asarray(b.column(0).to_numpy(), np.int64)
        a = [np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64) for i in (1, 2, 3)]
        yield t, row_z[0] * a[0] + row_z[1] * a[1] + row_z[2] * a[2]


def _streamed_path_events(pose_path: Path, length_m: float) -> tuple[IntArray, FloatArray]:
    """:func:`path_events` over the pose table read a batch at a time (only the boundaries,
    ~1/14 of the pose's rows at 10 m/s, are kept)."""
    carry: PathCarry | None = None
    times: list[IntArray] = []
    distances: list[FloatArray] = []
    for b in iter_table_batches(
        pose_path, "pose", columns=["t_ns", "x", "y"], batch_rows=BATCH_ROWS, lean=True
    ):
        t = np.asarray(b.column(0).to_numpy(), np.int64)
        x, y = (np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64) for i in (1, 2))
        t_b, s_b, carry = path_events_step(t, x, y, length_m, carry)
        times.append(t_b)
        distances.append(s_b)
    bounds_ns = np.concatenate([np.zeros(0, np.int64), *times])
    if bounds_ns.size < 2:  # shorter than one event: no boundary at all
        return np.zeros(0, np.int64), np.zeros(0)
    return bounds_ns, np.concatenate(distances)


@dataclass(frozen=True)
class _Shocks:
    """Per event (E,): shock (m/s^2, NaN when not computed), its time, samples, the
    ``span_peak`` rule's shock (the same as ``shock_mps2`` unless ``impact`` attributed) and
    whether the shock is an impact of the event's own; and the number of IMU runs the filter
    saw."""

    shock_mps2: FloatArray
    shock_t_ns: IntArray
    samples: IntArray
    span_peak_mps2: FloatArray
    own_impact: NDArray[np.bool_]
    runs: int


def _event_shocks(
    imu_path: Path,
    row_z: FloatArray,
    fir: ShockFir,
    period_ns: int,
    bounds_ns: IntArray,
    wanted: NDArray[np.bool_],
    statistic: str,
    envelope: ImpactEnvelope | None = None,
) -> _Shocks:
    """Stream the IMU through the filter and take each wanted event's shock as soon as the
    filtered samples past its end (plus the interpolation margin) have arrived, keeping only
    the samples the next wanted event can still need. ``envelope``: attribute impacts
    (:func:`~toolkit.model.shock.event_impact_shock`; ``max_abs`` only), whose crests
    within the filter's reach of the span are kept as well; None: ``span_peak``."""
    n_events = wanted.size
    shock = np.full(n_events, np.nan)
    span_peak = np.full(n_events, np.nan)
    own = np.ones(n_events, dtype=bool)
    when = np.zeros(n_events, np.int64)
    samples = np.zeros(n_events, np.int64)
    max_gap_ns = int(GAP_PERIODS * period_ns)
    attribute = envelope is not None and statistic == "max_abs"
    reach = int(np.ceil(envelope.reach_samples)) + 1 if envelope is not None and attribute else 0
    margin_ns = (reach + INTERP_MARGIN + 1) * period_ns
    todo = np.flatnonzero(wanted)
    k = 0  # next index into todo
    buf_t = np.zeros(0, np.int64)
    buf_v = np.zeros(0)
    buf_r = np.zeros(0, np.int64)
    runs = 0

    def take(e: int) -> None:
        t0, t1 = int(bounds_ns[e]), int(bounds_ns[e + 1])
        if envelope is not None and attribute:
            mine = event_impact_shock(buf_t, buf_v, buf_r, t0, t1, envelope, max_gap_ns)
            if mine is not None:
                shock[e], when[e], samples[e] = mine.shock_mps2, mine.peak_t_ns, mine.samples
                span_peak[e], own[e] = mine.span_peak_mps2, mine.own_impact
            return
        got = event_shock(buf_t, buf_v, buf_r, t0, t1, statistic, max_gap_ns)
        if got is not None:
            shock[e], when[e], samples[e] = got.shock_mps2, got.peak_t_ns, got.samples
            span_peak[e] = got.shock_mps2

    for chunk in filter_stream(_vertical_accel(imu_path, row_z), fir.taps, max_gap_ns):
        buf_t = np.concatenate([buf_t, chunk.t_ns])
        buf_v = np.concatenate([buf_v, chunk.value])
        buf_r = np.concatenate([buf_r, chunk.run])
        runs = int(chunk.run[-1]) + 1
        latest = int(buf_t[-1])
        while k < todo.size and int(bounds_ns[todo[k] + 1]) + margin_ns <= latest:
            take(int(todo[k]))
            k += 1
        keep_from = (
            int(np.searchsorted(buf_t, int(bounds_ns[todo[k]]) - margin_ns))
            if k < todo.size
            else buf_t.size
        )
        buf_t, buf_v, buf_r = buf_t[keep_from:], buf_v[keep_from:], buf_r[keep_from:]
    for e in todo[k:].tolist():  # the last events, with what the IMU had
        take(int(e))
    return _Shocks(shock, when, samples, span_peak, own, runs)


@dataclass(frozen=True)
class LabelSettings:
    """What label reads of the configuration: its section and the vehicle (the IMU's mount,
    the track and wheelbase)."""

    label: LabelConfig
    vehicle: VehicleConfig


def run_label(
    workspace: Workspace, log_id: str, config: PipelineConfig, *, overwrite: bool = False
) -> LabelResult:
    """Label one posed log (see the module docstring)."""
    result = run_stage(SPEC, workspace, config, log_id=log_id, overwrite=overwrite)
    return cast(LabelResult, result)


def _recall(last: Recalled) -> LabelResult:
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


def _compute(call: Call) -> Made:
    """Label the log in ``call.files`` (the module docstring); the runner records it."""
    config: LabelSettings = call.settings
    log_dir, log_id, start = call.files.dir, call.log_id, call.start
    cfg, cfg_hash, manifest = config.label, call.config_hash, call.manifest
    timings: dict[str, float] = {}
    t = time.perf_counter()
    imu_path = call.files.imu
    mounts = sensor_mounts(call.files.tf_static, config.vehicle, gps=False)
    warnings = list(mounts.warnings)
    row_z = np.asarray(mounts.imu.rotation[2], np.float64)
    period_ns = _imu_period_ns(imu_path)
    rate_hz = 1e9 / period_ns
    fir = design_shock_fir(rate_hz, cfg.fir_taps, cfg.fir_stop_hz, cfg.fir_pass_hz, where=imu_path)
    bounds_ns, s_b = _streamed_path_events(call.files.pose, cfg.event_length_m)
    n_events = max(bounds_ns.size - 1, 0)
    duration_s = np.diff(bounds_ns) * 1e-9
    # Every event has a positive duration (s rises through each boundary); a zero one (two
    # boundaries inside one nanosecond) is treated as infinitely slow rather than divided by.
    speed_mps = np.where(
        duration_s > 0, cfg.event_length_m / np.where(duration_s > 0, duration_s, 1.0), 0.0
    )
    fast = speed_mps >= cfg.min_speed_mps if cfg.min_speed_mps > 0 else speed_mps > 0
    timings["read"] = time.perf_counter() - t

    t = time.perf_counter()
    envelope = impact_envelope(fir) if cfg.attribution == "impact" else None
    shocks = _event_shocks(
        imu_path, row_z, fir, period_ns, bounds_ns, fast, cfg.shock_statistic, envelope
    )
    timings["filter"] = time.perf_counter() - t
    covered = fast & np.isfinite(shocks.shock_mps2)
    rejects = {"too_slow": int((~fast).sum()), "no_imu": int((fast & ~covered).sum())}
    if shocks.runs > 1:
        warnings.append(
            f"the IMU has {shocks.runs - 1} gap(s) longer than {GAP_PERIODS} periods: the "
            f"shock filter restarted after each"
        )
    if n_events == 0:
        warnings.append(
            f"the posed path is shorter than one event ({cfg.event_length_m} m): no events"
        )

    t = time.perf_counter()
    keep = np.flatnonzero(covered)
    speed_mph = speed_mps[keep] / MPS_PER_MPH
    shock_g = shocks.shock_mps2[keep] / cfg.gravity_mps2
    ruggedness = shock_g / speed_mph
    rough = ruggedness >= cfg.rough_threshold_g_per_mph
    truth, truth_warning = truth_under_events(log_dir, bounds_ns, config.vehicle.track_m)
    if truth_warning:
        warnings.append(truth_warning)
    columns: dict[str, pa.Array] = {
        "event_id": pa.array(keep, pa.int64()),
        "t_start_ns": pa.array(bounds_ns[keep], pa.int64()),
        "t_end_ns": pa.array(bounds_ns[keep + 1], pa.int64()),
        "s_start_m": pa.array(s_b[keep], pa.float64()),
        "s_end_m": pa.array(s_b[keep + 1], pa.float64()),
        "speed_mph": pa.array(speed_mph, pa.float64()),
        "shock_g": pa.array(shock_g, pa.float64()),
        "ruggedness": pa.array(ruggedness, pa.float64()),
        "rough": pa.array(rough, pa.bool_()),
        "shock_t_ns": pa.array(shocks.shock_t_ns[keep], pa.int64()),
        "imu_samples": pa.array(shocks.samples[keep], pa.int32()),
    }
    truth_summary: dict[str, int] | None = None
    if truth is not None:
        height = truth.height_m[keep]
        kinds = [truth.kind[i] for i in keep.tolist()]
        columns["truth_feature_height_m"] = pa.array(height, pa.float64())
        columns["truth_feature_kind"] = pa.array(kinds, pa.string())
        under = height > 0
        truth_summary = {
            "with_feature": int(under.sum()),
            "rough_with_feature": int((rough & under).sum()),
            "without_feature": int((~under).sum()),
            "rough_without_feature": int((rough & ~under).sum()),
        }
    else:
        columns["truth_feature_height_m"] = pa.nulls(keep.size, pa.float64())
        columns["truth_feature_kind"] = pa.nulls(keep.size, pa.string())
    attribution = attribution_summary(
        cfg.attribution,
        cfg.shock_statistic,
        shocks.shock_mps2[keep],
        shocks.span_peak_mps2[keep],
        shocks.own_impact[keep],
        speed_mph,
        cfg.gravity_mps2,
        cfg.rough_threshold_g_per_mph,
        ~(truth.height_m[keep] > 0) if truth is not None else None,
    )
    changed = _attribution_line(attribution)
    if changed:
        _log.info("%s: %s", log_id, changed)
    sha = str((manifest.read().get("source") or {}).get("sha256", ""))
    with TableWriter(
        call.files.events, "events", source_sha256=sha, config_hash=cfg_hash
    ) as writer:
        writer.write(pa.table(columns))
    outputs = [OUTPUT]
    fig5: LineFit | None = None
    if _sim_profile(log_dir) == "calibration" and truth is not None:
        passes = obstacle_passes(
            s_b[keep],
            s_b[keep + 1],
            speed_mph,
            shock_g,
            [truth.kind[i] for i in keep.tolist()],
            config.vehicle.wheelbase_m,
        )
        if len({round(p.speed_mph, 1) for p in passes}) >= 2:
            fig5 = fit_line(
                np.array([p.speed_mph for p in passes]), np.array([p.peak_g for p in passes])
            )
            write_fig5(log_dir / FIG5_CSV, log_dir / FIG5_PNG, passes, fig5, f"{log_id}: Fig. 5")
            outputs += [FIG5_CSV, FIG5_PNG]
        else:
            warnings.append(
                f"calibration log with {len(passes)} obstacle pass(es) at distinct speeds: "
                "no Fig. 5 (needs two)"
            )
    for stale in {FIG5_CSV, FIG5_PNG} - set(outputs):  # from an earlier run's generation
        (log_dir / stale).unlink(missing_ok=True)
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - start
    n_rough = int(rough.sum())
    detail: dict[str, Any] = {
        "imu_rate_hz": round(rate_hz, 6),
        "fir": fir.to_json(),
        "imu_runs": shocks.runs,
        "events": int(keep.size),
        "rough": n_rough,
        "rough_rate": round(n_rough / keep.size, 6) if keep.size else 0.0,
        "rejects": rejects,
        "attribution": attribution,
        "truth": truth_summary,
        "fig5": fig5.to_json() if fig5 is not None else None,
    }
    outcome = LabelResult(
        log_id,
        "labelled",
        int(keep.size),
        n_rough,
        rejects,
        rate_hz,
        time.perf_counter() - start,
        warnings=tuple(warnings),
        truth=truth_summary,
        fig5=detail["fig5"],
        outputs=tuple(outputs),
        attribution=attribution,
    )
    return Made(
        outcome,
        tuple(outputs),
        row_counts={"events": int(keep.size)},
        rejects=rejects,
        timings_s=timings,
        warnings=tuple(warnings),
        header={"label": detail},
    )


SPEC = Stage(
    STAGE,
    "log",
    needs=(
        Need("imu", "ingest"),
        *(Need(name, "ingest", optional=True) for name in INGEST_EXTRAS),
        Need("pose", "pose"),
    ),
    makes=("events",),
    sections=CONFIG_SECTIONS,
    settings=LabelSettings,
    compute=_compute,
    recall=_recall,
    rows=("events",),
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "STAGE",
    "LabelResult",
    "LabelSettings",
    "PathCarry",
    "attribution_summary",
    "path_events",
    "path_events_step",
    "run_label",
    "stage_config_hash",
]
