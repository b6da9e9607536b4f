"""The world frame of every table: a local-level map of the Earth around an origin.

A log's world frame was the tangent plane at its origin. D metres away that plane is tilted
from the local vertical by D / R (0.27 deg at 30 km, 0.9 deg at 100 km) and lies D^2 / 2R
above the ground (70 m at 30 km), while the pose filter takes gravity along the frame's -z
everywhere: far from the origin the vehicle's attitude, and so every point's height at
range, came out wrong by the tilt (8 cm at 25 m, 30 km out).

The world frame is now a map whose "up" is the local vertical everywhere:

- ``x, y`` (east, north): the transverse Mercator projection of the WGS-84 ellipsoid about
  the origin's meridian, scale 1 on it, zero at the origin (PROJ's ``tmerc``, its exact
  Poder/Engsager algorithm, through pyproj);
- ``z`` (up): the ellipsoidal height above the origin's.

Locally, at any point, these axes are a level east-north-up frame (the projection is
conformal: angles are kept, and the ellipsoid's normal is ``z``), so gravity is along -z
wherever the vehicle drives and the filter's model holds. What the map changes, and who
accounts for it:

- lengths on it are those on the ground times the scale factor ``k ~ 1 + x^2 / 2R^2``
  (1.2e-4 at 100 km east or west of the origin's meridian: 4 mm over a 30 m laser range;
  1.1e-3 at 300 km), which the filter's wheel scale absorbs;
- its north (grid north) is turned from true north by the meridian convergence
  (``~ dlon sin(lat)``: 0.6 deg 100 km east of the origin at 35 deg N), so a compass's true
  heading is turned into the map's by :func:`grid_minus_true_yaw_rad` before it reaches the
  filter, and the simulator turns its map heading into a true one the same way.

Heights are the ellipsoid's, not the geoid's: the geoid's slope (the deflection of the
vertical, ~10 arc-seconds, 1 mm over 25 m) is below what any stage resolves.
"""

from __future__ import annotations

import threading
from functools import lru_cache

import numpy as np
import pyproj
from numpy.typing import ArrayLike

from toolkit.arrays import FloatArray
from toolkit.geometry.geodesy import GeodeticOrigin

#: Latitude step of the finite difference that finds true north on the map, deg (0.11 m:
#: the map's meridian bends by nanoradians over it).
_NORTH_STEP_DEG = 1e-6
_GEODETIC = "+proj=longlat +ellps=WGS84 +no_defs"


def _tmerc(origin: GeodeticOrigin) -> str:
    return (
        f"+proj=tmerc +lat_0={origin.latitude_deg!r} +lon_0={origin.longitude_deg!r} +k_0=1 "
        "+x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
    )


@lru_cache(maxsize=64)
def _transformer(origin: GeodeticOrigin, forward: bool, _thread: int) -> pyproj.Transformer:
    """A transformer between geodetic coordinates and the map of ``origin``; one per thread
    (pyproj's transformers are not to be shared between threads)."""
    src, dst = (_GEODETIC, _tmerc(origin)) if forward else (_tmerc(origin), _GEODETIC)
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def _project(
    origin: GeodeticOrigin, forward: bool, a: FloatArray, b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    t = _transformer(origin, forward, threading.get_ident())
    x, y = t.transform(a, b, errcheck=True)
    return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)


def geodetic_to_world(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: GeodeticOrigin
) -> FloatArray:
    """Geodetic points (degrees, metres) to the world frame of ``origin``, shape (..., 3):
    map east and north, and height above the origin's (module docstring)."""
    lat, lon, alt = np.broadcast_arrays(
        np.asarray(lat_deg, np.float64),
        np.asarray(lon_deg, np.float64),
        np.asarray(alt_m, np.float64),
    )
    x, y = _project(origin, True, lon.ravel(), lat.ravel())
    up = alt - origin.altitude_m
    return np.stack([x.reshape(lat.shape), y.reshape(lat.shape), up], axis=-1)


def world_to_geodetic(
    world_m: ArrayLike, origin: GeodeticOrigin
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World-frame points (..., 3) of ``origin`` to (latitude_deg, longitude_deg, altitude_m)."""
    p = np.asarray(world_m, dtype=np.float64)
    lon, lat = _project(origin, False, p[..., 0].ravel(), p[..., 1].ravel())
    return lat.reshape(p.shape[:-1]), lon.reshape(p.shape[:-1]), p[..., 2] + origin.altitude_m


def grid_minus_true_yaw_rad(
    lat_deg: ArrayLike, lon_deg: ArrayLike, origin: GeodeticOrigin
) -> FloatArray:
    """The map's yaw minus the true (local east-north-up) yaw of one direction at each
    point, rad: ``yaw_world = yaw_true + this`` (both counter-clockwise from east).

    True north's direction on the map, from two points a :data:`_NORTH_STEP_DEG` apart on
    the meridian (the step taken southward at the north pole's side): its angle from the
    map's east, minus the pi/2 it has in a true east-north-up frame. Zero on the origin's
    meridian; the meridian convergence elsewhere."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.broadcast_to(np.asarray(lon_deg, dtype=np.float64), lat.shape)
    step = np.where(lat + _NORTH_STEP_DEG <= 90.0, _NORTH_STEP_DEG, -_NORTH_STEP_DEG)
    x0, y0 = _project(origin, True, lon.ravel(), lat.ravel())
    x1, y1 = _project(origin, True, lon.ravel(), (lat + step).ravel())
    sign = np.sign(step).ravel()
    angle = np.arctan2(sign * (y1 - y0), sign * (x1 - x0)) - np.pi / 2.0
    return np.asarray((angle + np.pi) % (2.0 * np.pi) - np.pi).reshape(lat.shape)


def move_between_frames(
    xyz_m: ArrayLike, yaw_rad: ArrayLike | None, src: GeodeticOrigin, dst: GeodeticOrigin
) -> tuple[FloatArray, FloatArray | None]:
    """Positions (n, 3) and yaws (n,) in the world frame of ``src`` as they are in that of
    ``dst``. Both frames are level at every point (module docstring), so only the yaw moves:
    by the difference of the two maps' convergences there. Roll and pitch are the same in
    both."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    if src == dst:
        return xyz, None if yaw_rad is None else np.asarray(yaw_rad, dtype=np.float64)
    lat, lon, alt = world_to_geodetic(xyz, src)
    moved = geodetic_to_world(lat, lon, alt, dst)
    if yaw_rad is None:
        return moved, None
    turn = grid_minus_true_yaw_rad(lat, lon, dst) - grid_minus_true_yaw_rad(lat, lon, src)
    return moved, np.asarray(yaw_rad, dtype=np.float64) + turn


__all__ = [
    "geodetic_to_world",
    "grid_minus_true_yaw_rad",
    "move_between_frames",
    "world_to_geodetic",
]
