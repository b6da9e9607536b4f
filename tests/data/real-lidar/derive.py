"""Derive the vendored real-lidar test logs from the recordings in ``shared/real-lidar/``.

Run by hand, never by the tests (the toolkit never imports ouster-sdk or rosbags)::

    python3 -m venv /tmp/derive-venv
    /tmp/derive-venv/bin/pip install ouster-sdk rosbags mcap mcap-ros2-support numpy
    /tmp/derive-venv/bin/pip install 'rosbags>=0.10'   # the MCAP writer of rosbags.rosbag2
    /tmp/derive-venv/bin/python tests/data/real-lidar/derive.py [--source /work/shared/real-lidar]

(ouster-sdk 1.0.1 pins rosbags 0.9.23 for its bag reader, which this script does not use; its pcap
reader works with rosbags 0.10+, whose rosbag2 Writer is the first to write MCAP storage.)

It writes, beside itself:

- ``ouster-os1-128.mcap``: 3 scans of an Ouster OS-1-128 pcap decoded with ouster-sdk into
  PointCloud2 messages in ouster-ros's layout (every 16th beam kept), its IMU packets as
  sensor_msgs/Imu and its metadata's transforms on ``/tf_static``; plus, derived, what the
  pose stage needs and the recording lacks: ``/derived/odom`` (geometry_msgs/TwistStamped at
  the IMU's stamps: the speed and yaw rate between the recording's per-scan poses) and a
  ``base_link`` on the ground under the sensor (the height: the median z of the returns
  below it within 12 m); and
  ``ouster-os1-128.reference.npz``, the vendor decoder's values for the kept points.
- ``vlp16-nebula.mcap``: nebula's decoded VLP-16 PCD wrapped unchanged as one PointCloud2; its
  re-packings in velodyne_pointcloud's and livox_ros_driver2's layouts
  (``vlp16-velodyne-derived.mcap``, ``vlp16-livox-derived.mcap``); and ``vlp16.reference.npz``.
- ``ouster-packets-only.mcap``: a ROS 1 bag of raw Ouster packets converted to a ROS 2 MCAP.

Every output is then read back with the ``mcap`` reader and ``mcap_ros2``'s decoder (every
message decoded) and summarised. See README.md beside this script for provenance and layouts.
"""

from __future__ import annotations

import argparse
import re
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
MSG_DIR = REPO / "schemas" / "msg"
SEPARATOR = "=" * 80

#: Primitive field types of ROS 2 ``.msg`` files (anything else names a message).
PRIMITIVES = frozenset(
    [
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    ]
)

#: sensor_msgs/PointField datatype constants.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

#: Beams of the OS-1-128 kept in the derived cloud (every 16th: 8 of 128, to keep the vendored
#: files near 2 MB; ring = the beam's index among all 128).
OUSTER_BEAMS = tuple(range(0, 128, 16))
OUSTER_PCAP = "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
OUSTER_JSON = "OS-1-128_v2.3.0_1024x10.json"
OUSTER_POSES = "OS-1-128_v2.3.0_1024x10_lb_n3_poses_kitti.txt"
VLP16_PCD = "1673400472138016708.pcd"
VLP16_STAMP_NS = 1673400472138016708


# --------------------------------------------------------------------------- schemas and messages


def _deps(pkg: str, text: str) -> list[str]:
    """The message types (``pkg/Type``) a ``.msg`` text's fields refer to, in field order.

    Constants are always of primitive types, so any field whose type (without array or bound
    suffix) is not primitive names a message, in ``pkg`` when it has no package.
    """
    deps = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        base = re.sub(r"<=\d+$", "", re.sub(r"\[.*\]$", "", tokens[0]))
        if base not in PRIMITIVES:
            deps.append(base if "/" in base else f"{pkg}/{base}")
    return deps


def ros2msg(name: str) -> str:
    """The concatenated ros2msg schema text of ``pkg/Type`` from ``schemas/msg`` of the repo.

    The type's own text first, then each dependency (depth-first in field order, each once)
    after a line of 80 ``=`` and ``MSG: pkg/Type``: the layout rosbag2 writes.
    """
    order: list[str] = []

    def visit(t: str) -> None:
        if t in order:
            return
        order.append(t)
        pkg, typ = t.split("/")
        for dep in _deps(pkg, (MSG_DIR / pkg / f"{typ}.msg").read_text()):
            visit(dep)

    visit(name)
    pkg, typ = name.split("/")
    blocks = [(MSG_DIR / pkg / f"{typ}.msg").read_text().rstrip("\n")]
    for dep in order[1:]:
        pkg, typ = dep.split("/")
        text = (MSG_DIR / pkg / f"{typ}.msg").read_text().rstrip()
        blocks.append(f"{SEPARATOR}\nMSG: {dep}\n{text}")
    return "\n".join(blocks) + "\n"


