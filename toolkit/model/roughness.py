"""The roughness model of sect. 4: pairwise scores, the total score R, and R_combined.

For the ``N`` laser points ``L_i = [x, y, z, tau, gamma, psi]`` (eq. 1) under one rear tyre
in one event (a *patch*, :mod:`toolkit.model.patches`)::

    S[r, c]  = Delta(L_r, L_c)                                                     (eq. 2)
    Delta    = a1 |z_r - z_c|^a2 - a3 |tau_r - tau_c|^a4 - a5 |xy_r - xy_c|^a6
               - a7 |gamma_r|^a8 - a7 |gamma_c|^a8 - a9 |psi_r|^a10 - a9 |psi_c|^a10   (eq. 4)
    W        = the omega largest entries of S masked to its lower triangle, ascending
    R        = sum_i W_i upsilon^i                                                 (eq. 3)
    R_comb   = R_left^zeta + R_right^zeta                                           (eq. 5)
    rough   <=> R_comb > mu

Only the ``N (N - 1) / 2`` entries below the diagonal are computed (sect. 4: S is symmetric
with a zero diagonal). Sect. 4 then takes "the element-by-element product of S and the lower
triangular matrix whose non-zero elements are 1" and extracts "the largest omega elements"
of that product: the zeros the mask leaves (the diagonal and the upper triangle, N (N + 1) /
2 of them) are elements too. So W holds the omega largest of the scores *and those zeros*:
a negative score never enters W while a zero is left, and ``W_i = max(score, 0)``. Units: z
and xy in m, tau in s, gamma and psi in rad/s.

**Beyond the paper, optional: a look-ahead term.** Fig. 4 motivates the time term: pose error
grows with the time between two scans. A far laser's error grows with its range instead (an
attitude error times the range: ``benchmarks/README.md``, "The simulator's side of the gap"),
and two far-laser points of one cell are often seen a fraction of a second apart, so the time
term cannot discount them. With 12 alphas Delta also subtracts, per point,
``a11 |lead_r|^a12 + a11 |lead_c|^a12``, where ``lead`` is how long before its event began
the point was seen (s): the laser's look-ahead distance over the speed, known for every
point. With 10 alphas (the paper's) the term is absent.

**Where the paper leaves a gap, this implementation decides** (each tested in
``tests/model/test_roughness.py``):

1. *Eq. (3)'s upper limit.* "The largest omega elements are extracted into W", so W has
   omega entries, ``W_0 .. W_{omega-1}`` in ascending order; the sum runs ``i = 0 .. omega-1``
   (eq. 3's ``omega`` read as W's last index, else W would need omega + 1 elements). With
   upsilon > 1 the largest score gets the largest weight, ``upsilon^(omega-1)``: "large,
   compelling evidence should win out over the cumulative effect of small evidence".
2. *Fewer than omega positive scores.* The masked matrix's zeros fill the remaining ranks:
   the k-th largest always gets ``upsilon^(omega-k)``, so a patch's largest score weighs the
   same whether the patch has 3 points or 300, and no evidence adds nothing. A patch of N
   points has N (N + 1) / 2 zeros; where omega exceeds them and the positive scores (a patch
   of two or three points and a large omega) the literal reading would put negative scores
   into W, so a sparse patch would score below a flat one for its lack of points. Here the
   zeros never run out: W_i = max(score, 0) always.
3. *A patch with fewer than two points* has no pair: its matrix is all zeros, R = 0.
4. *R is never negative* (W >= 0, upsilon > 0), so ``R^zeta`` of eq. (5) is always real; the
   code still applies the signed power ``sign(R) |R|^zeta``, equal to it for R >= 0.
   A term of eq. (4) beyond float32's range saturates to +-inf. A penalty of +inf makes
   Delta -inf: the pair weighs nothing, the limit of an ever larger penalty. Any other
   non-finite score (a height of +inf, a negative weight's -inf penalty, NaN from a
   non-finite feature or from +inf less +inf) is not an absent pair: it makes R
   non-finite, and the learner rejects such parameters.
5. *Exponents* a2, a4, a6, a8, a10 must be positive: ``|0|^a`` is infinite for a <= 0 (two
   points at the same height, or a still vehicle). With ``a > 0``, ``|0|^a = 0``.
6. *Where mu sits* between two adjacent R_combined values is decided by the learner
   (:mod:`toolkit.model.ascent`): at their midpoint.

Computation: ``Delta`` is evaluated as ``exp(a * log|d|)`` over precomputed logarithms of the
pair differences (:class:`PairTable`), in float32, a chunk of patches at a time on two
threads (numpy releases the GIL), in one fixed order: the height term ``a1 |dz|^a2`` less
the penalties (time, distance, roll rate, pitch rate) summed, the penalty set to +inf for
a pair with a padding point. Only patches with a positive score are partitioned for
their largest entries (:func:`top_w`): most have none. During the search the table keeps
the height term and the penalty sum of the current point and of the latest candidate
(:meth:`PairTable.hold`), so a candidate recomputes only the part it changes; changing
upsilon, omega or zeta reuses the sorted top scores (the learner caches them).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.model.patches import TyrePatches

Float32Array = NDArray[np.float32]

N_ALPHA = 10
#: The alphas with the optional look-ahead term (beyond the paper): a11, a12.
N_ALPHA_LEAD = 12
#: Index of each alpha that is an exponent (0-based: a2, a4, a6, a8, a10, and a12).
EXPONENTS = (1, 3, 5, 7, 9, 11)
#: Patches per chunk of the vectorised score (keeps each chunk's ~10 temporaries in cache).
CHUNK_GROUPS = 512
#: Patches whose pairs :class:`Blockwise` holds at once (~40 MB of pairs at 40 points a tyre).
BLOCK_GROUPS = 8 * CHUNK_GROUPS
THREADS = 2


def _saturating() -> np.errstate:
    """Where a term of eq. (4) is computed: a term beyond float32's range (|d|^a above
    3.4e38) saturates to +-inf without a warning, as decision 4 of the module docstring
    reads it (a penalty of +inf makes the pair absent; a height of +inf, or +inf less +inf =
    NaN, makes R non-finite, which the learner rejects). An invalid operation still warns.

    A new context each time, entered in the function that computes: numpy's error state is
    per thread (the scoring threads), and one errstate object is not reentrant."""
    return np.errstate(over="ignore")


@dataclass(frozen=True)
class RoughnessParams:
    """The 14 parameters of sect. 4: alpha_1..alpha_10 (eq. 4), upsilon, omega (eq. 3),
    zeta (eq. 5) and the threshold mu."""

    alpha: tuple[float, ...]
    upsilon: float
    omega: int
    zeta: float
    mu: float

    def vector(self) -> tuple[float, ...]:
        """The 13-vector B of sect. 6: (alpha_1..alpha_10, upsilon, omega, zeta); 15 with
        the look-ahead term's alpha_11 and alpha_12."""
        return (*self.alpha, self.upsilon, float(self.omega), self.zeta)

    @classmethod
    def from_vector(cls, b: Sequence[float], mu: float) -> RoughnessParams:
        """From B (13 or 15 elements: the alphas, then upsilon, omega, zeta)."""
        n = len(b) - 3
        return cls(
            tuple(float(v) for v in b[:n]),
            float(b[n]),
            int(round(b[n + 1])),
            float(b[n + 2]),
            float(mu),
        )

    def admissible(self) -> bool:
        """Whether eqs. (3)-(5) are defined: exponents, upsilon and zeta positive, omega at
        least 1, everything finite (see the module docstring, decision 5)."""
        finite = all(math.isfinite(v) for v in (*self.alpha, self.upsilon, self.zeta))
        return (
            finite
            and len(self.alpha) in (N_ALPHA, N_ALPHA_LEAD)
            and all(self.alpha[i] > 0.0 for i in EXPONENTS if i < len(self.alpha))
            and self.upsilon > 0.0
            and self.zeta > 0.0
            and self.omega >= 1
        )

    def to_json(self) -> dict[str, object]:
        return {
            "alpha": list(self.alpha),
            "upsilon": self.upsilon,
            "omega": self.omega,
            "zeta": self.zeta,
            "mu": self.mu,
        }


