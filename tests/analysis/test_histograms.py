"""Fixed-bin histograms: the bins covering a range, and quantiles with open ends."""

from __future__ import annotations

import math

import numpy as np
import pytest

from toolkit.analysis.histograms import bins_covering, histogram_quantile


def test_histogram_quantiles_and_open_ends() -> None:
    hist = np.array([0, 2, 2, 0], np.int64)  # values in [1, 3) of width-1 bins from 0
    assert histogram_quantile(hist, 0.5, 0.0, 1.0) == pytest.approx(2.0)
    assert histogram_quantile(np.array([5, 1, 0]), 0.5, -1.0, 1.0) == 0.0  # open low end
    assert histogram_quantile(np.array([0, 1, 5]), 0.5, 0.0, 1.0) == 2.0  # open high end
    assert math.isnan(histogram_quantile(np.zeros(3, np.int64), 0.5, 0.0, 1.0))


def test_bins_covering_a_range() -> None:
    assert bins_covering(2.1, 0.3) == 7  # 2.1 / 0.3 = 7.000000000000001: no extra bin
    assert bins_covering(1.05, 0.1) == 11
    assert bins_covering(0.01, 0.1) == 1
