"""The events of the paper's Sect. 5: the rear-axle path cut by distance into stretches.

The rear-axle path (pose x, y; base_link is on the ground below the rear-axle centre) is cut
by distance ``s`` along it into consecutive stretches of ``L`` = ``label.event_length_m``:
event ``k`` is ``s`` in ``[k L, (k+1) L)``, entered and left at the times the path reaches
those distances (linear in ``s`` between pose samples). Sect. 5 labels each stretch by the
shock the IMU felt over it (:mod:`toolkit.model.shock`) divided by the speed it was driven
at (:mod:`toolkit.model.ruggedness`).

The path may be fed in consecutive runs (:func:`path_events_step`, with a
:class:`PathCarry`): any split gives, bit for bit, the boundaries of the whole path
(:func:`path_events`), so a stage holds only a run of the pose at a time.

Times are int64 ns; distances m. Shapes in the docstrings: (K,) pose rows, (B,) boundaries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.arrays import FloatArray, IntArray


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


__all__ = ["PathCarry", "path_events", "path_events_step"]
