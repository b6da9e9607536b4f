"""Which points lie near the rear tyres' paths: the near_path cloud keeps all the tables use."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from toolkit.config import default_config
from toolkit.tyre_paths import (
    META_CUT_AROUND,
    META_KEPT_WITHIN_M,
    PATH_STEP_M,
    NearPath,
    PathsDrawnFrom,
    cut_differences,
    cut_metadata,
)


@pytest.mark.parametrize("spin_rad_per_row", [0.0, 0.3, 1.2], ids=["straight", "turn", "spin"])
def test_every_point_near_a_tyre_is_kept_also_where_the_robot_spins(
    spin_rad_per_row: float,
) -> None:
    """A pose at 2 Hz creeping 5 cm a row while turning up to 1.2 rad a row (a skid-steer
    robot on the spot): every point within the radius of the tyres' exact positions at any
    time between rows is kept with the tables' allowance (radius + PATH_STEP_M); points
    far from both tyres are not."""
    rows, track, radius = 40, 1.0, 0.3
    t = np.arange(rows, dtype=np.int64) * 500_000_000
    yaw = np.arange(rows) * spin_rad_per_row
    xy = np.c_[np.arange(rows) * 0.05, np.zeros(rows)]
    near = NearPath(t, xy, yaw, track, radius + PATH_STEP_M)
    # The tyres' positions every 1/1000 of a row, as the tables would place them at events'
    # ends anywhere between rows (position and yaw linear in time).
    f = np.linspace(0, rows - 1, (rows - 1) * 1000 + 1)
    cx, cy, a = (
        np.interp(f, np.arange(rows), xy[:, 0]),
        np.interp(f, np.arange(rows), xy[:, 1]),
        np.interp(f, np.arange(rows), yaw),
    )
    half = track / 2
    tyres = np.r_[
        np.c_[cx - np.sin(a) * half, cy + np.cos(a) * half],
        np.c_[cx + np.sin(a) * half, cy - np.cos(a) * half],
    ]
    rng = np.random.default_rng(1)
    pts = tyres[rng.integers(0, len(tyres), 20_000)] + rng.uniform(-0.45, 0.45, (20_000, 2))
    dist, _ = cKDTree(tyres).query(pts)
    kept = near.mask(pts[:, 0], pts[:, 1])
    assert kept[dist < radius].all()
    assert not kept[dist > radius + PATH_STEP_M + 0.01].any()


POSE_SHA = "a" * 64


def _drawn_from(track_m: float = 1.65, pose_sha: str = POSE_SHA) -> PathsDrawnFrom:
    cfg = default_config()
    vehicle = dataclasses.replace(cfg.vehicle, track_m=track_m)
    return PathsDrawnFrom.of(dataclasses.replace(cfg, vehicle=vehicle), {"pose": pose_sha})


def test_a_cut_serves_only_the_paths_it_was_cut_around_out_to_its_distance() -> None:
    """A cloud cut around paths is read back as cut around them (its metadata's text read
    back equal), fits them out to its distance less the paths' sampling, and says in words
    what differs from other paths: each setting and input that moved, a narrower cut."""
    cut = _drawn_from()
    meta = cut_metadata(0.5, cut)
    assert PathsDrawnFrom.from_text(meta[META_CUT_AROUND]) == cut
    assert cut_differences(meta, cut, 0.3) == []
    assert cut_differences(meta, cut, 0.5 - PATH_STEP_M) == []
    assert cut_differences({}, _drawn_from(2.65), 0.3) == []  # every point kept
    assert cut_differences(meta, _drawn_from(2.65, "b" * 64), 0.3) == [
        "vehicle.track_m = 1.65 when cut, 2.65 now",
        "pose sha256 aaaaaaaaaaaa when cut, bbbbbbbbbbbb now",
    ]
    (narrower,) = cut_differences(meta, cut, 0.6)
    assert narrower.startswith("kept only within 0.5 m of the paths, and the tables reach 0.6 m")


def test_a_cut_without_a_readable_record_of_its_paths_is_refused() -> None:
    """A cloud cut before the paths were recorded, or whose record is not one, cannot be
    checked: it never passes for any paths."""
    now = _drawn_from()
    (missing,) = cut_differences({META_KEPT_WITHIN_M: "0.5"}, now, 0.3)
    assert missing.startswith("no record of what its paths were drawn from")
    for bad in ("not json", "[1, 2]", '{"settings": {}}'):
        meta = {META_KEPT_WITHIN_M: "0.5", META_CUT_AROUND: bad}
        (unreadable,) = cut_differences(meta, now, 0.3)
        assert (
            unreadable.startswith(f"metadata {META_CUT_AROUND} = ") and "unreadable" in unreadable
        )
    meta = {**cut_metadata(0.5, now), META_KEPT_WITHIN_M: "wide"}
    assert cut_differences(meta, now, 0.3) == [
        f"metadata {META_KEPT_WITHIN_M} = 'wide' is not a distance"
    ]