def stamp(ns: int) -> dict:
    """builtin_interfaces/Time of a nanosecond count."""
    return {"sec": int(ns) // 1_000_000_000, "nanosec": int(ns) % 1_000_000_000}


def point_fields(fields: list[tuple[str, int, int]]) -> list[dict]:
    """sensor_msgs/PointField dicts from (name, offset, datatype) triples (count 1)."""
    return [{"name": n, "offset": o, "datatype": d, "count": 1} for n, o, d in fields]


def cloud_msg(
    stamp_ns: int, frame: str, height: int, width: int, fields: list, step: int, data: bytes
) -> dict:
    """A little-endian sensor_msgs/PointCloud2 dict (rows unpadded, is_dense true)."""
    assert len(data) == height * width * step
    return {
        "header": {"stamp": stamp(stamp_ns), "frame_id": frame},
        "height": height,
        "width": width,
        "fields": point_fields(fields),
        "is_bigendian": False,
        "point_step": step,
        "row_step": width * step,
        "data": data,
        "is_dense": True,
    }


def quaternion(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a 3x3 rotation matrix (Shepperd's method)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    return tuple(float(v) for v in q)  # type: ignore[return-value]


def transform_msg(mat_mm: np.ndarray, parent: str, child: str, stamp_ns: int) -> dict:
    """geometry_msgs/TransformStamped of a 4x4 Ouster metadata transform (translation in mm)."""
    x, y, z, w = quaternion(np.asarray(mat_mm)[:3, :3])
    t = np.asarray(mat_mm)[:3, 3] * 1e-3
    return {
        "header": {"stamp": stamp(stamp_ns), "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
            "rotation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


class McapOut:
    """A ROS 2 MCAP being written (zstd chunks), schemas taken from ``schemas/msg``."""

    def __init__(self, path: Path) -> None:
        self._file = path.open("wb")
        self._writer = Ros2Writer(self._file)
        self._schemas: dict = {}

    def write(self, topic: str, msgtype: str, msg: dict, log_ns: int) -> None:
        """Write one message; log and publish time are ``log_ns``."""
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._writer.register_msgdef(
                msgtype.replace("/msg/", "/"), ros2msg(msgtype.replace("/msg/", "/"))
            )
        self._writer.write_message(topic, self._schemas[msgtype], msg, log_ns, log_ns)

    def close(self) -> None:
        """Finish the summary section and close the file."""
        self._writer.finish()
        self._file.close()


# ------------------------------------------------------------------------------- Ouster OS-1-128

#: ouster-ros's point (sensor-native "original" point type): PCL_ADD_POINT4D (x, y, z and a
#: padding float PCL sets to 1.0), then intensity, t, reflectivity, ring, ambient, range, 16-byte
#: aligned to 48 bytes.
OUSTER_DTYPE = np.dtype(
    {
        "names": [
            "x",
            "y",
            "z",
            "pad4d",
            "intensity",
            "t",
            "reflectivity",
            "ring",
            "ambient",
            "range",
        ],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
        "offsets": [0, 4, 8, 12, 16, 20, 24, 26, 28, 32],
        "itemsize": 48,
    }
)
OUSTER_FIELDS = [
    ("x", 0, FLOAT32),
    ("y", 4, FLOAT32),
    ("z", 8, FLOAT32),
    ("intensity", 16, FLOAT32),
    ("t", 20, UINT32),
    ("reflectivity", 24, UINT16),
    ("ring", 26, UINT16),
    ("ambient", 28, UINT16),
    ("range", 32, UINT32),
]


def ouster_scan_cloud(scan, info, lut, beams: tuple[int, ...]) -> tuple[dict, dict, int]:
    """One LidarScan as ouster-ros publishes it, restricted to ``beams``.

    Returns the PointCloud2 dict, the reference arrays of its points and its stamp (ns). As
    ouster-ros does: the cloud is destaggered (target column v of beam u takes measurement
    column (v - pixel_shift_by_row[u]) mod w), points are in os_sensor frame (XYZLut's default
    applies lidar_to_sensor), invalid returns (range 0) are kept as zero points, ``t`` is the
    column timestamp minus the scan's first valid column timestamp (the header stamp), intensity
    is SIGNAL (absent from the RNG15_RFL8_NIR8 profile, so zeros, as ouster-ros's
    get_or_fill_zero gives), ambient is NEAR_IR.
    """
    from ouster.sdk.core import ChanField

    w = info.format.columns_per_frame
    ts = np.asarray(scan.timestamp, dtype=np.int64)
    scan_ts = int(ts[scan.get_first_valid_column()])
    rng = np.asarray(scan.field(ChanField.RANGE)).astype(np.uint32)
    refl = np.asarray(scan.field(ChanField.REFLECTIVITY)).astype(np.uint16)
    nir = np.asarray(scan.field(ChanField.NEAR_IR)).astype(np.uint16)
    xyz = lut(rng)  # (h, w, 3) metres, os_sensor frame, float64
    xyz[rng == 0] = 0.0
    shift = np.asarray(info.format.pixel_shift_by_row)

    rows = np.asarray(beams)
    src_col = (np.arange(w)[None, :] - shift[rows][:, None]) % w  # (len(beams), w)
    beam = np.broadcast_to(rows[:, None], src_col.shape)
    pts = np.zeros(src_col.shape, OUSTER_DTYPE)
    sel_xyz = xyz[beam, src_col]
    pts["x"], pts["y"], pts["z"] = (sel_xyz[..., i].astype(np.float32) for i in range(3))
    pts["pad4d"] = 1.0
    col_ts = ts[src_col]
    pts["t"] = np.where(col_ts > scan_ts, col_ts - scan_ts, 0).astype(np.uint32)
    pts["reflectivity"] = refl[beam, src_col]
    pts["ring"] = beam
    pts["ambient"] = nir[beam, src_col]
    pts["range"] = rng[beam, src_col]
    msg = cloud_msg(scan_ts, "os_sensor", len(beams), w, OUSTER_FIELDS, 48, pts.tobytes())
    ref = {
        "xyz": sel_xyz.reshape(-1, 3),
        "time_ns": col_ts.reshape(-1),
        "beam": beam.reshape(-1).astype(np.uint16),
        "column": src_col.reshape(-1).astype(np.uint16),
        "range_mm": rng[beam, src_col].reshape(-1),
    }
    return msg, ref, scan_ts


def ouster_imu_msgs(pcap: Path, meta: Path) -> list[tuple[int, dict]]:
    """The IMU packets as ouster-ros publishes them: (stamp ns, sensor_msgs/Imu dict).

    Stamp = the packet's gyro timestamp (ouster-ros's TIME_FROM_INTERNAL_OSC mode), frame
    os_imu, acceleration in g times 9.80665, angular velocity in deg/s times pi/180,
    orientation (0, 0, 0, 1) with covariance all -1, diagonal covariances 6e-4 (gyro) and 0.01
    (accelerometer).
    """
    from ouster.sdk import core, open_packet_source

    source = open_packet_source(str(pcap), meta=[str(meta)])
    pf = core.PacketFormat(source.sensor_info[0])
    out = []
    for _, packet in source:
        if not isinstance(packet, core.ImuPacket):
            continue
        buf = packet.buf
        ts = int(pf.imu_gyro_ts(buf))
        g = 9.80665
        d2r = np.pi / 180.0
        diag = [1.0 if i % 4 == 0 else 0.0 for i in range(9)]
        out.append(
            (
                ts,
                {
                    "header": {"stamp": stamp(ts), "frame_id": "os_imu"},
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    "orientation_covariance": [-1.0] * 9,
                    "angular_velocity": {
                        "x": pf.imu_av_x(buf) * d2r,
                        "y": pf.imu_av_y(buf) * d2r,
                        "z": pf.imu_av_z(buf) * d2r,
                    },
                    "angular_velocity_covariance": [6e-4 * v for v in diag],
                    "linear_acceleration": {
                        "x": pf.imu_la_x(buf) * g,
                        "y": pf.imu_la_y(buf) * g,
                        "z": pf.imu_la_z(buf) * g,
                    },
                    "linear_acceleration_covariance": [0.01 * v for v in diag],
                },
            )
        )
    return out


def kitti_poses(path: Path) -> np.ndarray:
    """(n, 4, 4) poses of a KITTI pose file (a row of 12 numbers: a 3x4 [R | t] per scan)."""
    rows = np.loadtxt(path).reshape(-1, 3, 4)
    out = np.tile(np.eye(4), (len(rows), 1, 1))
    out[:, :3, :] = rows
    return out


def ground_height_m(ref: dict) -> float:
    """The ground's height in os_sensor (m, negative): the median z of the returns below the
    sensor within 12 m horizontally (the kept beams that look down hit the road at 6-10 m)."""
    xyz = ref["xyz"][ref["range_mm"] > 0]
    near = (np.hypot(xyz[:, 0], xyz[:, 1]) < 12.0) & (xyz[:, 2] < -1.0)
    return float(np.median(xyz[near, 2]))


def derived_odometry(
    poses: np.ndarray, scan_ns: list[int], at_ns: list[int]
) -> list[tuple[int, dict]]:
    """Wheel odometry derived from the recording's poses: (stamp ns, TwistStamped dict).

    The recording has no wheel encoders; its poses (one per scan, os_sensor's, KITTI layout)
    give the speed along the sensor's x and the yaw rate between consecutive scans, held over
    each interval and beyond the ends, published at ``at_ns`` (the IMU's stamps) in frame
    base_link (placed under the sensor, so its velocity is the sensor's horizontal one).
    """
    dt = np.diff(np.asarray(scan_ns, np.int64)) * 1e-9
    step = np.einsum("nji,nj->ni", poses[:-1, :3, :3], poses[1:, :3, 3] - poses[:-1, :3, 3])
    speed = step[:, 0] / dt
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    yaw_rate = np.arctan2(rel[:, 1, 0], rel[:, 0, 0]) / dt
    which = np.clip(np.searchsorted(scan_ns, at_ns, side="right") - 1, 0, len(dt) - 1)
    return [
        (
            t,
            {
                "header": {"stamp": stamp(t), "frame_id": "base_link"},
                "twist": {
                    "linear": {"x": float(speed[k]), "y": 0.0, "z": 0.0},
                    "angular": {"x": 0.0, "y": 0.0, "z": float(yaw_rate[k])},
                },
            },
        )
        for t, k in zip(at_ns, which.tolist(), strict=True)
    ]


def derive_ouster(src: Path, out: Path) -> None:
    """Write ``ouster-os1-128.mcap`` and ``ouster-os1-128.reference.npz``."""
    from ouster.sdk import core, open_source

    pcap, meta = src / OUSTER_PCAP, src / OUSTER_JSON
    source = open_source(str(pcap), meta=[str(meta)], sensor_idx=0)
    info = source.sensor_info[0]
    lut = core.XYZLut(info)  # default: sensor frame, i.e. lidar_to_sensor applied
    records: list[tuple[int, str, str, dict]] = []
    refs = []
    stamps = []
    for frame in source:
        scan = frame[0] if not hasattr(frame, "timestamp") else frame
        msg, ref, ts = ouster_scan_cloud(scan, info, lut, OUSTER_BEAMS)
        ref["scan"] = np.full(ref["beam"].shape, len(stamps), np.uint8)
        refs.append(ref)
        stamps.append(ts)
        records.append((ts, "/ouster/points", "sensor_msgs/msg/PointCloud2", msg))
    imu = ouster_imu_msgs(pcap, meta)
    for ts, msg in imu:
        records.append((ts, "/ouster/imu", "sensor_msgs/msg/Imu", msg))
    # Derived: the wheel odometry and base_link the pose stage needs, which the recording
    # lacks (README: "derived").
    odometry = derived_odometry(kitti_poses(src / OUSTER_POSES), stamps, [t for t, _ in imu])
    for ts, msg in odometry:
        records.append((ts, "/derived/odom", "geometry_msgs/msg/TwistStamped", msg))
    first = min(r[0] for r in records)
    ground = ground_height_m({k: np.concatenate([r[k] for r in refs]) for k in refs[0]})
    sensor_on_base = np.eye(4)
    sensor_on_base[2, 3] = -ground * 1e3  # mm, as the metadata's transforms
    tf = {
        "transforms": [
            transform_msg(sensor_on_base, "base_link", "os_sensor", first),
            transform_msg(info.lidar_to_sensor_transform, "os_sensor", "os_lidar", first),
            transform_msg(info.imu_to_sensor_transform, "os_sensor", "os_imu", first),
        ]
    }
    records.append((first, "/tf_static", "tf2_msgs/msg/TFMessage", tf))
    records.sort(key=lambda r: (r[0], r[1] != "/tf_static"))
    mcap = McapOut(out / "ouster-os1-128.mcap")
    for ts, topic, msgtype, msg in records:
        mcap.write(topic, msgtype, msg, ts)
    mcap.close()
    ref = {k: np.concatenate([r[k] for r in refs]) for k in refs[0]}
    np.savez_compressed(
        out / "ouster-os1-128.reference.npz",
        **ref,
        stamp_ns=np.asarray(stamps, np.int64),
        beams_kept=np.asarray(OUSTER_BEAMS, np.uint16),
    )


# ----------------------------------------------------------------------------------- VLP-16 PCD


def read_pcd(path: Path) -> tuple[list[tuple[str, int, int]], int, int, bytes]:
    """A binary PCD's (name, offset, PointField datatype) list, point size, count and data.

    Offsets come from the header's FIELDS, SIZE, TYPE and COUNT (fields packed in order, as
    binary PCD stores them).
    """
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.index(b"\n", pos)
        line = raw[pos:end].decode("ascii").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key] = vals
        if key == "DATA":
            break
    if header["DATA"] != ["binary"]:
        raise ValueError(f"{path}: DATA {header['DATA']}, expected binary")
    kinds = {
        ("F", 4): FLOAT32,
        ("F", 8): FLOAT64,
        ("U", 1): UINT8,
        ("U", 2): UINT16,
        ("U", 4): UINT32,
        ("I", 1): INT8,
        ("I", 2): INT16,
        ("I", 4): INT32,
    }
    fields, offset = [], 0
    for name, size, typ, count in zip(
        header["FIELDS"], header["SIZE"], header["TYPE"], header["COUNT"], strict=True
    ):
        if int(count) != 1:
            raise ValueError(f"{path}: field {name} has COUNT {count}")
        fields.append((name, offset, kinds[(typ, int(size))]))
        offset += int(size)
    n = int(header["POINTS"][0])
    data = raw[pos : pos + n * offset]
    if len(data) != n * offset:
        raise ValueError(f"{path}: {len(data)} data bytes for {n} points of {offset}")
    return fields, offset, n, data


def pcd_array(fields: list[tuple[str, int, int]], step: int, data: bytes) -> np.ndarray:
    """The PCD points as a numpy structured array (little-endian)."""
    np_types = {
        INT8: "i1",
        UINT8: "u1",
        INT16: "<i2",
        UINT16: "<u2",
        INT32: "<i4",
        UINT32: "<u4",
        FLOAT32: "<f4",
        FLOAT64: "<f8",
    }
    dtype = np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [np_types[f[2]] for f in fields],
            "offsets": [f[1] for f in fields],
            "itemsize": step,
        }
    )
    return np.frombuffer(data, dtype)


VELODYNE_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "ring", "time"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
        "offsets": [0, 4, 8, 12, 16, 18],
        "itemsize": 22,
    }
)
VELODYNE_FIELDS = [
    ("x", 0, FLOAT32),
    ("y", 4, FLOAT32),
    ("z", 8, FLOAT32),
    ("intensity", 12, FLOAT32),
    ("ring", 16, UINT16),
    ("time", 18, FLOAT32),
]
LIVOX_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "tag", "line", "timestamp"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "u1", "u1", "<f8"],
        "offsets": [0, 4, 8, 12, 16, 17, 18],
        "itemsize": 26,
    }
)
LIVOX_FIELDS = [
    ("x", 0, FLOAT32),
    ("y", 4, FLOAT32),
    ("z", 8, FLOAT32),
    ("intensity", 12, FLOAT32),
    ("tag", 16, UINT8),
    ("line", 17, UINT8),
    ("timestamp", 18, FLOAT64),
]


