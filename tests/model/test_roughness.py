"""Eqs. (2)-(5): the vectorised scores against plain loops, and each decision the paper
leaves open (toolkit.model.roughness's docstring)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.model.helpers import combined_loop, make_patches, r_loop, random_patches
from toolkit.model.roughness import (
    CHUNK_GROUPS,
    Blockwise,
    PairTable,
    RoughnessParams,
    model_pairs,
    score_events,
    signed_power,
    top_k_desc,
    total_score,
)


def _random_params(rng: np.random.Generator) -> RoughnessParams:
    alpha = []
    for i in range(10):
        alpha.append(float(rng.uniform(0.3, 2.5)) if i % 2 else float(rng.uniform(-0.5, 2.0)))
    return RoughnessParams(
        tuple(alpha),
        float(rng.uniform(0.8, 1.5)),
        int(rng.integers(1, 12)),
        float(rng.uniform(0.3, 2.0)),
        0.0,
    )


@pytest.mark.parametrize("seed", range(6))
def test_vectorised_scores_equal_a_loop_over_pairs(seed: int) -> None:
    """Patches of 0 to 9 points a tyre (so some with fewer pairs than omega, some with none)
    and random admissible parameters: R_left, R_right and R_combined equal eqs. (2)-(5)
    computed pair by pair (float32 differences: relative 1e-4)."""
    rng = np.random.default_rng(seed)
    raw = random_patches(rng, 12, 9)
    params = _random_params(rng)
    got = score_events(PairTable(make_patches(raw)), params)
    for e, (left, right) in enumerate(raw):
        rl, rr = r_loop(left, params), r_loop(right, params)
        assert got.r_left[e] == pytest.approx(rl, rel=1e-4, abs=1e-5)
        assert got.r_right[e] == pytest.approx(rr, rel=1e-4, abs=1e-5)
        assert got.r_combined[e] == pytest.approx(
            combined_loop(rl, rr, params.zeta), rel=1e-3, abs=1e-5
        )


def test_only_the_lower_triangle_is_scored() -> None:
    """N points give N (N - 1) / 2 pairs, each once: with omega = all pairs and upsilon = 1,
    R is the plain sum of Delta over r > c (the upper triangle would double it)."""
    pts = [
        (0.0, 0.0, 0.00, 0.0, 0.0, 0.0),
        (0.1, 0.0, 0.03, 0.0, 0.0, 0.0),
        (0.2, 0.0, 0.10, 0.0, 0.0, 0.0),
        (0.3, 0.0, 0.01, 0.0, 0.0, 0.0),
    ]
    table = PairTable(make_patches([[pts, pts]]))
    assert table.pairs == 6
    alpha = (1.0, 1.0, 0, 1, 0, 1, 0, 1, 0, 1)
    r = total_score(table.top_scores(alpha, 6), 1.0, 6)
    dz = [abs(p[2] - q[2]) for i, p in enumerate(pts) for q in pts[:i]]
    assert r[0] == pytest.approx(sum(dz), rel=1e-6)


def test_the_largest_score_weighs_upsilon_to_the_omega_minus_one() -> None:
    """Decision 1: W has omega entries, W_0..W_{omega-1} ascending, i = 0..omega-1."""
    top = np.array([[5.0, 3.0, 2.0, 1.0]])
    assert total_score(top, 2.0, 3)[0] == 5 * 4 + 3 * 2 + 2 * 1


def test_fewer_pairs_than_omega_rank_from_the_top() -> None:
    """Decision 2: two pairs and omega = 4: the largest still weighs upsilon^3, the next
    upsilon^2; the empty ranks add nothing."""
    top = top_k_desc(np.array([[1.0, 4.0]], np.float32), 4)
    assert np.isinf(top[0, 2:]).all()
    assert total_score(top, 2.0, 4)[0] == 4 * 8 + 1 * 4


def test_a_patch_with_fewer_than_two_points_scores_zero() -> None:
    """Decision 3: one point (no pair) or none: R = 0."""
    one = [(0.0, 0.0, 0.5, 0.0, 0.0, 0.0)]
    pts = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.1, 0.0, 0.1, 0.0, 0.0, 0.0)]
    got = score_events(
        PairTable(make_patches([[one, []], [pts, one]])),
        RoughnessParams((1.0, 1.0, 0, 1, 0, 1, 0, 1, 0, 1), 1.1, 3, 1.0, 0.0),
    )
    assert got.r_left[0] == 0.0 and got.r_right[0] == 0.0
    assert got.r_left[1] > 0.0 and got.r_right[1] == 0.0


def test_negative_scores_lose_to_the_masks_zeros() -> None:
    """Sect. 4 extracts W from S times the lower-triangular mask, whose zeros are elements:
    a patch whose every pair scores below zero has W all zeros, R = 0; a single positive
    pair among negative ones is W's largest entry and the rest are zeros."""
    flat = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0, 3.0, 0.0, 0.0), (1.0, 0, 0, 6.0, 0, 0)]
    step = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.05, 0.0, 0.1, 0.0, 0.0, 0.0)]
    p = RoughnessParams((1.0, 1.0, 0.5, 1.0, 0.1, 1.0, 0, 1, 0, 1), 2.0, 3, 1.0, 0.0)
    got = score_events(PairTable(make_patches([[flat, step + flat[1:]]])), p)
    assert got.r_left[0] == 0.0
    # step pair: 0.1 - 0.1 x 0.05 = 0.095, the largest of W, weighs upsilon^2; the rest 0.
    assert got.r_right[0] == pytest.approx(0.095 * 4.0, rel=1e-5)


