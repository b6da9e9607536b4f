"""The figures the project stage makes beside the points, fed batch by batch.

The paper's Fig. 4 (|dz| of two scans of one ground cell against the time between them,
:mod:`toolkit.analysis.scan_agreement`) from the log's own points, and on simulated logs the
points' z error against the true terrain by laser and range
(:mod:`toolkit.analysis.truth_terrain`): both accumulated as the points are made, so the
cloud is never read back.
"""

from __future__ import annotations

import threading
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from toolkit.analysis.fig4 import ScanAgreementResult, write_fig4
from toolkit.analysis.scan_agreement import ScanAgreement
from toolkit.analysis.truth_terrain import (
    TrueGround,
    ZErrorAccumulator,
    true_ground,
    write_z_error,
)
from toolkit.arrays import FloatArray
from toolkit.errors import StageError

#: Fig. 4 is accumulated over the scans of the log's first this-many seconds: all their
#: pairs up to 10 s apart, from one stretch of driving (as the paper's figure is), at a bounded
#: cost (~1 us per point, more than projecting it; ~8 M points here). Sampling windows spread
#: over the whole log instead changed the fitted slope of the sample log from 2.4 to 4.5 cm/s
#: (long-dt pairs lost at every window's edge), so the figure is of one contiguous stretch.
FIG4_SECONDS = 120.0
#: The z error against the true terrain (simulated logs) from every this-many-th point: the
#: route coordinates of a point cost ~1 us (measured: 0.6 s of the projecting threads for
#: the 650 k of a 10-minute log); 1/64 of all the sample log's points gave the same
#: per-laser medians as all of them to within a millimetre.
Z_ERROR_STRIDE = 64
#: ... lying on every this-many-th tile of the simulated terrain (51.2 m of road; ~80 k
#: points for ten minutes of driving, ~470 k for an hour). The terrain is synthesised where
#: it is first asked about (~115 ms for a tile alone, measured, under the lock the lazy
#: terrain needs), so the check samples *stretches of road*, each seen by every laser at
#: every range as the vehicle approaches it, at one tile's cost each: ~1.8 s of terrain for
#: a 10-minute log, about what sampling every 8th batch of scans cost (their points span
#: three tiles each), without holding the lock for three tiles at a time.
Z_ERROR_TILE_EVERY = 8
#: ... or closer, so that a short route still has this many checked stretches (the sample
#: log's 0.7 km: every tile).
Z_ERROR_FEWEST_STRETCHES = 15
#: Bytes the figures take beside the cloud, for the stage's disk estimate: Fig. 4 and the z
#: error, a PNG and a CSV each. Measured on the sample log (``terrain run
#: sample_logs/sample.mcap``): Fig. 4 57.2 kB (PNG) + 16.7 kB (CSV), the z error 79.8 + 4.6 kB,
#: 158 kB in all. Neither grows with the log (their CSVs are binned, by dt and by laser and
#: range; their PNGs 700 x 450 pixels); twice the sample's leaves room for busier plots and
#: more lasers.
FIGURE_BYTES = 320_000
#: Batches handed to the Fig. 4 thread at most, the one it is working on included (each
#: ~30 MB of points).
FIGURE_QUEUE = 2


class Figures:
    """The paper's Fig. 4 from the log itself, and on simulated logs the points' z error
    against the true terrain, accumulated batch by batch as the points are made.

    Fig. 4 runs beside the writing, on a thread of its own (the batches in order, as it
    needs); at most :data:`FIGURE_QUEUE` of them are handed to it at once."""

    def __init__(self, log_dir: Path, warnings: list[str]) -> None:
        """Figures of the log in ``log_dir``; a warning added to ``warnings`` when the
        log's points cannot be checked against the true terrain."""
        self.agreement = ScanAgreement()
        self.ground: TrueGround | None
        try:
            self.ground = true_ground(log_dir)
        except StageError as exc:  # a simulated log posed without GPS: no tie to the truth
            self.ground = None
            warnings.append(f"no z error against the true terrain: {exc}")
        self.z_error = ZErrorAccumulator() if self.ground is not None else None
        self.z_every = (
            self.ground.stretch_every(Z_ERROR_FEWEST_STRETCHES, Z_ERROR_TILE_EVERY)
            if self.ground is not None
            else Z_ERROR_TILE_EVERY
        )
        self.fig4_until_ns: int | None = None
        #: A lidar's last cloud of the batch before, which the next batch may continue.
        self.pending: pa.Table | None = None
        self.jobs: deque[Future[None]] = deque()
        self.lock = threading.Lock()  # the simulated world builds its tiles lazily

    def sample(self, table: pa.Table) -> ZSample | None:
        """The z-error sample of a batch's points (:func:`z_sample`; None on a log without
        the true terrain): run on the projecting threads."""
        if self.ground is None or not table.num_rows:
            return None
        return z_sample(self.ground, table, self.lock, self.z_every)

    def feed(self, table: pa.Table, sample: ZSample | None, pool: ThreadPoolExecutor) -> None:
        """Hand a batch's points ``table`` (all of them projected, in order) to Fig. 4's
        thread ``pool`` while within :data:`FIG4_SECONDS` of the first, and its z-error
        ``sample`` to the accumulator."""
        if table.num_rows:
            first_ns = int(pc.min(table.column("scan_t_ns")).as_py())
            if self.fig4_until_ns is None:
                self.fig4_until_ns = first_ns + int(FIG4_SECONDS * 1e9)
            if first_ns < self.fig4_until_ns:
                if "ring" in table.column_names:  # a lidar's: its rings' sweeps, whole
                    table, self.pending = whole_clouds(self.pending, table)
                self.jobs.append(pool.submit(self.agreement.feed, lidar_sweeps(table)))
                while len(self.jobs) > FIGURE_QUEUE:
                    self.jobs.popleft().result()
        if self.z_error is not None and sample is not None:
            self.z_error.feed(sample.laser, sample.range_m, sample.z_error_m)

    def drain(self) -> None:
        """Wait for Fig. 4's thread to take in every batch handed to it."""
        while self.jobs:
            self.jobs.popleft().result()

    def cancel(self) -> None:
        """Let no batch still waiting for Fig. 4's thread be fed to it (an error)."""
        for job in self.jobs:
            job.cancel()

    def write(self, log_dir: Path, log_id: str) -> tuple[ScanAgreementResult, list[str]]:
        """Fig. 4 and (with the true terrain) the z error written into ``log_dir``: Fig. 4's
        result and the names of the files written."""
        if self.pending is not None:  # the lidar's last cloud
            self.agreement.feed(lidar_sweeps(self.pending))
            self.pending = None
        fig4 = self.agreement.result()
        figure_files = [p.name for p in write_fig4(fig4, log_dir, log_id)]
        if self.z_error is not None:
            z_files = write_z_error(self.z_error.result(), log_dir, title=log_id)
            figure_files += [p.name for p in z_files]
        return fig4, figure_files


