"""Reading a simulated log back for the simulator tests: topics as columns, metadata, truth.

Everything the tests compare against comes from the log itself (header stamps, the
``terrain_sim`` metadata record, ``/truth/odom``, ``/tf_static``) or from rebuilding the world
with :func:`toolkit.sim.world.make_world` from that metadata; never from the simulator's
internal state.
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation, Slerp

from toolkit.mcapio.cdr import decode_batch
from toolkit.sim.world import World, make_world
from toolkit.sim.world_params import WorldParams

from .reference_labeller import Events, label_events

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

GRAVITY_MPS2 = 9.80665
LASER_TOPICS = tuple(f"/laser/front_{i}" for i in range(1, 6))
LASER_FRAMES = tuple(f"laser_{i}" for i in range(1, 6))


def _tuples(value: Any) -> Any:
    """JSON lists back to the tuples a frozen dataclass field holds."""
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def world_params_from_json(text: str) -> WorldParams:
    return WorldParams(**{k: _tuples(v) for k, v in json.loads(text).items()})


def stamps_ns(columns: dict[str, Any]) -> IntArray:
    """``header.stamp`` as int64 nanoseconds."""
    sec = np.asarray(columns["header.stamp.sec"], dtype=np.int64)
    nsec = np.asarray(columns["header.stamp.nanosec"], dtype=np.int64)
    return sec * 1_000_000_000 + nsec


def on_grid_true_times(
    stamp_ns: IntArray, offset_ns: int, start_ns: int, period_ns: int
) -> IntArray:
    """True times of a sensor sampled on a ``period_ns`` grid from ``start_ns``: its stamps
    less the clock offset, rounded to the grid (jitter is far below half a period)."""
    k = np.round((stamp_ns - offset_ns - start_ns) / period_ns).astype(np.int64)
    return start_ns + k * period_ns


@dataclass
class Truth:
    """``/truth/odom`` (100 Hz), interpolable at any true time."""

    t_ns: IntArray
    position: FloatArray  # (n, 3) base_link in ENU
    rotation: Rotation  # world_from_base
    velocity_body: FloatArray  # (n, 3)
    omega_body: FloatArray  # (n, 3)
    route_s: FloatArray  # route distance of each pose
    route_d: FloatArray  # lateral offset of each pose from the centreline (left positive)
    _slerp: Slerp = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._slerp = Slerp(self._rel(self.t_ns), self.rotation)

    def _rel(self, t_ns: IntArray) -> FloatArray:
        return (np.asarray(t_ns, dtype=np.int64) - self.t_ns[0]) * 1e-9

    @property
    def speed(self) -> FloatArray:
        return np.linalg.norm(self.velocity_body, axis=1)

    @cached_property
    def path_length(self) -> FloatArray:
        """Horizontal distance travelled by the rear axle (base_link) since the first pose."""
        step = np.hypot(*np.diff(self.position[:, :2], axis=0).T)
        return np.concatenate([[0.0], np.cumsum(step)])

    def covers(self, t_ns: IntArray) -> NDArray[np.bool_]:
        return (t_ns >= self.t_ns[0]) & (t_ns <= self.t_ns[-1])

    def interp(self, t_ns: IntArray, values: FloatArray) -> FloatArray:
        """Linear interpolation of per-pose ``values`` (n,) or (n, k) at true times."""
        x, xp = self._rel(t_ns), self._rel(self.t_ns)
        if values.ndim == 1:
            return np.interp(x, xp, values)
        return np.stack([np.interp(x, xp, values[:, j]) for j in range(values.shape[1])], axis=1)

    def rotation_at(self, t_ns: IntArray) -> Rotation:
        return self._slerp(self._rel(t_ns))


@dataclass
class SimLog:
    """One simulated log, decoded: ``columns[topic]`` as produced by ``decode_batch`` (decoded
    by the schema the log carries), ``log_times[topic]`` and the ``terrain_sim`` metadata."""

    path: Path
    columns: dict[str, dict[str, Any]]
    log_times: dict[str, IntArray]
    schemas: dict[str, str]
    meta: dict[str, str]

    def json(self, key: str) -> Any:
        return json.loads(self.meta[key])

    @property
    def seed(self) -> int:
        return int(self.meta["seed"])

    @property
    def start_ns(self) -> int:
        return int(self.meta["start_time_ns"])

    @cached_property
    def sensors(self) -> dict[str, Any]:
        return self.json("sensors")

    @cached_property
    def clock_offsets(self) -> dict[str, int]:
        return {k: int(v) for k, v in self.json("clock_offsets_ns").items()}

    def stamps(self, topic: str) -> IntArray:
        return stamps_ns(self.columns[topic])

    @cached_property
    def world(self) -> World:
        return make_world(world_params_from_json(self.meta["world"]), self.seed)

    @cached_property
    def truth(self) -> Truth:
        c = self.columns["/truth/odom"]
        pos = np.stack([c[f"pose.pose.position.{a}"] for a in "xyz"], axis=1)
        quat = np.stack([c[f"pose.pose.orientation.{a}"] for a in "xyzw"], axis=1)
        vel = np.stack([c[f"twist.twist.linear.{a}"] for a in "xyz"], axis=1)
        omega = np.stack([c[f"twist.twist.angular.{a}"] for a in "xyz"], axis=1)
        route = self.world.route
        # Nearest centreline vertex as the guess, then the route's own Newton projection.
        _, nearest = cKDTree(np.stack([route.x_m, route.y_m], axis=1)).query(pos[:, :2])
        s, d = route.to_route(pos[:, 0], pos[:, 1], route.s_m[nearest])
        return Truth(
            t_ns=self.stamps("/truth/odom"),
            position=pos,
            rotation=Rotation.from_quat(quat),
            velocity_body=vel,
            omega_body=omega,
            route_s=s,
            route_d=d,
        )

    def static_transform(self, child_frame: str) -> tuple[FloatArray, FloatArray]:
        """``/tf_static``'s translation (3,) and quaternion xyzw (4,) for ``child_frame``."""
        tf = self.columns["/tf_static"]["transforms"][0]
        rows = np.flatnonzero(np.asarray(tf["child_frame_id"]) == child_frame)
        assert rows.size == 1, f"{child_frame}: {rows.size} transforms in /tf_static"
        k = int(rows[0])
        xyz = np.array([tf[f"transform.translation.{a}"][k] for a in "xyz"], dtype=np.float64)
        q = np.array([tf[f"transform.rotation.{a}"][k] for a in "xyzw"], dtype=np.float64)
        return xyz, q


