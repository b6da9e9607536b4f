"""WGS-84 <-> ECEF <-> local ENU: published constants, round trips, and 1 km steps whose ENU
coordinates follow from the ellipsoid's radii of curvature."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.geometry.geodesy import (
    WGS84_A_M,
    WGS84_E2,
    WGS84_F,
    GeodeticOrigin,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)

#: WGS-84 semi-minor axis (NIMA TR8350.2, table 3.3), m: the pole's distance from the centre.
WGS84_B_M = 6356752.3142
#: The sample log's ENU origin (the Mojave desert).
ORIGIN = GeodeticOrigin(latitude_deg=35.61, longitude_deg=-115.39, altitude_m=800.0)


def test_ecef_of_known_points() -> None:
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A_M, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 90.0, 0.0), [0.0, WGS84_A_M, 0.0], atol=1e-9)
    np.testing.assert_allclose(
        geodetic_to_ecef(0.0, 180.0, 100.0), [-WGS84_A_M - 100.0, 0.0, 0.0], atol=1e-9
    )
    np.testing.assert_allclose(geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, WGS84_B_M], atol=1e-4)
    np.testing.assert_allclose(
        geodetic_to_ecef(-90.0, 0.0, 50.0), [0.0, 0.0, -WGS84_B_M - 50.0], atol=1e-4
    )


def test_origin_maps_to_zero_and_back() -> None:
    o = ORIGIN
    enu = geodetic_to_enu(o.latitude_deg, o.longitude_deg, o.altitude_m, o)
    np.testing.assert_allclose(enu, np.zeros(3), atol=1e-9)
    lat, lon, alt = enu_to_geodetic(np.zeros(3), o)
    assert float(lat) == pytest.approx(o.latitude_deg, abs=1e-12)
    assert float(lon) == pytest.approx(o.longitude_deg, abs=1e-12)
    assert float(alt) == pytest.approx(o.altitude_m, abs=1e-6)


def test_enu_round_trip_is_sub_millimetre() -> None:
    """ENU -> WGS-84 -> ENU, up to 50 km out and 3 km up or down; and the other way round."""
    rng = np.random.default_rng(0)
    enu = np.column_stack(
        [rng.uniform(-5e4, 5e4, 1000), rng.uniform(-5e4, 5e4, 1000), rng.uniform(-3e3, 3e3, 1000)]
    )
    lat, lon, alt = enu_to_geodetic(enu, ORIGIN)
    back = geodetic_to_enu(lat, lon, alt, ORIGIN)
    assert np.abs(back - enu).max() < 1e-4

    ecef = geodetic_to_ecef(lat, lon, alt)
    lat2, lon2, alt2 = ecef_to_geodetic(ecef)
    assert np.abs(geodetic_to_ecef(lat2, lon2, alt2) - ecef).max() < 1e-4
    assert np.abs(alt2 - alt).max() < 1e-4


@pytest.mark.parametrize("lat_deg", [-90.0, -89.9999999, -45.0, 0.0, 60.0, 89.9999999, 90.0])
def test_geodetic_round_trip_at_any_latitude(lat_deg: float) -> None:
    """Through ECEF and back, the poles included (where rho / cos(lat) would divide by 0)."""
    lat, lon, alt = ecef_to_geodetic(geodetic_to_ecef(lat_deg, 30.0, 1234.5))
    assert float(lat) == pytest.approx(lat_deg, abs=1e-11)  # 1e-11 deg ~ 1 micrometre
    assert float(alt) == pytest.approx(1234.5, abs=1e-6)
    if abs(lat_deg) < 90.0:
        assert float(lon) == pytest.approx(30.0, abs=1e-9)


@pytest.mark.parametrize("rho_m", [0.0, 1e-3, 1.0])
def test_points_on_and_next_to_the_polar_axis(rho_m: float) -> None:
    """100 m above the north pole and up to 1 m off the axis, where latitude is within
    ~1e-10 rad of 90 degrees and rho / cos(lat) would lose metres (or divide 0 by ~0)."""
    pole_m = WGS84_A_M * (1.0 - WGS84_F)  # the semi-minor axis b, exactly
    lat, _, alt = ecef_to_geodetic(np.array([rho_m, 0.0, pole_m + 100.0]))
    assert float(lat) == pytest.approx(90.0, abs=1e-5)
    assert float(alt) == pytest.approx(100.0, abs=1e-6)  # the 1 m offset lowers it ~1e-7 m


def test_one_kilometre_east_lies_on_the_parallel_circle() -> None:
    """1 km of arc east along the origin's parallel, a circle of radius r = (N + h) cos(lat).

    The point turns by dlon = 1000 / r about the polar axis, so in ENU it is r sin(dlon) east
    and has dropped d = r (1 - cos(dlon)) towards the axis: d sin(lat) north, d cos(lat) down.
    """
    o = ORIGIN
    lat = np.radians(o.latitude_deg)
    prime_vertical_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    r = (prime_vertical_m + o.altitude_m) * np.cos(lat)
    dlon = 1000.0 / r
    d = r * (1.0 - np.cos(dlon))
    enu = geodetic_to_enu(o.latitude_deg, o.longitude_deg + np.degrees(dlon), o.altitude_m, o)
    np.testing.assert_allclose(
        enu, [r * np.sin(dlon), d * np.sin(lat), -d * np.cos(lat)], rtol=0, atol=1e-6
    )
    assert np.hypot(enu[0], enu[1]) == pytest.approx(1000.0, abs=1e-3)


def test_one_kilometre_north_follows_the_meridian() -> None:
    """1000 / (M + h) radians north along the meridian (M its radius of curvature).

    M = a (1 - e^2) / (1 - e^2 sin^2 lat)^(3/2) grows northwards at M' = dM/dlat, so with
    R = M + h and dlat = 1000 / R the point lies (to ~1e-7 m)

        north = R sin(dlat) + M' dlat^2 / 2        (~1000.0008 m: M' adds 0.75 mm)
        up    = -R (1 - cos(dlat))                 (~7.9 cm below the tangent plane)
    """
    o = ORIGIN
    lat = np.radians(o.latitude_deg)
    w2 = 1.0 - WGS84_E2 * np.sin(lat) ** 2
    meridian_m = WGS84_A_M * (1.0 - WGS84_E2) / w2**1.5
    meridian_slope_m = 3.0 * meridian_m * WGS84_E2 * np.sin(lat) * np.cos(lat) / w2
    radius = meridian_m + o.altitude_m
    dlat = 1000.0 / radius
    enu = geodetic_to_enu(o.latitude_deg + np.degrees(dlat), o.longitude_deg, o.altitude_m, o)
    north = radius * np.sin(dlat) + meridian_slope_m * dlat**2 / 2.0
    np.testing.assert_allclose(enu, [0.0, north, -radius * (1.0 - np.cos(dlat))], rtol=0, atol=1e-5)
    assert np.linalg.norm(enu) == pytest.approx(1000.0, abs=1e-3)
