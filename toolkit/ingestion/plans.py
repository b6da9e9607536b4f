"""Which topics of a log are ingested, and how: a :class:`TopicPlan` per configured topic.

A plan binds a topic to its role, its table, a decoder (:func:`~toolkit.mcapio.cdr.decode_batch`
bound to the channel's type) and the role's converter for that type
(:mod:`toolkit.ingestion.roles`). Any role may be missing from a log (its table is written
empty); a log holding none of the configured topics, or a type a role does not accept, is a
StageError that says what the log does hold and what the role accepts.

The log's schema decides how its bytes are read. Once per channel, its schema is compared
with the toolkit's layout of the type (:mod:`toolkit.mcapio.layout_check`): when they agree
(comments, constants and spacing aside) the fast decoder lays the bytes out by the toolkit's
definition; when they differ, the topic is decoded by the log's own schema if every field its
role reads is there by name with its standard type (one line on the terminal), and refused
with one line naming the topic and the first differing field otherwise.
"""

from __future__ import annotations

import difflib
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from toolkit.config import LidarConfig, TimeConfig, TopicsConfig
from toolkit.errors import SchemaError, StageError, ToolkitError
from toolkit.ingestion.roles import ROLE_SPECS, Decoder
from toolkit.ingestion.rows import ConvertContext, Converter
from toolkit.mcapio.cdr import decode_batch
from toolkit.mcapio.layout_check import ChannelLayout, channel_layout
from toolkit.mcapio.msgdefs import full_type_name
from toolkit.mcapio.pointcloud2 import packets_note
from toolkit.mcapio.reader import Channel


@dataclass(frozen=True)
class TopicPlan:
    """How one topic of the log is ingested: its role, table, decoder and converter."""

    topic: str
    role: str
    table: str
    schema_name: str
    type_name: str
    decode: Decoder
    convert: Converter
    context: ConvertContext
    #: The channel planned (another channel of the topic is planned on its own).
    channel_id: int = 0
    #: The terminal's line when the topic's schema departs from the standard layout and is
    #: decoded by the log's own schema ("" otherwise).
    notice: str = ""


def channel_decoder(topic: str, channel: Channel) -> Decoder:
    """decode_batch bound to the channel's type, by the layout its bytes follow: the
    toolkit's own (fast, by name) when the log's schema agrees with it, else the log's own
    schema (parsed once here). StageError when the messages are not CDR or the log's schema
    is unusable or missing for a type the toolkit does not ship."""
    return _decoder(topic, _layout(topic, channel))


def _layout(topic: str, channel: Channel) -> ChannelLayout:
    """The channel's schema compared with the toolkit's layout (StageError naming the topic
    when its messages are not CDR or its schema cannot be parsed)."""
    if channel.message_encoding != "cdr":
        raise StageError(
            f"topic {topic} has message encoding {channel.message_encoding!r}; only ROS 2 "
            "'cdr' messages can be ingested"
        )
    try:
        return channel_layout(channel)
    except SchemaError as exc:
        raise StageError(f"topic {topic}: unusable schema {channel.schema_name!r}: {exc}") from exc


def _decoder(topic: str, layout: ChannelLayout) -> Decoder:
    """decode_batch bound to the type's name (the fast layout) when the schema is standard,
    else to the log's own definition and its text; StageError when there is neither."""
    if layout.is_standard:
        return functools.partial(decode_batch, layout.type_name)
    if layout.log is not None:
        return functools.partial(decode_batch, layout.log, schema_text=layout.log_text)
    raise StageError(
        f"topic {topic}: no message definition for {layout.type_name!r} in the log or toolkit"
    )


def schema_notice(topic: str, layout: ChannelLayout, role: str) -> str:
    """The terminal's line for a topic whose schema departs from the standard layout but
    holds every field ``role`` reads ("" for a standard one)."""
    if layout.difference is None:
        return ""
    return (
        f"topic {topic}: its schema {layout.type_name} {layout.difference}: decoded by "
        f"the log's own schema, which has every field role {role} reads"
    )


def _check_schema(topic: str, role: str, layout: ChannelLayout) -> None:
    """StageError when the log's schema departs from the standard layout in a way the role
    cannot read (a field its converter reads is missing or of another type)."""
    problem = ROLE_SPECS[role].schema_problem(layout)
    if problem is not None:
        raise StageError(
            f"topic {topic}: its schema {layout.type_name} {layout.difference}; {problem}"
        )


def _is_ros_name(schema_name: str) -> bool:
    try:
        full_type_name(schema_name)
    except ToolkitError:
        return False
    return True


def _role_line(role: str, topics: Sequence[str]) -> str:
    accepts = ", ".join(ROLE_SPECS[role].accepted_types)
    return f"{role} ({', '.join(topics)}; accepts {accepts})"


