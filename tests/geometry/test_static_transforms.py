"""The one rule for a usable static transform: finite, a rotation of non-zero norm,
normalised; one transform per child frame, repeats merged, a conflict said and counted."""

from __future__ import annotations

import math

import pytest

from toolkit.geometry.static_transforms import (
    DROP_REASONS,
    TransformRecord,
    select_static_transforms,
    transform_problem,
    usable_transform,
)

NAN, INF = math.nan, math.inf


def tf(
    child: str,
    xyz: tuple[float, ...] = (1.0, 0.0, 0.5),
    q: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0),
    parent: str = "base_link",
) -> TransformRecord:
    return TransformRecord(parent, child, 7, xyz, q)


@pytest.mark.parametrize(
    ("xyz", "q", "reason"),
    [
        ((NAN, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), "non_finite_translation"),
        ((0.0, INF, 0.0), (0.0, 0.0, 0.0, 1.0), "non_finite_translation"),
        ((0.0, 0.0, 0.0), (0.0, NAN, 0.0, 1.0), "non_finite_rotation"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, -INF, 1.0), "non_finite_rotation"),
        ((0.0, 0.0, 0.0), (1.5e308, 1.5e308, 0.0, 0.0), "non_finite_rotation"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), "zero_rotation"),
        ((0.0, 0.0, 0.0), (1e-12, 0.0, 0.0, 0.0), "zero_rotation"),
        ((0.0, 0.0), (0.0, 0.0, 0.0, 1.0), "non_finite_translation"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), "non_finite_rotation"),
    ],
)
def test_unusable_transforms_are_named_by_reason(
    xyz: tuple[float, ...], q: tuple[float, ...], reason: str
) -> None:
    assert reason in DROP_REASONS
    assert transform_problem(xyz, q) == reason
    assert usable_transform(tf("imu_link", xyz, q)) == reason


def test_a_usable_transform_is_kept_normalised() -> None:
    kept = usable_transform(tf("imu_link", q=(0.0, 0.0, 2.0, 2.0)))
    assert isinstance(kept, TransformRecord)
    assert kept.rotation_xyzw == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert kept.translation_m == (1.0, 0.0, 0.5)


def test_unusable_ones_are_dropped_counted_and_said() -> None:
    got = select_static_transforms(
        [
            tf("imu_link", xyz=(NAN, 0.0, 0.0)),
            tf("gps_link", q=(0.0, 0.0, 0.0, 0.0)),
            tf("laser", q=(INF, 0.0, 0.0, 1.0)),
            tf("lidar"),
        ],
        "/tf_static",
    )
    assert [t.child for t in got.transforms] == ["lidar"]
    assert got.to_json() == {
        "read": 4,
        "written": 1,
        "repeats": 0,
        "dropped": {
            "non_finite_translation": 1,
            "non_finite_rotation": 1,
            "zero_rotation": 1,
            "conflicting": 0,
        },
    }
    (line,) = got.warnings
    assert line.startswith("/tf_static: 3 unusable static transform(s) dropped: ")
    assert "'base_link' -> 'imu_link' (NaN or inf in its translation)" in line
    assert "'base_link' -> 'gps_link' (a rotation quaternion of zero norm)" in line
    assert "'laser'" in line


def test_identical_repeats_are_merged_silently() -> None:
    """The same transform again, with a quaternion scaled, negated or off by far under the
    tolerance, is one transform: nothing said."""
    got = select_static_transforms(
        [
            tf("imu_link"),
            tf("imu_link", q=(0.0, 0.0, 0.0, -3.0)),
            tf("imu_link", xyz=(1.0 + 1e-12, 0.0, 0.5)),
        ],
        "/tf_static",
    )
    assert len(got.transforms) == 1 and got.repeats == 2
    assert got.warnings == () and got.dropped == {}


@pytest.mark.parametrize(
    "later",
    [
        tf("imu_link", xyz=(1.0, 0.0, 0.6)),
        tf("imu_link", q=(0.0, 0.0, 1.0, 0.0)),
        tf("imu_link", parent="chassis"),
    ],
)
def test_a_conflicting_transform_replaces_the_earlier_and_is_said(later: TransformRecord) -> None:
    """A child frame has one transform: the last kept (as tf2 does), the line naming the
    frame and both transforms, the replaced one counted."""
    got = select_static_transforms([tf("imu_link"), tf("gps_link"), later], "/tf_static")
    assert [t.child for t in got.transforms] == ["imu_link", "gps_link"]
    assert got.transforms[0] == later
    assert got.dropped == {"conflicting": 1} and got.to_json()["written"] == 2
    (line,) = got.warnings
    assert "child frame 'imu_link' has conflicting static transforms" in line
    assert tf("imu_link").describe() in line and later.describe() in line
    assert "last one is kept" in line


def test_many_unusable_transforms_are_one_line() -> None:
    got = select_static_transforms(
        [tf(f"f{k}", xyz=(NAN, 0.0, 0.0)) for k in range(9)], "/tf_static"
    )
    (line,) = got.warnings
    assert "9 unusable" in line and "and 4 more" in line and got.transforms == ()
