"""The world frame's origin: the first GPS fix that agrees with the fixes after it."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from toolkit.geometry.frames import choose_enu_origin
from toolkit.geometry.geodesy import GeodeticOrigin, enu_to_geodetic

ORIGIN = GeodeticOrigin(35.6, -115.4, 800.0)


def _gps(east_m: list[float], status: list[int] | None = None, rate_hz: float = 10.0) -> pa.Table:
    """Fixes along a straight road east at 10 m/s, with the given east offsets (m)."""
    n = len(east_m)
    t = np.arange(n) / rate_hz
    enu = np.stack([np.asarray(east_m) + 10.0 * t, np.zeros(n), np.zeros(n)], axis=1)
    lat, lon, alt = enu_to_geodetic(enu, ORIGIN)
    return pa.table(
        {
            "t_ns": (1_000_000_000 + t * 1e9).astype(np.int64),
            "latitude": lat,
            "longitude": lon,
            "altitude": alt,
            "status": pa.array(status or [0] * n, pa.int8()),
        }
    )


def test_origin_is_the_first_fix_when_it_agrees() -> None:
    chosen = choose_enu_origin(_gps([0.0] * 20))
    assert chosen is not None and chosen[1] == 0
    assert abs(chosen[0].latitude_deg - ORIGIN.latitude_deg) < 1e-9


def test_one_wild_first_fix_does_not_move_the_map() -> None:
    chosen = choose_enu_origin(_gps([800.0] + [0.0] * 19))  # 800 m off, 0.1 s before the next
    assert chosen is not None and chosen[1] == 1


def test_a_wild_later_fix_does_not_disqualify_a_good_origin() -> None:
    chosen = choose_enu_origin(_gps([0.0, 0.0, 900.0, 0.0, 0.0, 0.0, 0.0]))
    assert chosen is not None and chosen[1] == 0


def test_no_fix_rows_and_bad_status_are_skipped() -> None:
    gps = _gps([0.0] * 10, status=[-1, -1, 0, 0, 0, 0, 0, 0, 0, 0])
    chosen = choose_enu_origin(gps)
    assert chosen is not None and chosen[1] == 2
    assert choose_enu_origin(_gps([0.0] * 3, status=[-1, -1, -1])) is None


def test_a_lone_fix_is_its_own_origin() -> None:
    chosen = choose_enu_origin(_gps([0.0]))
    assert chosen is not None and chosen[1] == 0
