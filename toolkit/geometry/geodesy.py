"""WGS-84 geodetic <-> ECEF <-> a local east-north-up tangent plane, vectorised, exactly.

The tangent plane at a point is the exact local frame there (what the origin choice measures
fixes in, over a few kilometres); the world frame every table is written in is the map of
:mod:`toolkit.geometry.map_frame`, level everywhere. Conversions go through Earth-centred,
Earth-fixed (ECEF) coordinates, exactly, so a round trip loses nothing but float rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from toolkit.arrays import FloatArray

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


@dataclass(frozen=True)
class GeodeticOrigin:
    """The ENU origin: latitude and longitude in degrees, altitude in metres (ellipsoidal)."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike) -> FloatArray:
    """Geodetic (degrees, metres) to ECEF, shape (..., 3) in metres."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    alt = np.asarray(alt_m, dtype=np.float64)
    sin_lat = np.sin(lat)
    prime_vertical_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    x = (prime_vertical_m + alt) * np.cos(lat) * np.cos(lon)
    y = (prime_vertical_m + alt) * np.cos(lat) * np.sin(lon)
    z = (prime_vertical_m * (1.0 - WGS84_E2) + alt) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(ecef_m: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF (..., 3) metres to (latitude_deg, longitude_deg, altitude_m).

    With ``rho`` the distance from the polar axis and ``N(lat)`` the prime-vertical radius,
    the geodetic latitude is the fixed point of ``lat = atan2(z + e^2 N(lat) sin(lat), rho)``,
    started from its value on the ellipsoid; each iteration shrinks the error by about
    ``e^2`` (1/150), so four reach float64 round-off anywhere near the Earth's surface.
    The altitude is the distance along the normal from the ellipsoid point at ``lat``::

        h = rho cos(lat) + (z + e^2 N sin(lat)) sin(lat) - N

    which, unlike ``rho / cos(lat) - N``, stays exact at and near the poles.
    """
    p = np.asarray(ecef_m, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    lon = np.arctan2(y, x)
    rho = np.hypot(x, y)
    lat = np.arctan2(z, rho * (1.0 - WGS84_E2))
    for _ in range(4):
        sin_lat = np.sin(lat)
        prime_vertical_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
        lat = np.arctan2(z + WGS84_E2 * prime_vertical_m * sin_lat, rho)
    sin_lat = np.sin(lat)
    prime_vertical_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    alt = (
        rho * np.cos(lat) + (z + WGS84_E2 * prime_vertical_m * sin_lat) * sin_lat - prime_vertical_m
    )
    return np.degrees(lat), np.degrees(lon), alt


def _enu_from_ecef_rotation(origin: GeodeticOrigin) -> FloatArray:
    lat = np.radians(origin.latitude_deg)
    lon = np.radians(origin.longitude_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    return np.array(
        [
            [-so, co, 0.0],
            [-sl * co, -sl * so, cl],
            [cl * co, cl * so, sl],
        ]
    )


def geodetic_to_enu(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: GeodeticOrigin
) -> FloatArray:
    """Geodetic points to local ENU metres, shape (..., 3)."""
    ecef = geodetic_to_ecef(lat_deg, lon_deg, alt_m)
    origin_ecef = geodetic_to_ecef(origin.latitude_deg, origin.longitude_deg, origin.altitude_m)
    return (ecef - origin_ecef) @ _enu_from_ecef_rotation(origin).T


def enu_to_geodetic(
    enu_m: ArrayLike, origin: GeodeticOrigin
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Local ENU metres (..., 3) to (latitude_deg, longitude_deg, altitude_m)."""
    enu = np.asarray(enu_m, dtype=np.float64)
    origin_ecef = geodetic_to_ecef(origin.latitude_deg, origin.longitude_deg, origin.altitude_m)
    ecef = enu @ _enu_from_ecef_rotation(origin) + origin_ecef
    return ecef_to_geodetic(ecef)
