"""What is in an MCAP log, and what is wrong with it: the ``terrain info`` verb.

:func:`scan_log` reports per topic the message type, count, messages lost, first and last log
time, mean rate, largest gap and the number of gaps longer than three median periods; overall
the time span, header, metadata and attachment names, chunks and their compression; and the
problems found.

It reads the log through the toolkit's one MCAP reader (:class:`~toolkit.mcapio.reader.LogReader`),
the same one ingest uses, so both report the same damage: every :class:`~toolkit.mcapio.reader.
Damage` the reader finds becomes a problem whose kind is the damage's reason (``no_summary``,
``bad_index``, ``truncated``, ``chunk_crc``, ``chunk_decompress``, ``unsupported_compression``,
``bad_record``, ``unknown_channel``), and messages the reader could not salvage are counted per
topic as lost, exactly as ingest's manifest counts them. To those, ``info`` adds what it sees in
the messages themselves: ``out_of_order`` (a message of a topic earlier in log time than one
before it in the file), ``duplicates`` (same topic, log time and bytes), ``empty_topic``,
``unknown_schema`` (not decodable as ROS 2 CDR), ``nonstandard_schema`` (the log's schema of a
type the toolkit ships departs from the toolkit's layout of it: the first differing field,
:mod:`toolkit.mcapio.layout_check`) and ``summary_mismatch`` (the summary's message count
disagrees with the data).

When the log has a complete summary with chunk and message indexes the scan reads only those
(``scan == "index"``: fast, no chunk is decompressed, so chunk CRCs are not checked; chunks
holding same-topic same-time messages force a full read to compare their bytes). ``full=True``,
or a log whose index cannot vouch for every message, reads every chunk with CRC checks
(``scan == "full"``). Only a file that is missing or not MCAP at all raises
:class:`~toolkit.errors.LogReadError`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding

from toolkit.errors import ToolkitError
from toolkit.mcapio.layout_check import ChannelLayout, channel_layout
from toolkit.mcapio.msgdefs import full_type_name
from toolkit.mcapio.pointcloud2 import packets_note
from toolkit.mcapio.reader import Channel, LogReader, ReadReport


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a log: a short machine-readable ``kind`` and a readable message.

    Kinds: the reader's damage reasons (see :mod:`toolkit.mcapio.reader`) and ``out_of_order``,
    ``duplicates``, ``empty_topic``, ``unknown_schema``, ``nonstandard_schema``,
    ``summary_mismatch``.
    """

    kind: str
    message: str


