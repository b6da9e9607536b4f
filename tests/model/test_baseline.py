"""The race's obstacle test (Thrun et al. 2006a) as the baseline of Fig. 6."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from tests.model.helpers import Point, make_patches, random_patches
from toolkit.model.baseline import BaselineParams, FixedScores, flagged, pair_scores
from toolkit.model.roughness import CHUNK_GROUPS, Blockwise

PARAMS = BaselineParams(
    cell_m=0.25, delta_m=0.15, sigma0_m=0.03, growth_m2_per_s=0.0025, confidence=0.95
)


def _pair(dz: float, dt: float, dx: float = 0.05) -> list[Point]:
    return [(0.1, 0.1, 0.0, 5.0, 0.0, 0.0), (0.1 + dx, 0.1, dz, 5.0 + dt, 0.0, 0.0)]


def test_a_planted_step_is_flagged() -> None:
    """A 30 cm step seen by two scans 10 ms apart in one cell: (0.30 - 0.15) / 0.030 = 5
    standard deviations: a probability of 1 - 3e-7 that the step exceeds delta."""
    p = make_patches([[_pair(0.30, 0.01), _pair(0.0, 0.01)]])
    assert flagged(p, PARAMS).tolist() == [True, False]
    s = pair_scores(p, PARAMS)
    assert s[0][np.isfinite(s[0])].max() > 0.9999


def test_a_difference_explained_by_the_time_between_scans_is_ignored() -> None:
    """The same 30 cm, but the scans 20 s apart: the pose error's variance has grown to
    0.03^2 + 0.0025 x 20 (sigma 0.23 m), so the difference is 0.65 sigma above delta: not
    significant."""
    p = make_patches([[_pair(0.30, 20.0), _pair(0.30, 0.01)]])
    assert flagged(p, PARAMS).tolist() == [False, True]


def test_points_in_different_cells_are_not_compared() -> None:
    """A 30 cm difference across a cell boundary (x = 0.24 and 0.26) is no pair at all."""
    pts = [(0.24, 0.1, 0.0, 5.0, 0.0, 0.0), (0.26, 0.1, 0.3, 5.0, 0.0, 0.0)]
    p = make_patches([[pts, pts]])
    assert not flagged(p, PARAMS).any()
    assert np.isneginf(pair_scores(p, PARAMS)).all()


def test_fixed_scores_rank_and_score_blockwise_as_whole() -> None:
    p = make_patches([[_pair(0.30, 0.01), _pair(0.2, 0.01)], [_pair(0.1, 0.01), _pair(0.0, 0.01)]])
    fixed = FixedScores(pair_scores(p, PARAMS))
    top = fixed.top_scores((), 1)[:, 0]
    assert top[0] > top[1] > top[2] > top[3]
    blocks = Blockwise(p, lambda b: FixedScores(pair_scores(b, PARAMS)), block_groups=3)
    np.testing.assert_array_equal(blocks.top_scores((), 2), fixed.top_scores((), 2))


def test_pair_scores_in_chunks_equal_a_loop_over_pairs() -> None:
    """More patches than one chunk (CHUNK_GROUPS): each pair's score is Phi((|dz| - delta) /
    sigma(dt)) where both points are real and share a cell, -inf elsewhere, pair by pair."""
    rng = np.random.default_rng(5)
    raw = random_patches(rng, CHUNK_GROUPS // 2 + 40, 6)
    # Heights spread enough that some same-cell pairs pass delta.
    raw = [[[(x, y, 3 * z, t, g, q) for (x, y, z, t, g, q) in w] for w in ev] for ev in raw]
    p = make_patches(raw)
    assert p.groups > CHUNK_GROUPS
    got = pair_scores(p, PARAMS)
    r, c = np.tril_indices(p.n_max, -1)
    for g in range(0, p.groups, 7):  # every 7th patch, both chunks
        for k, (i, j) in enumerate(zip(r, c, strict=True)):
            a, b = (p.x[g, i], p.y[g, i]), (p.x[g, j], p.y[g, j])
            same = all(
                np.floor(u / PARAMS.cell_m) == np.floor(v / PARAMS.cell_m)
                for u, v in zip(a, b, strict=True)
            )
            if not (p.valid[g, i] and p.valid[g, j] and same):
                assert np.isneginf(got[g, k])
                continue
            sigma = math.sqrt(
                PARAMS.sigma0_m**2 + PARAMS.growth_m2_per_s * abs(p.tau[g, i] - p.tau[g, j])
            )
            want = norm.cdf((abs(p.z[g, i] - p.z[g, j]) - PARAMS.delta_m) / sigma)
            assert got[g, k] == pytest.approx(want, rel=1e-6, abs=1e-7)
    assert (got > 0.5).any()
