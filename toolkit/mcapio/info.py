"""What is in an MCAP log, and what is wrong with it: the ``terrain info`` verb.

:func:`scan_log` reports per topic the message type, count, first and last log time, mean rate,
largest gap and the number of gaps longer than three median periods; overall the time span,
header, metadata and attachment names, chunks and their compression; and the problems found:
no summary, truncation, CRC failures, messages out of log-time order, duplicate messages, topics
without messages, schemas that cannot be decoded, summaries that disagree with the data.

When the log has a summary with chunk and message indexes the scan reads only those (fast: no
chunk is decompressed, except the few holding duplicate candidates); chunk CRCs are then not
checked. ``full=True``, or a log without a usable summary, streams the whole file instead with
CRC checks, tolerating truncation and corruption: it reports the problem and keeps what it read.
Only a file that is missing or not MCAP at all raises :class:`~toolkit.errors.LogReadError`.
"""

from __future__ import annotations

import struct
import zlib
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.summary import Summary
from mcap.well_known import MessageEncoding, SchemaEncoding

from toolkit.errors import LogReadError, ToolkitError
from toolkit.mcapio.msgdefs import parse_schema_text
from toolkit.mcapio.reader import open_mcap

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD = 1 + 8 + 8 + 8 + 4
#: Errors a damaged file can provoke inside the mcap library (besides its own McapError).
_READ_ERRORS = (
    McapError,
    CRCValidationError,
    struct.error,
    ValueError,
    KeyError,
    IndexError,
    UnicodeDecodeError,
    EOFError,
    OSError,
    MemoryError,
    RuntimeError,
)


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a log: a short machine-readable ``kind`` and a readable message.

    Kinds: ``no_summary``, ``truncated``, ``corrupt``, ``crc``, ``out_of_order``,
    ``duplicates``, ``empty_topic``, ``unknown_schema``, ``summary_mismatch``.
    """

    kind: str
    message: str


@dataclass(frozen=True)
class TopicInfo:
    """Per-topic figures from the messages' log times (ns).

    ``mean_rate_hz`` is (count - 1) / (last - first); ``max_gap_s`` the largest step between
    consecutive log times; ``long_gaps`` the number of steps longer than three times the median
    (non-zero) step. Rate and gap are None with fewer than two messages.
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

    def to_dict(self) -> dict[str, Any]:
        return {
            "topic": self.topic,
            "message_type": self.message_type,
            "schema_encoding": self.schema_encoding,
            "message_encoding": self.message_encoding,
            "message_count": self.message_count,
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
            "topics": [t.to_dict() for t in self.topics],
            "metadata_names": list(self.metadata_names),
            "attachment_names": list(self.attachment_names),
            "chunk_count": self.chunk_count,
            "compression": list(self.compression),
            "has_summary": self.has_summary,
            "scan": self.scan,
            "problems": [{"kind": p.kind, "message": p.message} for p in self.problems],
        }


@dataclass
class _Scan:
    """What a pass over the file collects."""

    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata_names: list[str] = field(default_factory=list)
    attachment_names: list[str] = field(default_factory=list)
    chunk_count: int = 0
    compression: set[str] = field(default_factory=set)
    # One entry per message, in file order.
    channel_ids: array[int] = field(default_factory=lambda: array("H"))
    times: array[int] = field(default_factory=lambda: array("Q"))
    digests: array[int] | None = field(default_factory=lambda: array("q"))
    problems: list[Problem] = field(default_factory=list)

    def problem(self, kind: str, message: str) -> None:
        self.problems.append(Problem(kind, message))


# --------------------------------------------------------------------------------------------
# Opening, header and summary
# --------------------------------------------------------------------------------------------


def _read_header(f: IO[bytes], path: Path, size: int) -> Header:
    f.seek(0)
    try:
        record = next(iter(StreamReader(f, record_size_limit=size).records))
    except (StopIteration, *_READ_ERRORS) as exc:
        raise LogReadError(f"MCAP file without a readable header record ({exc!r})", path) from exc
    if not isinstance(record, Header):
        raise LogReadError(f"MCAP file starts with {type(record).__name__}, not Header", path)
    return record