class TopScores(Protocol):
    """Anything that gives, per patch, its k largest pair scores: the model's Delta
    (:class:`PairTable`) or the baseline's (:mod:`toolkit.model.baseline`)."""

    @property
    def groups(self) -> int: ...

    def top_scores(self, alpha: Sequence[float], k: int) -> FloatArray:
        """(G, k) each patch's k largest entries of W: ``max(score, 0)``, descending, 0
        where a patch has fewer than k positive scores (:func:`top_w`)."""
        ...

    def hold(self, alpha: Sequence[float] | None) -> None:
        """A hint from the search: ``alpha`` is its current point, the next calls differ
        from it in one element (None: the search is over). Sources may cache by it."""
        ...


def _log_abs(d: FloatArray) -> Float32Array:
    with np.errstate(divide="ignore"):
        return np.log(np.abs(d)).astype(np.float32)


class PairTable:
    """Every pair below the diagonal of each patch's S, as logarithms of its differences.

    For a patch of ``n_max`` padded points the pairs are ``(r, c) = np.tril_indices(n_max,
    -1)`` (``r > c``), P = n_max (n_max - 1) / 2 of them, the same for every patch; a pair
    with a padding point is invalid. Arrays: ``log_dz``, ``log_dtau``, ``log_dxy`` (G, P)
    float32 (``log 0 = -inf``, which ``exp(a * -inf) = 0`` turns into ``|0|^a = 0`` for
    a > 0); ``log_gamma``, ``log_psi`` (G, n_max) float32; ``pair_valid`` (G, P) bool.
    Memory: about 13 bytes a pair (the 10-mile race's training half: ~9 M pairs at the
    default 40 points a tyre, ~120 MB), and up to 16 more while a search holds a point
    (:meth:`hold`). The pair logarithms are -inf for a pair with a padding point (no term).
    """

    def __init__(self, patches: TyrePatches) -> None:
        r, c = np.tril_indices(patches.n_max, -1)
        self.r = r.astype(np.intp)
        self.c = c.astype(np.intp)
        shape = (patches.groups, self.r.size)
        self.pair_valid = np.empty(shape, bool)
        self.log_dz = np.empty(shape, np.float32)
        self.log_dtau = np.empty(shape, np.float32)
        self.log_dxy = np.empty(shape, np.float32)
        # A chunk of patches at a time: the float64 differences of all pairs at once would
        # be (G, P) x 8 bytes each (347 MB on a 60-minute log), up to three alive together.
        for lo in range(0, patches.groups, CHUNK_GROUPS):
            rows = slice(lo, lo + CHUNK_GROUPS)
            self.pair_valid[rows] = patches.valid[rows][:, self.r] & patches.valid[rows][:, self.c]
            # A pair with a padding point has no terms (every |0|^a = 0): its Delta is then
            # 0 - inf = -inf exactly (the penalty is +inf there, :meth:`_penalty`). Its
            # logarithms are -inf, not those of a real point less the padding's 0, which
            # overflow float32 (tau is a raw clock: |1.7e9 s|^a4 for a4 above 4.2).
            padding = ~self.pair_valid[rows]
            dxy = np.hypot(self._diff(patches.x[rows]), self._diff(patches.y[rows]))
            for name, diff in (
                ("log_dz", self._diff(patches.z[rows])),
                ("log_dtau", self._diff(patches.tau[rows])),
                ("log_dxy", dxy),
            ):
                logs = _log_abs(diff)
                logs[padding] = -np.inf
                getattr(self, name)[rows] = logs
        self.log_gamma = _log_abs(patches.gamma)
        self.log_psi = _log_abs(patches.psi)
        # Without look-ahead times the term cannot be asked for (it would read -inf logs).
        self.log_lead = None if patches.lead is None else _log_abs(patches.lead)
        self._groups = patches.groups
        self._held: tuple[tuple[object, ...], tuple[object, ...]] | None = None
        self._cache: dict[tuple[object, ...], Float32Array] = {}

    #: The arrays with a row per patch, which :meth:`take` and :meth:`join` carry.
    _ROWS = ("pair_valid", "log_dz", "log_dtau", "log_dxy", "log_gamma", "log_psi", "log_lead")

    def _with_rows(self, rows: Callable[[str], Any]) -> PairTable:
        """A table of the same pairs whose per-patch arrays are ``rows(name)``."""
        out = object.__new__(PairTable)
        out.r, out.c = self.r, self.c
        for name in self._ROWS:
            setattr(out, name, rows(name))
        out._groups = int(out.pair_valid.shape[0])
        out._held, out._cache = None, {}
        return out

    def take(self, groups: IntArray) -> PairTable:
        """The patches ``groups`` (in that order): what :class:`PairTable` of those patches
        is, without computing their pairs again."""
        index = np.asarray(groups, np.intp)
        return self._with_rows(
            lambda n: None if getattr(self, n) is None else getattr(self, n)[index]
        )

    def join(self, other: PairTable) -> PairTable:
        """This table's patches, then ``other``'s (both of patches of ``n_max`` points)."""
        if other.r.size != self.r.size or (self.log_lead is None) != (other.log_lead is None):
            raise ValueError("pair tables of different patch sizes or terms cannot be joined")

        def both(name: str) -> Any:
            a, b = getattr(self, name), getattr(other, name)
            return None if a is None else np.concatenate([a, b])

        return self._with_rows(both)

    def _diff(self, values: FloatArray) -> FloatArray:
        """(g, P) ``values[:, r] - values[:, c]`` for every pair of (g, n_max) ``values``."""
        out: FloatArray = values[:, self.r] - values[:, self.c]
        return out

    @property
    def groups(self) -> int:
        return self._groups

    @property
    def pairs(self) -> int:
        """Pairs per patch, padding included (P)."""
        return int(self.r.size)

    def hold(self, alpha: Sequence[float] | None) -> None:
        """Keep the terms of ``alpha`` (the search's current point), or None to let go.

        Coordinate ascent scores candidates that differ from its current point in one
        element of B: one term of eq. (4) changes, the others stay. While a point is held,
        the table caches, for it and for the latest candidate, the height term
        ``a1 |dz|^a2`` and the sum of the penalty terms, so a candidate that moves a1 or a2
        recomputes one term and one that moves a penalty recomputes the penalties alone.
        The cache costs 16 bytes a pair between calls (4 arrays of float32; up to 24 during
        a call) and is skipped beyond :data:`CACHE_BYTES`; scores are the same with or
        without it, bit for bit (the same operations on the same arrays). A call that moves
        more than one term from the held point is scored right, only with less reuse."""
        if alpha is None or self.groups * self.pairs * 16 > CACHE_BYTES:
            self._held = None
            self._cache = {}
            return
        self._held = _term_keys(alpha)

    def delta(self, alpha: Sequence[float], rows: slice = slice(None)) -> Float32Array:
        """Eq. (4) for every pair of the patches ``rows``: (g, P) float32, -inf for pairs
        with a padding point. Computed as ``height - penalty`` (:meth:`_height`,
        :meth:`_penalty`), the order every path takes."""
        a = [np.float32(v) for v in alpha]
        height = self._height(a, rows)
        penalty = self._penalty(a, rows)
        return self._combine(height, penalty)

    def _height(self, a: list[np.float32], rows: slice) -> Float32Array:
        """(g, P) ``a1 |dz|^a2``; beyond float32's range it is +-inf (:func:`_saturating`)."""
        with _saturating():
            out: Float32Array = a[0] * np.exp(a[1] * self.log_dz[rows])
        return out

    def _penalty(self, a: list[np.float32], rows: slice) -> Float32Array:
        """(g, P) the terms eq. (4) subtracts, summed in a fixed order (time, distance, roll
        rate, pitch rate; those with a zero weight left out), and +inf for a pair with a
        padding point, so that Delta is -inf there (an absent pair) whatever the terms. A term
        beyond float32's range is +-inf (:func:`_saturating`)."""
        total: Float32Array = np.zeros(self.log_dz[rows].shape, np.float32)
        with _saturating():
            if a[2] != 0.0:
                total += a[2] * np.exp(a[3] * self.log_dtau[rows])
            if a[4] != 0.0:
                total += a[4] * np.exp(a[5] * self.log_dxy[rows])
        # The per-point terms (rates, and the look-ahead with 12 alphas): |gamma|^a8 once
        # per point, then summed per pair.
        per_point = [(a[6], a[7], self.log_gamma), (a[8], a[9], self.log_psi)]
        if len(a) == N_ALPHA_LEAD:
            if self.log_lead is None:
                raise ValueError("the look-ahead term needs the patches' lead times")
            per_point.append((a[10], a[11], self.log_lead))
        for w, e, logs in per_point:
            if w != 0.0:
                with _saturating():
                    per_point = w * np.exp(e * logs[rows])
                pair = per_point[:, self.r]
                pair += per_point[:, self.c]
                total += pair
        # Set last, not summed onto, so that it holds whatever a term is (a negative weight
        # with an overflowing term would make inf - inf = NaN).
        total[~self.pair_valid[rows]] = np.inf
        return total

    @staticmethod
    def _combine(height: Float32Array, penalty: Float32Array) -> Float32Array:
        """Eq. (4): the height term less the penalties (-inf for an absent pair)."""
        d: Float32Array = height - penalty
        return d

    def _top_chunk(self, alpha: Sequence[float], k: int, rows: slice) -> FloatArray:
        return top_w(self.delta(alpha, rows), k)

    def top_scores(self, alpha: Sequence[float], k: int) -> FloatArray:
        """(G, k) float64: each patch's k largest ``max(Delta, 0)``, descending
        (:func:`top_w`)."""
        chunks = [
            slice(i, min(i + CHUNK_GROUPS, self._groups))
            for i in range(0, self._groups, CHUNK_GROUPS)
        ]
        if not chunks:
            return np.zeros((0, k))
        work = self._top_chunk if self._held is None else self._cached_chunker(alpha)
        pool = scoring_threads()
        if pool is None:
            parts = [work(alpha, k, s) for s in chunks]
        else:
            parts = list(pool.map(lambda s: work(alpha, k, s), chunks))
        if self._held is not None:
            self._keep_only({*self._held, *_term_keys(alpha)})
        return np.concatenate(parts, axis=0)

    def _cached_chunker(
        self, alpha: Sequence[float]
    ) -> Callable[[Sequence[float], int, slice], FloatArray]:
        """The chunk worker while a point is held: each of the height and the penalty taken
        from the cache, or computed and stored in a new whole-table array (each chunk fills
        its rows; the threads write disjoint rows)."""
        a = [np.float32(v) for v in alpha]
        height_key, penalty_key = _term_keys(alpha)
        height_all = self._cache.get(height_key)
        new_height = height_all is None
        if height_all is None:
            height_all = np.empty((self._groups, self.pairs), np.float32)
            self._cache[height_key] = height_all
        penalty_all = self._cache.get(penalty_key)
        new_penalty = penalty_all is None
        if penalty_all is None:
            penalty_all = np.empty_like(height_all)
            self._cache[penalty_key] = penalty_all

        def work(_: Sequence[float], k: int, rows: slice) -> FloatArray:
            if new_height:
                height_all[rows] = self._height(a, rows)
            if new_penalty:
                penalty_all[rows] = self._penalty(a, rows)
            return top_w(self._combine(height_all[rows], penalty_all[rows]), k)

        return work

    def _keep_only(self, wanted: set[tuple[object, ...]]) -> None:
        """Drop the cached arrays but those of ``wanted``: the held point's and the latest
        call's height and penalty keys."""
        for key in list(self._cache):
            if key not in wanted:
                del self._cache[key]


