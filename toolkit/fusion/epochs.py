"""The estimator's time grid: filter steps ("epochs") and output times, around IMU gaps.

Filter steps fall on every valid GPS fix and every compass reading, with filler epochs so
that no step is longer than :data:`MAX_STEP_S`, except inside the IMU gaps the filter
restarts across (longer than :data:`MAX_BRIDGE_S`), where there is nothing to step on.
Output times are the ``1 / output_rate_hz`` grid from the start, less those strictly inside
such a gap: with no IMU there, a row would be an extrapolation, not an estimate.
"""

from __future__ import annotations

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.estimator_io import SensorData

#: Longest filter step, s.
MAX_STEP_S = 0.1
#: Longest IMU gap bridged; a longer one restarts the filter, s.
MAX_BRIDGE_S = 0.5
#: Longest IMU gap crossed at constant velocity and attitude, s. After a longer one (a
#: recorder paused, a sensor unplugged) where the vehicle went is unknown: the crossing
#: stops after this long (so neither the motion nor the process noise is integrated over a
#: gap of hours, which would only make up a position and overflow the covariance), and the
#: first GPS fix after the gap re-initialises position and velocity.
MAX_CROSS_S = 2.0


def inside_gaps(x: FloatArray, gaps: FloatArray) -> np.ndarray:
    """Whether each time of ``x`` lies strictly inside one of the sorted, disjoint
    ``gaps`` (K, 2) intervals."""
    if gaps.shape[0] == 0:
        return np.zeros(np.shape(x), dtype=bool)
    i = np.searchsorted(gaps[:, 0], x, side="right") - 1
    ok = i >= 0
    j = np.maximum(i, 0)
    return np.asarray(ok & (x > gaps[j, 0]) & (x < gaps[j, 1]), dtype=bool)


def filter_epochs(d: SensorData, t_start: float, t_end: float, imu_gaps: FloatArray) -> FloatArray:
    """Filter step times: every GPS fix and compass reading, and fillers so that no step is
    longer than :data:`MAX_STEP_S` -- except inside the IMU gaps the filter restarts
    across, where there is nothing to step on. So the count grows with the data, never
    with the time a log spans (a recorder paused for a year adds two epochs, not 300 M)."""
    t = np.union1d(d.gps_t, d.head_t)
    t = t[(t > t_start) & (t <= t_end)]
    edges = imu_gaps.ravel()
    edges = edges[(edges > t_start) & (edges <= t_end)]
    t = np.unique(np.concatenate([[t_start], t, edges, [t_end]]))
    gaps = np.diff(t)
    n_fill = np.maximum(np.ceil(gaps / MAX_STEP_S).astype(int) - 1, 0)
    n_fill[inside_gaps(0.5 * (t[:-1] + t[1:]), imu_gaps)] = 0
    if n_fill.any():
        fills = [
            t[i] + gaps[i] * np.arange(1, n + 1) / (n + 1) for i, n in enumerate(n_fill) if n > 0
        ]
        t = np.union1d(t, np.concatenate(fills))
    return np.asarray(t[1:], dtype=np.float64)


def grid_outside_gaps(
    t0: float, step: float, m_lo: int, m_hi: int, gaps: FloatArray
) -> tuple[FloatArray, int]:
    """The output times ``t0 + step m`` for ``m_lo <= m <= m_hi`` that are not strictly
    inside a gap, and how many were left out; nothing is allocated for the times left out."""
    pieces: list[np.ndarray] = []
    m = m_lo
    lo_t, hi_t = t0 + step * m_lo, t0 + step * m_hi
    for a, b in gaps[(gaps[:, 1] > lo_t) & (gaps[:, 0] < hi_t)]:
        m_a = min(int(np.floor((a - t0) / step)), m_hi)  # the last time at or before a
        if m_a >= m:
            pieces.append(np.arange(m, m_a + 1))
        m = max(m, int(np.ceil((b - t0) / step)))  # the first at or after b
    if m <= m_hi:
        pieces.append(np.arange(m, m_hi + 1))
    ms = np.concatenate(pieces) if pieces else np.zeros(0, dtype=np.int64)
    return np.asarray(t0 + step * ms, dtype=np.float64), (m_hi - m_lo + 1) - int(ms.size)


__all__ = [
    "MAX_BRIDGE_S",
    "MAX_CROSS_S",
    "MAX_STEP_S",
    "filter_epochs",
    "grid_outside_gaps",
    "inside_gaps",
]