def _read_summary(f: IO[bytes], size: int, scan: _Scan) -> tuple[Summary | None, Footer | None]:
    """The summary section and footer, or None where absent or unreadable (problems noted)."""
    f.seek(max(size - len(MAGIC), 0))
    if size < 2 * len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
        return None, None  # no footer: the stream pass tells truncation from a missing summary
    try:
        f.seek(0)
        reader = SeekingReader(f, record_size_limit=size)
        f.seek(size - len(MAGIC) - _FOOTER_RECORD)
        footer = next(iter(StreamReader(f, skip_magic=True, record_size_limit=size).records))
        if not isinstance(footer, Footer):
            raise McapError(f"expected a footer, found {type(footer).__name__}")
        summary = reader.get_summary()
    except (StopIteration, *_READ_ERRORS) as exc:
        scan.problem("corrupt", f"the footer or summary section cannot be read: {exc}")
        return None, None
    if footer.summary_start and footer.summary_crc:
        f.seek(footer.summary_start)
        data = f.read(size - len(MAGIC) - 4 - footer.summary_start)
        if zlib.crc32(data) != footer.summary_crc:
            scan.problem("crc", "the summary section fails its CRC")
    return summary, footer


# --------------------------------------------------------------------------------------------
# Index pass (fast)
# --------------------------------------------------------------------------------------------

# A MessageIndex record body: channel_id u16, byte length u32 of (log_time u64, offset u64)[].
_INDEX_ENTRY = np.dtype([("time", "<u8"), ("offset", "<u8")])


