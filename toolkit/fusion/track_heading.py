"""The heading without a compass: from the direction of the GPS track.

The filter starts once a run of fixes lies on a straight line long enough for its direction
(:func:`start_heading`), whatever the speed; afterwards the direction of the latest straight
stretch of the track (:func:`track_headings`), carried from the stretch's mean time to now by
the turn the filter made since (:class:`YawHistory`), is a yaw measurement at every fix
(``gps_track``, variance ``2 sigma_h^2 / L^2 +`` :data:`TRACK_YAW_FLOOR_RAD` ``^2``).
"""

from __future__ import annotations

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.fusion.estimator_io import SensorData
from toolkit.geometry.rotations import wrap_angle

#: Longest time a run of fixes may span to give the GPS-track heading, s.
TRACK_MAX_SPAN_S = 30.0
#: Largest RMS distance of a run of fixes from their line, in fix sigmas, for a track heading.
TRACK_STRAIGHT_SIGMAS = 1.5
#: 1 sigma added to a GPS-track yaw: the direction of travel is not exactly the heading (the
#: slight crabbing of a skid-steer robot, what is left of a turn in a "straight" run), rad.
TRACK_YAW_FLOOR_RAD = 0.05


def track_end(d: SensorData, i: int, track_min_distance_m: float) -> int | None:
    """The first fix ``j > i`` at least ``D = max(track_min_distance_m, 10 sigma_h)`` from
    fix ``i`` and at most :data:`TRACK_MAX_SPAN_S` later, or None. (Only that window is
    searched, so a vehicle parked for an hour costs time linear in the fixes.)"""
    sigma_h = float(np.sqrt(0.5 * (d.gps_var[i, 0] + d.gps_var[i, 1])))
    reach = max(track_min_distance_m, 10.0 * sigma_h)
    hi = int(np.searchsorted(d.gps_t, d.gps_t[i] + TRACK_MAX_SPAN_S, side="right"))
    dist = np.hypot(*(d.gps_enu[i + 1 : hi, :2] - d.gps_enu[i, :2]).T)
    far = np.flatnonzero(dist >= reach)
    return i + 1 + int(far[0]) if far.size else None


def track_line(d: SensorData, i: int, j: int) -> tuple[float | None, float]:
    """Direction (rad, ENU yaw) of fixes ``i..j`` if they lie on a straight line, and its
    variance ``2 sigma_h^2 / L^2`` (``L`` their span); (None, inf) if they do not.

    The line is the principal axis of the fixes' scatter, pointed from ``p_i`` to ``p_j``;
    they lie on it when the RMS of their distances to it is at most
    :data:`TRACK_STRAIGHT_SIGMAS` ``sigma_h`` (a turn bends them off it, and a chord across a
    turn gives the heading of no point of it).
    """
    pts = d.gps_enu[i : j + 1, :2]
    sigma_h = float(np.sqrt(0.5 * (d.gps_var[i : j + 1, 0] + d.gps_var[i : j + 1, 1])).mean())
    centred = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    chord = pts[-1] - pts[0]
    axis = vt[0] if vt[0] @ chord > 0 else -vt[0]
    normal = np.array([-axis[1], axis[0]])
    if float(np.sqrt(np.mean((centred @ normal) ** 2))) > TRACK_STRAIGHT_SIGMAS * sigma_h:
        return None, np.inf
    span = float(np.hypot(chord[0], chord[1]))
    return float(np.arctan2(axis[1], axis[0])), 2.0 * sigma_h**2 / span**2


