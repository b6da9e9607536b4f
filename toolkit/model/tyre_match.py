"""Which laser points lie near the ground the rear tyres traversed in an event (paper sect. 7).

Sect. 7 trains on "all laser points [that] fall within 30cm of terrain the vehicle's rear tires
traversed": for each event (a stretch of the rear-axle path, sect. 5) and each rear tyre, the
points observed *before* the rear axle reached the stretch (by at most a lookahead) that lie
within the radius of a sample of that tyre's path over it (:mod:`toolkit.tyre_paths`, samples
at most ``PATH_STEP_M`` apart). :class:`PathSource` samples the paths of a run of events from
the pose rows around them; :func:`match_points` sieves a batch of points, cheapest first: the
grid cells the paths pass near, then a KD-tree of the samples.

Times are int64 ns; positions m. Shapes in the docstrings: (P,) points, (M,) path samples,
(Q,) matches.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial import cKDTree

from toolkit.arrays import FloatArray, IntArray
from toolkit.tyre_paths import TyrePaths, near_cells, tyre_paths

#: Samples asked for per point near a tyre path (at 5 cm spacing a 30 cm radius holds ~13
#: of one event's path; a point near two events' ends, or a slow stretch, holds more).
NEIGHBOURS = 24


class EventPaths(Protocol):
    """Whatever samples the tyre paths of a run of a log's events (:class:`PathSource`)."""

    def paths(self, first: int, stop: int) -> TyrePaths: ...


@dataclass(frozen=True)
class PathSource:
    """Pose rows and a log's events, from which the tyre paths of any run of consecutive
    events the rows cover are sampled when needed (:meth:`paths`), so a log's paths are
    never whole in memory.

    ``pose_yaw`` is unwrapped as over the whole log (the stage's pose stream,
    :class:`~toolkit.stages.tables_points.RunningUnwrap`): its steps are within pi, so
    :func:`tyre_paths` unwrapping a slice of it leaves it as it is, and the paths of a run
    of events are bit for bit those :func:`tyre_paths` gives over the whole log (but where
    rounding puts an unwrapped step a hair past pi, which the second unwrap would move by
    2 pi). The rows may be a window of the log's pose (the stage passes the rows around the
    open events), the events are the log's."""

    pose_t_ns: IntArray
    pose_xy: FloatArray
    pose_yaw: FloatArray
    t_start_ns: IntArray
    t_end_ns: IntArray
    track_m: float

    def paths(self, first: int, stop: int) -> TyrePaths:
        """The paths of events ``first .. stop - 1`` (their ``event`` the log's event rows),
        from the pose rows around them (the row at or before the first start to the row at
        or after the last end: what the interpolation reads)."""
        t = self.pose_t_ns
        lo = max(int(np.searchsorted(t, self.t_start_ns[first], side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t, self.t_end_ns[stop - 1], side="left")) + 1, t.size)
        run = tyre_paths(
            t[lo:hi],
            self.pose_xy[lo:hi],
            self.pose_yaw[lo:hi],
            self.t_start_ns[first:stop],
            self.t_end_ns[first:stop],
            self.track_m,
        )
        return TyrePaths(run.xy, run.event + first, run.wheel, run.first)


def match_points(
    t: IntArray,
    x: FloatArray,
    y: FloatArray,
    events_t_start: IntArray,
    source: EventPaths,
    radius_m: float,
    lookahead_ns: int,
) -> tuple[IntArray, IntArray, IntArray]:
    """Matches of a batch of points (``t`` ns, ``x``, ``y`` m, each (P,), in time order to
    within a scan): (point row, event row, wheel) (each (Q,)), a row per point within
    ``radius_m`` of the path a tyre traversed in an event that starts after the point's time,
    by at most ``lookahead_ns``.

    Two sieves, cheapest first: a coarse grid of the cells the open events' tyre paths
    pass within the radius of (:func:`~toolkit.tyre_paths.near_cells`; ~90 % of the cloud
    is off the tyre tracks), then every sample within the radius (KD-tree), asked as the
    :data:`NEIGHBOURS` nearest (a point with that many within the radius is asked again
    with no limit)."""
    empty = (np.zeros(0, np.int64),) * 3
    if t.size == 0:
        return empty
    t_lo, t_hi = int(t.min()), int(t.max())
    open_events = np.flatnonzero((events_t_start > t_lo) & (events_t_start <= t_hi + lookahead_ns))
    if open_events.size == 0:
        return empty
    # Events are in time order: the open ones are a run, and only their paths are sampled.
    paths = source.paths(int(open_events[0]), int(open_events[-1]) + 1)
    if paths.event.size == 0:
        return empty
    sample_xy, sample_event, sample_wheel = paths.xy, paths.event, paths.wheel
    # Sieve 1: grid cells of side r; a point within r of a sample lies in the sample's cell
    # or one of its 8 neighbours.
    candidate = near_cells(sample_xy, x, y, radius_m)
    if candidate.size == 0:
        return empty
    # Sieve 2: every sample within the radius (KD-tree), asked as the NEIGHBOURS nearest,
    # vectorised (~65 % of the candidates have one; asking them all at once is faster than
    # first asking each for its nearest, measured); the rare point whose last neighbour is
    # still inside (a slow stretch: samples 1-2 cm apart) is asked for all of them.
    tree = cKDTree(sample_xy)
    xy = np.c_[np.take(x, candidate), np.take(y, candidate)]
    dist, idx = tree.query(xy, k=NEIGHBOURS, distance_upper_bound=radius_m)
    near_rows = np.flatnonzero(np.isfinite(dist[:, 0]))
    if near_rows.size == 0:
        return empty
    near, xy, dist, idx = candidate[near_rows], xy[near_rows], dist[near_rows], idx[near_rows]
    inside = np.isfinite(dist)
    point = np.repeat(near, inside.sum(axis=1))
    samples = idx[inside]
    full = np.flatnonzero(inside[:, -1])
    if full.size:
        hits = tree.query_ball_point(xy[full], r=radius_m)
        lengths = np.array([len(h) for h in hits], dtype=np.int64)  # per saturated point
        extra = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits])
        keep = ~np.isin(point, near[full])
        point = np.concatenate([point[keep], np.repeat(near[full], lengths)])
        samples = np.concatenate([samples[keep], extra])
    # One row per (point, event, wheel), as one int64 key; only points seen before the
    # event, and not too long before.
    n_ev = np.int64(events_t_start.size)
    key = np.unique(
        (point.astype(np.int64) * n_ev + sample_event[samples]) * 2 + sample_wheel[samples]
    )
    wheel = key % 2
    event = (key // 2) % n_ev
    point = key // 2 // n_ev
    ahead = events_t_start[event] - t[point]
    ok = (ahead > 0) & (ahead <= lookahead_ns)
    return point[ok], event[ok], wheel[ok]


__all__ = ["NEIGHBOURS", "EventPaths", "PathSource", "match_points"]
