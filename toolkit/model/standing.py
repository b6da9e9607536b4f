"""Standings: the scores of different model versions made comparable (sect. 8's online
learning, :mod:`toolkit.model.online`).

A version's score of an event is ranked against a *reference* of smooth labelled events
scored by the same version: its standing is the share of them below it (ties half), an
estimate of the false-positive rate a cut just below it would have. The reference is a
sample spread over every smooth label known so far on the drive: every ``stride``-th in the
order known, the stride the least power of two leaving at most ``reference_smooth`` events
(:func:`reference_of`); :class:`Reference` keeps it, and its events' pairs, as the labels
come. With ``reference_smooth = 0`` it is the learner's buffer's smooth events instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit.arrays import FloatArray, IntArray
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import PairTable


def event_groups(events: IntArray) -> IntArray:
    """Event indices (N,) -> their patches' group indices (2N,), left then right."""
    return np.stack([2 * events, 2 * events + 1], axis=1).reshape(-1)


def reference_stride(known: int, size: int) -> int:
    """The least power of two ``s`` such that every ``s``-th of ``known`` events is at most
    ``size`` events (1 for none)."""
    stride = 1
    while -(-known // stride) > size:
        stride *= 2
    return stride


def reference_of(smooth_known: IntArray, reference_smooth: int, buffer_smooth: int) -> IntArray:
    """The standings' reference (module docstring) among ``smooth_known``, the smooth events
    known so far in the order known: every stride-th from the first, or with
    ``reference_smooth = 0`` the buffer's (the latest ``buffer_smooth``)."""
    if reference_smooth == 0:
        return smooth_known[-buffer_smooth:]
    return smooth_known[:: reference_stride(smooth_known.size, reference_smooth)]


@dataclass(frozen=True)
class Reference:
    """The smooth events standings rank against (module docstring): their indices in the
    stream (in the order known) and pairs, and how many smooth labels are known so far.
    Grows with the labels as :func:`reference_of` says, without the labels' list: when the
    stride doubles every other event kept is dropped."""

    index: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    known: int = 0
    pairs: PairTable | None = None

    @classmethod
    def of(cls, patches: TyrePatches, index: IntArray, known: int) -> Reference:
        """A reference of these events (a resumed replay's), their pairs computed."""
        return cls(index, known, PairTable(patches) if index.size else None)

    def add(self, patches: TyrePatches, index: IntArray, size: int) -> Reference:
        """The reference once the smooth events ``index`` (in the order known; their
        patches) are known too, at most ``size`` events."""
        known = self.known + index.size
        stride = reference_stride(known, size)
        kept = np.flatnonzero(
            (np.arange(self.index.size) * reference_stride(self.known, size)) % stride == 0
        )
        new = np.flatnonzero((self.known + np.arange(index.size)) % stride == 0)
        pairs = None if self.pairs is None else self.pairs.take(event_groups(kept))
        if new.size:
            fresh = PairTable(patches.take(event_groups(new)))
            pairs = fresh if pairs is None else pairs.join(fresh)
        return Reference(np.r_[self.index[kept], index[new]].astype(np.int64), known, pairs)


def standing_of(r: FloatArray, reference: FloatArray) -> FloatArray:
    """The share of ``reference`` (sorted) below each of ``r``, ties counted half (NaN
    without a reference)."""
    if reference.size == 0:
        return np.full(r.size, np.nan)
    below = np.searchsorted(reference, r, side="left")
    at_most = np.searchsorted(reference, r, side="right")
    return (below + at_most) / (2.0 * reference.size)


__all__ = ["Reference", "event_groups", "reference_of", "reference_stride", "standing_of"]