def resolve_topics(
    topics: TopicsConfig,
    time: TimeConfig,
    found: Mapping[str, Channel],
    log_path: Path,
    lidar: LidarConfig | None = None,
) -> tuple[dict[str, TopicPlan], dict[str, list[str]], list[str]]:
    """Plan every configured topic present in the log.

    Returns (topic -> plan, role -> configured topics missing from the log, warnings). Any
    role may be missing: all missing roles are reported in one warning line, each with its
    configured topics and the message types it accepts (their tables are written empty). A
    log holding none of the configured topics is a StageError naming the topics it does
    hold; a message type a role does not accept is a StageError naming topic, type and the
    accepted types.
    """
    plans: dict[str, TopicPlan] = {}
    missing: dict[str, list[str]] = {}
    warnings: list[str] = []
    wholly_missing: list[str] = []
    by_role = topics.by_role()
    claimed = {t for role_topics in by_role.values() for t in role_topics}
    for role, role_topics in by_role.items():
        absent = [t for t in role_topics if t not in found]
        if absent:
            missing[role] = absent
            for topic in absent:
                hint = did_you_mean(topic, role, found, claimed)
                if hint:
                    warnings.append(f"role {role}: topic {topic} not in the log; {hint}")
        if len(absent) == len(role_topics):
            wholly_missing.append(role)
        elif absent:
            warnings.append(f"role {role}: topic(s) {', '.join(absent)} not in the log")
        for topic in role_topics:
            if topic in found:
                plans[topic] = plan_topic(topic, role, found[topic], time, log_path, lidar)
                if plans[topic].notice:
                    warnings.append(plans[topic].notice)
    if not plans:
        configured = "; ".join(_role_line(r, t) for r, t in by_role.items()) or "none"
        packets = [
            packets_note(t, full_type_name(c.schema_name))
            for t, c in sorted(found.items())
            if c.schema_name and _is_ros_name(c.schema_name)
        ]
        raise StageError(
            f"none of the configured topics is in the log (configured: {configured}; topics "
            f"found: {', '.join(sorted(found)) or 'none'}); give a configuration for this "
            "vehicle with -c" + "".join(f"; {n}" for n in packets if n),
            path=log_path,
        )
    if wholly_missing:
        warnings.insert(
            0,
            "roles missing from the log, their tables empty: "
            + "; ".join(_role_line(r, by_role[r]) for r in wholly_missing),
        )
    return plans, missing, warnings


def did_you_mean(
    topic: str, role: str, found: Mapping[str, Channel], configured: set[str]
) -> str | None:
    """For a configured ``topic`` the log lacks: the log's topic it most likely meant, as
    a hint ("did you mean /imu/data (sensor_msgs/msg/Imu)?"), or None. Candidates are the
    log's topics of a type ``role`` accepts that no role reads; the closest name wins
    (``difflib``), and the only candidate is named even when its name is not close (a
    vehicle's one IMU under another name)."""
    accepts = set(ROLE_SPECS[role].accepted_types)
    candidates = {}
    for name, channel in found.items():
        if name in configured or not channel.schema_name or not _is_ros_name(channel.schema_name):
            continue
        type_name = full_type_name(channel.schema_name)
        if type_name in accepts:
            candidates[name] = type_name
    if not candidates:
        return None
    close = difflib.get_close_matches(topic, list(candidates), n=1, cutoff=0.6)
    if close:
        best = close[0]
    elif len(candidates) == 1:
        (best,) = candidates
    else:
        return None
    only = ", the log's only one of a type it accepts" if len(candidates) == 1 else ""
    return f"did you mean {best} ({candidates[best]}{only})?"


def plan_topic(
    topic: str,
    role: str,
    channel: Channel,
    time: TimeConfig,
    log_path: Path,
    lidar: LidarConfig | None = None,
) -> TopicPlan:
    """The plan of one channel playing ``role``; StageError (naming the log) when the role
    does not accept its type or its messages cannot be decoded."""
    spec = ROLE_SPECS[role]
    try:
        note = packets_note(topic, full_type_name(channel.schema_name))
        if note and role == "lidars":
            raise StageError(note)
        convert = spec.converter_for(topic, channel.schema_name)
        layout = _layout(topic, channel)
        _check_schema(topic, role, layout)
        decode = spec.decoder_for(topic, channel.schema_name) or _decoder(topic, layout)
    except StageError as exc:
        raise StageError(str(exc), path=log_path) from None
    return TopicPlan(
        topic=topic,
        role=role,
        table=spec.table,
        schema_name=channel.schema_name,
        type_name=full_type_name(channel.schema_name),
        decode=decode,
        convert=convert,
        context=ConvertContext.for_topic(
            topic, role, channel.schema_name, time, lidar if role == "lidars" else None
        ),
        channel_id=channel.id,
        notice=schema_notice(topic, layout, role),
    )


__all__ = [
    "Decoder",
    "TopicPlan",
    "channel_decoder",
    "plan_topic",
    "resolve_topics",
    "schema_notice",
]
