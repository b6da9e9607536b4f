"""The project stage's reading and writing of 3-D lidar returns (the arithmetic is
:mod:`toolkit.model.lidar_projection`'s).

The ``lidar`` table (:mod:`toolkit.ingestion.lidar`) is read in time order, a batch of
:data:`RETURN_BATCH` returns at a time, so a long log is never whole in memory; each batch
becomes :class:`~toolkit.model.lidar_projection.Returns`, then a table of the points schema's
columns with the lidar's topic as the laser and its ring as the beam (and as ``ring``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit.geometry.mounts import Mount
from toolkit.model.lidar_projection import (
    PreparedReturns,
    Returns,
    ScanClock,
    prepare_returns,
    project_returns,
)
from toolkit.model.projection import Counts
from toolkit.stages.project_scans import PoseStream, points_batch
from toolkit.tableio import iter_table_batches

#: Returns per read batch: about a second of a 32-beam lidar at 10 Hz (~30 MB of arrays in
#: flight), as many points as a batch of the lasers' scans.
RETURN_BATCH = 400_000
#: The lidar table's columns projection reads.
LIDAR_COLUMNS = ["t_ns", "scan_t_ns", "lidar", "frame_id", "ring", "x", "y", "z"]


def lidar_batches(lidar_path: Path) -> Iterator[pa.RecordBatch]:
    """The lidar table's :data:`LIDAR_COLUMNS`, :data:`RETURN_BATCH` rows at a time."""
    return iter_table_batches(lidar_path, "lidar", columns=LIDAR_COLUMNS, batch_rows=RETURN_BATCH)


def returns_of(batch: pa.RecordBatch) -> Returns:
    """A record batch of the lidar table as :class:`Returns`."""
    lidar_code, lidar_names = _codes(batch.column("lidar"))
    frame_code, frame_names = _codes(batch.column("frame_id"))
    ring = pc.fill_null(pc.cast(batch.column("ring"), pa.int32()), -1)
    return Returns(
        t_ns=np.asarray(batch.column("t_ns").to_numpy(), np.int64),
        scan_t_ns=np.asarray(batch.column("scan_t_ns").to_numpy(), np.int64),
        lidar_code=lidar_code,
        lidar_names=lidar_names,
        frame_code=frame_code,
        frame_names=frame_names,
        ring=np.asarray(ring.to_numpy(zero_copy_only=False), np.int32),
        p_lidar=np.stack([np.asarray(batch.column(a).to_numpy(), np.float64) for a in "xyz"]),
    )


def _codes(column: pa.Array) -> tuple[NDArray[np.int64], list[str]]:
    """A string (or dictionary) column as codes into its distinct values (null is "")."""
    if not pa.types.is_dictionary(column.type):
        column = pc.dictionary_encode(column)
    values = [str(v or "") for v in column.dictionary.to_pylist()]
    return np.asarray(column.indices.to_numpy(zero_copy_only=False), np.int64), values


def lidar_frames(lidar_path: Path) -> list[str]:
    """The distinct frames of the returns (one small dictionary column read)."""
    frames: set[str] = set()
    for batch in iter_table_batches(lidar_path, "lidar", columns=["frame_id"], batch_rows=1 << 20):
        frames.update(str(f or "") for f in pc.unique(batch.column("frame_id")).to_pylist())
    return sorted(frames)


class LidarSource:
    """What the project stage's batch loop needs of the returns: the batches, their
    sequential preparation (the pose stream, each lidar's scans) and their projection (a pure
    function, on a worker thread)."""

    def __init__(self, lidar_path: Path, mounts: dict[str, Mount], poses: PoseStream) -> None:
        self.batches = lidar_batches(lidar_path)
        self._mounts = mounts
        self._poses = poses
        self._clock = ScanClock()

    def prepare(self, batch: pa.RecordBatch) -> PreparedReturns:
        return prepare_returns(returns_of(batch), self._mounts, self._clock, self._poses.window)

    @staticmethod
    def project(prepared: PreparedReturns) -> tuple[pa.Table, Counts]:
        chunks, counts = project_returns(prepared)
        return points_table(chunks, prepared.returns.lidar_names), counts


def scanner_name(lidar: str, ring: int) -> str:
    """The name a ring of a lidar goes by as the points' ``laser``: ``"/ouster/points ring 5"``
    (the lidar's topic alone for a cloud without rings)."""
    return lidar if ring < 0 else f"{lidar} ring {ring}"


def _scanners(ch: dict[str, NDArray[Any]], lidar_names: list[str]) -> pa.DictionaryArray:
    """Each point's ring of its lidar as the ``laser`` column: codes into the chunk's few
    (lidar, ring) names. A ring of a spinning lidar sweeps a cone as one of Stanley's lasers
    sweeps its line, so everything the lasers are ranked and compared by (the nearest laser
    first in a patch, the race test's closest laser, Fig. 4 and the z error by laser) takes
    the rings one by one."""
    # One key per (lidar, ring); ring -1 (none) keys as 0.
    key = ch["lidar"].astype(np.int64) * 65_536 + (ch["beam"].astype(np.int64) + 1)
    keys, codes = np.unique(key, return_inverse=True)
    names = [scanner_name(lidar_names[int(k) // 65_536], int(k) % 65_536 - 1) for k in keys]
    return pa.DictionaryArray.from_arrays(
        pa.array(codes.astype(np.int32), pa.int32()), pa.array(names, pa.string())
    )


def points_table(chunks: list[dict[str, NDArray[Any]]], lidar_names: list[str]) -> pa.Table:
    """The points of a batch's chunks with the points schema's columns, plus ``ring``; the
    laser of a point is its lidar's ring (:func:`_scanners`)."""
    if not chunks:
        empty: dict[str, NDArray[Any]] = {
            "t_ns": np.zeros(0, np.int64),
            "lidar": np.zeros(0, np.int64),
            "beam": np.zeros(0, np.int32),
            "range": np.zeros(0, np.float32),
            **{c: np.zeros(0) for c in ("x", "y", "z", "roll_rate", "pitch_rate", "scan_dt_s")},
            "scan_t_ns": np.zeros(0, np.int64),
        }
        chunks = [empty]
    return pa.Table.from_batches(
        [
            points_batch(ch, _scanners(ch, lidar_names), ring=pa.array(ch["beam"], pa.int32()))
            for ch in chunks
        ]
    )


__all__ = ["LIDAR_COLUMNS", "LidarSource", "lidar_frames", "points_table", "returns_of"]
