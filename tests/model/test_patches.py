"""Tyre patches: the padded layout and the capped, reproducible sample."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from tests.model.helpers import events_table, points_table, random_patches
from toolkit.errors import StageError
from toolkit.model.patches import build_patches


def _kept(p, g: int) -> set[tuple[float, float]]:  # type: ignore[no-untyped-def]
    return {
        (float(a), float(b)) for a, b in zip(p.x[g][p.valid[g]], p.tau[g][p.valid[g]], strict=True)
    }


def test_layout_counts_and_values() -> None:
    rng = np.random.default_rng(0)
    raw = random_patches(rng, 5, 6)
    p = build_patches(events_table(5), points_table(raw), 0)
    for e, wheels in enumerate(raw):
        for w, pts in enumerate(wheels):
            g = 2 * e + w
            assert p.count[g] == len(pts) == p.valid[g].sum()
            assert _kept(p, g) == {(x, tau) for x, _, _, tau, _, _ in pts}


def test_the_cap_keeps_the_same_sample_whatever_the_order_and_batching() -> None:
    """40 of 100 points; shuffling the rows or streaming them in batches of 7 keeps the same
    40 (bottom-k by a hash of each point's identity)."""
    rng = np.random.default_rng(1)
    pts = [[[(float(i), 0.0, 0.0, float(i), 0.0, 0.0) for i in range(100)], []]]
    table = points_table(pts)
    a = build_patches(events_table(1), table, 40)
    shuffled = table.take(pa.array(rng.permutation(table.num_rows)))
    b = build_patches(events_table(1), shuffled.to_batches(max_chunksize=7), 40)
    assert a.count[0] == 40 and a.n_max == 40
    assert _kept(a, 0) == _kept(b, 0)


def test_a_point_under_two_events_is_kept_in_both_or_neither() -> None:
    """The same 60 points listed under events 0 and 1: the same sample in both."""
    pts = [(float(i), 0.0, 0.0, float(i), 0.0, 0.0) for i in range(60)]
    p = build_patches(events_table(2), points_table([[pts, []], [pts, []]]), 20)
    assert _kept(p, 0) == _kept(p, 2)


def test_only_laser_and_unknown_events() -> None:
    a = points_table([[[(0.0, 0, 0, 1.0, 0, 0), (0.1, 0, 0, 2.0, 0, 0)], []]], laser="/a")
    b = points_table([[[(0.2, 0, 0, 3.0, 0, 0)], []], [[(0.3, 0, 0, 4.0, 0, 0)], []]], laser="/b")
    both = pa.concat_tables([a, b])
    p = build_patches(events_table(1), both, 0)  # event 1 is not asked for
    assert p.count.tolist() == [3, 0] and p.lasers == ("/a", "/b")
    only = build_patches(events_table(1), both, 0, only_laser="/b")
    assert only.count.tolist() == [1, 0]


def test_a_wheel_that_is_neither_left_nor_right_is_refused() -> None:
    t = points_table([[[(0.0, 0, 0, 1.0, 0, 0)], []]])
    t = t.set_column(t.schema.get_field_index("wheel"), "wheel", pa.array(["middle"]))
    with pytest.raises(StageError, match="'middle'"):
        build_patches(events_table(1), t, 0)


def test_the_freshest_sample_keeps_the_points_seen_last() -> None:
    """With point_sample "freshest", the kept points are those with the shortest time between
    their observation and the event's start."""
    pts = [[[(float(i), 0.0, 0.0, float(i), 0.0, 0.0) for i in range(30)], []]]
    events = events_table(1).append_column("t_start_ns", pa.array([40_000_000_000], pa.int64()))
    p = build_patches(events, points_table(pts), 10, sample="freshest")
    assert {tau for _, tau in _kept(p, 0)} == {float(i) for i in range(20, 30)}


def test_a_non_finite_feature_is_refused_naming_the_column() -> None:
    """A NaN roll rate would silently change the scores: the file and column are named."""
    t = points_table([[[(0.0, 0, 0, 1.0, float("nan"), 0), (0.1, 0, 0, 2.0, 0, 0)], []]])
    with pytest.raises(StageError, match="'roll_rate': 1 non-finite"):
        build_patches(events_table(1), t, 0)
