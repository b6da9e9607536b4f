"""Benchmark: decoding PointCloud2 payloads to positions and point times, against rosbags.

Both ways go from a CDR payload to the same arrays, for Ouster clouds (ouster-ros's layout,
point_step 48, header at the sweep's start, ``t`` uint32 ns), 128 x 1024 points each:

* ``toolkit``: :func:`parse_cloud` + :func:`cloud_dtype` + :func:`cloud_points` +
  :func:`xyz_valid` + :func:`point_times_ns` (toolkit.mcapio.pointcloud2);
* ``rosbags``: rosbags' public deserialiser (``get_typestore(Stores.ROS2_HUMBLE)
  .deserialize_cdr``), a numpy structured view of ``msg.data`` built from ``msg.fields``, then
  the plain numpy a user would write for the same arrays (xyz float32 of the finite, non-zero
  points, and int64 ns times);
* ``rosbags+ours``: rosbags' deserialiser, then the toolkit's dtype, view, ``xyz_valid`` and
  times, so the difference from ``toolkit`` is the deserialisation alone.

Each way runs ``--clouds`` decodes, cycling over ``--distinct`` generated payloads (distinct
payloads of 6.3 MB each are already far larger than the caches; holding 200 of them would take
1.3 GB for nothing). The ways are timed in turn, ``--repeats`` times, and the best time of each
is kept. The arrays of every way are checked equal first. One process, one thread.

Usage::

    python benchmarks/pointcloud2_decode.py [--clouds 200] [--distinct 8] [--repeats 3]

Targets: toolkit at least 2x the rosbags way, and at least 20 M points/s.
"""

from __future__ import annotations

import argparse
import os
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from toolkit.mcapio.pointcloud2 import (
    DATATYPES,
    PRESETS,
    PointField,
    cloud_dtype,
    cloud_points,
    parse_cloud,
    point_times_ns,
    xyz_valid,
)

TOPIC = "/ouster/points"
TYPE = "sensor_msgs/msg/PointCloud2"
#: ouster-ros PointOS: name, offset, datatype; point_step 48.
OUSTER = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6),
          ("reflectivity", 24, 4), ("ring", 26, 4), ("ambient", 28, 4), ("range", 32, 6)]  # fmt: skip
STEP = 48
STAMP_NS = 1_700_000_000_000_000_000
SWEEP_NS = 100_000_000

#: What each way returns: xyz (m, 3), keep (n,), times of the kept points (m,).
Result = tuple[np.ndarray, np.ndarray, np.ndarray]


def make_payload(height: int, width: int, seed: int) -> bytes:
    """One Ouster cloud as CDR: a sphere of points, 10 % of them "no return" (zero)."""
    rng = np.random.default_rng(seed)
    n = height * width
    dt = np.dtype({"names": [f[0] for f in OUSTER],
                   "formats": ["<" + DATATYPES[f[2]] for f in OUSTER],
                   "offsets": [f[1] for f in OUSTER], "itemsize": STEP})  # fmt: skip
    pts = np.zeros(n, dtype=dt)
    r = rng.uniform(1, 80, n)
    az = np.tile(np.linspace(0, 2 * np.pi, width, endpoint=False), height)
    el = np.repeat(np.linspace(-0.4, 0.4, height), width)
    pts["x"], pts["y"], pts["z"] = (
        r * np.cos(el) * np.cos(az),
        r * np.cos(el) * np.sin(az),
        r * np.sin(el),
    )
    pts["t"] = np.tile(np.arange(width) * (SWEEP_NS // width), height)
    pts["ring"] = np.repeat(np.arange(height), width)
    none = rng.random(n) < 0.1
    for axis in "xyz":
        pts[axis][none] = 0.0
    out = bytearray(b"\x00\x01\x00\x00")

    def u32(v: int) -> None:
        out.extend(bytes(-(len(out) - 4) % 4))
        out.extend(struct.pack("<I", v))

    def string(s: str) -> None:
        u32(len(s) + 1)
        out.extend(s.encode() + b"\x00")

    out.extend(struct.pack("<iI", *divmod(STAMP_NS + seed * SWEEP_NS, 10**9)))
    string("os_lidar")
    u32(height)
    u32(width)
    u32(len(OUSTER))
    for name, offset, datatype in OUSTER:
        string(name)
        u32(offset)
        out.append(datatype)
        u32(1)
    out.append(0)
    u32(STEP)
    u32(width * STEP)
    u32(n * STEP)
    out.extend(pts.tobytes())
    out.append(0)  # is_dense false: ouster-ros publishes zeros for no return
    return bytes(out)


def toolkit_way(payload: bytes) -> Result:
    cloud = parse_cloud(payload, topic=TOPIC)
    dtype = cloud_dtype(cloud.fields, cloud.point_step, cloud.is_bigendian, topic=TOPIC)
    points = cloud_points(cloud, dtype)
    xyz, keep, _ = xyz_valid(points)
    times = point_times_ns(points, cloud.stamp_ns, PRESETS["ouster"], topic=TOPIC, keep=keep)
    return xyz, keep, times


def rosbags_way(typestore: Any) -> Callable[[bytes], Result]:
    def decode(payload: bytes) -> Result:
        msg = typestore.deserialize_cdr(payload, TYPE)
        order = ">" if msg.is_bigendian else "<"
        dt = np.dtype({"names": [f.name for f in msg.fields],
                       "formats": [order + DATATYPES[f.datatype] for f in msg.fields],
                       "offsets": [f.offset for f in msg.fields],
                       "itemsize": msg.point_step})  # fmt: skip
        points = np.frombuffer(msg.data, dtype=dt, count=msg.height * msg.width)
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=1)
        keep = np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)
        stamp_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        times = points["t"][keep].astype(np.int64) + stamp_ns
        return xyz[keep], keep, times

    return decode


