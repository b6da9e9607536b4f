"""Terrain height queries: a one-off query's window and the simulator's agree (issue 11)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from toolkit.sim.profiles import make_profile
from toolkit.sim.world import make_world

SEED = 11  # as tests/sim/test_features.py: no other test uses it


def test_a_one_off_height_query_builds_only_the_tiles_it_needs() -> None:
    """``Terrain.height`` (the truth lookups) takes a window without the simulator's spare
    tile, and reads the same heights as the simulator's window: everywhere in the queried
    stretch, up to the last fine row before a tile's end, where interpolation reaches into
    the next tile."""
    params = replace(make_profile("race").world, length_m=400.0)
    terrain = make_world(params, SEED).terrain
    tile = terrain.tile_length_m
    rng = np.random.default_rng(5)
    # s_hi well inside a tile, within a fine step, within a coarse step (beyond a fine
    # one) and a hair before a tile's end, just past a tile's start.
    for s_hi in (2 * tile - 0.9, 2 * tile - 0.1, 2 * tile - 0.01, 3 * tile - 1e-9, 2 * tile + 0.01):
        s = np.r_[rng.uniform(10.0, s_hi, 400), [s_hi] * 4, s_hi - 0.049, s_hi - 0.19]
        d = rng.uniform(-40.0, 40.0, s.size)
        d[400:404] = (-30.0, -3.0, 3.0, 30.0)  # the last rows of both grids at s_hi
        spare = terrain.window(float(s.min()), float(s.max()))
        tight = terrain.window(float(s.min()), float(s.max()), spare=False)
        assert tight.fine.heights_m.shape[0] <= spare.fine.heights_m.shape[0]
        np.testing.assert_array_equal(terrain.height(s, d), spare.height(s, d))
    # Well inside a tile the tight window is one tile shorter than the spare one.
    s = np.array([60.0, 90.0])
    spare, tight = terrain.window(60.0, 90.0), terrain.window(60.0, 90.0, spare=False)
    assert spare.fine.heights_m.shape[0] - tight.fine.heights_m.shape[0] == round(
        tile / terrain.fine_spacing_m
    )
    np.testing.assert_array_equal(tight.height(s, s * 0), spare.height(s, s * 0))