def _message_index(f: IO[bytes], offset: int, size: int) -> tuple[int, np.ndarray]:
    f.seek(offset)
    head = f.read(9)
    if len(head) != 9 or head[0] != Opcode.MESSAGE_INDEX:
        raise McapError(f"no message index record at offset {offset}")
    length = struct.unpack_from("<Q", head, 1)[0]
    if length < 6 or offset + 9 + length > size:
        raise McapError(f"message index record at offset {offset} has a bad length")
    body = f.read(length)
    channel_id, nbytes = struct.unpack_from("<HI", body, 0)
    if nbytes % 16 or 6 + nbytes > len(body):
        raise McapError(f"message index record at offset {offset} is malformed")
    return channel_id, np.frombuffer(body, dtype=_INDEX_ENTRY, count=nbytes // 16, offset=6)


def _index_pass(f: IO[bytes], size: int, summary: Summary, scan: _Scan) -> bool:
    """Collect message times from the message indexes; False when they are incomplete."""
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    if not chunks or any(not c.message_index_offsets for c in chunks):
        return False
    parts: list[tuple[int, int, np.ndarray]] = []  # (chunk number, channel id, entries)
    try:
        for number, chunk in enumerate(chunks):
            for channel_id, offset in sorted(chunk.message_index_offsets.items()):
                found, entries = _message_index(f, offset, size)
                if found != channel_id:
                    raise McapError(f"message index at {offset} is for channel {found}")
                parts.append((number, channel_id, entries))
    except (*_READ_ERRORS,) as exc:
        scan.problem("corrupt", f"message indexes cannot be read ({exc}); streamed the file")
        return False
    total = sum(len(e) for _, _, e in parts)
    stats = summary.statistics
    if stats is not None and stats.message_count != total:
        return False  # messages outside chunks, or a lying index: the stream pass decides
    channels = {c for _, c, _ in parts}
    if not channels <= set(summary.channels) or any(
        ch.schema_id and ch.schema_id not in summary.schemas for ch in summary.channels.values()
    ):
        return False  # channels or schemas not repeated in the summary: they are in the chunks
    scan.schemas = dict(summary.schemas)
    scan.channels = dict(summary.channels)
    scan.chunk_count = len(chunks)
    scan.compression = {c.compression or "none" for c in chunks}
    scan.metadata_names = [m.name for m in summary.metadata_indexes]
    scan.attachment_names = [a.name for a in summary.attachment_indexes]
    if not parts:
        scan.digests = None
        return True
    chunk_no = np.concatenate([np.full(len(e), n, dtype=np.int64) for n, _, e in parts])
    chan = np.concatenate([np.full(len(e), c, dtype=np.uint16) for _, c, e in parts])
    times = np.concatenate([e["time"] for _, _, e in parts])
    offs = np.concatenate([e["offset"] for _, _, e in parts])
    order = np.lexsort((offs, chunk_no))  # file order
    scan.channel_ids = array("H", chan[order].tobytes())
    scan.times = array("Q", times[order].astype(np.uint64).tobytes())
    scan.digests = None
    _confirm_duplicates(f, chunks, chunk_no[order], chan[order], times[order], scan)
    return True


def _confirm_duplicates(
    f: IO[bytes],
    chunks: list[ChunkIndex],
    chunk_no: np.ndarray,
    chan: np.ndarray,
    times: np.ndarray,
    scan: _Scan,
) -> None:
    """Read only the chunks holding same-channel same-time messages, to compare their bytes."""
    keys = np.stack([chan.astype(np.uint64), times], axis=1)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    suspect = counts[inverse.reshape(-1)] > 1
    if not suspect.any():
        return
    wanted = {(int(c), int(t)) for c, t in zip(chan[suspect], times[suspect], strict=True)}
    digests: list[tuple[int, int, int]] = []
    for number in sorted(set(chunk_no[suspect].tolist())):
        index = chunks[number]
        try:
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            records = breakup_chunk(chunk, validate_crc=False)
        except (*_READ_ERRORS,) as exc:
            scan.problem("corrupt", f"chunk at offset {index.chunk_start_offset}: {exc}")
            continue
        for rec in records:
            if isinstance(rec, Message) and (rec.channel_id, rec.log_time) in wanted:
                digests.append((rec.channel_id, rec.log_time, hash(rec.data)))
    _report_duplicates(np.asarray(digests, dtype=np.int64).reshape(-1, 3), scan)


# --------------------------------------------------------------------------------------------
# Stream pass (full, tolerant)
# --------------------------------------------------------------------------------------------


def _chunk_records(chunk: Chunk, scan: _Scan, offset: int) -> list[Any]:
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except CRCValidationError:
        scan.problem("crc", f"chunk at offset {offset} fails its CRC")
    except (*_READ_ERRORS,) as exc:
        scan.problem("corrupt", f"chunk at offset {offset} cannot be decompressed: {exc}")
        return []
    try:
        return breakup_chunk(chunk, validate_crc=False)
    except (*_READ_ERRORS,) as exc:
        scan.problem("corrupt", f"chunk at offset {offset} cannot be read: {exc}")
        return []


def _stream_pass(f: IO[bytes], size: int, scan: _Scan) -> None:
    """Read every record from the start; stop at the first unreadable one, keeping the rest."""
    f.seek(0)
    reader = StreamReader(f, emit_chunks=True, validate_crcs=True, record_size_limit=size)
    records: Iterator[Any] = iter(reader.records)
    digests = scan.digests if scan.digests is not None else array("q")
    scan.digests = digests
    saw_footer = False
    while True:
        offset = f.tell()
        try:
            record = next(records)
        except StopIteration:
            break
        except CRCValidationError as exc:
            kind = "data section" if isinstance(exc.record, DataEnd) else type(exc.record).__name__
            scan.problem("crc", f"{kind} fails its CRC")
            break
        except (*_READ_ERRORS,) as exc:
            if isinstance(exc, EndOfFile | EOFError | struct.error) and f.tell() >= size:
                scan.problem(
                    "truncated", f"the file ends inside a record that starts at offset {offset}"
                )
            else:
                scan.problem("corrupt", f"unreadable record at offset {offset}: {exc!r}")
            break
        inner = _chunk_records(record, scan, offset) if isinstance(record, Chunk) else [record]
        if isinstance(record, Chunk):
            scan.chunk_count += 1
            scan.compression.add(record.compression or "none")
        for rec in inner:
            if isinstance(rec, Message):
                scan.channel_ids.append(rec.channel_id)
                scan.times.append(rec.log_time)
                digests.append(hash(rec.data))
            elif isinstance(rec, Schema):
                scan.schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                scan.channels.setdefault(rec.id, rec)
            elif isinstance(rec, Metadata):
                scan.metadata_names.append(rec.name)
            elif isinstance(rec, Attachment):
                scan.attachment_names.append(rec.name)
            elif isinstance(rec, Footer):
                saw_footer = True
    if not saw_footer and not any(p.kind in ("truncated", "corrupt", "crc") for p in scan.problems):
        scan.problem("truncated", "the file ends before its footer")
    if len(scan.digests or ()):
        chan = np.frombuffer(scan.channel_ids, dtype=np.uint16).astype(np.int64)
        times = np.frombuffer(scan.times, dtype=np.uint64).astype(np.int64)
        dig = np.frombuffer(digests, dtype=np.int64)
        _report_duplicates(np.stack([chan, times, dig], axis=1), scan)


def _summary_counts(summary: Summary, scan: _Scan) -> None:
    """Compare the summary's statistics with what the stream pass counted."""
    stats = summary.statistics
    if stats is None:
        return
    if stats.message_count != len(scan.times):
        scan.problem(
            "summary_mismatch",
            f"the summary counts {stats.message_count} messages, the data holds {len(scan.times)}",
        )


# --------------------------------------------------------------------------------------------
# Findings
# --------------------------------------------------------------------------------------------


def _report_duplicates(rows: np.ndarray, scan: _Scan) -> None:
    """``rows`` of (channel, log time, digest): report extra copies of identical messages."""
    if not len(rows):
        return
    _, counts = np.unique(rows, axis=0, return_counts=True)
    extra = int((counts - 1).sum())
    if extra:
        scan.problem(
            "duplicates",
            f"{extra} duplicate messages (same topic, log time and bytes as another)",
        )


def _topic_info(channel: Channel, schema: Schema | None, times: np.ndarray) -> TopicInfo:
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
        message_type=schema.name if schema is not None else "",
        schema_encoding=schema.encoding if schema is not None else "",
        message_encoding=channel.message_encoding,
        message_count=count,
        first_time_ns=first,
        last_time_ns=last,
        mean_rate_hz=rate,
        max_gap_s=gap,
        long_gaps=long_gaps,
    )


