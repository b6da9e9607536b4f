"""Fixed-bin histograms of the analyses (Fig. 4, the z error): how many bins cover a range,
and a quantile read from the counts, exact to the bin and linear within it."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def bins_covering(span: float, width: float) -> int:
    """Bins of ``width`` covering ``[0, span)``: ``ceil(span / width)``, at least one (the
    last may reach past ``span``; a ratio within 1e-9 of a whole number counts as whole, so
    round-off in ``span / width`` adds no bin)."""
    return max(1, math.ceil(span / width - 1e-9))


def histogram_quantile(
    hist: NDArray[np.int64],
    q: float,
    first_edge: float,
    width: float,
    *,
    open_low: bool = True,
    open_high: bool = True,
) -> float:
    """Quantile ``q`` of values counted in ``hist`` (K,), bin k covering
    ``[first_edge + k width, first_edge + (k + 1) width)``, linear within a bin. An open end
    bin (everything below / above) reports its inner edge: the quantile is known only to lie
    beyond it. NaN for an empty histogram."""
    total = int(hist.sum())
    if total == 0:
        return math.nan
    target = q * total
    cum = np.cumsum(hist)
    k = min(int(np.searchsorted(cum, target, side="left")), hist.size - 1)
    if open_high and k == hist.size - 1 and hist.size > 1:
        return float(first_edge + k * width)
    if open_low and k == 0 and hist.size > 1:
        return float(first_edge + width)
    prev = int(cum[k - 1]) if k else 0
    frac = (target - prev) / hist[k] if hist[k] else 0.0
    return float(first_edge + (k + frac) * width)


__all__ = ["bins_covering", "histogram_quantile"]
