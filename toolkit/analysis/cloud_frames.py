"""One log's point cloud in two world frames, compared where both hold the same returns.

Each table's world frame is the map of its own origin (:mod:`toolkit.geometry.map_frame`,
named in its ``enu_origin`` metadata); a cloud made with another origin is taken to
geodetic coordinates through its own frame and into the first cloud's, return by return,
and the differences measured. What the curved-earth check of ``benchmarks/curved_earth.py``
and its test read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.arrays import FloatArray
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import geodetic_to_world, world_to_geodetic


@dataclass(frozen=True)
class Cloud:
    """A points table's returns: ids ``t_ns``, ``beam`` (n,), ``range_m`` (n,), world
    ``xyz_m`` (n, 3), and the origin of its frame."""

    t_ns: np.ndarray
    beam: np.ndarray
    range_m: FloatArray
    xyz_m: FloatArray
    origin: GeodeticOrigin


@dataclass(frozen=True)
class FrameAgreement:
    """Absolute differences at the returns compared, m: height and horizontal, p95 and max."""

    returns: int
    dz_p95_m: float
    dz_max_m: float
    dxy_p95_m: float
    dxy_max_m: float


def read_cloud(path: Path) -> Cloud:
    """The returns of a points table (coordinates as float64: they are stored to the mm)."""
    table = pq.read_table(path, columns=["t_ns", "beam", "range", "x", "y", "z"])
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    o = json.loads(meta["enu_origin"])

    def floats(name: str) -> FloatArray:
        return np.asarray(table.column(name).cast(pa.float64()).to_numpy(), np.float64)

    return Cloud(
        t_ns=table.column("t_ns").to_numpy(),
        beam=table.column("beam").to_numpy(),
        range_m=floats("range"),
        xyz_m=np.column_stack([floats("x"), floats("y"), floats("z")]),
        origin=GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["altitude_m"]),
    )


def frame_agreement(
    ref: Cloud, other: Cloud, min_range_m: float, max_range_m: float
) -> FrameAgreement:
    """``other`` (the same returns, another frame) in ``ref``'s frame, against ``ref``, at
    the returns between ``min_range_m`` and ``max_range_m``."""
    if not (np.array_equal(ref.t_ns, other.t_ns) and np.array_equal(ref.beam, other.beam)):
        raise ValueError("the two clouds do not hold the same returns in the same order")
    lat, lon, alt = world_to_geodetic(other.xyz_m, other.origin)
    moved = geodetic_to_world(lat, lon, alt, ref.origin)
    sel = (ref.range_m >= min_range_m) & (ref.range_m <= max_range_m)
    dz = np.abs(moved[sel, 2] - ref.xyz_m[sel, 2])
    dxy = np.hypot(*(moved[sel, :2] - ref.xyz_m[sel, :2]).T)
    return FrameAgreement(
        returns=int(sel.sum()),
        dz_p95_m=float(np.quantile(dz, 0.95)),
        dz_max_m=float(dz.max()),
        dxy_p95_m=float(np.quantile(dxy, 0.95)),
        dxy_max_m=float(dxy.max()),
    )


__all__ = ["Cloud", "FrameAgreement", "frame_agreement", "read_cloud"]
