"""The world frame of a log: local ENU at a GPS fix that agrees with the fixes after it.

The contract's world frame is local ENU (x east, y north, z up) whose origin is the log's
first valid GPS fix *that agrees with the fixes after it*. A receiver that has just acquired
can report one wild first fix (hundreds of metres off); taking it as the origin would shift
the whole map by that error. A fix agrees when most of the next few valid fixes (within
:data:`AGREE_WINDOW_S`) lie where a vehicle could have driven from it::

    |p_j - p_i|_horizontal <= MAX_SPEED_MPS * (t_j - t_i) + AGREE_SLACK_M

Both the pose stage (which poses the log in this frame) and ingest (which writes the
simulator's truth in it, so the two tables compare row for row) choose the origin with
:func:`choose_enu_origin`, over the same GPS table, so they cannot disagree.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from toolkit.geometry.geodesy import GeodeticOrigin, geodetic_to_enu

#: The fastest a ground vehicle is believed to move (m/s; 216 km/h), for the agreement test.
MAX_SPEED_MPS = 60.0
#: Distance allowed beyond what the speed explains (m): consumer GPS noise is metres.
AGREE_SLACK_M = 25.0
#: How many following fixes are compared, and over how long at most (s).
AGREE_NEXT = 5
AGREE_WINDOW_S = 30.0

#: The ``frame_id`` written in the metadata of tables in this frame.
ENU_FRAME_ID = "enu_agreeing_fix"

#: Fixes that may define the origin: NavSatStatus STATUS_FIX (0) or better. A constant, not
#: the pose stage's ``gps_min_status``, so ingest (writing truth) needs no pose setting and
#: both stages always choose the same origin.
ORIGIN_MIN_STATUS = 0


def valid_fixes(gps: pa.Table, min_status: int) -> np.ndarray:
    """Boolean mask (n,) of the GPS rows that are fixes: status at least ``min_status`` and a
    finite latitude, longitude and altitude."""
    status = np.asarray(gps.column("status").to_numpy(zero_copy_only=False))
    ok = status >= min_status
    for name in ("latitude", "longitude", "altitude"):
        ok &= np.isfinite(np.asarray(gps.column(name).to_numpy(zero_copy_only=False), float))
    return np.asarray(ok, dtype=bool)


def choose_enu_origin(
    gps: pa.Table, min_status: int = ORIGIN_MIN_STATUS
) -> tuple[GeodeticOrigin, int] | None:
    """The origin fix and its row index in ``gps`` (time-sorted), or None without any fix.

    The first valid fix that most of its next :data:`AGREE_NEXT` fixes (within
    :data:`AGREE_WINDOW_S`) agree with; a fix with no later fix in the window agrees by
    default; if no fix agrees, the first valid one.
    """
    ok = valid_fixes(gps, min_status)
    rows = np.flatnonzero(ok)
    if rows.size == 0:
        return None
    t_s = np.asarray(gps.column("t_ns").to_numpy(), dtype=np.int64)[rows] * 1e-9
    lat = np.asarray(gps.column("latitude").to_numpy(zero_copy_only=False), float)[rows]
    lon = np.asarray(gps.column("longitude").to_numpy(zero_copy_only=False), float)[rows]
    alt = np.asarray(gps.column("altitude").to_numpy(zero_copy_only=False), float)[rows]
    # Horizontal positions in a frame at the first fix: good to metres over kilometres,
    # which is all the agreement test needs.
    enu = geodetic_to_enu(lat, lon, alt, GeodeticOrigin(lat[0], lon[0], alt[0]))
    xy = np.asarray(enu)[:, :2]
    chosen = 0
    for i in range(rows.size):
        later = np.arange(i + 1, min(i + 1 + AGREE_NEXT, rows.size))
        later = later[t_s[later] - t_s[i] <= AGREE_WINDOW_S]
        if later.size == 0:
            chosen = i
            break
        reach = MAX_SPEED_MPS * (t_s[later] - t_s[i]) + AGREE_SLACK_M
        agree = np.hypot(*(xy[later] - xy[i]).T) <= reach
        if int(agree.sum()) * 2 > later.size:
            chosen = i
            break
    k = int(rows[chosen])
    return GeodeticOrigin(float(lat[chosen]), float(lon[chosen]), float(alt[chosen])), k


__all__ = [
    "AGREE_NEXT",
    "AGREE_SLACK_M",
    "AGREE_WINDOW_S",
    "ENU_FRAME_ID",
    "MAX_SPEED_MPS",
    "ORIGIN_MIN_STATUS",
    "choose_enu_origin",
    "valid_fixes",
]