def whole_clouds(pending: pa.Table | None, table: pa.Table) -> tuple[pa.Table, pa.Table | None]:
    """A lidar batch's points (``pending``, the cloud held back before, first) without its
    last cloud, which the next batch may continue, and that cloud (None when empty)."""
    if pending is not None:
        table = pa.concat_tables([pending, table.cast(pending.schema)])
    scan = table.column("scan_t_ns").to_numpy()
    last = scan == scan.max()
    return table.filter(pa.array(~last)), table.filter(pa.array(last))


def lidar_sweeps(table: pa.Table) -> pa.Table:
    """A lidar's points laid out as Fig. 4 reads a laser's scans: each ring's sweep of one
    cloud contiguous and in time order, its ``beam`` the return's place along that sweep
    (0, 1, ...), so the flatness test's neighbouring beams are neighbours on the ring's
    line across the ground. A laser's points (no ``ring``) are returned as they are."""
    if "ring" not in table.column_names or not table.num_rows:
        return table
    laser = pc.dictionary_encode(pc.cast(table.column("laser"), pa.string())).combine_chunks()
    names = np.asarray(laser.dictionary.to_pylist(), dtype=object)
    code = np.argsort(np.argsort(names))[laser.indices.to_numpy()]  # rings by name
    scan = table.column("scan_t_ns").to_numpy()
    order = np.lexsort((table.column("t_ns").to_numpy(), code, scan))
    code, scan = code[order], scan[order]
    start = np.r_[True, (code[1:] != code[:-1]) | (scan[1:] != scan[:-1])]
    place = np.arange(order.size) - np.flatnonzero(start)[np.cumsum(start) - 1]
    out = table.take(pa.array(order))
    column = out.schema.get_field_index("beam")
    return out.set_column(column, "beam", pa.array(place.astype(np.int32)))


class ZSample(NamedTuple):
    """A batch's z-error sample (:func:`z_sample`): each point's laser, range and z error
    against the true terrain, m (K,)."""

    laser: pa.Array
    range_m: FloatArray
    z_error_m: FloatArray


def z_sample(
    ground: TrueGround, table: pa.Table, lock: threading.Lock, every: int
) -> ZSample | None:
    """The z-error sample of a batch's points ``table``: of every :data:`Z_ERROR_STRIDE`-th
    point, those on a checked stretch of road (every ``every``-th terrain tile,
    :meth:`~toolkit.analysis.truth_terrain.TrueGround.checked_stretch`), with their error
    against the true terrain (None: no point there). The terrain is built under ``lock``,
    one stretch at a time (a window across two stretches would build every tile between)."""
    some = table.take(pa.array(np.arange(0, table.num_rows, Z_ERROR_STRIDE)))
    xyz = np.stack([some.column(c).to_numpy() for c in "xyz"], axis=1)
    s, d, z = ground.route_coordinates(xyz)
    stretch = ground.checked_stretch(s, every)
    rows = np.flatnonzero(stretch >= 0)
    if rows.size == 0:
        return None
    error = np.empty(rows.size)
    for k in np.unique(stretch[rows]):
        on = np.flatnonzero(stretch[rows] == k)
        with lock:
            error[on] = z[rows[on]] - ground.terrain_height_m(s[rows[on]], d[rows[on]])
    return ZSample(
        some.column("laser").take(pa.array(rows)), some.column("range").to_numpy()[rows], error
    )


__all__ = ["FIG4_SECONDS", "FIGURE_BYTES", "Z_ERROR_STRIDE", "Figures", "ZSample", "z_sample"]
