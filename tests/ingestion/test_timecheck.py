"""Time outliers: small groups of rows cut off from a table's ends by a long gap."""

from __future__ import annotations

import numpy as np

from toolkit.ingestion.timecheck import time_outliers

NS = 1_000_000_000


def test_time_outliers_rule() -> None:
    t = np.arange(10_000, dtype=np.int64) * 10_000_000  # 100 s at 100 Hz
    assert not time_outliers(t).any()
    far = np.concatenate([[t[0] - 120 * NS], t, [t[-1] + 120 * NS] * 3])
    drop = time_outliers(far)
    assert drop[0] and drop[-3:].all() and drop.sum() == 4  # limit is max(2, 10) rows
    # A long gap with plenty of data on both sides is a gap, not an outlier.
    halves = np.concatenate([t, t + 200 * NS])
    assert not time_outliers(halves).any()