#: Largest cache a :class:`PairTable` keeps for the search (:meth:`PairTable.hold`), bytes:
#: 16 bytes a pair, so up to ~130 M pairs (~6 hours of race at 40 points a tyre).
CACHE_BYTES = 2 << 30


def _term_keys(alpha: Sequence[float]) -> tuple[tuple[object, ...], tuple[object, ...]]:
    """The cache keys of eq. (4)'s height term and of its penalty terms for ``alpha``: the
    float32 values they are computed from, tagged."""
    a = [float(np.float32(v)) for v in alpha]
    # A term with no weight is left out, whatever its exponent.
    penalty = [(a[i], a[i + 1]) if a[i] != 0.0 else None for i in range(2, len(a), 2)]
    return ("height", a[0], a[1]), ("penalty", *penalty)


#: This process's scoring threads, by process id (:func:`scoring_threads`).
_THREADS_OF: dict[int, ThreadPoolExecutor] = {}


def scoring_threads() -> ThreadPoolExecutor | None:
    """The threads every :class:`PairTable` of this process scores its chunks on (None with
    one :data:`THREADS`: the calling thread), made on first use. A child forked to train
    rows beside this process (evaluate) makes its own: a pool's threads are not forked with
    it, and one inherited would wait for them for ever."""
    if THREADS <= 1:
        return None
    pid = os.getpid()
    pool = _THREADS_OF.get(pid)
    if pool is None:
        _THREADS_OF.clear()  # a parent's, in a forked child: its threads are not here
        pool = _THREADS_OF[pid] = ThreadPoolExecutor(THREADS, thread_name_prefix="pairs")
    return pool


