"""What the tableio tests share: provenance values and small tables to write."""

from __future__ import annotations

import pyarrow as pa

SHA = "ab" * 32
CFG = "cd" * 32


def heading_table(n: int = 3) -> pa.Table:
    return pa.table(
        {
            "t_ns": pa.array(range(n), pa.int64()),
            "yaw": pa.array([0.1 * i for i in range(n)], pa.float64()),
            "yaw_std": pa.array([None] * n, pa.float64()),
        }
    )


def heading_rows(t_ns: list[int]) -> pa.Table:
    n = len(t_ns)
    return pa.table({"t_ns": t_ns, "yaw": [0.1] * n, "yaw_std": [0.01] * n})