@dataclass(frozen=True)
class TopicInfo:
    """Per-topic figures from the messages' log times (ns).

    ``mean_rate_hz`` is (count - 1) / (last - first); ``max_gap_s`` the largest step between
    consecutive log times; ``long_gaps`` the number of steps longer than three times the median
    (non-zero) step. Rate and gap are None with fewer than two messages. ``messages_lost`` is
    what the reader knows it could not salvage from a damaged file (not in ``message_count``).
    ``layout`` is its schema compared with the toolkit's layout of its type (None when the
    schema cannot be parsed or is no ROS 2 ``ros2msg``/``cdr`` one), for the callers that
    know which fields a role reads.
    """

    topic: str
    message_type: str
    schema_encoding: str
    message_encoding: str
    message_count: int
    first_time_ns: int | None
    last_time_ns: int | None
    mean_rate_hz: float | None
    max_gap_s: float | None
    long_gaps: int
    messages_lost: int = 0
    layout: ChannelLayout | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict."""
        return {
            "topic": self.topic,
            "message_type": self.message_type,
            "schema_encoding": self.schema_encoding,
            "message_encoding": self.message_encoding,
            "message_count": self.message_count,
            "messages_lost": self.messages_lost,
            "first_time_ns": self.first_time_ns,
            "last_time_ns": self.last_time_ns,
            "mean_rate_hz": self.mean_rate_hz,
            "max_gap_s": self.max_gap_s,
            "long_gaps": self.long_gaps,
        }


@dataclass(frozen=True)
class LogInfo:
    """Everything :func:`scan_log` learned about a log. ``scan`` is ``index`` or ``full``."""

    path: Path
    size_bytes: int
    profile: str
    library: str
    start_time_ns: int | None
    end_time_ns: int | None
    message_count: int
    topics: tuple[TopicInfo, ...]
    metadata_names: tuple[str, ...]
    attachment_names: tuple[str, ...]
    chunk_count: int
    compression: tuple[str, ...]
    has_summary: bool
    scan: str
    problems: tuple[Problem, ...]
    messages_lost: int = 0
    damage_summary: str | None = None

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last message (0 without messages)."""
        if self.start_time_ns is None or self.end_time_ns is None:
            return 0.0
        return (self.end_time_ns - self.start_time_ns) / 1e9

    def problem_kinds(self) -> set[str]:
        """The kinds of the problems found."""
        return {p.kind for p in self.problems}

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict of the whole report."""
        return {
            "path": str(self.path),
            "size_bytes": self.size_bytes,
            "profile": self.profile,
            "library": self.library,
            "start_time_ns": self.start_time_ns,
            "end_time_ns": self.end_time_ns,
            "duration_s": self.duration_s,
            "message_count": self.message_count,
            "messages_lost": self.messages_lost,
            "topics": [t.to_dict() for t in self.topics],
            "metadata_names": list(self.metadata_names),
            "attachment_names": list(self.attachment_names),
            "chunk_count": self.chunk_count,
            "compression": list(self.compression),
            "has_summary": self.has_summary,
            "scan": self.scan,
            "damage_summary": self.damage_summary,
            "problems": [{"kind": p.kind, "message": p.message} for p in self.problems],
        }


@dataclass
class _Scan:
    """What a pass over the log collects: per channel id, log times and payload digests in
    file order (digests only from a full read)."""

    times: dict[int, list[np.ndarray]] = field(default_factory=dict)
    digests: dict[int, list[np.ndarray]] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)

    def problem(self, kind: str, message: str) -> None:
        self.problems.append(Problem(kind, message))

    def channel_times(self, channel_id: int) -> np.ndarray:
        parts = self.times.get(channel_id)
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def channel_digests(self, channel_id: int) -> np.ndarray | None:
        parts = self.digests.get(channel_id)
        return np.concatenate(parts) if parts else None


def _full_pass(reader: LogReader, scan: _Scan) -> ReadReport:
    """Every message of every topic through the reader (CRCs checked, damage salvaged)."""
    for batch in reader.batches():
        cid = batch.channel.id
        scan.times.setdefault(cid, []).append(batch.log_time_ns)
        # hash() per payload: a digest to find exact copies without keeping the bytes.
        digests = np.fromiter((hash(p) for p in batch.payloads), np.int64, len(batch.payloads))
        scan.digests.setdefault(cid, []).append(digests)
    return reader.report


def _has_same_time_pairs(times: dict[int, np.ndarray]) -> bool:
    """Whether some topic has two messages at the same log time (duplicate candidates)."""
    return any(len(t) != len(np.unique(t)) for t in times.values())


# --------------------------------------------------------------------------------------------
# Findings
# --------------------------------------------------------------------------------------------


def _duplicates(times: np.ndarray, digests: np.ndarray) -> int:
    """Extra copies among messages of one topic with equal log time and bytes digest."""
    if len(times) < 2:
        return 0
    keys = np.stack([times, digests], axis=1)
    return int(len(keys) - len(np.unique(keys, axis=0)))


def _out_of_order(times: np.ndarray) -> tuple[int, int]:
    """(count, first index) of messages earlier in log time than one before them."""
    if len(times) < 2:
        return 0, -1
    behind = times[1:] < np.maximum.accumulate(times)[:-1]
    n = int(behind.sum())
    return n, (int(np.flatnonzero(behind)[0]) + 1 if n else -1)


def _topic_info(
    channel: Channel, times: np.ndarray, lost: int, layout: ChannelLayout | None
) -> TopicInfo:
    count = len(times)
    first = int(times.min()) if count else None
    last = int(times.max()) if count else None
    rate = gap = None
    long_gaps = 0
    if count >= 2:
        diffs = np.diff(np.sort(times)).astype(np.float64)
        span = (last or 0) - (first or 0)
        rate = (count - 1) / (span / 1e9) if span > 0 else None
        gap = float(diffs.max()) / 1e9
        positive = diffs[diffs > 0]
        if positive.size:
            long_gaps = int((diffs > 3.0 * float(np.median(positive))).sum())
    return TopicInfo(
        topic=channel.topic,
        message_type=channel.schema_name,
        schema_encoding=channel.schema_encoding,
        message_encoding=channel.message_encoding,
        message_count=count,
        first_time_ns=first,
        last_time_ns=last,
        mean_rate_hz=rate,
        max_gap_s=gap,
        long_gaps=long_gaps,
        messages_lost=lost,
        layout=layout,
    )


def _schema_check(channel: Channel) -> tuple[str, ChannelLayout | None]:
    """Why a channel's messages cannot be decoded as ROS 2 CDR ("" when they can), and its
    schema compared with the toolkit's layout (None when it cannot be)."""
    if channel.schema_id == 0:
        return f"topic {channel.topic} has no schema", None
    if not channel.schema_name and not channel.schema_encoding:
        return f"topic {channel.topic} refers to undefined schema id {channel.schema_id}", None
    if (
        channel.schema_encoding != SchemaEncoding.ROS2
        or channel.message_encoding != MessageEncoding.CDR
    ):
        return (
            f"topic {channel.topic}: schema {channel.schema_name!r} "
            f"({channel.schema_encoding or 'none'}) with message encoding "
            f"{channel.message_encoding!r} is not ROS 2 ros2msg/cdr"
        ), None
    try:
        layout = channel_layout(channel)
    except ToolkitError as exc:
        return (
            f"topic {channel.topic}: schema {channel.schema_name!r} cannot be parsed: {exc}",
            None,
        )
    return "", layout