class Blockwise:
    """Top scores of patches too many to hold all their pairs at once.

    Each block of ``block_groups`` patches is turned into its pair scores by ``make`` (for
    the model, :class:`PairTable`) when :meth:`top_scores` is asked, and let go before the
    next: memory is one block's pairs whatever the number of patches, at the price of
    building the pairs on every call. The scores are the same as ``make(patches)``'s: every
    patch's pairs are computed from its own points alone. For scoring once (every event of
    a split, one parameter set); the learner, which asks hundreds of times, holds its
    training pairs whole.
    """

    def __init__(
        self,
        patches: TyrePatches,
        make: Callable[[TyrePatches], TopScores],
        block_groups: int = BLOCK_GROUPS,
    ) -> None:
        self.patches = patches
        self.make = make
        self.block_groups = block_groups

    @property
    def groups(self) -> int:
        return self.patches.groups

    def hold(self, alpha: Sequence[float] | None) -> None:
        """Nothing to keep: every call builds its blocks afresh."""

    def top_scores(self, alpha: Sequence[float], k: int) -> FloatArray:
        """(G, k) float64, as :meth:`TopScores.top_scores`."""
        parts = [
            self.make(self.patches.take(slice(lo, lo + self.block_groups))).top_scores(alpha, k)
            for lo in range(0, self.groups, self.block_groups)
        ]
        return np.concatenate(parts, axis=0) if parts else np.zeros((0, k))