def track_headings(
    d: SensorData, track_min_distance_m: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per fix ``k``, the GPS track's direction over the latest straight run of fixes ending
    at ``k`` (:func:`track_line` of ``i..k``, ``i`` the last fix at least ``D`` back), its
    variance and the run's mean time (s); NaN where there is none. Causal: only fixes up to
    ``k``.

    The principal axis of a run is the direction of travel near the run's centroid, that is
    at its mean time, not at fix ``k``: on a gentle curve (which still passes the
    straightness test) the two differ by the turn made since. The filter therefore compares
    the track with its own yaw at the mean time (see :class:`YawHistory`).
    """
    n = d.gps_t.size
    yaw = np.full(n, np.nan)
    var = np.full(n, np.nan)
    t_mid = np.full(n, np.nan)
    xy = d.gps_enu[:, :2]
    for k in range(1, n):
        sigma_h = float(np.sqrt(0.5 * (d.gps_var[k, 0] + d.gps_var[k, 1])))
        reach = max(track_min_distance_m, 10.0 * sigma_h)
        lo = int(np.searchsorted(d.gps_t, d.gps_t[k] - TRACK_MAX_SPAN_S))
        back = np.flatnonzero(np.hypot(*(xy[lo:k] - xy[k]).T) >= reach)
        if back.size == 0:
            continue
        i = lo + int(back[-1])
        y, v = track_line(d, i, k)
        if y is not None:
            yaw[k], var[k], t_mid[k] = y, v, float(d.gps_t[i : k + 1].mean())
    return yaw, var, t_mid


class YawHistory:
    """The filter's posterior yaw at recent epochs (unwrapped), to carry a measurement of
    the yaw at an earlier time to now: ``z_now = z_then + (yaw_now - yaw_then)``, the turn
    made since as the filter itself integrated it (gyro and corrections). Holds at most
    :data:`TRACK_MAX_SPAN_S` of history, so memory is bounded."""

    def __init__(self) -> None:
        self._t: list[float] = []
        self._yaw: list[float] = []

    def add(self, t: float, yaw: float) -> None:
        if self._yaw:
            yaw = self._yaw[-1] + float(wrap_angle(np.array(yaw - self._yaw[-1])))
        self._t.append(t)
        self._yaw.append(yaw)
        if len(self._t) > 64 and self._t[0] < t - TRACK_MAX_SPAN_S - 1.0:
            cut = int(np.searchsorted(self._t, t - TRACK_MAX_SPAN_S - 1.0))
            del self._t[:cut], self._yaw[:cut]

    def turn_since(self, t_then: float, yaw_now: float) -> float | None:
        """``yaw_now - yaw(t_then)`` wrapped to [-pi, pi), or None before the history."""
        if not self._t or t_then < self._t[0]:
            return None
        then = float(np.interp(t_then, self._t, self._yaw))
        return float(wrap_angle(np.array(yaw_now - then)))


def start_heading(d: SensorData, track_min_distance_m: float) -> tuple[float, float, str]:
    """Start time, initial yaw and where the heading comes from.

    With a compass: its first reading at or after the first fix. Without: the GPS track,
    from the first run of fixes ``i..j`` that spans a straight line long enough for its
    direction to be good to a few degrees at any speed (a robot at 1 m/s included):

    - ``|p_j - p_i| >= D = max(track_min_distance_m, 10 sigma_h)`` (``sigma_h`` the fixes'
      horizontal 1 sigma), within :data:`TRACK_MAX_SPAN_S`;
    - the fixes fit a line: the RMS of their distances to the least-squares line through
      them (principal axis of their scatter) is at most :data:`TRACK_STRAIGHT_SIGMAS`
      ``sigma_h`` (a turn bends them off it; a chord across a turn would give the heading
      of no point of it).

    The heading is the line's direction, pointing from ``p_i`` to ``p_j``; the filter starts
    at ``t_j``. Its error, about ``sqrt(2) sigma_h / D`` rad, is within the initial yaw
    uncertainty (0.3 rad) and the GPS refines it as the vehicle moves.
    """
    if d.gps_t.size == 0:
        # No GPS: a local frame whose origin and yaw 0 are the first pose, once the wheels
        # (the only speed reference left) have started.
        t0 = float(d.wheel_t[0]) if d.wheel_t.size else 0.0
        return t0, 0.0, "local"
    t_fix = float(d.gps_t[0])
    if d.head_t.size:
        i = int(np.searchsorted(d.head_t, t_fix))
        if i < d.head_t.size:
            return max(t_fix, float(d.head_t[i])), float(d.head_yaw[i]), "compass"
    for i in range(d.gps_t.size):
        j = track_end(d, i, track_min_distance_m)
        if j is None:
            continue
        yaw, _ = track_line(d, i, j)
        if yaw is not None:
            return float(d.gps_t[j]), yaw, "gps_track"
    return t_fix, 0.0, "none"


__all__ = [
    "TRACK_MAX_SPAN_S",
    "TRACK_STRAIGHT_SIGMAS",
    "TRACK_YAW_FLOOR_RAD",
    "YawHistory",
    "start_heading",
    "track_end",
    "track_headings",
    "track_line",
]