def _schema_problem(channel: Channel, schema: Schema | None) -> str:
    """Why a channel's messages cannot be decoded as ROS 2 CDR, or "" when they can."""
    if channel.schema_id == 0:
        return f"topic {channel.topic} has no schema"
    if schema is None:
        return f"topic {channel.topic} refers to undefined schema id {channel.schema_id}"
    if schema.encoding != SchemaEncoding.ROS2 or channel.message_encoding != MessageEncoding.CDR:
        return (
            f"topic {channel.topic}: schema {schema.name!r} ({schema.encoding or 'none'}) with "
            f"message encoding {channel.message_encoding!r} is not ROS 2 ros2msg/cdr"
        )
    try:
        parse_schema_text(schema.name, schema.data.decode("utf-8"))
    except (ToolkitError, UnicodeDecodeError) as exc:
        return f"topic {channel.topic}: schema {schema.name!r} cannot be parsed: {exc}"
    return ""


def _findings(path: Path, size: int, scan: _Scan, has_summary: bool, mode: str) -> LogInfo:
    chan = (
        np.frombuffer(scan.channel_ids, dtype=np.uint16)
        if len(scan.channel_ids)
        else (np.zeros(0, dtype=np.uint16))
    )
    times = (
        np.frombuffer(scan.times, dtype=np.uint64).astype(np.int64)
        if len(scan.times)
        else (np.zeros(0, dtype=np.int64))
    )
    if times.size >= 2:
        behind = times[1:] < np.maximum.accumulate(times)[:-1]
        late = int(behind.sum())
        if late:
            k = int(np.flatnonzero(behind)[0]) + 1
            ch = scan.channels.get(int(chan[k]))
            scan.problem(
                "out_of_order",
                f"{late} messages are out of log-time order (first on "
                f"{ch.topic if ch else f'channel {int(chan[k])}'} at log time {int(times[k])} ns)",
            )
    unknown = sorted(set(np.unique(chan).tolist()) - set(scan.channels))
    if unknown:
        scan.problem("corrupt", f"messages on undefined channel ids {unknown}")
    topics: list[TopicInfo] = []
    for channel_id in sorted(scan.channels):
        channel = scan.channels[channel_id]
        schema = scan.schemas.get(channel.schema_id)
        info = _topic_info(channel, schema, times[chan == channel_id])
        topics.append(info)
        if info.message_count == 0:
            scan.problem("empty_topic", f"topic {channel.topic} has no messages")
        why = _schema_problem(channel, schema)
        if why:
            scan.problem("unknown_schema", why)
    if not has_summary:
        scan.problems.insert(0, Problem("no_summary", "the log has no summary section or index"))
    header = scan.header
    return LogInfo(
        path=path,
        size_bytes=size,
        profile=header.profile if header else "",
        library=header.library if header else "",
        start_time_ns=int(times.min()) if times.size else None,
        end_time_ns=int(times.max()) if times.size else None,
        message_count=int(times.size),
        topics=tuple(topics),
        metadata_names=tuple(scan.metadata_names),
        attachment_names=tuple(scan.attachment_names),
        chunk_count=scan.chunk_count,
        compression=tuple(sorted(scan.compression)),
        has_summary=has_summary,
        scan=mode,
        problems=tuple(scan.problems),
    )


