"""The label stage's inputs, streamed: the IMU's vertical specific force through the shock
filter, and the posed path cut into events (the stage: :mod:`toolkit.stages.label`).

The IMU is read in batches of :data:`BATCH_ROWS` and only the filtered samples of the event
being labelled (plus the interpolation margin, and under ``impact`` the filter's reach) are
kept (:func:`event_shocks`); the pose is cut into events run by run
(:func:`~toolkit.model.events.path_events_step`, :func:`streamed_path_events`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.errors import StageError
from toolkit.model.events import PathCarry, path_events_step
from toolkit.model.shock import INTERP_MARGIN, ShockFir, event_shock, filter_stream
from toolkit.model.shock_attribution import ImpactEnvelope, event_impact_shock
from toolkit.tableio import iter_table_batches

#: Rows per IMU read batch.
BATCH_ROWS = 4_096
IMU_COLUMNS = ["t_ns", "accel_x", "accel_y", "accel_z"]
#: A step between IMU stamps longer than this many nominal periods is a gap (as pose).
GAP_PERIODS = 1.5


def imu_period_ns(imu_path: Path) -> int:
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


def vertical_accel(imu_path: Path, row_z: FloatArray) -> Iterator[tuple[IntArray, FloatArray]]:
    """(t_ns (M,), base_link z specific force (M,) m/s^2) batch by batch: ``row_z`` (3,) is
    the mount rotation's last row, so ``a_z = row_z . a_imu``."""
    for b in iter_table_batches(
        imu_path, "imu", columns=IMU_COLUMNS, batch_rows=BATCH_ROWS, lean=True
    ):
        t = np.asarray(b.column(0).to_numpy(), np.int64)
        a = [np.asarray(b.column(i).to_numpy(zero_copy_only=False), np.float64) for i in (1, 2, 3)]
        yield t, row_z[0] * a[0] + row_z[1] * a[1] + row_z[2] * a[2]


def streamed_path_events(pose_path: Path, length_m: float) -> tuple[IntArray, FloatArray]:
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
class EventShocks:
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


def event_shocks(
    imu_path: Path,
    row_z: FloatArray,
    fir: ShockFir,
    period_ns: int,
    bounds_ns: IntArray,
    wanted: NDArray[np.bool_],
    statistic: str,
    envelope: ImpactEnvelope | None = None,
) -> EventShocks:
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

    for chunk in filter_stream(vertical_accel(imu_path, row_z), fir.taps, max_gap_ns):
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
    return EventShocks(shock, when, samples, span_peak, own, runs)


__all__ = [
    "BATCH_ROWS",
    "GAP_PERIODS",
    "EventShocks",
    "event_shocks",
    "imu_period_ns",
    "streamed_path_events",
    "vertical_accel",
]