def test_negative_r_under_a_fractional_zeta_is_a_signed_power() -> None:
    """Decision 4: sign(R) |R|^zeta: real, odd, increasing in R."""
    r = np.array([-4.0, -1.0, 0.0, 1.0, 4.0])
    got = signed_power(r, 0.5)
    assert got.tolist() == [-2.0, -1.0, 0.0, 1.0, 2.0]
    assert np.all(np.diff(signed_power(np.linspace(-3, 3, 101), 0.3)) > 0)


def test_exponents_must_be_positive_and_zero_differences_score_zero() -> None:
    """Decision 5: an exponent <= 0 is outside the model; with a > 0, |0|^a = 0, so two
    points at the same height and time add nothing but the distance term."""
    base = RoughnessParams((1.0, 0.5, 1.0, 0.5, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0), 1.0, 1, 1.0, 0.0)
    assert base.admissible()
    for i in (1, 3, 5, 7, 9):
        bad = list(base.alpha)
        bad[i] = 0.0
        assert not RoughnessParams(tuple(bad), 1.0, 1, 1.0, 0.0).admissible()
    assert not RoughnessParams(base.alpha, 0.0, 1, 1.0, 0.0).admissible()
    assert not RoughnessParams(base.alpha, 1.0, 0, 1.0, 0.0).admissible()
    assert not RoughnessParams(base.alpha, 1.0, 1, 0.0, 0.0).admissible()
    same = [(0.0, 0.0, 0.2, 1.0, 0.0, 0.0), (0.0, 0.0, 0.2, 1.0, 0.0, 0.0)]
    got = score_events(PairTable(make_patches([[same, same]])), base)
    assert got.r_left[0] == 0.0 and math.isfinite(got.r_combined[0])


def test_predicted_is_r_combined_above_mu() -> None:
    """rough iff R_combined > mu, strictly."""
    pts = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.1, 0.0, 0.1, 0.0, 0.0, 0.0)]
    table = PairTable(make_patches([[pts, pts]]))
    p = RoughnessParams((1.0, 1.0, 0, 1, 0, 1, 0, 1, 0, 1), 1.0, 1, 1.0, 0.0)
    r = score_events(table, p).r_combined[0]
    at = RoughnessParams(p.alpha, 1.0, 1, 1.0, float(r))
    below = RoughnessParams(p.alpha, 1.0, 1, 1.0, float(np.nextafter(r, -np.inf)))
    assert not score_events(table, at).predicted[0]
    assert score_events(table, below).predicted[0]


def test_the_pairs_of_some_patches_score_them_as_the_whole_table_does() -> None:
    """PairTable of TyrePatches.take (training events only) scores its patches as the whole
    table does."""
    rng = np.random.default_rng(7)
    patches = make_patches(random_patches(rng, 10, 6))
    keep = np.repeat(np.arange(10) % 3 == 0, 2)
    alpha = (1.0, 1.5, 0.1, 1.0, 0.2, 1.0, 0.05, 1.0, 0.05, 1.0)
    np.testing.assert_array_equal(
        PairTable(patches.take(keep)).top_scores(alpha, 5),
        PairTable(patches).top_scores(alpha, 5)[keep],
    )


@pytest.mark.parametrize("block_groups", [1, 7, 64, 10_000])
def test_blockwise_scores_equal_the_whole_table(block_groups: int) -> None:
    """Blocks of any size, a last one short or the only one: the same top scores, bit for
    bit, as one PairTable of every patch."""
    rng = np.random.default_rng(5)
    patches = make_patches(random_patches(rng, 45, 8))
    alpha = (1.0, 1.5, 0.1, 1.0, 0.2, 1.0, 0.05, 1.0, 0.05, 1.0)
    got = Blockwise(patches, PairTable, block_groups).top_scores(alpha, 6)
    np.testing.assert_array_equal(got, PairTable(patches).top_scores(alpha, 6))
    np.testing.assert_array_equal(
        model_pairs(patches).top_scores(alpha, 6), PairTable(patches).top_scores(alpha, 6)
    )