def scan_log(path: str | Path, *, full: bool = False) -> LogInfo:
    """Inspect an MCAP log (see the module docstring); never raises on a damaged MCAP file.

    ``full`` streams the whole file with CRC checks even when a summary would do.
    Raises :class:`LogReadError` for a missing file or one that is not MCAP at all.
    """
    path = Path(path)
    f, size = open_mcap(path)
    try:
        scan = _Scan(header=_read_header(f, path, size))
        summary, _footer = _read_summary(f, size, scan)
        has_summary = summary is not None
        if summary is not None and not full and _index_pass(f, size, summary, scan):
            return _findings(path, size, scan, has_summary, "index")
        _stream_pass(f, size, scan)
        if summary is not None:
            _summary_counts(summary, scan)
            for name in (m.name for m in summary.metadata_indexes):
                if name not in scan.metadata_names:
                    scan.metadata_names.append(name)
        return _findings(path, size, scan, has_summary, "full")
    finally:
        f.close()


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


def render_table(info: LogInfo) -> str:
    """A plain-text report of a :class:`LogInfo`, for a terminal."""
    lines = [
        f"file:         {info.path} ({_size(info.size_bytes)})",
        f"profile:      {info.profile or '-'}    library: {info.library or '-'}",
        f"start:        {_clock(info.start_time_ns)}",
        f"end:          {_clock(info.end_time_ns)}",
        f"duration:     {info.duration_s:.3f} s",
        f"messages:     {info.message_count} in {info.chunk_count} chunks "
        f"({', '.join(info.compression) or 'not chunked'})",
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
    header = ("topic", "type", "count", "first s", "last s", "rate Hz", "max gap s", "gaps>3x")
    rows = [header]
    for t in info.topics:
        rows.append(
            (
                t.topic,
                t.message_type or "-",
                str(t.message_count),
                _fmt(None if t.first_time_ns is None else (t.first_time_ns - start) / 1e9, 3),
                _fmt(None if t.last_time_ns is None else (t.last_time_ns - start) / 1e9, 3),
                _fmt(t.mean_rate_hz, 2),
                _fmt(t.max_gap_s, 3),
                str(t.long_gaps),
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    for k, row in enumerate(rows):
        cells = [
            cell.ljust(w) if i < 2 else cell.rjust(w)
            for i, (cell, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    lines.append("")
    if info.problems:
        lines.append(f"problems found ({len(info.problems)}):")
        lines.extend(f"  - [{p.kind}] {p.message}" for p in info.problems)
    else:
        lines.append("problems found: none")
    return "\n".join(lines) + "\n"


__all__ = ["LogInfo", "Problem", "TopicInfo", "render_table", "scan_log"]