def load_log(path: Path) -> SimLog:
    payloads: dict[str, list[bytes]] = defaultdict(list)
    times: dict[str, list[int]] = defaultdict(list)
    schemas: dict[str, str] = {}
    schema_text: dict[str, str] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        for schema, channel, message in reader.iter_messages():
            payloads[channel.topic].append(message.data)
            times[channel.topic].append(message.log_time)
            if channel.topic not in schemas:
                assert schema is not None
                schemas[channel.topic] = schema.name
                schema_text[channel.topic] = schema.data.decode("utf-8")
    columns = {
        topic: decode_batch(schemas[topic], p, schema_text=schema_text[topic])
        for topic, p in payloads.items()
    }
    log_times = {t: np.asarray(v, dtype=np.int64) for t, v in times.items()}
    return SimLog(Path(path), columns, log_times, schemas, meta["terrain_sim"])


def label_log(log: SimLog, imu_rate_hz: float) -> Events:
    """The reference labeller's events for a simulated log: IMU z at its true sample times,
    rear-axle travel and speed from the truth."""
    t = on_grid_true_times(
        log.stamps("/imu/data"),
        log.clock_offsets["/imu/data"],
        log.start_ns,
        int(round(1e9 / imu_rate_hz)),
    )
    return label_events(
        t,
        np.asarray(log.columns["/imu/data"]["linear_acceleration.z"], dtype=np.float64),
        log.truth.t_ns,
        log.truth.position[:, :2],
        log.truth.speed,
        imu_rate_hz=imu_rate_hz,
    )