def test_pair_table_built_in_chunks_equals_all_pairs_at_once() -> None:
    """More patches than one chunk (CHUNK_GROUPS): every array equals the differences of all
    pairs taken at once, as eq. (2) lays them out."""
    rng = np.random.default_rng(11)
    patches = make_patches(random_patches(rng, CHUNK_GROUPS + 77, 7))
    assert patches.groups > 2 * CHUNK_GROUPS
    table = PairTable(patches)
    r, c = np.tril_indices(patches.n_max, -1)
    with np.errstate(divide="ignore"):
        want_dz = np.log(np.abs(patches.z[:, r] - patches.z[:, c])).astype(np.float32)
        want_dtau = np.log(np.abs(patches.tau[:, r] - patches.tau[:, c])).astype(np.float32)
        dxy = np.hypot(patches.x[:, r] - patches.x[:, c], patches.y[:, r] - patches.y[:, c])
        want_dxy = np.log(dxy).astype(np.float32)
    # A pair with a padding point has no terms: its logarithms are -inf (|0|^a = 0).
    padding = ~(patches.valid[:, r] & patches.valid[:, c])
    for want in (want_dz, want_dtau, want_dxy):
        want[padding] = -np.inf
    np.testing.assert_array_equal(table.log_dz, want_dz)
    np.testing.assert_array_equal(table.log_dtau, want_dtau)
    np.testing.assert_array_equal(table.log_dxy, want_dxy)
    np.testing.assert_array_equal(table.pair_valid, patches.valid[:, r] & patches.valid[:, c])


def test_total_score_does_not_depend_on_where_the_scores_sit_in_memory() -> None:
    """The same scores, once aligned and once at an odd offset in a larger buffer, give
    bit-identical R (a stage is deterministic run to run, whatever the allocator does)."""
    rng = np.random.default_rng(3)
    top = rng.normal(0.0, 1.0, size=(4000, 17))
    buffer = np.empty(top.size + 1)
    shifted = buffer[1:].reshape(top.shape)
    shifted[...] = top
    assert shifted.ctypes.data % 16 != top.ctypes.data % 16
    np.testing.assert_array_equal(total_score(shifted, 1.3, 17), total_score(top, 1.3, 17))
    assert total_score(top, 1.3, 17)[0] == pytest.approx(
        sum(max(v, 0.0) * 1.3 ** (16 - k) for k, v in enumerate(top[0])), rel=1e-12
    )


def test_a_held_point_caches_terms_and_scores_as_a_fresh_table_does() -> None:
    """The search's pattern: hold B, score candidates that move one element (the height
    term, a penalty, a rate term switched on), accept one and hold it. Every call gives
    the scores a table without a cache gives, bit for bit, and at most four arrays are
    kept (B's and the latest candidate's height and penalty)."""
    rng = np.random.default_rng(9)
    patches = make_patches(random_patches(rng, 40, 9))
    held, fresh = PairTable(patches), PairTable(patches)
    b = [1.0, 2.0, 0.05, 1.0, 0.01, 1.0, 0.0, 1.0, 0.0, 1.0]
    held.hold(b)
    moves = [(0, 0.5), (1, -0.5), (2, 0.1), (3, 0.5), (6, 0.2), (7, 0.3), (8, 0.1), (4, -0.01)]
    for n, (j, step) in enumerate(moves):
        t = list(b)
        t[j] += step
        np.testing.assert_array_equal(held.top_scores(t, 7), fresh.top_scores(t, 7))
        assert len(held._cache) <= 4
        if n % 2 == 0:  # accepted
            b = t
            held.hold(b)
        np.testing.assert_array_equal(held.top_scores(b, 7), fresh.top_scores(b, 7))
    held.hold(None)
    assert not held._cache