def derive_vlp16(src: Path, out: Path) -> None:
    """Write the nebula VLP-16 cloud (unchanged), its two derived re-packings and the reference."""
    fields, step, n, data = read_pcd(src / VLP16_PCD)
    pts = pcd_array(fields, step, data)
    stamp_ns = VLP16_STAMP_NS
    topic, frame = "/velodyne_points", "velodyne"

    def write(name: str, fields_: list, step_: int, data_: bytes) -> None:
        mcap = McapOut(out / name)
        msg = cloud_msg(stamp_ns, frame, 1, n, fields_, step_, data_)
        mcap.write(topic, "sensor_msgs/msg/PointCloud2", msg, stamp_ns)
        mcap.close()

    write("vlp16-nebula.mcap", fields, step, data)

    velo = np.zeros(n, VELODYNE_DTYPE)
    for k in ("x", "y", "z", "intensity"):
        velo[k] = pts[k]
    velo["ring"] = pts["channel"]
    velo["time"] = pts["time_stamp"].astype(np.float64) * 1e-9
    write("vlp16-velodyne-derived.mcap", VELODYNE_FIELDS, 22, velo.tobytes())

    livox = np.zeros(n, LIVOX_DTYPE)
    for k in ("x", "y", "z", "intensity"):
        livox[k] = pts[k]
    livox["line"] = pts["channel"]
    livox["timestamp"] = (stamp_ns + pts["time_stamp"].astype(np.int64)).astype(np.float64)
    write("vlp16-livox-derived.mcap", LIVOX_FIELDS, 26, livox.tobytes())

    np.savez_compressed(
        out / "vlp16.reference.npz",
        xyz=np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64),
        time_ns=stamp_ns + pts["time_stamp"].astype(np.int64),
        channel=pts["channel"].astype(np.uint16),
        stamp_ns=np.int64(stamp_ns),
    )