def model_pairs(patches: TyrePatches) -> Blockwise:
    """The model's pair scores of ``patches``, built block by block."""
    return Blockwise(patches, PairTable)


def top_k_desc(scores: Float32Array | FloatArray, k: int) -> FloatArray:
    """(g, k) float64: the k largest of each row of ``scores`` (g, P), descending, padded
    with -inf when P < k."""
    g, p = scores.shape
    if k >= p:
        top = np.sort(scores, axis=1)[:, ::-1]
        pad = np.full((g, k - p), -np.inf)
        return np.concatenate([top.astype(np.float64), pad], axis=1)
    part = np.partition(scores, p - k, axis=1)[:, p - k :]
    return np.sort(part, axis=1)[:, ::-1].astype(np.float64)


def top_w(scores: Float32Array | FloatArray, k: int) -> FloatArray:
    """(g, k) float64: the k largest of ``max(score, 0)`` in each row of ``scores`` (g, P),
    descending: W's top entries (decision 2: the mask's zeros outrank negative scores and
    fill ranks without a pair). NaN stays NaN (it sorts above every number).

    Few patches hold a positive score (measured on race logs: 3-15 % of them, 0.1-0.8 % of
    the pairs), and a row with none is all zeros: only the rows with a positive (or NaN)
    score are partitioned: 0.28 ms a chunk of 512 patches against :func:`top_k_desc`'s
    0.69 ms on all of them (measured on a race log's training pairs)."""
    g = scores.shape[0]
    out = np.zeros((g, k))
    if g == 0 or scores.shape[1] == 0:
        return out
    # ``not (max <= 0)``: True for a positive maximum and for NaN.
    rows = np.flatnonzero(~(scores.max(axis=1) <= 0.0))
    if rows.size:
        out[rows] = np.maximum(top_k_desc(scores[rows], k), 0.0)
    return out


