"""The lidar's scans as ``sensor_msgs/msg/PointCloud2`` in ouster-ros's exact point layout.

ouster-ros (the driver's default ``ouster_ros::Point``, PCL-registered) lays each point out
in 48 bytes: ``x, y, z`` float32 at 0, 4, 8 (PCL's 16-byte ``PCL_ADD_POINT4D`` block, its
fourth float padding), ``intensity`` float32 at 16, ``t`` uint32 at 20 (ns after the
cloud's stamp), ``reflectivity`` uint16 at 24, ``ring`` uint16 at 26, ``ambient`` uint16 at
28, ``range`` uint32 at 32 (mm), padding to 48 (the point is 16-byte aligned). The cloud is
organised: ``height`` = beams (row = ring), ``width`` = columns, ``is_dense`` false, and a
pixel without a return is all zeros but for ``t``, ``ring`` and ``ambient``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from toolkit.mcapio.cdr_encode import encode_message

POINTFIELD_UINT16 = 4
POINTFIELD_UINT32 = 6
POINTFIELD_FLOAT32 = 7

#: (name, offset, PointField datatype, numpy type) of every field, in ouster-ros's order.
OUSTER_FIELDS: tuple[tuple[str, int, int, str], ...] = (
    ("x", 0, POINTFIELD_FLOAT32, "<f4"),
    ("y", 4, POINTFIELD_FLOAT32, "<f4"),
    ("z", 8, POINTFIELD_FLOAT32, "<f4"),
    ("intensity", 16, POINTFIELD_FLOAT32, "<f4"),
    ("t", 20, POINTFIELD_UINT32, "<u4"),
    ("reflectivity", 24, POINTFIELD_UINT16, "<u2"),
    ("ring", 26, POINTFIELD_UINT16, "<u2"),
    ("ambient", 28, POINTFIELD_UINT16, "<u2"),
    ("range", 32, POINTFIELD_UINT32, "<u4"),
)
POINT_STEP = 48

#: One point as numpy sees it; ``np.zeros`` of it leaves the padding zero.
POINT_DTYPE = np.dtype(
    {
        "names": [f[0] for f in OUSTER_FIELDS],
        "formats": [f[3] for f in OUSTER_FIELDS],
        "offsets": [f[1] for f in OUSTER_FIELDS],
        "itemsize": POINT_STEP,
    }
)

_FIELDS_MSG = [
    {"name": name, "offset": offset, "datatype": datatype, "count": 1}
    for name, offset, datatype, _ in OUSTER_FIELDS
]


def encode_cloud(stamp_ns: int, frame_id: str, points: NDArray[np.void]) -> bytes:
    """One organised cloud's CDR payload from ``points`` (beams, columns) of
    :data:`POINT_DTYPE`, stamped ``stamp_ns`` (ns) in ``frame_id``."""
    height, width = points.shape
    msg = {
        "header": {
            "stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000},
            "frame_id": frame_id,
        },
        "height": height,
        "width": width,
        "fields": _FIELDS_MSG,
        "is_bigendian": False,
        "point_step": POINT_STEP,
        "row_step": width * POINT_STEP,
        "data": np.ascontiguousarray(points).view(np.uint8).reshape(-1),
        "is_dense": False,
    }
    return encode_message("sensor_msgs/msg/PointCloud2", msg)