def rosbags_then_ours(typestore: Any) -> Callable[[bytes], Result]:
    def decode(payload: bytes) -> Result:
        msg = typestore.deserialize_cdr(payload, TYPE)
        fields = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
        dtype = cloud_dtype([PointField(*f) for f in fields], msg.point_step,
                            msg.is_bigendian, topic=TOPIC)  # fmt: skip
        points = np.frombuffer(msg.data, dtype=dtype, count=msg.height * msg.width)
        xyz, keep, _ = xyz_valid(points)
        stamp_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        times = point_times_ns(points, stamp_ns, PRESETS["ouster"], topic=TOPIC, keep=keep)
        return xyz, keep, times

    return decode


def time_way(decode: Callable[[bytes], Result], payloads: list[bytes], clouds: int) -> float:
    t0 = time.perf_counter()
    for i in range(clouds):
        decode(payloads[i % len(payloads)])
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clouds", type=int, default=200)
    ap.add_argument("--distinct", type=int, default=8)
    ap.add_argument("--height", type=int, default=128)
    ap.add_argument("--width", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    payloads = [make_payload(args.height, args.width, s) for s in range(args.distinct)]
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    ways = {
        "toolkit": toolkit_way,
        "rosbags": rosbags_way(typestore),
        "rosbags+ours": rosbags_then_ours(typestore),
    }
    for p in payloads:  # the same arrays, every way
        ref = ways["toolkit"](p)
        for name, way in ways.items():
            got = way(p)
            for a, b in zip(ref, got, strict=True):
                if not np.array_equal(a, b):
                    raise SystemExit(f"{name} disagrees with toolkit")
    n_points = args.clouds * args.height * args.width
    print(f"{args.clouds} clouds of {args.height}x{args.width} points ({STEP} B each, "
          f"{len(payloads[0]) / 1e6:.1f} MB a payload), best of {args.repeats}; "
          f"load average before {os.getloadavg()}")  # fmt: skip
    best = dict.fromkeys(ways, float("inf"))
    for _ in range(args.repeats):
        for name, way in ways.items():
            best[name] = min(best[name], time_way(way, payloads, args.clouds))
    for name, wall in best.items():
        print(f"{name:>13}: {wall:6.2f} s  {wall / args.clouds * 1e3:6.2f} ms/cloud  "
              f"{n_points / wall / 1e6:6.1f} M points/s")  # fmt: skip
    print(
        f"toolkit / rosbags: {best['rosbags'] / best['toolkit']:.2f}x faster; "
        f"toolkit / rosbags+ours: {best['rosbags+ours'] / best['toolkit']:.2f}x"
    )
    print(f"load average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