def _ros_type_name(schema_name: str) -> str:
    try:
        return full_type_name(schema_name)
    except ToolkitError:
        return schema_name


def _content_problems(
    channels: dict[int, Channel],
    scan: _Scan,
    topics: list[TopicInfo],
    schema_problems: Mapping[int, str],
) -> None:
    """What info sees in the messages themselves (the reader reports the file's damage)."""
    late_total, first_late = 0, ""
    dup_total = 0
    for (channel_id, channel), info in zip(channels.items(), topics, strict=True):
        times = scan.channel_times(channel_id)
        late, k = _out_of_order(times)
        if late and not first_late:
            first_late = f"{channel.topic} at log time {int(times[k])} ns"
        late_total += late
        digests = scan.channel_digests(channel_id)
        if digests is not None:
            dup_total += _duplicates(times, digests)
        if info.message_count == 0 and info.messages_lost == 0:
            scan.problem("empty_topic", f"topic {channel.topic} has no messages")
        why = schema_problems.get(channel_id, "")
        if why:
            scan.problem("unknown_schema", why)
        if info.layout is not None and info.layout.difference is not None:
            scan.problem(
                "nonstandard_schema",
                f"topic {channel.topic}: its schema {info.layout.type_name} "
                f"{info.layout.difference}: ingest decodes it by the log's own schema if its "
                "role's fields are all there, and refuses it otherwise",
            )
        packets = packets_note(channel.topic, _ros_type_name(channel.schema_name))
        if packets:
            scan.problem("lidar_packets", packets)
    if late_total:
        scan.problem(
            "out_of_order",
            f"{late_total} messages are out of log-time order (first on {first_late})",
        )
    if dup_total:
        scan.problem(
            "duplicates",
            f"{dup_total} duplicate messages (same topic, log time and bytes as another)",
        )


def _findings(
    path: Path, reader: LogReader, scan: _Scan, report: ReadReport | None, mode: str
) -> LogInfo:
    channels = reader.channel_by_id()
    lost_by_topic = report.lost if report is not None else {}
    if report is not None:
        for d in report.damage:
            scan.problem(d.reason, d.detail)
    checks = {channel_id: _schema_check(channel) for channel_id, channel in channels.items()}
    topics = [
        _topic_info(
            channel,
            scan.channel_times(channel_id),
            sum(lost_by_topic.get(channel.topic, {}).values()),
            checks[channel_id][1],
        )
        for channel_id, channel in channels.items()
    ]
    _content_problems(channels, scan, topics, {c: why for c, (why, _) in checks.items()})
    delivered = sum(t.message_count for t in topics)
    lost = sum(sum(r.values()) for r in lost_by_topic.values())
    stats = reader.statistics
    if report is not None and stats is not None and stats.message_count != delivered + lost:
        scan.problem(
            "summary_mismatch",
            f"the summary counts {stats.message_count} messages, the data holds "
            f"{delivered + lost}" + (f" ({lost} of them lost)" if lost else ""),
        )
    starts = [t.first_time_ns for t in topics if t.first_time_ns is not None]
    ends = [t.last_time_ns for t in topics if t.last_time_ns is not None]
    if report is not None:
        metadata = list(report.metadata)
        metadata += [n for n in reader.summary_metadata_names if n not in metadata]
        attachments = list(report.attachment_names)
        chunk_count, compression = report.chunk_count, report.compression
    else:
        metadata = reader.summary_metadata_names
        attachments = reader.summary_attachment_names
        chunks = reader.chunk_indexes()
        chunk_count = len(chunks)
        compression = {c.compression or "none" for c in chunks}
    return LogInfo(
        path=path,
        size_bytes=path.stat().st_size,
        profile=reader.profile,
        library=reader.library,
        start_time_ns=min(starts) if starts else None,
        end_time_ns=max(ends) if ends else None,
        message_count=delivered,
        topics=tuple(topics),
        metadata_names=tuple(metadata),
        attachment_names=tuple(attachments),
        chunk_count=chunk_count,
        compression=tuple(sorted(compression)),
        has_summary=reader.has_summary,
        scan=mode,
        problems=tuple(scan.problems),
        messages_lost=lost,
        damage_summary=report.summary_line() if report is not None else None,
    )


