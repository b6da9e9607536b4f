"""A workspace's training tables as the drive that made them: the stream online learning
replays (:class:`toolkit.model.online.Stream`).

Every event of both splits, log after log in the tables' order, each log's events in the
order driven, their patches read a window at a time as the replay asks for them
(:mod:`toolkit.stages.online_patches`). Per event:

- ``t_seen_ns``: when the last point under either of its tyres was seen (of all its
  points, not only those its patches keep: the vehicle has to have seen them all to
  sample them; its start when it has none);
- ``t_known_ns``: its end plus ``label_delay_s``, the time the shock filter needs after the
  rear axle left the event before the event's peak is known (:func:`label_delay_s`);
- distances and times on one clock over the whole drive: each log's own continue where the
  previous log's ended (logs are separate drives; their clocks may even overlap).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from toolkit.arrays import IntArray
from toolkit.config import LabelConfig, ModelConfig
from toolkit.errors import StageError
from toolkit.model.online import Stream
from toolkit.stages.online_patches import NO_POINT, PatchWindows, point_extent
from toolkit.stages.training_data import laser_order, split_events
from toolkit.workspace import Workspace

#: The IMU rate the label delay assumes when the log does not say (Hz): the simulator's and
#: the Stanley 2005 IMU's 100 Hz.
DEFAULT_IMU_RATE_HZ = 100.0


def label_delay_s(label: LabelConfig, imu_rate_hz: float = DEFAULT_IMU_RATE_HZ) -> float:
    """The shock filter's delay: a linear-phase FIR of ``fir_taps`` taps delays every
    frequency by (taps - 1) / 2 samples (sect. 5.1's 40 taps at 100 Hz: 0.195 s)."""
    return (label.fir_taps - 1) / 2.0 / imu_rate_hz


@dataclass(frozen=True)
class DriveStream:
    """The stream, and what each of its events is in the tables: log, event id, split."""

    stream: Stream
    log_id: np.ndarray
    event_id: IntArray
    split: np.ndarray


def drive_stream(
    workspace: Workspace, model: ModelConfig, label: LabelConfig, delay_s: float | None = None
) -> DriveStream:
    """The workspace's events as one drive (module docstring); ``delay_s`` overrides the
    label delay."""
    events = split_events(workspace, None)
    order = _driven_order(events, workspace)
    events = events.take(pa.array(order))
    extent = point_extent(workspace, events)
    patches = PatchWindows(workspace, events, model, laser_order(workspace, model), extent)
    t_start = events.column("t_start_ns").to_numpy().astype(np.int64)
    t_end = events.column("t_end_ns").to_numpy().astype(np.int64)
    s_start = events.column("s_start_m").to_numpy().astype(np.float64)
    s_end = events.column("s_end_m").to_numpy().astype(np.float64)
    log_id = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    last = extent.last_seen_ns
    t_seen = np.where(last == NO_POINT, t_start, last).astype(np.int64)
    delay_ns = round(1e9 * (label_delay_s(label) if delay_s is None else delay_s))
    t_known = t_end + delay_ns
    clock, metres = one_clock(log_id, t_seen, t_known, s_start, s_end)
    stream = Stream(
        t_start + clock,
        s_start + metres,
        t_seen + clock,
        t_known + clock,
        events.column("rough").to_numpy(zero_copy_only=False).astype(bool),
        patches,
    )
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    return DriveStream(stream, log_id, events.column("event_id").to_numpy(), split)


def one_clock(
    log_id: np.ndarray,
    t_seen_ns: IntArray,
    t_known_ns: IntArray,
    s_start_m: np.ndarray,
    s_end_m: np.ndarray,
) -> tuple[IntArray, np.ndarray]:
    """What to add to each event's times (ns) and distances (m), (E,) each, so that the logs
    (in the order of their first event) make one drive: the first log's clock starts at its
    first point seen, each later one 1 s after the last label of the one before, and each
    log's distances continue from where the previous log's ended."""
    clock, metres = np.zeros(log_id.size, np.int64), np.zeros(log_id.size)
    t_next, s_next = 0, 0.0
    for log in dict.fromkeys(log_id.tolist()):
        mine = log_id == log
        shift_ns = t_next - int(t_seen_ns[mine].min())
        shift_m = s_next - float(s_start_m[mine].min())
        clock[mine], metres[mine] = shift_ns, shift_m
        t_next = int(t_known_ns[mine].max()) + shift_ns + 1_000_000_000
        s_next = float(s_end_m[mine].max()) + shift_m
    return clock, metres


def _driven_order(events: pa.Table, workspace: Workspace) -> IntArray:
    """The rows of ``events`` log after log (in table order), each log's by start time."""
    log_id = np.asarray(events.column("log_id").to_pylist(), dtype=object)
    first = {log: k for k, log in enumerate(dict.fromkeys(log_id.tolist()))}
    rank = np.array([first[v] for v in log_id], np.int64)
    missing = events.column("t_start_ns").null_count
    if missing:
        raise StageError(
            f"{missing} event(s) without a start time cannot be replayed in time order",
            path=workspace.events_table,
        )
    t = events.column("t_start_ns").to_numpy()
    return np.lexsort((t, rank)).astype(np.int64)


__all__ = ["DEFAULT_IMU_RATE_HZ", "DriveStream", "drive_stream", "label_delay_s", "one_clock"]
