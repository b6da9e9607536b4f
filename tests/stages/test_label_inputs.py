"""The label stage's streamed inputs: the IMU's rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from toolkit.stages.label_inputs import imu_period_ns


def test_the_imu_rate_of_jittered_stamps_is_unbiased(tmp_path: Path) -> None:
    """100 Hz stamps with +-2 ms uniform jitter and a few gaps: 100 Hz within 0.05 %."""
    import pyarrow as pa

    from toolkit.tableio import write_table

    rng = np.random.default_rng(5)
    t = np.arange(20_000, dtype=np.int64) * 10_000_000 + rng.integers(-2_000_000, 2_000_001, 20_000)
    t = np.sort(np.delete(t, np.arange(500, 20_000, 1_000)))  # gaps of two periods
    zeros = np.zeros(t.size)
    from toolkit.tableio import load_table_schema

    cols = {"t_ns": t, **{f"{q}_{a}": zeros for q in ("accel", "gyro") for a in "xyz"}}
    schema = load_table_schema("imu")
    for c in schema.columns:  # the orientation the IMU does not report: nulls
        if c.name not in cols:
            cols[c.name] = pa.nulls(t.size, c.arrow_type())
    table = pa.table(cols)
    path = tmp_path / "imu.parquet"
    write_table(path, table, "imu", source_sha256="0" * 64, config_hash="c")
    assert 1e9 / imu_period_ns(path) == pytest.approx(100.0, rel=5e-4)