def test_the_search_is_the_same_with_and_without_the_cache(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A table too large for CACHE_BYTES searches without a cache: the same steps and
    parameters, bit for bit."""
    from toolkit.model import roughness
    from toolkit.model.ascent import AscentConfig, coordinate_ascent

    rng = np.random.default_rng(12)
    raw = random_patches(rng, 60, 8)
    rough = rng.random(60) < 0.3
    config = AscentConfig(
        initial=(1.0, 2.0, 0.05, 1.0, 0.01, 1.0, 0.0, 1.0, 0.0, 1.0, 1.05, 3.0, 1.0),
        increments=(0.5, 0.5, 0.02, 0.5, 0.005, 0.5, 0.02, 0.5, 0.02, 0.5, 0.05, 2.0, 0.2),
        iterations=4,
    )
    cached = coordinate_ascent(PairTable(make_patches(raw)), rough, config)
    monkeypatch.setattr(roughness, "CACHE_BYTES", 0)
    uncached = coordinate_ascent(PairTable(make_patches(raw)), rough, config)
    assert cached.steps and cached.steps == uncached.steps
    assert cached.params == uncached.params


# Any warning fails the test: the terms of a padding pair are never computed as a number.
@pytest.mark.filterwarnings("error")
def test_a_padding_pair_is_absent_even_where_a_negative_weight_overflows() -> None:
    """A negative time weight with a steep exponent: the time term of a real point paired
    with the padding's 0 (tau of 1.7e9 s, a raw clock) would overflow float32. The pair is
    absent (Delta = -inf, not NaN), R stays finite and nothing is printed."""
    t0 = 1.7e9
    pts = [(0.0, 0.0, 0.0, t0, 0.0, 0.0), (0.1, 0.0, 0.1, t0 + 0.1, 0.0, 0.0)]
    three = [*pts, (0.2, 0.0, 0.3, t0 + 0.2, 0.0, 0.0)]
    table = PairTable(make_patches([[pts, three]]))
    alpha = (1.0, 2.0, -0.01, 5.0, 0.01, 1.0, 0.0, 1.0, 0.0, 1.0)
    d = table.delta(alpha)
    got = score_events(table, RoughnessParams(alpha, 1.1, 3, 1.0, 0.0))
    assert not table.pair_valid[0].all()
    assert np.isneginf(d[~table.pair_valid]).all()
    assert np.isfinite(d[table.pair_valid]).all()
    assert np.isfinite(got.r_left).all() and np.isfinite(got.r_right).all()
    assert got.r_right[0] > 0.0


@pytest.mark.filterwarnings("error")
def test_a_penalty_beyond_float32_makes_its_pair_absent_without_a_warning() -> None:
    """Two real points 100 s apart under a time exponent of 25 (100^25 = 1e50, beyond
    float32): the penalty saturates to +inf, so that pair is absent, and the patch scores
    as it would without it (decision 4). The same pair's height term beyond float32 makes
    R non-finite instead, which the learner rejects. Neither prints numpy's warning."""
    t0 = 1.7e9
    near = [(0.0, 0.0, 0.0, t0, 0.0, 0.0), (0.1, 0.0, 0.4, t0 + 0.1, 0.0, 0.0)]
    late = [*near, (0.2, 0.0, 0.2, t0 + 100.0, 0.0, 0.0)]
    table = PairTable(make_patches([[near, late]]))
    alpha = (1.0, 1.0, 1e-3, 25.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0)
    d = table.delta(alpha)
    late_pairs = table.pair_valid[1] & (table.log_dtau[1] > math.log(50.0))
    assert late_pairs.sum() == 2 and np.isneginf(d[1, late_pairs]).all()
    got = score_events(table, RoughnessParams(alpha, 1.1, 3, 1.0, 0.0))
    # The late point adds nothing: the right patch is the left one's two points.
    assert got.r_right[0] == pytest.approx(got.r_left[0]) and got.r_left[0] > 0.0
    steep_height = (1.0, 15.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0)  # (1e3 m)^15 = 1e45
    tall = [(0.0, 0.0, 0.0, t0, 0.0, 0.0), (0.1, 0.0, 1e3, t0 + 0.1, 0.0, 0.0)]
    high = score_events(
        PairTable(make_patches([[tall, tall]])), RoughnessParams(steep_height, 1.1, 3, 1.0, 0.0)
    )
    assert not np.isfinite(high.r_combined).all()


def test_a_table_taken_and_joined_is_the_table_of_those_patches() -> None:
    """Pairs kept from one update to the next (the online buffer) are the pairs of the
    patches kept: take and join give PairTable's arrays for the patches taken and joined."""
    rng = np.random.default_rng(8)
    a = make_patches(random_patches(rng, 12, 6))
    b = make_patches(random_patches(rng, 8, 6))
    groups = np.array([23, 0, 5, 30, 31, 7])
    got = PairTable(a).join(PairTable(b)).take(groups)
    want = PairTable(a.join(b).take(groups))
    for name in ("pair_valid", "log_dz", "log_dtau", "log_dxy", "log_gamma", "log_psi"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    params = RoughnessParams((1.0, 1.2, 0.1, 1.0, 0.2, 1.0, 0.05, 1.0, 0.05, 1.0), 1.1, 3, 1.0, 0.0)
    np.testing.assert_array_equal(
        score_events(got, params).r_combined, score_events(want, params).r_combined
    )
