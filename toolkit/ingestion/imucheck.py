"""IMU samples no sensor produces: beyond its measuring range, or a jump no vehicle makes.

One corrupt gyro sample (a bit flip, a bus error: 100 rad/s once in a 100 Hz stream) is
integrated by the pose filter like any other: 100 rad/s for 10 ms turns the attitude by
57 deg, which no later GPS or wheel reading can fully undo, and the pose exits 0. So once the
IMU table is finished (sorted by time) each sample is checked before any stage reads it:

- ``imu_beyond_range``: a rate or a specific force beyond the sensor's full scale
  (``[imu] gyro_range_radps``, ``accel_range_mps2``): the sensor cannot have measured it.
- ``imu_spike``: a gyro sample farther from the median of its :data:`NEIGHBOURS` neighbours
  on each side than ``max_angular_accel_radps2`` times the time to the farthest of them. A
  body whose angular acceleration is at most ``alpha`` changes its rate by at most
  ``alpha |t_i - t_j|`` between two samples, so a clean sample is never farther than that
  from any neighbour, hence from their median; a run of up to ``NEIGHBOURS - 1`` bad
  samples leaves the median to the clean ones (and every clean sample beside the run keeps a
  clean median), so the run is caught and nothing else. Across a gap in the stream the
  allowance grows with the gap. At 100 Hz the allowance is 3 rad/s: a spike below it turns
  the attitude by at most 3 rad/s x 10 ms = 1.7 deg, which the filter's GPS and gravity
  updates then pull back.

The accelerometer gets the range test only: a tyre's impact is a real shock a sample or two
long, and it is what the labels measure (``docs/label.md``), so a jump in specific force is
no sign of a fault.

Rejected samples are dropped from the table, counted per reason in the IMU topic's account
and said on the terminal (:func:`imu_warnings`), however few.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from toolkit.arrays import AnyFloatArray as FloatArray
from toolkit.arrays import BoolArray, IntArray
from toolkit.config import ImuConfig
from toolkit.tableio import ROW_GROUP_ROWS

#: Neighbours on each side whose median a gyro sample is compared with.
NEIGHBOURS = 3
#: The reasons, in the order they are checked (a sample counts under the first).
IMU_REJECT_REASONS: tuple[str, ...] = ("imu_beyond_range", "imu_spike")

GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")


@dataclass(frozen=True)
class ImuVerdict:
    """Per-sample masks (n,) of a time-sorted IMU stream: beyond range, and gyro spikes
    (among the samples within range)."""

    beyond_range: BoolArray
    spike: BoolArray


def beyond_range(gyro_radps: FloatArray, accel_mps2: FloatArray, cfg: ImuConfig) -> BoolArray:
    """Mask (n,) of samples with any axis of ``gyro_radps`` (n, 3) or ``accel_mps2`` (n, 3)
    beyond the full scales of ``cfg``."""
    gyro_over = np.abs(gyro_radps) > cfg.gyro_range_radps
    accel_over = np.abs(accel_mps2) > cfg.accel_range_mps2
    return np.asarray(gyro_over.any(axis=1) | accel_over.any(axis=1), dtype=bool)


def gyro_spikes(
    t_ns: IntArray, gyro_radps: FloatArray, max_angular_accel_radps2: float, rows: slice
) -> BoolArray:
    """Mask of the samples ``rows`` of ``gyro_radps`` (n, 3; NaN where a sample is not to be
    used as a neighbour) that are spikes (module docstring), judged against up to
    :data:`NEIGHBOURS` samples each side within the arrays (fewer at their ends)."""
    n = len(t_ns)
    idx = np.arange(n)[rows]
    offsets = np.r_[-NEIGHBOURS:0, 1 : NEIGHBOURS + 1]
    nb = idx[:, None] + offsets[None, :]  # (m, 2k)
    inside = (nb >= 0) & (nb < n)
    nb = np.clip(nb, 0, n - 1)
    values = gyro_radps[nb]  # (m, 2k, 3)
    values[~inside] = np.nan
    usable = inside & np.isfinite(values).all(axis=2)
    if not usable.all():
        values[~usable] = np.nan
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        # A sample with no usable neighbour is not judged (numpy's "All-NaN slice" warning).
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(values, axis=1) if not usable.all() else np.median(values, axis=1)
        span_s = np.where(usable, np.abs(t_ns[nb] - t_ns[idx, None]), 0).max(axis=1) * 1e-9
        allowed = max_angular_accel_radps2 * span_s
        far = np.abs(gyro_radps[idx] - median) > allowed[:, None]
    spikes: BoolArray = far.any(axis=1) & usable.any(axis=1)
    return spikes


def stream_imu_check(path: Path, cfg: ImuConfig) -> ImuVerdict | None:
    """:class:`ImuVerdict` of a finished IMU table, read a row group at a time with
    :data:`NEIGHBOURS` rows of context carried across (memory does not grow with the log);
    None when every sample is good."""
    over_parts: list[BoolArray] = []
    spike_parts: list[BoolArray] = []
    k = NEIGHBOURS
    carry_t = np.zeros(0, dtype=np.int64)
    carry_g = np.zeros((0, 3))
    pending = 0  # rows at the end of the carry whose spike test waits for right context
    for t, gyro, accel in _read(path):
        over = beyond_range(gyro, accel, cfg)
        over_parts.append(over)
        gyro = np.where(over[:, None], np.nan, gyro)  # not a neighbour either
        t_all = np.concatenate([carry_t, t])
        g_all = np.concatenate([carry_g, gyro])
        first = len(carry_t) - pending
        last = len(t_all) - k  # the newest k wait for the next piece
        if last > first:
            spike_parts.append(
                gyro_spikes(t_all, g_all, cfg.max_angular_accel_radps2, slice(first, last))
            )
        unjudged = max(first, last)
        keep_from = max(0, unjudged - k)  # k judged rows stay as left context
        carry_t, carry_g = t_all[keep_from:], g_all[keep_from:]
        pending = len(t_all) - unjudged
    if pending:
        spike_parts.append(
            gyro_spikes(
                carry_t, carry_g, cfg.max_angular_accel_radps2, slice(len(carry_t) - pending, None)
            )
        )
    if not over_parts:
        return None
    over_all = np.concatenate(over_parts)
    spike_all = np.concatenate(spike_parts) & ~over_all
    if not over_all.any() and not spike_all.any():
        return None
    return ImuVerdict(over_all, spike_all)


def _read(path: Path) -> Iterator[tuple[IntArray, FloatArray, FloatArray]]:
    """(t_ns (m,), gyro (m, 3), accel (m, 3)) of a table, a row group at a time."""
    with pq.ParquetFile(path, pre_buffer=False) as f:
        for batch in f.iter_batches(batch_size=ROW_GROUP_ROWS, columns=["t_ns", *GYRO, *ACCEL]):
            if not batch.num_rows:
                continue
            cols = [batch.column(i).to_numpy(zero_copy_only=False) for i in range(7)]
            yield (
                np.asarray(cols[0], dtype=np.int64),
                np.column_stack(cols[1:4]).astype(np.float64),
                np.column_stack(cols[4:7]).astype(np.float64),
            )


__all__ = [
    "IMU_REJECT_REASONS",
    "NEIGHBOURS",
    "ImuVerdict",
    "beyond_range",
    "gyro_spikes",
    "stream_imu_check",
]