def scan_log(path: str | Path, *, full: bool = False) -> LogInfo:
    """Inspect an MCAP log (see the module docstring); never raises on a damaged MCAP file.

    ``full`` reads every chunk with CRC checks even when the summary's indexes would do.
    Raises :class:`LogReadError` for a missing file or one that is not MCAP at all.
    """
    path = Path(path)
    with LogReader(path) as reader:
        if not full:
            indexed = reader.index_times()
            if indexed is not None and not _has_same_time_pairs(indexed):
                scan = _Scan(times={cid: [t] for cid, t in indexed.items()})
                return _findings(path, reader, scan, None, "index")
        scan = _Scan()
        report = _full_pass(reader, scan)
        return _findings(path, reader, scan, report, "full")


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def _clock(ns: int | None) -> str:
    if ns is None:
        return "-"
    stamp = datetime.fromtimestamp(ns / 1e9, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    return f"{ns / 1e9:.3f} s ({stamp})"


def _size(n: int) -> str:
    value = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024 or unit == "GiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{n} B"


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def render_table(info: LogInfo, roles: Mapping[str, Sequence[str]] | None = None) -> str:
    """A plain-text report of a :class:`LogInfo`, for a terminal. ``roles`` (topic -> the
    roles of ``[topics]`` its type can play; the caller's, as this layer knows no roles) adds
    a column, "-" for a topic no role reads."""
    lines = [
        f"file:         {info.path} ({_size(info.size_bytes)})",
        f"profile:      {info.profile or '-'}    library: {info.library or '-'}",
        f"start:        {_clock(info.start_time_ns)}",
        f"end:          {_clock(info.end_time_ns)}",
        f"duration:     {info.duration_s:.3f} s",
        f"messages:     {info.message_count} in {info.chunk_count} chunks "
        f"({', '.join(info.compression) or 'not chunked'})"
        + (f"; {info.messages_lost} lost" if info.messages_lost else ""),
        f"metadata:     {', '.join(info.metadata_names) or '-'}",
        f"attachments:  {', '.join(info.attachment_names) or '-'}",
        f"scan:         {info.scan}"
        + (
            " (summary and indexes; chunk CRCs not checked)"
            if info.scan == "index"
            else " (every record read)"
        ),
        "",
    ]
    start = info.start_time_ns or 0
    header: tuple[str, ...] = (
        "topic",
        "type",
        "count",
        "lost",
        "first s",
        "last s",
        "rate Hz",
        "max gap s",
        "gaps>3x",
    )
    if roles is not None:
        header = (*header, "can be")
    rows: list[tuple[str, ...]] = [header]
    for t in info.topics:
        rows.append(
            (
                t.topic,
                t.message_type or "-",
                str(t.message_count),
                str(t.messages_lost),
                _fmt(None if t.first_time_ns is None else (t.first_time_ns - start) / 1e9, 3),
                _fmt(None if t.last_time_ns is None else (t.last_time_ns - start) / 1e9, 3),
                _fmt(t.mean_rate_hz, 2),
                _fmt(t.max_gap_s, 3),
                str(t.long_gaps),
            )
        )
        if roles is not None:
            rows[-1] = (*rows[-1], " or ".join(roles.get(t.topic, ())) or "-")
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    for k, row in enumerate(rows):
        cells = [
            cell.ljust(w) if i < 2 or i == 9 else cell.rjust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    lines.append("")
    if info.damage_summary:
        lines.append(info.damage_summary)
    if info.problems:
        lines.append(f"problems found ({len(info.problems)}):")
        lines.extend(f"  - [{p.kind}] {p.message}" for p in info.problems)
    else:
        lines.append("problems found: none")
    return "\n".join(lines) + "\n"


__all__ = ["LogInfo", "Problem", "TopicInfo", "render_table", "scan_log"]
