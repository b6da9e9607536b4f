"""The events of sect. 5: the path cut by distance, whole or fed in runs."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.model.events import path_events, path_events_step

T0_NS = 1_000_000_000_000


def test_path_events_times() -> None:
    t = T0_NS + np.arange(11, dtype=np.int64) * 100_000_000
    x = np.array([0, 1, 2, 3, 3, 3, 4, 5, 6, 7, 8.5])  # standstill from 0.3 to 0.5 s
    bounds, s = path_events(t, x, np.zeros(11), 1.4)
    assert s.tolist() == pytest.approx([0, 1.4, 2.8, 4.2, 5.6, 7.0, 8.4])
    expected = [0.0, 0.14, 0.28, 0.62, 0.76, 0.9, 0.9 + 1.4 / 1.5 * 0.1]
    np.testing.assert_allclose((bounds - T0_NS) * 1e-9, expected, atol=1e-9)
    empty, _ = path_events(t[:1], x[:1], np.zeros(1), 1.4)
    assert empty.size == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_path_events_fed_in_runs_equal_the_whole_path(seed: int) -> None:
    """The stage feeds the pose a batch at a time: any split into runs gives the whole
    path's boundaries bit for bit, across stops and rows that land exactly on a boundary."""
    rng = np.random.default_rng(seed)
    n = 3_000
    step = rng.uniform(0.0, 0.3, n - 1)
    step[rng.random(n - 1) < 0.1] = 0.0  # standstills, some across a run's edge
    step[500:540] = 0.35  # 0.35 m steps: every fourth row is exactly on a 1.4 m boundary
    heading = np.cumsum(rng.normal(0.0, 0.05, n - 1))
    x = np.concatenate([[5.0], 5.0 + np.cumsum(step * np.cos(heading))])
    y = np.concatenate([[-2.0], -2.0 + np.cumsum(step * np.sin(heading))])
    t = T0_NS + np.cumsum(rng.integers(9_000_000, 11_000_000, n)).astype(np.int64)
    whole_t, whole_s = path_events(t, x, y, 1.4)
    cuts = np.sort(rng.choice(np.arange(1, n), size=40, replace=False))
    carry = None
    parts_t, parts_s = [], []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
        t_b, s_b, carry = path_events_step(t[lo:hi], x[lo:hi], y[lo:hi], 1.4, carry)
        parts_t.append(t_b)
        parts_s.append(s_b)
    assert whole_t.size > 100
    np.testing.assert_array_equal(np.concatenate(parts_t), whole_t)
    np.testing.assert_array_equal(np.concatenate(parts_s), whole_s)
    # Each boundary lies within the pose rows that bracket its distance.
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    i = np.searchsorted(s, whole_s[1:], side="left")
    assert np.all((t[i - 1] <= whole_t[1:]) & (whole_t[1:] <= t[i]))
