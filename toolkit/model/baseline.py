"""The race's obstacle test as the baseline of Fig. 6 (sect. 7.1; Thrun et al. 2006a).

Stanley's terrain analysis during the race (Thrun, Montemerlo and Aron, "Probabilistic
Terrain Analysis for High-Speed Desert Driving", RSS 2006; also Thrun et al., J. Field
Robotics 23(9), 2006, sect. 6) compares pairs of laser points that fall into the same small
grid cell: the cell holds an obstacle when two of its points differ in height by more than
``delta``, judged probabilistically against the error of the pose, whose variance grows
with the time between the two scans (a Markov chain model of pose error, so a random walk:
variance linear in time). Here, for points i and j of one patch in the same cell::

    sigma^2(dt) = sigma0^2 + q |tau_i - tau_j|
    p_ij        = Phi((|z_i - z_j| - delta) / sigma(dt))

``p_ij`` is the probability that the true height difference exceeds ``delta`` when the
measured one is Gaussian around it with that standard deviation; a pair is *flagged* when
``p_ij > confidence``. The probability itself is the pair's score: as in sect. 7.1 ("we use
the method in (Thrun et al., 2006a) to generate a vector W"), the scores of a patch's
same-cell pairs replace Delta of eq. (4); eqs. (3) and (5) and the threshold then apply with
their own upsilon, omega, zeta and mu, trained separately
(:func:`toolkit.model.ascent.coordinate_ascent` with the alphas frozen). Pairs in different
cells are not compared (score -inf, an absent pair).

The constants (``[evaluate]`` in the configuration): ``delta`` 15 cm, the race's obstacle
height (Thrun et al. 2006, sect. 6); the cell, ``sigma0``, ``q`` and the confidence are not
given in the sources at hand and are set a priori (not tuned on any result): a 25 cm cell;
``sigma0`` 3 cm, near the spread of the z difference of two scans of one flat cell taken
at no time apart in this toolkit's Fig. 4 analogue (intercept 1.4-1.8 cm of mean |dz|, a
standard deviation of about 2 cm), rounded up; ``q`` 0.0025 m^2/s, so that sigma reaches
about 10 cm after 4 s, as Fig. 4's |dz| grows by a few cm per second; the conventional 95 %
confidence. A probability is never negative, so eq. (3)'s zeros (see
:mod:`toolkit.model.roughness`) do not erase the ranking of pairs below the test's
threshold: the baseline keeps a continuous score, as Fig. 6's curves for it have.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm

from toolkit.arrays import FloatArray
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import CHUNK_GROUPS, Blockwise, top_w

Float32Array = NDArray[np.float32]


@dataclass(frozen=True)
class BaselineParams:
    """The race test's constants: cell size, obstacle height delta, the pose-error model
    (sigma0 and its growth q) and the confidence of the test."""

    cell_m: float = 0.25
    delta_m: float = 0.15
    sigma0_m: float = 0.03
    growth_m2_per_s: float = 0.0025
    confidence: float = 0.95

    @property
    def flag_score(self) -> float:
        """The score (a probability) above which a pair is flagged."""
        return self.confidence


def pair_scores(patches: TyrePatches, params: BaselineParams) -> Float32Array:
    """(G, P) float32: ``p_ij`` for the pairs ``np.tril_indices(n_max, -1)`` of every patch
    (the layout of :class:`toolkit.model.roughness.PairTable`), -inf where the two points are
    not both real or not in the same cell."""
    r, c = np.tril_indices(patches.n_max, -1)
    cx = np.floor(patches.x / params.cell_m)
    cy = np.floor(patches.y / params.cell_m)
    out: Float32Array = np.empty((patches.groups, r.size), np.float32)
    # A chunk of patches at a time, so the float64 temporaries stay small (all pairs at once:
    # several (G, P) float64 arrays, gigabytes on an hour's log).
    for lo in range(0, patches.groups, CHUNK_GROUPS):
        rows = slice(lo, lo + CHUNK_GROUPS)
        same = (cx[rows][:, r] == cx[rows][:, c]) & (cy[rows][:, r] == cy[rows][:, c])
        same &= patches.valid[rows][:, r] & patches.valid[rows][:, c]
        dz = np.abs(patches.z[rows][:, r] - patches.z[rows][:, c])
        dt = np.abs(patches.tau[rows][:, r] - patches.tau[rows][:, c])
        sigma = np.sqrt(params.sigma0_m**2 + params.growth_m2_per_s * dt)
        s = norm.cdf((dz - params.delta_m) / sigma).astype(np.float32)
        s[~same] = -np.inf
        out[rows] = s
    return out


def flagged(patches: TyrePatches, params: BaselineParams) -> NDArray[np.bool_]:
    """(G,) whether any same-cell pair of a patch passes the race's obstacle test."""
    return np.asarray((pair_scores(patches, params) > params.flag_score).any(axis=1), bool)


class FixedScores:
    """Pair scores that do not depend on the alphas (the baseline's ``s_ij``), in the
    interface the learner scores through (:class:`toolkit.model.roughness.TopScores`)."""

    def __init__(self, scores: Float32Array) -> None:
        self.scores = scores

    @property
    def groups(self) -> int:
        return int(self.scores.shape[0])

    def hold(self, alpha: Sequence[float] | None) -> None:
        """Nothing to keep: the scores are fixed."""

    def top_scores(self, alpha: Sequence[float], k: int) -> FloatArray:
        del alpha  # the race's test has no alphas
        parts = [
            top_w(self.scores[i : i + CHUNK_GROUPS], k) for i in range(0, self.groups, CHUNK_GROUPS)
        ]
        return np.concatenate(parts, axis=0) if parts else np.zeros((0, k))


def baseline_pairs(patches: TyrePatches, params: BaselineParams) -> Blockwise:
    """The race test's pair scores of ``patches``, built a block at a time when asked (to
    score every event once without holding all their pairs)."""
    return Blockwise(patches, lambda block: FixedScores(pair_scores(block, params)))


__all__ = ["BaselineParams", "FixedScores", "baseline_pairs", "flagged", "pair_scores"]
