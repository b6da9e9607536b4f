"""Decoding one ``sensor_msgs/msg/PointCloud2`` CDR payload into numpy points, without a copy.

A 3-D lidar publishes ~100k points per message, each ``point_step`` bytes laid out by the
message's own ``fields``. The generic decoder (:mod:`toolkit.mcapio.cdr`) cannot batch this
type (its ``fields`` is an array of messages) and would copy the point bytes; here the work is:

1. :func:`parse_cloud` reads the few header fields with ``struct.unpack_from`` (Python work per
   message, none per point) and keeps ``data`` as a zero-copy slice of the payload;
2. :func:`cloud_dtype` turns ``fields`` into a numpy structured dtype (cached per layout);
3. :func:`cloud_points` views ``data`` through it: shape ``(height*width,)``, no copy unless
   organised rows are padded;
4. :func:`xyz_valid` keeps the points with a finite, non-zero position;
5. :func:`point_times_ns` gives each point its time in integer nanoseconds, by a
   :class:`PointTime` spec (one of :data:`PRESETS`, named after the drivers).

The CDR rules are those of :mod:`toolkit.mcapio.cdr_layout`, with one addition: besides
little-endian CDR (``00 01``) this module also reads big-endian CDR (``00 00``), whose
primitives are big-endian and aligned the same way. Errors are :class:`CloudPayloadError`
(truncated or inconsistent CDR) and :class:`CloudLayoutError` (an unusable point layout), both
naming the topic.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import numpy as np
from numpy.lib.recfunctions import structured_to_unstructured
from numpy.typing import NDArray

from toolkit.arrays import AnyFloatArray, BoolArray, IntArray
from toolkit.errors import CloudLayoutError, CloudPayloadError

#: PointField datatype constants (sensor_msgs/PointField) -> numpy kind and size.
DATATYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}

#: Representation identifiers of plain CDR (XCDR1): big- and little-endian.
_CDR_BE = b"\x00\x00"
_CDR_LE = b"\x00\x01"
#: Most bytes tolerated after ``is_dense`` (some DDS layers pad a payload to a multiple of 4).
MAX_TRAILING = 7
#: Nanoseconds per unit of a time field.
NS_PER_UNIT: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
_NS_PER_S = 1_000_000_000


#: Message types of drivers' raw packets, by driver: a log of them holds no point cloud until
#: the vendor's driver decodes them into ``sensor_msgs/PointCloud2`` (ouster-ros ROS 1 and 2,
#: velodyne_driver, hesai's and robosense's drivers, livox_ros_driver2's own format).
PACKET_TYPES: frozenset[str] = frozenset(
    {
        "ouster_ros/msg/PacketMsg",
        "ouster_sensor_msgs/msg/PacketMsg",
        "velodyne_msgs/msg/VelodyneScan",
        "velodyne_msgs/msg/VelodynePacket",
        "pandar_msgs/msg/PandarScan",
        "hesai_ros_driver/msg/UdpFrame",
        "rslidar_msg/msg/RslidarPacket",
        "rslidar_msgs/msg/rslidarScan",
        "livox_ros_driver2/msg/CustomMsg",
        "nebula_msgs/msg/NebulaPackets",
    }
)


def packets_note(topic: str, type_name: str) -> str:
    """One line saying that ``topic`` holds raw lidar packets ("" when its type is not one)."""
    if type_name not in PACKET_TYPES:
        return ""
    return (
        f"topic {topic} holds a lidar driver's raw packets ({type_name}), not points: the "
        "driver must decode them into sensor_msgs/msg/PointCloud2 first (e.g. replay the log "
        "through it and record its cloud topic)"
    )


@dataclass(frozen=True)
class PointField:
    """One field of a point: ``name``, byte ``offset`` in the point, ``datatype`` (1..8, see
    :data:`DATATYPES`) and ``count`` elements (0 is read as 1, as drivers mean it)."""

    name: str
    offset: int
    datatype: int
    count: int


@dataclass(frozen=True)
class Cloud:
    """The header of one PointCloud2 message and a zero-copy view of its point bytes.

    ``stamp_ns`` is the header stamp in ns since the epoch; ``height`` rows of ``width``
    points (height 1: unorganised), ``point_step`` bytes per point, ``row_step`` bytes per row;
    ``data`` is a ``memoryview`` into the payload (``len(data)`` bytes, never copied).
    ``is_dense`` is what the driver claims; :func:`xyz_valid` does not trust it.
    """

    topic: str
    stamp_ns: int
    frame_id: str
    height: int
    width: int
    fields: tuple[PointField, ...]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: memoryview
    is_dense: bool

    @property
    def n_points(self) -> int:
        """``height * width``."""
        return self.height * self.width


class _Reader:
    """A cursor over one payload: reads CDR primitives in its byte order, aligned from the end
    of the 4-byte encapsulation header; every read names the field it was for on failure."""

    def __init__(self, buf: memoryview, topic: str) -> None:
        self.buf = buf
        self.topic = topic
        self.n = len(buf)
        if self.n < 4:
            raise CloudPayloadError(topic, f"payload has {self.n} bytes, no CDR header")
        rep = bytes(buf[:2])
        if rep not in (_CDR_BE, _CDR_LE):
            raise CloudPayloadError(
                topic, f"encapsulation {rep.hex()} is not plain CDR (0000 or 0001)"
            )
        self.order = "<" if rep == _CDR_LE else ">"
        self.u32 = struct.Struct(self.order + "I")
        self.i32_u32 = struct.Struct(self.order + "iI")
        self.off = 4

    def _need(self, size: int, what: str) -> int:
        """Align to ``size`` (at most 4 here) and reserve ``size`` bytes; their offset."""
        at = 4 + (self.off - 4 + size - 1) // size * size
        if at + size > self.n:
            raise CloudPayloadError(
                self.topic,
                f"payload is truncated in {what} (needs {at + size} bytes, has {self.n})",
            )
        self.off = at + size
        return at

    def uint32(self, what: str) -> int:
        value: int = self.u32.unpack_from(self.buf, self._need(4, what))[0]
        return value

    def stamp_ns(self) -> int:
        sec, nanosec = self.i32_u32.unpack_from(self.buf, self._need(8, "header.stamp"))
        if nanosec >= _NS_PER_S:
            raise CloudPayloadError(self.topic, f"header.stamp.nanosec is {nanosec} (>= 1e9)")
        return int(sec) * _NS_PER_S + int(nanosec)

    def uint8(self, what: str) -> int:
        return self.buf[self._need(1, what)]

    def boolean(self, what: str) -> bool:
        value = self.uint8(what)
        if value > 1:
            raise CloudPayloadError(self.topic, f"{what} is {value}, not a bool (0 or 1)")
        return value == 1

    def string(self, what: str) -> str:
        length = self.uint32(f"the length of {what}")
        start = self.off
        if start + length > self.n:
            raise CloudPayloadError(
                self.topic,
                f"payload is truncated in {what} (needs {start + length} bytes, has {self.n})",
            )
        self.off = start + length
        if length == 0:  # some writers send an empty string as a bare zero length
            return ""
        if self.buf[start + length - 1] != 0:
            raise CloudPayloadError(self.topic, f"{what} is not NUL-terminated")
        try:
            return str(self.buf[start : start + length - 1], "utf-8")
        except UnicodeDecodeError as exc:
            raise CloudPayloadError(self.topic, f"{what} is not valid UTF-8") from exc

    def octets(self, what: str) -> memoryview:
        length = self.uint32(f"the length of {what}")
        start = self.off
        if start + length > self.n:
            raise CloudPayloadError(
                self.topic,
                f"payload is truncated in {what} ({length} bytes announced, "
                f"{self.n - start} present)",
            )
        self.off = start + length
        return self.buf[start : start + length]


def parse_cloud(payload: bytes | memoryview, *, topic: str) -> Cloud:
    """Read one ``sensor_msgs/msg/PointCloud2`` CDR payload (little- or big-endian CDR).

    Python work is per message and per field, never per point: ``data`` is a ``memoryview``
    slice of ``payload`` (keep ``payload`` alive as long as the points are used). Raises
    :class:`CloudPayloadError` naming ``topic`` if the payload is truncated, has a bad
    encapsulation, a string without its NUL, a bool that is not 0/1, or more than
    :data:`MAX_TRAILING` bytes after its last field. The point layout is checked later, by
    :func:`cloud_dtype` and :func:`cloud_points`.
    """
    buf = memoryview(payload).cast("B")
    r = _Reader(buf, topic)
    stamp_ns = r.stamp_ns()
    frame_id = r.string("header.frame_id")
    height = r.uint32("height")
    width = r.uint32("width")
    n_fields = r.uint32("the length of fields")
    # Each PointField takes at least 13 bytes: refuse an absurd count before looping on it.
    if n_fields * 13 > r.n - r.off:
        raise CloudPayloadError(
            topic, f"payload is truncated in fields ({n_fields} announced, {r.n} bytes)"
        )
    fields = []
    for i in range(n_fields):
        name = r.string(f"fields[{i}].name")
        offset = r.uint32(f"fields[{i}].offset")
        datatype = r.uint8(f"fields[{i}].datatype")
        count = r.uint32(f"fields[{i}].count")
        fields.append(PointField(name, offset, datatype, count))
    is_bigendian = r.boolean("is_bigendian")
    point_step = r.uint32("point_step")
    row_step = r.uint32("row_step")
    data = r.octets("data")
    is_dense = r.boolean("is_dense")
    if r.n - r.off > MAX_TRAILING:
        raise CloudPayloadError(
            topic,
            f"{r.n - r.off} unexpected bytes after is_dense (not a PointCloud2?)",
        )
    return Cloud(
        topic, stamp_ns, frame_id, height, width, tuple(fields),
        is_bigendian, point_step, row_step, data, is_dense,
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# The point layout
# --------------------------------------------------------------------------------------------


def cloud_dtype(
    fields: Sequence[PointField], point_step: int, is_bigendian: bool, *, topic: str
) -> np.dtype[np.void]:
    """The numpy structured dtype of one point: ``names``, ``formats`` (a field of count > 1
    is a sub-array ``(count,)``), ``offsets`` and ``itemsize == point_step``.

    Byte order is the cloud's (``is_bigendian``); offsets need not be aligned (velodyne's
    ``time`` float32 sits at offset 18). Cached per layout. Raises :class:`CloudLayoutError`
    naming ``topic`` for point_step 0, an unknown datatype, an empty or duplicate name, a field
    running past point_step, overlapping fields, or x, y, z missing (or not single numbers).
    """
    found = _dtype_for(tuple(fields), point_step, is_bigendian)
    if isinstance(found, str):
        raise CloudLayoutError(topic, found)
    return found


@lru_cache(maxsize=64)
def _dtype_for(
    fields: tuple[PointField, ...], point_step: int, is_bigendian: bool
) -> np.dtype[np.void] | str:
    """The dtype of a layout, or the one-line problem that refuses it (both cached)."""
    if point_step == 0:
        return "point_step is 0"
    order = ">" if is_bigendian else "<"
    names: list[str] = []
    formats: list[Any] = []
    spans: list[tuple[int, int, str]] = []
    for f in fields:
        kind = DATATYPES.get(f.datatype)
        if kind is None:
            return f"field {f.name!r} has unknown datatype {f.datatype} (known: 1..8)"
        if not f.name:
            return f"a field at offset {f.offset} has an empty name"
        if f.name in names:
            return f"field {f.name!r} appears twice"
        base = np.dtype(order + kind)
        count = max(f.count, 1)
        size = base.itemsize * count
        if f.offset + size > point_step:
            return (
                f"field {f.name!r} at offset {f.offset} ({size} bytes) runs past "
                f"point_step {point_step}"
            )
        names.append(f.name)
        formats.append(base if count == 1 else (base, (count,)))
        spans.append((f.offset, f.offset + size, f.name))
    spans.sort()
    for (_, end, first), (start, _, second) in zip(spans, spans[1:], strict=False):
        if start < end:
            return f"fields {first!r} and {second!r} overlap (bytes {start}..{end - 1})"
    for axis in ("x", "y", "z"):
        if axis not in names:
            return f"no field {axis!r} (fields: {', '.join(names) or 'none'})"
        if isinstance(formats[names.index(axis)], tuple):
            return f"field {axis!r} has count > 1"
    offsets = [f.offset for f in fields]
    return np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )


def cloud_points(cloud: Cloud, dtype: np.dtype[np.void]) -> NDArray[np.void]:
    """The cloud's points as a structured array ``(height*width,)`` of ``dtype`` (from
    :func:`cloud_dtype`), read-only when the payload is ``bytes``.

    A zero-copy view of ``cloud.data`` whenever rows are not padded (or there is one row);
    organised clouds with padded rows (``row_step > width*point_step``) are viewed with
    strides ``(row_step, point_step)`` and copied once to drop the padding. Bytes past
    ``height*row_step`` are ignored. Raises :class:`CloudLayoutError` if ``row_step`` is
    shorter than a row or ``data`` is shorter than ``height*row_step``.
    """
    h, w, step = cloud.height, cloud.width, cloud.point_step
    if dtype.itemsize != step:
        raise CloudLayoutError(
            cloud.topic, f"dtype itemsize {dtype.itemsize} is not point_step {step}"
        )
    if cloud.row_step < w * step:
        raise CloudLayoutError(
            cloud.topic,
            f"row_step {cloud.row_step} is shorter than width {w} x point_step {step}",
        )
    need = h * cloud.row_step
    if len(cloud.data) < need:
        raise CloudLayoutError(
            cloud.topic,
            f"data has {len(cloud.data)} bytes, fewer than height {h} x row_step "
            f"{cloud.row_step} = {need}",
        )
    if h <= 1 or cloud.row_step == w * step:
        return np.frombuffer(cloud.data, dtype=dtype, count=h * w)
    rows: NDArray[np.void] = np.ndarray(
        (h, w), dtype=dtype, buffer=cloud.data, strides=(cloud.row_step, step)
    )
    return rows.reshape(h * w)  # the one copy: padding between rows cannot be viewed away


# --------------------------------------------------------------------------------------------
# Valid positions
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DropCounts:
    """How many of ``total`` points :func:`xyz_valid` dropped, by reason: ``non_finite`` (a
    NaN or infinite coordinate) and ``zero_range`` (exactly at the origin: Ouster's "no
    return")."""

    total: int
    non_finite: int
    zero_range: int

    @property
    def kept(self) -> int:
        return self.total - self.non_finite - self.zero_range


def xyz_valid(points: NDArray[np.void]) -> tuple[AnyFloatArray, BoolArray, DropCounts]:
    """The positions of the valid points: ``(xyz (m, 3), keep (n,), counts)``.

    ``xyz`` is in the sensor frame, metres, native byte order: float32 when x, y and z are all
    float32 on the wire, else float64. ``keep`` marks which of the ``n`` input points are in
    ``xyz`` (to select their times or other fields). Points with any non-finite coordinate and
    points exactly at the origin are dropped and counted, whatever ``is_dense`` claims.
    """
    names = points.dtype.names
    if names is None or not {"x", "y", "z"} <= set(names):
        raise ValueError(f"points need fields x, y, z; got {names}")
    all_f4 = all(points[a].dtype.kind == "f" and points[a].dtype.itemsize == 4 for a in "xyz")
    ftype = np.dtype(np.float32 if all_f4 else np.float64)
    # One pass over the point bytes into a contiguous (n, 3) of native floats (x, y, z side by
    # side in a point, as every driver lays them, are read as one strided block); every later
    # pass then reads 12 or 24 bytes a point instead of point_step.
    xyz = np.ascontiguousarray(structured_to_unstructured(points[["x", "y", "z"]]), dtype=ftype)
    # The largest |coordinate| of each point, compared as IEEE bits: at or above the exponent
    # of infinity means a NaN or an infinity; 0 means all three are (+ or -) zero. Exact,
    # unlike a squared range (which can overflow or underflow), and two passes of n.
    utype, magnitude, infinity = _FLOAT_BITS[ftype.itemsize]
    bits: NDArray[np.unsignedinteger[Any]] = xyz.view(utype)
    mag = np.bitwise_and(bits, np.array(magnitude, dtype=utype))
    biggest = np.maximum(np.maximum(mag[:, 0], mag[:, 1]), mag[:, 2])
    bad = biggest >= infinity
    zero = biggest == 0
    keep: BoolArray = ~(bad | zero)
    out: AnyFloatArray = np.compress(keep, xyz, axis=0)
    n = len(points)
    non_finite = int(np.count_nonzero(bad))
    counts = DropCounts(n, non_finite, n - non_finite - out.shape[0])
    return out, keep, counts


#: By float size: the unsigned integer of the same size, the mask of an IEEE float's magnitude
#: bits (all but the sign) and the bits of infinity.
_FLOAT_BITS: dict[int, tuple[np.dtype[np.unsignedinteger[Any]], int, int]] = {
    4: (np.dtype(np.uint32), 0x7FFF_FFFF, 0x7F80_0000),
    8: (np.dtype(np.uint64), 0x7FFF_FFFF_FFFF_FFFF, 0x7FF0_0000_0000_0000),
}


# --------------------------------------------------------------------------------------------
# Per-point time
# --------------------------------------------------------------------------------------------

TimeUnit = Literal["s", "ms", "us", "ns"]


@dataclass(frozen=True)
class PointTime:
    """Where a point's time is and what it means.

    ``field`` names the time field (None: every point at the header stamp), in ``unit``;
    ``reference`` is ``header`` (the value is an offset from the header stamp) or ``absolute``
    (ns/s since the epoch). ``header_at`` says where in the sweep the driver stamps the header
    (``start``: offsets >= 0; ``end``: offsets <= 0, as velodyne_pointcloud does); it does not
    change the arithmetic (time = stamp + offset either way) but tells a caller which end of
    the sweep the header stamp is.
    """

    field: str | None
    unit: TimeUnit = "ns"
    reference: Literal["header", "absolute"] = "header"
    header_at: Literal["start", "end"] = "start"


#: Per-point time of each driver's cloud, by driver name (see :func:`preset_for_fields`).
PRESETS: dict[str, PointTime] = {
    "ouster": PointTime("t", "ns", "header", "start"),  # ouster-ros: uint32 ns since the header
    "velodyne": PointTime("time", "s", "header", "end"),  # float32 s, header at sweep end
    "nebula": PointTime("time_stamp", "ns", "header", "start"),  # uint32 ns since the header
    "livox": PointTime("timestamp", "ns", "absolute", "start"),  # float64 ns since the epoch
    "rslidar": PointTime("timestamp", "s", "absolute", "start"),  # float64 s since the epoch
    "none": PointTime(None),
}

#: Field names that identify a driver, checked in this order (first match wins).
_SIGNATURES: tuple[tuple[str, frozenset[str]], ...] = (
    ("ouster", frozenset({"t", "ring"})),
    ("velodyne", frozenset({"time", "ring"})),
    ("nebula", frozenset({"time_stamp", "channel"})),
    ("livox", frozenset({"timestamp", "line"})),
    ("rslidar", frozenset({"timestamp", "ring"})),
)


def preset_for_fields(names: Iterable[str]) -> str:
    """The name of the :data:`PRESETS` entry whose driver writes these field names: ouster
    (``t``, ``ring``), velodyne (``time``, ``ring``), nebula (``time_stamp``, ``channel``),
    livox (``timestamp``, ``line``), rslidar (``timestamp``, ``ring``), else ``none``."""
    have = set(names)
    for preset, needed in _SIGNATURES:
        if needed <= have:
            return preset
    return "none"


def point_times_ns(
    points: NDArray[np.void],
    stamp_ns: int,
    spec: PointTime,
    *,
    topic: str,
    keep: BoolArray | None = None,
) -> IntArray:
    """Each point's time, int64 ns since the epoch, shape ``(n,)``, or ``(m,)`` for the
    points ``keep`` selects (the mask of :func:`xyz_valid`; cheaper than ``points[keep]``,
    which copies whole points).

    Integer fields are converted exactly (int64 arithmetic, no float on the way). A float field
    in seconds is split into whole seconds and a fraction before scaling, so the result is the
    nanosecond nearest to the value the driver wrote. That value has its own resolution, which
    no decoder can improve: a float64 absolute ns time near 1.7e18 is a multiple of 256 ns, a
    float64 absolute second time near 1.7e9 s resolves ~238 ns, and a float32 offset of 0.1 s
    ~7 ns. Offsets (``reference == "header"``) are added to ``stamp_ns``. Raises
    :class:`CloudLayoutError` naming ``topic`` if the spec's field is not in ``points``, and
    :class:`CloudPayloadError` if a float time is NaN, infinite or beyond 2**62 ns (pass
    ``keep`` from :func:`xyz_valid` if a driver leaves its invalid points' times undefined).
    """
    n = len(points) if keep is None else int(np.count_nonzero(keep))
    if spec.field is None:
        return np.full(n, stamp_ns, dtype=np.int64)
    names = points.dtype.names or ()
    if spec.field not in names:
        raise CloudLayoutError(
            topic, f"no time field {spec.field!r} (fields: {', '.join(names) or 'none'})"
        )
    values = points[spec.field]
    if values.ndim != 1:
        raise CloudLayoutError(topic, f"time field {spec.field!r} has count > 1")
    if keep is not None:
        values = values[keep]
    scale = NS_PER_UNIT[spec.unit]
    if values.dtype.kind in "iu":
        t_ns = values.astype(np.int64)
        if scale != 1:
            t_ns *= scale
    else:
        v = values.astype(np.float64)
        # NaN fails this comparison too; past 2**62 ns (146 years) an int64 could overflow.
        fits = np.abs(v) * scale < 2.0**62
        if not fits.all():
            bad = int(v.size - np.count_nonzero(fits))
            raise CloudPayloadError(
                topic, f"{bad} values of {spec.field!r} are not finite or out of range"
            )
        t_ns = _float_to_ns(v, scale)
    if spec.reference == "header":
        t_ns += np.int64(stamp_ns)
    return t_ns


def _float_to_ns(v: NDArray[np.float64], scale: int) -> IntArray:
    """Finite float64 times ``(n,)`` in units of ``scale`` ns -> the nearest int64 ns, without
    the rounding a plain ``v * scale`` in float64 would add to large (absolute) values."""
    if scale == 1:
        # Already ns: above 2**53 every float64 is an integer, so this conversion is exact.
        return np.rint(v).astype(np.int64)
    whole = np.floor(v)
    # Exact when |v| >= 1 (the fraction is a multiple of v's own ulp); for a negative offset
    # above -1 s (velodyne) it is v + 1, off by at most 1.1e-16 s: far below a nanosecond.
    frac = v - whole
    t_ns = whole.astype(np.int64) * np.int64(scale)
    t_ns += np.rint(frac * scale).astype(np.int64)
    return t_ns


__all__ = [
    "DATATYPES",
    "PRESETS",
    "Cloud",
    "DropCounts",
    "PointField",
    "PointTime",
    "cloud_dtype",
    "cloud_points",
    "parse_cloud",
    "point_times_ns",
    "preset_for_fields",
    "xyz_valid",
]
