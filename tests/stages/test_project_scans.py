"""The project stage's reading: the pose table streamed alongside the scans."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from toolkit.errors import StageError
from toolkit.stages.project_scans import PoseStream
from toolkit.tableio import load_table_schema
from toolkit.tableio import write_table as write


def test_the_pose_stream_serves_requests_that_reach_back_a_little() -> None:
    """Windows asked in time order may start up to 1 s before the previous one (beam times of
    a scan with a negative time_increment): the rows are still there; further back is an
    out-of-order log, one line."""
    t = np.arange(0, 5_000_000_000, 10_000_000, dtype=np.int64)
    cols = {c.name: pa.array(np.zeros(t.size)) for c in load_table_schema("pose").columns}
    cols["t_ns"] = pa.array(t)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "pose.parquet"
        write(path, pa.table(cols), "pose", source_sha256="0" * 64, config_hash="c")
        stream = PoseStream(path)
        first = stream.window(2_000_000_000, 2_100_000_000)
        assert first.t_ns[0] <= 2_000_000_000 and first.t_ns[-1] >= 2_100_000_000
        back = stream.window(1_500_000_000, 1_600_000_000)
        assert back.t_ns[0] <= 1_500_000_000 and back.t_ns[-1] >= 1_600_000_000
        with pytest.raises(StageError, match="not in time order"):
            stream.window(500_000_000, 600_000_000)
