"""The pose's accuracy against the simulator's truth (simulated logs only).

The pose stage (:mod:`toolkit.stages.pose`) hands each chunk of pose rows it writes to a
:class:`TruthAccuracy`, which reads the truth table (``truth_pose.parquet``) alongside in
batches (both are time-sorted), interpolates it to the pose's times and keeps only sums of
squares, counts and the error at the end of each GPS dropout: horizontal and vertical RMSE
(m), roll / pitch / yaw RMSE (deg, angles wrapped), the horizontal error at the end of each
dropout and of the log. Without GPS the pose is in a local frame whose origin and zero yaw are
the first pose: the truth is moved into it, so the errors are the dead reckoning's drift.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.arrays import FloatArray
from toolkit.errors import StageError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import move_between_frames
from toolkit.geometry.rotations import wrap_angle
from toolkit.layout import LogFiles
from toolkit.sim.record import SIM_RECORD
from toolkit.tableio import iter_table_batches, read_table, read_table_metadata

#: Rows per truth read batch.
BATCH_ROWS = 4_096


def column(table: pa.Table, name: str) -> FloatArray:
    """A table's column as float64."""
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)


def table_batches(path: Path, table: str, columns: list[str]) -> Iterator[pa.RecordBatch]:
    """Record batches of a table, in file (time) order, :data:`BATCH_ROWS` at a time."""
    return iter_table_batches(path, table, columns=columns, batch_rows=BATCH_ROWS)


def last_t_ns(path: Path) -> int:
    """The last t_ns of a time-sorted table, reading only its last row group."""
    with pq.ParquetFile(path, page_checksum_verification=True) as f:
        rg = f.read_row_group(f.metadata.num_row_groups - 1, columns=["t_ns"])
    return int(rg.column("t_ns")[-1].as_py())