def total_score(top_desc: FloatArray, upsilon: float, omega: int) -> FloatArray:
    """Eq. (3): R (G,) from each patch's scores ranked from the top (G, >= omega).

    The j-th largest (j = 0, 1, ...) is ``W_{omega-1-j}`` and weighs ``upsilon^(omega-1-j)``;
    the mask's zeros outrank negative scores and fill ranks without a pair (-inf), so each
    entry of W is ``max(score, 0)`` (module docstring, decisions 1-3); NaN stays NaN."""
    w = np.maximum(top_desc[:, :omega], 0.0)
    weights = float(upsilon) ** np.arange(omega - 1, -1, -1, dtype=np.float64)
    # Summed rank by rank, not with ``w @ weights``: a BLAS dot product may add in an order
    # that depends on where the array sits in memory, and then the same scores differ in
    # their last bit from one run to the next (seen in evaluate's ablations).
    r = np.zeros(w.shape[0])
    for j in range(w.shape[1]):
        r += w[:, j] * weights[j]
    return r


def signed_power(r: FloatArray, zeta: float) -> FloatArray:
    """``sign(R) |R|^zeta`` (decision 4)."""
    return np.sign(r) * np.abs(r) ** zeta


def combine(r_group: FloatArray, zeta: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eq. (5): (R_left, R_right, R_combined), each (E,), from R per patch (2E,) ordered
    event by event, left then right."""
    r_lr = r_group.reshape(-1, 2)
    r_left, r_right = r_lr[:, 0], r_lr[:, 1]
    return r_left, r_right, signed_power(r_left, zeta) + signed_power(r_right, zeta)


@dataclass(frozen=True)
class EventScores:
    """The model's verdict per event (E,): R_left, R_right, R_combined and R_combined > mu."""

    r_left: FloatArray
    r_right: FloatArray
    r_combined: FloatArray
    predicted: NDArray[np.bool_]


def score_events(source: TopScores, params: RoughnessParams) -> EventScores:
    """Eqs. (2)-(5) and the threshold for every event of ``source``."""
    top = source.top_scores(params.alpha, params.omega)
    r_left, r_right, r_comb = combine(total_score(top, params.upsilon, params.omega), params.zeta)
    return EventScores(r_left, r_right, r_comb, r_comb > params.mu)


__all__ = [
    "EXPONENTS",
    "N_ALPHA",
    "N_ALPHA_LEAD",
    "BLOCK_GROUPS",
    "CACHE_BYTES",
    "Blockwise",
    "THREADS",
    "EventScores",
    "PairTable",
    "RoughnessParams",
    "TopScores",
    "combine",
    "model_pairs",
    "scoring_threads",
    "score_events",
    "signed_power",
    "top_k_desc",
    "top_w",
    "total_score",
]