# ------------------------------------------------------------------------- Ouster packets (ROS 1)


def derive_packets(src: Path, out: Path) -> None:
    """Convert the ROS 1 bag of raw Ouster packets to ``ouster-packets-only.mcap`` (rosbags).

    Each ROS 1 message is deserialised and re-serialised as CDR with rosbags' typestore (the
    bag's own definitions registered as ROS 2 types), written by rosbags' rosbag2 Writer with
    MCAP storage, whose .mcap file carries a ros2msg schema per type. Log times are the bag's.
    """
    from rosbags.rosbag1 import Reader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(src / "512x10_raw.bag") as reader:
        types = {}
        for conn in reader.connections:
            if conn.msgtype not in store.types:
                types.update(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        store.register(types)
        with tempfile.TemporaryDirectory() as tmp:
            bag = Path(tmp) / "bag"
            with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
                conns = {
                    c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
                    for c in reader.connections
                }
                for conn, t, raw in reader.messages():
                    msg = store.deserialize_ros1(raw, conn.msgtype)
                    cdr = store.serialize_cdr(msg, conn.msgtype)
                    writer.write(conns[conn.id], t, cdr)
            (file,) = bag.glob("*.mcap")
            shutil.copyfile(file, out / "ouster-packets-only.mcap")


# --------------------------------------------------------------------------------------- checks


def summarise(path: Path) -> None:
    """Read an MCAP back, decode every message with mcap_ros2 and print a summary."""
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        counts: Counter[str] = Counter()
        times: dict[str, list[int]] = {}
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            times.setdefault(channel.topic, []).append(message.log_time)
            if hasattr(decoded, "point_step"):
                assert len(decoded.data) == decoded.row_step * decoded.height
    print(f"{path.name}: {path.stat().st_size} bytes, profile {header.profile!r}")
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        t = times.get(channel.topic, [0])
        print(
            f"  {channel.topic}: {schema.name} ({schema.encoding}, {len(schema.data)} B schema), "
            f"{channel.message_encoding}, {counts[channel.topic]} msgs, "
            f"log_time {min(t) / 1e9:.6f}..{max(t) / 1e9:.6f} s"
        )


def main() -> None:
    """Derive every output from ``--source`` into this script's folder and check them."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", type=Path, default=Path("/work/shared/real-lidar"))
    args = parser.parse_args()
    derive_ouster(args.source / "ouster-os1-128", HERE)
    derive_vlp16(args.source / "nebula-vlp16", HERE)
    derive_packets(args.source / "ouster-packets-ros1", HERE)
    for name in (
        "ouster-os1-128.mcap",
        "vlp16-nebula.mcap",
        "vlp16-velodyne-derived.mcap",
        "vlp16-livox-derived.mcap",
        "ouster-packets-only.mcap",
    ):
        summarise(HERE / name)
    for name in ("ouster-os1-128.reference.npz", "vlp16.reference.npz"):
        with np.load(HERE / name) as npz:
            print(name, {k: (npz[k].shape, str(npz[k].dtype)) for k in npz.files})


if __name__ == "__main__":
    main()