class TruthAccuracy:
    """Errors of the pose against the simulator's truth, accumulated chunk by chunk.

    The truth table is read in batches alongside the pose rows (both are time-sorted); only
    sums of squares, counts and the error at the end of each GPS dropout are kept.
    """

    def __init__(
        self, truth_path: Path, sim: dict[str, Any], origin: GeodeticOrigin | None
    ) -> None:
        """``origin`` None: the pose is in a local frame (no GPS) whose origin and zero yaw
        are the first pose; the truth is then moved into it (translated to its position and
        turned by its yaw at the first pose time), so the errors are the dead-reckoning's
        drift."""
        # The truth's frame: ingest writes it in the pose's frame (its metadata says so);
        # a table without that metadata is still in the simulator's own frame.
        meta = read_table_metadata(truth_path)
        o = json.loads(meta.get("enu_origin") or sim["origin"])
        self.sim_origin = GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"])
        self.origin = origin
        read_table(truth_path, "truth_pose", columns=[])  # checks the contract
        cols = ["t_ns", "x", "y", "z", "roll", "pitch", "yaw"]
        self._batches = table_batches(truth_path, "truth_pose", cols)
        first = next(table_batches(truth_path, "truth_pose", ["t_ns"]))
        self.tt0 = int(first.column(0)[0].as_py())
        self.tr_end = float(last_t_ns(truth_path) - self.tt0)
        self._buf: pa.Table | None = None
        self._exhausted = False
        self.sums = dict.fromkeys(("h", "v", "roll", "pitch", "yaw"), 0.0)
        self.n = 0
        self.t_first: int | None = None
        self.t_last: int | None = None
        self.dropouts = [
            (int(lo), int(hi)) for lo, hi in json.loads(sim.get("gps_dropouts_ns", "[]"))
        ]
        self.drop_err: dict[int, float] = {}
        self.local_ref: tuple[FloatArray, float] | None = None  # truth (xyz, yaw) at start
        self.last_h = 0.0

    def _cover(self, t_hi: int) -> pa.Table:
        """Truth rows from the last one at or before the previous chunk up to >= t_hi."""
        assert self._buf is not None or not self._exhausted
        while not self._exhausted and (
            self._buf is None or int(self._buf.column("t_ns")[-1].as_py()) < t_hi
        ):
            try:
                batch = pa.Table.from_batches([next(self._batches)])
            except StopIteration:
                self._exhausted = True
                break
            self._buf = batch if self._buf is None else pa.concat_tables([self._buf, batch])
        assert self._buf is not None
        return self._buf

    def add(self, t_ns: np.ndarray, cols: dict[str, FloatArray]) -> None:
        if t_ns.size == 0:
            return
        tq = (t_ns - self.tt0).astype(np.float64)
        inside = (tq >= 0.0) & (tq <= self.tr_end)
        if not inside.any():
            return
        truth = self._cover(int(t_ns[inside][-1]))
        tt = np.asarray(truth.column("t_ns").to_numpy(), dtype=np.int64)
        tr = (tt - self.tt0).astype(np.float64)
        tq = tq[inside]
        xyz = np.stack([column(truth, c) for c in "xyz"], axis=1)
        truth_yaw = np.unwrap(column(truth, "yaw"))
        yaw_shift = 0.0
        if self.origin is None:
            if self.local_ref is None:
                t_ref = tq[0]
                p_ref = np.array([np.interp(t_ref, tr, xyz[:, k]) for k in range(3)])
                yaw_ref = float(np.interp(t_ref, tr, truth_yaw))
                self.local_ref = (p_ref, yaw_ref)
            p_ref, yaw_shift = self.local_ref
            c, s_ = np.cos(-yaw_shift), np.sin(-yaw_shift)
            d = xyz - p_ref
            xyz = np.stack([c * d[:, 0] - s_ * d[:, 1], s_ * d[:, 0] + c * d[:, 1], d[:, 2]], 1)
        elif self.sim_origin != self.origin:
            xyz, moved_yaw = move_between_frames(xyz, truth_yaw, self.sim_origin, self.origin)
            truth_yaw = truth_yaw if moved_yaw is None else moved_yaw

        def at(v: FloatArray) -> FloatArray:
            return np.asarray(np.interp(tq, tr, v), dtype=np.float64)

        ex = cols["x"][inside] - at(xyz[:, 0])
        ey = cols["y"][inside] - at(xyz[:, 1])
        eh = np.hypot(ex, ey)
        ez = cols["z"][inside] - at(xyz[:, 2])
        self.sums["h"] += float(np.sum(eh**2))
        self.sums["v"] += float(np.sum(ez**2))
        for name in ("roll", "pitch", "yaw"):
            tv = truth_yaw - yaw_shift if name == "yaw" else np.unwrap(column(truth, name))
            e = wrap_angle(cols[name][inside] - wrap_angle(at(tv)))
            self.sums[name] += float(np.sum(e**2))
        t_abs = t_ns[inside]
        self.last_h = float(eh[-1])
        self.n += int(t_abs.size)
        if self.t_first is None:
            self.t_first = int(t_abs[0])
        self.t_last = int(t_abs[-1])
        for _lo, hi in self.dropouts:
            k = int(np.searchsorted(t_abs, hi)) - 1
            if k >= 0:
                self.drop_err[hi] = float(eh[k])
        # Keep only the truth rows the next chunk can still need.
        keep_from = max(int(np.searchsorted(tt, int(t_abs[-1]), side="right")) - 1, 0)
        self._buf = truth.slice(keep_from)

    def result(self) -> dict[str, Any] | None:
        if self.n == 0 or self.t_first is None or self.t_last is None:
            return None

        def rms(key: str) -> float:
            return float(np.sqrt(self.sums[key] / self.n))

        dropouts = []
        for lo, hi in self.dropouts:
            if lo < self.t_first or hi > self.t_last or hi not in self.drop_err:
                continue
            dropouts.append(
                {
                    "start_ns": int(lo),
                    "duration_s": round((hi - lo) * 1e-9, 3),
                    "horizontal_error_at_end_m": round(self.drop_err[hi], 4),
                }
            )
        return {
            "rows_compared": self.n,
            "horizontal_rmse_m": round(rms("h"), 4),
            "vertical_rmse_m": round(rms("v"), 4),
            "roll_rmse_deg": round(float(np.degrees(rms("roll"))), 4),
            "pitch_rmse_deg": round(float(np.degrees(rms("pitch"))), 4),
            "yaw_rmse_deg": round(float(np.degrees(rms("yaw"))), 4),
            "gps_dropouts": dropouts,
            "horizontal_error_at_end_m": round(self.last_h, 4),
        }


def truth_accuracy(log_dir: Path, origin: GeodeticOrigin | None) -> TruthAccuracy | None:
    """An accumulator against the simulator's truth, or None for a real log."""
    meta_path, truth_path = LogFiles(log_dir).mcap_metadata, LogFiles(log_dir).truth_pose
    if not (meta_path.is_file() and truth_path.is_file()):
        return None
    try:
        sim = json.loads(meta_path.read_text(encoding="utf-8")).get(SIM_RECORD)
        if not sim or "origin" not in sim:
            return None
        return TruthAccuracy(truth_path, sim, origin)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:  # JSONDecodeError too
        raise StageError(
            f"not the simulator metadata ingest writes ({type(exc).__name__}: {exc}); "
            "run `terrain ingest --overwrite` on its log",
            path=meta_path,
        ) from exc


__all__ = ["BATCH_ROWS", "TruthAccuracy", "column", "last_t_ns", "table_batches", "truth_accuracy"]
