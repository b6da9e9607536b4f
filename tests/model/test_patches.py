"""Tyre patches: the padded layout and the capped, reproducible sample."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from tests.model.helpers import events_table, points_table, random_patches
from toolkit.errors import StageError
from toolkit.model.patches import build_patches, lead_order


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
    assert only.lasers == ("/b",) and only.laser[0, 0] == 0
    assert build_patches(events_table(1), b, 0).lasers == ("/b",)


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


def test_dictionary_columns_several_logs_and_float32_give_the_same_patches() -> None:
    """Rows of two logs read as Arrow dictionaries (as the stages stream them), in batches
    whose dictionaries differ, give the same patches as plain columns; float32 features are
    read as their float64 values."""
    rng = np.random.default_rng(4)
    a = points_table(random_patches(rng, 4, 7), laser="/a", log_id="log_a")
    b = points_table(random_patches(rng, 4, 7), laser="/b", log_id="log_b")
    plain = pa.concat_tables([a, b]).take(pa.array(rng.permutation(a.num_rows + b.num_rows)))
    events = pa.concat_tables([events_table(4, "log_b"), events_table(3, "log_a")])
    want = build_patches(events, plain, 5)

    def encoded(t: pa.Table) -> pa.Table:
        for name in ("log_id", "wheel", "laser"):
            i = t.schema.get_field_index(name)
            t = t.set_column(i, name, t.column(name).dictionary_encode())
        return t

    # Each batch encoded on its own, rows ordered so that their dictionaries differ.
    first = encoded(plain.slice(0, 9).sort_by([("log_id", "descending")]))
    rest = encoded(plain.slice(9).sort_by("log_id"))
    dictionaries = [t.column("log_id").chunk(0).dictionary.to_pylist() for t in (first, rest)]
    assert dictionaries == [["log_b", "log_a"], ["log_a", "log_b"]]
    got = build_patches(events, [first, rest], 5)
    for name in ("x", "y", "z", "tau", "gamma", "psi", "valid", "count", "laser"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert got.lasers == want.lasers == ("/a", "/b")
    assert want.count[:8].sum() > 0 and want.count[8:].sum() > 0  # both logs matched
    z32 = plain.set_column(
        plain.schema.get_field_index("z"), "z", plain.column("z").cast(pa.float32())
    )
    np.testing.assert_array_equal(
        build_patches(events, z32, 5).z, want.z.astype(np.float32).astype(np.float64)
    )


def test_an_event_listed_twice_is_refused() -> None:
    """Two events with the same (log_id, event_id) would share points ambiguously."""
    events = pa.concat_tables([events_table(2), events_table(1)])
    with pytest.raises(StageError, match="lists event 0 twice"):
        build_patches(events, points_table([[[(0.0, 0, 0, 1.0, 0, 0)], []]]), 0)


def _two_lasers(near: int, far: int) -> tuple[pa.Table, pa.Table]:
    """One event, left tyre: ``near`` points of "/near" seen 1 s before the event and ``far``
    of "/far" seen 4 s before (taus distinct, so every point has its own identity)."""
    near_pts = [[[(0.01 * i, 0.0, 0.0, 9.0 + 0.001 * i, 0.0, 0.0) for i in range(near)], []]]
    far_pts = [[[(0.01 * i, 0.0, 0.0, 6.0 + 0.001 * i, 0.0, 0.0) for i in range(far)], []]]
    events = events_table(1).append_column("t_start_ns", pa.array([10_000_000_000], pa.int64()))
    both = pa.concat_tables([points_table(far_pts, laser="/far"), points_table(near_pts, "/near")])
    return events, both


def test_lead_order_puts_the_laser_seen_last_first() -> None:
    events, both = _two_lasers(5, 5)
    assert lead_order(events, both) == ("/near", "/far")
    # Batching and row order do not matter.
    assert lead_order(events, both.slice(3).to_batches() + both.slice(0, 3).to_batches()) == (
        "/near",
        "/far",
    )


@pytest.mark.parametrize(("near", "cap"), [(30, 10), (6, 10), (10, 10)])
def test_the_nearest_laser_sample_keeps_the_nearest_lasers_points(near: int, cap: int) -> None:
    """``nearest_laser``: the nearest laser's points fill a patch first (all of them when
    they are fewer than the cap), the far laser's only the places left; the hash sample of
    the same points takes both lasers alike."""
    events, both = _two_lasers(near, 40)
    order = lead_order(events, both)
    p = build_patches(events, both, cap, sample="nearest_laser", laser_order=order)
    near_index = p.lasers.index("/near")
    kept_near = int(np.count_nonzero(p.valid[0] & (p.laser[0] == near_index)))
    assert kept_near == min(near, cap) and p.count[0] == cap
    uniform = build_patches(events, both, cap)
    assert int(np.count_nonzero(uniform.valid[0] & (uniform.laser[0] == near_index))) < cap


def test_joined_patches_are_the_first_set_then_the_second() -> None:
    """``join`` keeps every array's rows in order; patches of another width are refused."""
    rng = np.random.default_rng(4)
    raw = random_patches(rng, 6, 5)
    whole = build_patches(events_table(6), points_table(raw), 8)
    joined = whole.take(slice(0, 4)).join(whole.take(slice(4, None)))
    for name in ("x", "y", "z", "tau", "gamma", "psi", "valid", "count", "laser", "lead"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name), err_msg=name)
    assert joined.lasers == whole.lasers
    narrow = build_patches(events_table(6), points_table(raw), 3)
    with pytest.raises(ValueError, match="width"):
        whole.join(narrow)


def test_conformed_patches_name_more_lasers_and_pad_wider_without_losing_a_point() -> None:
    """``conform`` renumbers the lasers into a larger sorted list and pads every row to a
    wider n_max; a list lacking one of the lasers, or a narrower width, is refused."""
    rng = np.random.default_rng(5)
    raw = random_patches(rng, 4, 5)
    whole = build_patches(events_table(4), points_table(raw, laser="/laser/b"), 6)
    wide = whole.conform(("/laser/a", "/laser/b", "/laser/c"), 9)
    assert wide.n_max == 9 and wide.lasers == ("/laser/a", "/laser/b", "/laser/c")
    for name in ("x", "y", "z", "tau", "gamma", "psi", "valid", "lead"):
        got = getattr(wide, name)
        np.testing.assert_array_equal(got[:, :6], getattr(whole, name), err_msg=name)
        assert not got[:, 6:].any(), name
    np.testing.assert_array_equal(wide.laser[:, :6], np.where(whole.valid, 1, -1))
    assert (wide.laser[:, 6:] == -1).all()
    np.testing.assert_array_equal(wide.count, whole.count)
    with pytest.raises(ValueError, match="do not fit"):
        whole.conform(("/laser/a",), 9)
    with pytest.raises(ValueError, match="do not fit"):
        whole.conform(whole.lasers, 5)
