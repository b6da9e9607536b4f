"""Step 1 of ``config init``: what a log says about its sensors (types, rates, frames,
the IMU's gravity, static transforms).

Part of :mod:`toolkit.config_init`, whose docstring tells the steps.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.errors import ToolkitError
from toolkit.geometry.mounts import StaticTransform
from toolkit.geometry.static_transforms import (
    StaticTransformSet,
    TransformRecord,
    select_static_transforms,
)
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.mcapio.info import LogInfo, scan_log
from toolkit.mcapio.layout_check import ChannelLayout
from toolkit.mcapio.msgdefs import full_type_name
from toolkit.mcapio.reader import LogReader

#: Sensor roles whose messages carry the frame their mount is looked up by.
FRAMED_ROLES: tuple[str, ...] = ("lasers", "lidars", "imu", "gps")
#: Largest mount offset the configuration accepts (``[vehicle] *_position_m``), m.
MAX_MOUNT_M = 100.0
#: An IMU tilted less than this (deg) at the start is taken as level (the robot on a slope).
LEVEL_DEG = 20.0

#: Kinds of `terrain info` problems that are no damage: said as notes (a lidar recorded as
#: packets, a schema departing from the toolkit's layout of its type).
NOTE_KINDS: frozenset[str] = frozenset({"lidar_packets", "nonstandard_schema"})

IMU_TYPE = "sensor_msgs/msg/Imu"
TF_TYPE = "tf2_msgs/msg/TFMessage"


# --------------------------------------------------------------------------------------
# 1. What the log says
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicSummary:
    """One topic: its full type name (or the schema name as given when it is not a ROS type
    name), count and mean rate (Hz, None under two messages); for sensor topics the frame of
    their first message ("" when not read) and for an IMU its mean acceleration (m/s^2, in
    its own frame) over the first messages."""

    topic: str
    type_name: str
    count: int
    rate_hz: float | None
    frame_id: str = ""
    accel_mean: tuple[float, float, float] | None = None
    problem: str = ""
    #: A point cloud's field names (its driver's layout), from its first message.
    point_fields: tuple[str, ...] = ()
    #: Its schema compared with the toolkit's layout of its type (None: not parsed).
    layout: ChannelLayout | None = None


@dataclass(frozen=True)
class LogSummary:
    """What :func:`summarize_log` read: the log, its duration, its topics, and the static
    transforms of its tf_static topic (``tf_static_topic`` "" when it has none) that ingest
    will keep (:mod:`toolkit.geometry.static_transforms`)."""

    path: Path
    duration_s: float
    topics: tuple[TopicSummary, ...]
    tf_static_topic: str = ""
    transforms: tuple[StaticTransform, ...] = ()
    problems: int = 0
    #: What the user must know of the log beyond its damage (a lidar recorded as packets).
    notes: tuple[str, ...] = ()
    #: What the static transforms' rule dropped or replaced, as ingest will say it.
    tf_warnings: tuple[str, ...] = ()

    def topic(self, name: str) -> TopicSummary:
        """The summary of one topic (KeyError when the log has no such topic)."""
        return next(t for t in self.topics if t.topic == name)


def _type_name(schema_name: str) -> str:
    try:
        return full_type_name(schema_name)
    except ToolkitError:  # not a ROS type name: kept as is, it matches no role
        return schema_name


def _accepted_by_any(type_name: str) -> bool:
    return any(type_name in spec.converters for spec in ROLE_SPECS.values())


def summarize_log(path: str | Path) -> LogSummary:
    """Read what :func:`guess_roles` and :func:`render_config` need from a log.

    Reads the summary (or index) for the topics, then only the first batch of every topic a
    role accepts and every message of a ``tf_static`` topic. Raises
    :class:`~toolkit.errors.LogReadError` for a file that is missing or not MCAP.
    """
    path = Path(path)
    info: LogInfo = scan_log(path)
    types = {t.topic: _type_name(t.message_type) for t in info.topics}
    # A topic with no message has no first batch: asking for it would read the whole log.
    counts = {t.topic: t.message_count for t in info.topics}
    wanted = {topic for topic, tp in types.items() if _accepted_by_any(tp) and counts[topic] != 0}
    tf_topic = _tf_static_topic(types)
    tf_count = next((t.message_count for t in info.topics if t.topic == tf_topic), 0)
    first: dict[str, dict[str, np.ndarray]] = {}
    problems: dict[str, str] = {}
    tf_messages: list[dict[str, np.ndarray]] = []
    if wanted:
        _read_first_batches(path, wanted, tf_topic, tf_count, first, problems, tf_messages)
    kept = _transforms(tf_messages, tf_topic)
    topics = []
    for t in info.topics:
        cols = first.get(t.topic, {})
        topics.append(
            TopicSummary(
                topic=t.topic,
                type_name=types[t.topic],
                count=t.message_count,
                rate_hz=t.mean_rate_hz,
                frame_id=_first_frame(cols),
                accel_mean=_accel_mean(cols) if types[t.topic] == IMU_TYPE else None,
                problem=problems.get(t.topic, ""),
                point_fields=_point_fields(cols),
                layout=t.layout,
            )
        )
    return LogSummary(
        path=path,
        duration_s=info.duration_s,
        topics=tuple(topics),
        tf_static_topic=tf_topic,
        transforms=tuple(StaticTransform.from_record(r) for r in kept.transforms),
        problems=sum(p.kind not in NOTE_KINDS for p in info.problems),
        notes=tuple(p.message for p in info.problems if p.kind in NOTE_KINDS),
        tf_warnings=kept.warnings,
    )


def _tf_static_topic(types: Mapping[str, str]) -> str:
    """The static-transform topic: a TFMessage topic named for it (``/tf`` is dynamic)."""
    found = sorted(t for t, tp in types.items() if tp == TF_TYPE and "tf_static" in t.lower())
    return found[0] if found else ""


def _read_first_batches(
    path: Path,
    wanted: set[str],
    tf_topic: str,
    tf_count: int,
    first: dict[str, dict[str, np.ndarray]],
    problems: dict[str, str],
    tf_messages: list[dict[str, np.ndarray]],
) -> None:
    """Decode the first batch of each wanted topic and every tf_static message, stopping as
    soon as that is done (the start of the log, for a log of any length)."""
    from toolkit.ingestion.plans import channel_decoder

    seen: set[str] = set()
    tf_seen = 0
    with LogReader(path, topics=wanted) as reader:
        for batch in reader.batches():
            topic = batch.channel.topic
            if topic == tf_topic or topic not in seen:
                try:
                    own = _own_decoder(topic, batch.channel.schema_name)
                    cols = (own or channel_decoder(topic, batch.channel))(batch.payloads)
                except ToolkitError as exc:  # a sensor whose messages do not decode
                    problems.setdefault(topic, str(exc))
                    cols = {}
                if topic == tf_topic:
                    tf_seen += len(batch.payloads)
                    if cols:
                        tf_messages.append(cols)
                elif cols:
                    first[topic] = cols
                seen.add(topic)
            if seen >= wanted and tf_seen >= tf_count:
                break


def _own_decoder(topic: str, schema_name: str) -> Any:
    """A role's own decoder of this type (a point cloud's), or None."""
    for spec in ROLE_SPECS.values():
        decoder = spec.decoder_for(topic, schema_name)
        if decoder is not None:
            return decoder
    return None


def _point_fields(cols: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    clouds = cols.get("cloud")
    if clouds is None or len(clouds) == 0:
        return ()
    return tuple(f.name for f in clouds[0].fields)


def _first_frame(cols: Mapping[str, np.ndarray]) -> str:
    clouds = cols.get("cloud")
    if clouds is not None and len(clouds):
        return str(clouds[0].frame_id).strip().lstrip("/")
    frames = cols.get("header.frame_id")
    if frames is None or len(frames) == 0:
        return ""
    return str(frames[0]).strip().lstrip("/")  # ROS 1 frames may start with "/"


def _accel_mean(cols: Mapping[str, np.ndarray]) -> tuple[float, float, float] | None:
    try:
        mean = [float(np.nanmean(np.asarray(cols[f"linear_acceleration.{a}"]))) for a in "xyz"]
    except KeyError:
        return None
    return (mean[0], mean[1], mean[2]) if all(math.isfinite(m) for m in mean) else None


def _transforms(messages: Iterable[Mapping[str, np.ndarray]], topic: str) -> StaticTransformSet:
    """The static transforms of decoded TFMessage batches, kept by the rule ingest keeps
    them by (:mod:`toolkit.geometry.static_transforms`)."""
    records: list[TransformRecord] = []
    for cols in messages:
        for per_msg in cols.get("transforms", []):
            parents = np.asarray(per_msg.get("header.frame_id", []), dtype=str)
            children = np.asarray(per_msg.get("child_frame_id", []), dtype=str)
            t = np.stack(
                [np.asarray(per_msg[f"transform.translation.{a}"], np.float64) for a in "xyz"],
                axis=-1,
            ).reshape(-1, 3)
            q = np.stack(
                [np.asarray(per_msg[f"transform.rotation.{a}"], np.float64) for a in "xyzw"],
                axis=-1,
            ).reshape(-1, 4)
            records.extend(
                TransformRecord(
                    str(parents[k]).lstrip("/"),
                    str(children[k]).lstrip("/"),
                    0,
                    tuple(float(v) for v in t[k]),
                    tuple(float(v) for v in q[k]),
                )
                for k in range(len(children))
            )
    return select_static_transforms(records, topic)
