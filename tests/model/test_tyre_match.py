"""Points near the rear tyres' paths (sect. 7): the paths of a run of events, and the matching
against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.model.tyre_match import NEIGHBOURS, PathSource, match_points
from toolkit.tyre_paths import TyrePaths, tyre_paths


def test_paths_of_a_run_of_events_are_those_of_the_whole_log() -> None:
    """Tables samples the paths of the open events only (bounded memory); they must be bit
    for bit the whole log's, across yaw wrapping through +-pi and slow and fast stretches."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.integers(9_000_000, 11_000_000, 3000)).astype(np.int64)
    speed = 2.0 + 12.0 * rng.random(t.size)
    yaw = np.angle(np.exp(1j * np.cumsum(rng.normal(0.0, 0.02, t.size))))  # wraps at +-pi
    step = np.diff(t, prepend=t[0]) * 1e-9 * speed
    xy = np.c_[np.cumsum(step * np.cos(yaw)), np.cumsum(step * np.sin(yaw))]
    bounds = np.sort(rng.integers(t[0], t[-1], 201))
    t_start, t_end = bounds[:-1], bounds[1:]
    whole = tyre_paths(t, xy, yaw, t_start, t_end, 1.65)
    unwrapped = np.unwrap(yaw)
    for first, stop in [(0, 200), (0, 1), (37, 90), (199, 200)]:
        # The pose rows around the run only, as the stage's pose window hands them over.
        lo = max(int(np.searchsorted(t, t_start[first], side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t, t_end[stop - 1], side="left")) + 1, t.size)
        source = PathSource(t[lo:hi], xy[lo:hi], unwrapped[lo:hi], t_start, t_end, 1.65)
        run = source.paths(first, stop)
        for w in (0, 1):
            lo, hi = whole.first[w][first], whole.first[w][stop]
            mine = run.wheel == w
            np.testing.assert_array_equal(run.xy[mine], whole.xy[lo:hi])
            np.testing.assert_array_equal(run.event[mine], whole.event[lo:hi])


@pytest.mark.parametrize("bitmap", [True, False], ids=["bitmap_sieve", "sorted_key_sieve"])
def test_matching_equals_brute_force_also_where_samples_crowd(
    bitmap: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """match_points against brute force: two events' tyre paths, one sampled every 1 mm (a
    crawl: hundreds of samples within the radius, more than the fixed-k query asks for), the
    other every 5 cm; random points around them, some seen after an event started. Both
    ways of the first sieve (a bitmap of cells, sorted cell keys for huge areas)."""
    from toolkit import tyre_paths as tyre_paths_module

    if not bitmap:
        monkeypatch.setattr(tyre_paths_module, "MAX_BITMAP_CELLS", 0)

    rng = np.random.default_rng(7)
    crawl = np.c_[np.arange(0.0, 1.4, 0.001), np.zeros(1400)]
    cruise = np.c_[np.arange(1.4, 2.8, 0.05), np.full(28, 0.1)]
    # Wheel-major, events in order within each wheel, as tyre_paths lays them out.
    xy = np.concatenate([crawl, cruise, crawl + [0, -1.65], cruise + [0, -1.65]])
    one_wheel = np.concatenate([np.zeros(1400, np.int64), np.ones(28, np.int64)])
    event = np.concatenate([one_wheel, one_wheel])
    wheel = np.repeat(np.array([0, 1], np.int64), 1428)
    first = np.array([0, 1400, 1428], np.int64)
    paths = TyrePaths(xy, event, wheel, (first, first + 1428))

    class BothEvents:  # the open events here are both, whose paths are the above
        def paths(self, first: int, stop: int) -> TyrePaths:
            assert (first, stop) == (0, 2)
            return paths

    n = 5000
    pts = np.c_[rng.uniform(-0.5, 3.3, n), rng.uniform(-2.2, 0.6, n)]
    t = rng.integers(0, 2_000_000_000, n).astype(np.int64)
    t_start = np.array([1_500_000_000, 1_800_000_000], dtype=np.int64)
    point, ev, wh = match_points(
        t, pts[:, 0], pts[:, 1], t_start, BothEvents(), 0.3, 60_000_000_000
    )
    got = set(zip(point.tolist(), ev.tolist(), wh.tolist(), strict=True))
    want = set()
    for k in range(n):
        d = np.hypot(*(xy - pts[k]).T)
        for e, w in set(zip(event[d <= 0.3].tolist(), wheel[d <= 0.3].tolist(), strict=True)):
            if 0 < t_start[e] - t[k] <= 60_000_000_000:
                want.add((k, e, w))
    assert got == want
    crowded = [(k, e) for k, e, _ in want if e == 0]
    assert len(crowded) > 100 and NEIGHBOURS < 600  # the crawl saturates the fixed-k query
