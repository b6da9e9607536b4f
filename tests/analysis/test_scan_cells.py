"""The vectorised pieces of Fig. 4: the two-key search of the window and the flatness test."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.analysis import scan_cells
from toolkit.analysis.scan_cells import flat_mask


@pytest.mark.parametrize("seed", [0, 1])
def test_the_two_key_search_equals_a_joint_sort(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The window's search (first row of a cell at or after a time, by one searchsorted on
    a joint int64 key) against the joint sort it replaced, on stamps near 1.7e18 ns, repeated
    stamps and queries before, at and after the cell's rows; and its fallback to the sort
    where the joint key would overflow."""
    rng = np.random.default_rng(seed)
    n = 5_000
    key = np.sort(rng.integers(-(2**40), 2**40, 300))[rng.integers(0, 300, n)]
    t = 1_700_000_000_000_000_000 + rng.integers(0, 10**10, n)
    t[rng.random(n) < 0.2] = t[0]  # repeated stamps
    order = np.lexsort((t, key))
    key, t = key[order], t[order]
    p = np.sort(rng.choice(n, 800, replace=False))
    q = t[p] - rng.choice([0, 1, 10**9, 10**10, 10**12], p.size)
    expected = scan_cells.lower_bound(key, t, key[p], q)
    np.testing.assert_array_equal(scan_cells.first_at_or_after(key, t, p, q), expected)
    assert np.all(expected <= p) and np.all(key[expected] == key[p])
    monkeypatch.setattr(scan_cells, "lower_bound", lambda *args: np.full(p.size, -7))
    wide = t.copy()
    wide[-1] = t[0] + 2**61  # span too wide for rank * span in int64: the sort answers
    assert scan_cells.first_at_or_after(key, wide, p, q).tolist() == [-7] * p.size


def test_only_flat_ground_is_used() -> None:
    """A 0.3 m step in one scan line and a 5 cm bump: the points whose window of +-3 beams
    holds them are left out; a gentle 5 % grade stays."""
    n = 60
    x = np.full(n, 5.0)
    y = np.arange(n) * 0.2
    z = 0.05 * y  # a 5 % grade along the line: flat enough
    z[40:] += 0.3  # a kerb
    z[20] += 0.05  # a bump
    flat = flat_mask(x, y, z, np.arange(n), np.zeros(n, np.int64), 3, 0.1, 0.03)
    expected = np.ones(n, bool)
    expected[:3] = expected[-3:] = False  # scan ends: flatness unknown
    expected[17:24] = False  # the bump within 3 beams
    expected[37:43] = False  # the kerb within the chord
    np.testing.assert_array_equal(flat, expected)
    # A dropped return: its neighbours' windows are incomplete.
    beam = np.delete(np.arange(n), 10)
    keep = np.delete(np.arange(n), 10)
    flat = flat_mask(x[keep], y[keep], 0 * y[keep], beam, np.zeros(n - 1, np.int64), 3, 0.1, 0.03)
    assert not flat[7:13].any() and flat[3:7].all() and flat[13:16].all()
