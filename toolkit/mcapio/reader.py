"""Reading an MCAP log as per-channel message batches: fast from its index, salvaging damage.

:class:`LogReader` yields :class:`MessageBatch` objects, one per channel per Chunk record (or per
run of Message records written outside chunks), in file order, holding one chunk in memory.
The caller sorts by time; every message of a wanted topic is delivered at most once.

How the file is read (record names as in the MCAP specification):

* The Header record must be readable; a file that is missing, empty, not MCAP (bad magic) or
  without a readable Header raises :class:`~toolkit.errors.LogReadError`. A file holding only
  the magic and a Header reads as empty, with ``truncated`` and ``no_summary`` damage: deciding
  that a log with nothing usable is an error is the caller's business.
* The Footer (fixed place before the closing magic) locates the summary section; its CRC is
  checked when nonzero, and its Schema, Channel, Chunk Index and Statistics records are kept.
* The data section is then walked record by record from the Header. A Chunk that has a Chunk
  Index is read together with its Message Index records in one read, its ``uncompressed_crc``
  is checked when nonzero, and each wanted channel's (log_time, offset) pairs locate its Message
  records: length, log_time and publish_time are gathered with numpy over the decompressed
  buffer and payloads cut with one list comprehension (the *fast path*; no per-message Python
  objects). With the summary's channels complete, chunks holding no wanted channel are not
  even read. A chunk without usable message indexes, or any chunk when there is no summary, is
  parsed record by record (the *salvage path*); Schema and Channel records may sit inside chunks.
  Messages outside chunks are collected in segments of about :data:`SEGMENT_BYTES`.
* Damage does not stop the walk: a chunk that fails its CRC or decompression is skipped and the
  next one read. Its lost messages are counted from its Message Index records (those of the
  summary's Chunk Index, or those that follow it in the data section); without any, its size
  goes to ``unknown_lost_bytes``. An unreadable record ends the walk, unless the chunk index
  names a later chunk to resume from. The data section's own CRC (Data End) is not checked:
  chunk CRCs already cover every message in chunks.

Damage reasons (``Damage.reason``, and keys of ``ReadReport.lost`` / ``unknown_lost_bytes``):

``no_summary``
    no summary section (none written, or no Footer at the end): the file is read by the
    linear walk. Loses nothing by itself.
``bad_index``
    the summary fails its CRC or cannot be parsed, or a Chunk Index / Message Index disagrees
    with the records it points at: that index is ignored and the data parsed record by record.
    Loses nothing by itself.
``truncated``
    the file ends inside a record or before Data End. Its ``unknown_lost_bytes`` is the length
    of the incomplete tail (from the start of the cut record to the end of the file); Message
    records complete in the readable part of a cut chunk are still delivered (their chunk CRC
    cannot be checked).
``chunk_crc``
    a decompressed chunk does not match its ``uncompressed_crc``.
``chunk_decompress``
    a chunk's compressed data cannot be decompressed to its ``uncompressed_size``.
``unsupported_compression``
    a chunk compressed with something other than none, ``zstd`` or ``lz4``.
``bad_record``
    a record whose length or fields are impossible (overruns its section, Message shorter
    than its fixed fields, reserved opcode 0, malformed Schema/Channel).
``unknown_channel``
    Message records on a channel id that no Channel record defines.
``chunk_size``
    a chunk's header misstates its uncompressed size, but its data decompresses (within
    :data:`MAX_CHUNK_BYTES`) and passes the chunk's CRC: it is read whole. Loses nothing.

Lost messages whose channel is never defined are counted under the topic key
``"<channel N>"`` (N the channel id), whether or not a topic filter is in force.
"""

from __future__ import annotations

import io
import struct
import zlib
from array import array
from collections.abc import Collection, Generator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, cast

import lz4.frame
import numpy as np
import zstandard
from mcap import records as mr
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode

from toolkit.errors import LogReadError

MAGIC = b"\x89MCAP0\r\n"

NO_SUMMARY = "no_summary"
BAD_INDEX = "bad_index"
TRUNCATED = "truncated"
CHUNK_CRC = "chunk_crc"
CHUNK_DECOMPRESS = "chunk_decompress"
UNSUPPORTED_COMPRESSION = "unsupported_compression"
BAD_RECORD = "bad_record"
UNKNOWN_CHANNEL = "unknown_channel"
CHUNK_SIZE = "chunk_size"

#: Messages outside chunks are delivered in segments of about this many payload bytes.
SEGMENT_BYTES = 4 * 1024 * 1024
#: Largest decompressed chunk accepted. Writers cut chunks at a few MiB; a header or a
#: compression frame claiming more is damage or a decompression bomb, and decompression stops
#: here, so memory stays bounded whatever the file claims.
MAX_CHUNK_BYTES = 256 * 1024**2

_HEAD = struct.Struct("<BQ")  # every record: opcode u8, content length u64
_FOOTER_BYTES = 9 + 20  # Footer: summary_start u64, summary_offset_start u64, summary_crc u32
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed_size, uncompressed_crc, len
_MESSAGE = struct.Struct("<HIqq")  # Message: channel_id, sequence, log_time, publish_time
_MESSAGE_HEAD = 9 + _MESSAGE.size  # a Message record up to its data
_INDEX_ENTRY = np.dtype([("time", "<u8"), ("offset", "<u8")])  # Message Index (timestamp, offset)
_COLUMNS = np.arange(_MESSAGE_HEAD, dtype=np.int64)
_PARSE_ERRORS = (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError)


# --------------------------------------------------------------------------------------------
# Public types
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Channel:
    """A Channel record with its Schema resolved (schema fields empty for schema id 0, or
    for a schema id that no Schema record defines)."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    schema_id: int = 0


@dataclass(frozen=True)
class MessageBatch:
    """One channel's messages from one chunk (or one salvage segment), in file order.

    Times are the Message records' uint64 nanoseconds viewed as int64."""

    channel: Channel
    log_time_ns: np.ndarray  # int64 (n,)
    publish_time_ns: np.ndarray  # int64 (n,)
    payloads: list[bytes]  # n CDR payloads


@dataclass(frozen=True)
class Damage:
    """Something wrong found at byte ``offset`` of the file (``reason``: see module docstring)."""

    reason: str
    offset: int
    detail: str


@dataclass
class ReadReport:
    """What a pass of :meth:`LogReader.batches` delivered, and what it could not.

    Besides messages: the Metadata records met (name -> key -> value, records of one name
    merged, later keys winning), the Attachment records' names, and the Chunk records met with
    their compression (``"none"`` for uncompressed). This report is the one account of a
    log's damage: ``terrain info`` and ``terrain ingest`` both print it (:meth:`summary_line`).
    """

    used_index: bool
    messages_read: dict[str, int] = field(default_factory=dict)
    lost: dict[str, dict[str, int]] = field(default_factory=dict)
    damage: list[Damage] = field(default_factory=list)
    unknown_lost_bytes: dict[str, int] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachment_names: list[str] = field(default_factory=list)
    chunk_count: int = 0
    compression: set[str] = field(default_factory=set)

    def reasons(self) -> set[str]:
        """The reasons of every damage found."""
        return {d.reason for d in self.damage}

    def lost_total(self) -> dict[str, int]:
        """Messages lost, by reason, over every topic."""
        total: dict[str, int] = {}
        for by_reason in self.lost.values():
            for reason, n in by_reason.items():
                total[reason] = total.get(reason, 0) + n
        return {k: v for k, v in sorted(total.items()) if v}

    def summary_line(self) -> str | None:
        """One line on what is wrong with the file and what that cost, or None if intact.

        ``no_summary`` alone loses nothing: a log written without an index is not damaged,
        so it gets no line either."""
        reasons: dict[str, int] = {}
        for d in self.damage:
            reasons[d.reason] = reasons.get(d.reason, 0) + 1
        lost = self.lost_total()
        unknown = sum(self.unknown_lost_bytes.values())
        if set(reasons) <= {NO_SUMMARY} and not lost and not unknown:
            return None
        what = ", ".join(f"{k} x{v}" if v > 1 else k for k, v in sorted(reasons.items()))
        line = f"damaged log ({what or 'damage'}): read {sum(self.messages_read.values())} messages"
        if lost:
            detail = ", ".join(f"{v} {k}" for k, v in lost.items())
            line += f", lost {sum(lost.values())} messages ({detail})"
        if unknown:
            line += f", {unknown} bytes of unknown content lost"
        return line


# --------------------------------------------------------------------------------------------
# Small parsing helpers
# --------------------------------------------------------------------------------------------


class _MalformedError(Exception):
    """A record that cannot be what it claims (internal: becomes a Damage)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


class _Strict(ReadDataStream):
    """mcap's ReadDataStream, raising on a short read instead of returning fewer bytes, so a
    damaged length inside a record body cannot slip through."""

    def read(self, length: int) -> bytes:
        data = super().read(length)
        if len(data) != length:
            raise EndOfFile()
        return data


def _parse(cls: Any, body: bytes) -> mr.McapRecord:
    """Parse one record body with mcap's record class ``cls`` (padding after it is ignored).

    ``cls`` is typed Any because mcap's record classes declare their ``read`` untyped; the
    result is checked to be a ``cls``."""
    record: object = cls.read(_Strict(io.BytesIO(body)))
    if isinstance(record, cls) and isinstance(record, mr.McapRecord):
        return record
    raise _MalformedError(BAD_RECORD, f"not a {cls.__name__} record")  # pragma: no cover


def _opcode_name(op: int) -> str:
    try:
        return Opcode(op).name.title().replace("_", "")
    except ValueError:
        return f"opcode 0x{op:02x}"


def _read_at(f: IO[bytes], pos: int, n: int) -> bytes:
    f.seek(pos)
    return f.read(n)


def _open_file(path: Path) -> IO[bytes]:
    """Open the log (a seam for tests that count the bytes read)."""
    return open(path, "rb")  # noqa: SIM115 - closed by LogReader.close


@dataclass
class _Fields:
    """Fixed fields of Message records gathered at known offsets of a chunk buffer."""

    opcode: np.ndarray
    length: np.ndarray  # uint64 record content length
    channel: np.ndarray
    log: np.ndarray  # int64
    pub: np.ndarray  # int64


def _gather(buf: bytes, offsets: np.ndarray) -> _Fields:
    """Read the fixed part of the Message records starting at ``offsets`` (int64, each at least
    31 bytes before the end of ``buf``) with one numpy gather, no per-message Python."""
    rows = np.frombuffer(buf, dtype=np.uint8)[offsets[:, None] + _COLUMNS]

    def col(a: int, b: int, dtype: str) -> np.ndarray:
        return np.ascontiguousarray(rows[:, a:b]).view(dtype).reshape(-1)

    return _Fields(
        rows[:, 0], col(1, 9, "<u8"), col(9, 11, "<u2"), col(15, 23, "<i8"), col(23, 31, "<i8")
    )


def _payloads(buf: bytes, offsets: np.ndarray, length: np.ndarray) -> list[bytes]:
    ends = (offsets + 9 + length.astype(np.int64)).tolist()
    return [buf[s:e] for s, e in zip((offsets + _MESSAGE_HEAD).tolist(), ends, strict=True)]


# --------------------------------------------------------------------------------------------
# Schemas and channels
# --------------------------------------------------------------------------------------------


@dataclass
class _Catalog:
    """Schema and Channel records learnt so far (the first definition of an id wins)."""

    schemas: dict[int, mr.Schema] = field(default_factory=dict)
    raw: dict[int, mr.Channel] = field(default_factory=dict)
    resolved: dict[int, Channel] = field(default_factory=dict)

    def copy(self) -> _Catalog:
        return _Catalog(dict(self.schemas), dict(self.raw), dict(self.resolved))

    def add(self, record: mr.McapRecord) -> None:
        if isinstance(record, mr.Schema):
            if record.id != 0:
                self.schemas.setdefault(record.id, record)
        elif isinstance(record, mr.Channel):
            self.raw.setdefault(record.id, record)

    def get(self, channel_id: int) -> Channel | None:
        known = self.resolved.get(channel_id)
        if known is not None:
            return known
        raw = self.raw.get(channel_id)
        if raw is None:
            return None
        schema = self.schemas.get(raw.schema_id) if raw.schema_id else None
        channel = Channel(
            id=raw.id,
            topic=raw.topic,
            message_encoding=raw.message_encoding,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=bytes(schema.data) if schema else b"",
            schema_id=raw.schema_id,
        )
        if schema is not None or raw.schema_id == 0:
            self.resolved[channel_id] = channel  # else a later Schema record may still come
        return channel


# --------------------------------------------------------------------------------------------
# Opening: magic, Header, Footer and summary
# --------------------------------------------------------------------------------------------


@dataclass
class _Layout:
    """Where things are in the file, from its Header, Footer and summary section."""

    size: int
    data_start: int  # first byte after the Header record
    data_end: int  # the linear walk stops here
    has_footer: bool = False
    summary: _Catalog = field(default_factory=_Catalog)
    chunks: dict[int, mr.ChunkIndex] = field(default_factory=dict)  # by chunk_start_offset
    chunk_starts: list[int] = field(default_factory=list)  # sorted
    channels_complete: bool = False  # the summary holds every channel of the file
    summary_read: bool = False  # a summary section was found and parsed
    statistics: mr.Statistics | None = None
    metadata_names: list[str] = field(default_factory=list)  # from the summary's indexes
    attachment_names: list[str] = field(default_factory=list)
    profile: str = ""
    library: str = ""
    damage: list[Damage] = field(default_factory=list)


def open_mcap(path: Path) -> tuple[IO[bytes], int]:
    """Open ``path`` after checking it is a readable file that starts with the MCAP magic;
    returns the file (positioned after the magic) and its size. LogReadError otherwise."""
    if not path.exists():
        raise LogReadError("no such file", path)
    if not path.is_file():
        raise LogReadError("not a regular file", path)
    try:
        f = _open_file(path)
    except OSError as exc:
        raise LogReadError(f"cannot open: {exc.strerror}", path) from exc
    size = path.stat().st_size
    if f.read(len(MAGIC)) != MAGIC:
        f.close()
        raise LogReadError("not an MCAP file (bad magic bytes at the start)", path)
    return f, size


def _read_header(f: IO[bytes], path: Path, size: int) -> _Layout:
    head = _read_at(f, len(MAGIC), 9)
    if len(head) < 9 or head[0] != Opcode.HEADER:
        raise LogReadError("MCAP file without a Header record after the magic bytes", path)
    length = _HEAD.unpack(head)[1]
    end = len(MAGIC) + 9 + length
    if end > size:
        raise LogReadError("MCAP file whose Header record is cut off", path)
    try:
        header = cast(mr.Header, _parse(mr.Header, _read_at(f, len(MAGIC) + 9, length)))
    except _PARSE_ERRORS as exc:
        raise LogReadError(f"MCAP file with an unreadable Header record ({exc!r})", path) from exc
    return _Layout(
        size=size, data_start=end, data_end=size, profile=header.profile, library=header.library
    )


def _read_footer(f: IO[bytes], layout: _Layout) -> tuple[int, int, int] | None:
    """The Footer's (summary_start, summary_offset_start, summary_crc), or None without one."""
    at = layout.size - len(MAGIC) - _FOOTER_BYTES
    if at < layout.data_start:
        return None
    tail = _read_at(f, at, _FOOTER_BYTES + len(MAGIC))
    if tail[_FOOTER_BYTES:] != MAGIC or _HEAD.unpack_from(tail) != (Opcode.FOOTER, 20):
        return None
    layout.has_footer = True
    layout.data_end = at
    start, offset_start, crc = struct.unpack_from("<QQI", tail, 9)
    if crc and start:
        section = _read_at(f, start, at - start) if layout.data_start <= start <= at else b""
        if zlib.crc32(tail[:25], zlib.crc32(section)) != crc:
            layout.damage.append(Damage(BAD_INDEX, start, "the summary section fails its CRC"))
            return None
    return start, offset_start, crc


def _summary_records(section: bytes) -> Iterator[mr.McapRecord]:
    pos = 0
    while pos < len(section):
        if pos + 9 > len(section):
            raise _MalformedError(BAD_INDEX, "the summary section ends inside a record header")
        op, length = _HEAD.unpack_from(section, pos)
        end = pos + 9 + length
        if end > len(section):
            raise _MalformedError(BAD_INDEX, f"a summary {_opcode_name(op)} record overruns it")
        cls = {
            Opcode.SCHEMA: mr.Schema,
            Opcode.CHANNEL: mr.Channel,
            Opcode.CHUNK_INDEX: mr.ChunkIndex,
            Opcode.STATISTICS: mr.Statistics,
            Opcode.METADATA_INDEX: mr.MetadataIndex,
            Opcode.ATTACHMENT_INDEX: mr.AttachmentIndex,
        }.get(op)
        if cls is not None:
            yield _parse(cls, section[pos + 9 : end])
        pos = end


def _read_summary(f: IO[bytes], layout: _Layout) -> None:
    """Fill ``layout`` from the Footer and the summary section (damage noted, never raised)."""
    footer = _read_footer(f, layout)
    if footer is None:
        if not layout.damage:
            layout.damage.append(
                Damage(
                    NO_SUMMARY,
                    layout.size,
                    "no Footer record before the closing magic: read by linear scan",
                )
            )
        return
    start, offset_start, _crc = footer
    if start == 0:
        layout.damage.append(
            Damage(NO_SUMMARY, layout.data_end, "the Footer says there is no summary section")
        )
        return
    if not layout.data_start <= start <= layout.data_end:
        layout.damage.append(
            Damage(
                BAD_INDEX,
                layout.data_end,
                f"the Footer's summary_start {start} is outside the file",
            )
        )
        return
    end = offset_start if start < offset_start <= layout.data_end else layout.data_end
    layout.data_end = start
    catalog = _Catalog()
    chunks: list[mr.ChunkIndex] = []
    stats: mr.Statistics | None = None
    metadata_names: list[str] = []
    attachment_names: list[str] = []
    try:
        for record in _summary_records(_read_at(f, start, end - start)):
            if isinstance(record, mr.ChunkIndex):
                chunks.append(record)
            elif isinstance(record, mr.Statistics):
                stats = record
            elif isinstance(record, mr.MetadataIndex):
                metadata_names.append(record.name)
            elif isinstance(record, mr.AttachmentIndex):
                attachment_names.append(record.name)
            else:
                catalog.add(record)
    except (_MalformedError, *_PARSE_ERRORS) as exc:
        layout.damage.append(Damage(BAD_INDEX, start, f"the summary section is unreadable: {exc}"))
        return
    layout.summary = catalog
    layout.summary_read = True
    layout.statistics = stats
    layout.metadata_names = metadata_names
    layout.attachment_names = attachment_names
    for ci in chunks:
        if _chunk_index_fits(ci, layout):
            layout.chunks.setdefault(ci.chunk_start_offset, ci)
        else:
            layout.damage.append(
                Damage(
                    BAD_INDEX,
                    ci.chunk_start_offset,
                    "a Chunk Index points outside the data section; that chunk is parsed instead",
                )
            )
    layout.chunk_starts = sorted(layout.chunks)
    indexed = {cid for ci in layout.chunks.values() for cid in ci.message_index_offsets}
    channels = catalog.raw.values()
    layout.channels_complete = (
        bool(catalog.raw)
        and indexed <= set(catalog.raw)
        and all(c.schema_id == 0 or c.schema_id in catalog.schemas for c in channels)
        and (stats is None or stats.channel_count == len(catalog.raw))
    )


def _chunk_index_fits(ci: mr.ChunkIndex, layout: _Layout) -> bool:
    chunk_end = ci.chunk_start_offset + ci.chunk_length
    return (
        layout.data_start <= ci.chunk_start_offset
        and ci.chunk_length >= 9 + _CHUNK_FIXED.size + 8
        and chunk_end <= layout.data_end
        and all(chunk_end <= o <= layout.data_end - 15 for o in ci.message_index_offsets.values())
    )


# --------------------------------------------------------------------------------------------
# Chunks
# --------------------------------------------------------------------------------------------


def _chunk_fields(record: bytes, length: int) -> tuple[str, int, int, bytes]:
    """(compression, uncompressed_size, uncompressed_crc, compressed records) of a Chunk record
    whose first ``length`` bytes (header included) are in ``record``; raises _MalformedError."""
    fixed_end = 9 + _CHUNK_FIXED.size
    if length < fixed_end + 8 or len(record) < fixed_end:
        raise _MalformedError(BAD_RECORD, "Chunk record too short for its fixed fields")
    _start, _end, usize, crc, clen = _CHUNK_FIXED.unpack_from(record, 9)
    at = fixed_end + clen
    if at + 8 > min(length, len(record)):
        raise _MalformedError(BAD_RECORD, "Chunk compression field overruns the record")
    compression = record[fixed_end:at].decode("utf-8", errors="replace")
    rlen = struct.unpack_from("<Q", record, at)[0]
    if at + 8 + rlen > length:
        raise _MalformedError(BAD_RECORD, f"Chunk records ({rlen} bytes) overrun the record")
    return compression, usize, crc, record[at + 8 : at + 8 + rlen]


def _too_big(what: str, n: int | str) -> _MalformedError:
    return _MalformedError(
        CHUNK_DECOMPRESS, f"{what} {n} bytes, more than the {MAX_CHUNK_BYTES} byte chunk limit"
    )


def _decompress(compression: str, data: bytes, zstd: zstandard.ZstdDecompressor) -> bytes:
    """The chunk's records, at most :data:`MAX_CHUNK_BYTES` of them whatever the frame or the
    header claims; raises _MalformedError. The caller compares the length with the header."""
    if compression == "":
        return data
    if compression == "zstd":
        try:
            declared = zstandard.frame_content_size(data)
            if declared > MAX_CHUNK_BYTES:
                raise _too_big("zstd frame declares", declared)
            if declared >= 0:  # a known size within the limit: one allocation
                return bytes(zstd.decompress(data, max_output_size=max(declared, 1)))
            # No size in the frame: stream at most one byte past the limit, so a bomb costs
            # the limit and is named as one.
            with zstd.stream_reader(io.BytesIO(data)) as stream:
                out = stream.read(MAX_CHUNK_BYTES + 1)
        except zstandard.ZstdError as exc:
            raise _MalformedError(CHUNK_DECOMPRESS, f"zstd: {exc}") from exc
        if len(out) > MAX_CHUNK_BYTES:
            raise _too_big("zstd frame holds over", MAX_CHUNK_BYTES)
        return bytes(out)
    if compression == "lz4":
        try:
            lz4d = lz4.frame.LZ4FrameDecompressor()
            out = lz4d.decompress(data, max_length=MAX_CHUNK_BYTES)
            if not lz4d.eof:
                if len(out) >= MAX_CHUNK_BYTES:
                    raise _too_big("lz4 frame holds over", MAX_CHUNK_BYTES)
                raise _MalformedError(CHUNK_DECOMPRESS, "lz4: the frame ends early")
        except (RuntimeError, ValueError, TypeError) as exc:
            raise _MalformedError(CHUNK_DECOMPRESS, f"lz4: {exc}") from exc
        return bytes(out)
    raise _MalformedError(UNSUPPORTED_COMPRESSION, f"unsupported compression {compression!r}")


def _decompress_prefix(compression: str, data: bytes, zstd: zstandard.ZstdDecompressor) -> bytes:
    """As much of a cut-off chunk's records as its compressed prefix yields (b"" if none)."""
    try:
        if compression == "":
            return data
        if compression == "zstd":
            return zstd.decompressobj().decompress(data)
        if compression == "lz4":
            out = lz4.frame.LZ4FrameDecompressor().decompress(data)
            return out if isinstance(out, bytes) else b""
    except (zstandard.ZstdError, RuntimeError, ValueError, TypeError):
        return b""
    return b""


# --------------------------------------------------------------------------------------------
# The walk over the data section
# --------------------------------------------------------------------------------------------


@dataclass
class _Segment:
    """Message records met outside chunks, per channel, until a chunk or SEGMENT_BYTES."""

    offset: int = -1
    nbytes: int = 0
    logs: dict[int, array[int]] = field(default_factory=dict)
    pubs: dict[int, array[int]] = field(default_factory=dict)
    payloads: dict[int, list[bytes]] = field(default_factory=dict)

    def add(self, pos: int, channel_id: int, log: int, pub: int, payload: bytes) -> None:
        if self.offset < 0:
            self.offset = pos
        if channel_id not in self.logs:
            self.logs[channel_id] = array("q")
            self.pubs[channel_id] = array("q")
            self.payloads[channel_id] = []
        self.logs[channel_id].append(log)
        self.pubs[channel_id].append(pub)
        self.payloads[channel_id].append(payload)
        self.nbytes += len(payload) + _MESSAGE_HEAD


class _Walk:
    """One pass over the data section, yielding batches and filling a :class:`ReadReport`."""

    def __init__(
        self, f: IO[bytes], layout: _Layout, topics: frozenset[str] | None, report: ReadReport
    ) -> None:
        self.f = f
        self.layout = layout
        self.topics = topics
        self.report = report
        self.catalog = layout.summary.copy()
        self.lost: dict[int, dict[str, int]] = {}
        self.pending: tuple[str, int, int] | None = None  # failed chunk: reason, offset, bytes
        self.pending_counted = False
        self.segment = _Segment()
        self.zstd = zstandard.ZstdDecompressor()  # one per pass: not shared between threads

    # -- bookkeeping ------------------------------------------------------------------------

    def damage(self, reason: str, offset: int, detail: str) -> None:
        self.report.damage.append(Damage(reason, offset, detail))

    def lose_bytes(self, reason: str, n: int) -> None:
        self.report.unknown_lost_bytes[reason] = self.report.unknown_lost_bytes.get(reason, 0) + n

    def lose(self, channel_id: int, reason: str, n: int) -> None:
        by_reason = self.lost.setdefault(channel_id, {})
        by_reason[reason] = by_reason.get(reason, 0) + n

    def wants(self, channel_id: int) -> bool:
        channel = self.catalog.get(channel_id)
        return channel is not None and (self.topics is None or channel.topic in self.topics)

    def batch(
        self, channel: Channel, log: np.ndarray, pub: np.ndarray, payloads: list[bytes]
    ) -> MessageBatch:
        read = self.report.messages_read
        read[channel.topic] = read.get(channel.topic, 0) + len(payloads)
        return MessageBatch(channel, log, pub, payloads)

    def register(self, op: int, body: bytes, offset: int) -> None:
        try:
            self.catalog.add(_parse(mr.Schema if op == Opcode.SCHEMA else mr.Channel, body))
        except _PARSE_ERRORS as exc:
            self.damage(BAD_RECORD, offset, f"unreadable {_opcode_name(op)} record: {exc!r}")

    def metadata(self, body: bytes, offset: int) -> None:
        """A Metadata record: merged into the report by name (later keys win)."""
        try:
            record = cast(mr.Metadata, _parse(mr.Metadata, body))
        except _PARSE_ERRORS as exc:
            self.damage(BAD_RECORD, offset, f"unreadable Metadata record: {exc!r}")
            return
        merged = self.report.metadata.setdefault(record.name, {})
        merged.update({str(k): str(v) for k, v in record.metadata.items()})

    def attachment(self, pos: int, length: int) -> None:
        """An Attachment record: only its name is kept (log_time u64, create_time u64, then
        the name as a u32-length string), so its data is never read."""
        head = _read_at(self.f, pos + 9, min(length, 20))
        if len(head) < 20:
            self.damage(BAD_RECORD, pos, "Attachment record too short for its fixed fields")
            return
        n = struct.unpack_from("<I", head, 16)[0]
        if 20 + n > length:
            self.damage(BAD_RECORD, pos, "Attachment name overruns its record")
            return
        name = _read_at(self.f, pos + 29, n).decode("utf-8", errors="replace")
        self.report.attachment_names.append(name)

    def settle_pending(self) -> None:
        """A failed chunk with no Message Index after it: its size is all we know of it."""
        if self.pending is not None and not self.pending_counted:
            self.lose_bytes(self.pending[0], self.pending[2])
        self.pending = None

    def finish(self) -> None:
        for channel_id, reasons in self.lost.items():
            channel = self.catalog.get(channel_id)
            if channel is None:
                key = f"<channel {channel_id}>"
            elif self.topics is None or channel.topic in self.topics:
                key = channel.topic
            else:
                continue
            lost = self.report.lost.setdefault(key, {})
            for reason, n in reasons.items():
                lost[reason] = lost.get(reason, 0) + n
        for channel_id in self.catalog.raw:
            channel = self.catalog.get(channel_id)
            if channel is not None and (self.topics is None or channel.topic in self.topics):
                self.report.messages_read.setdefault(channel.topic, 0)

    # -- the walk ---------------------------------------------------------------------------

    def run(self) -> Iterator[MessageBatch]:
        pos, end = self.layout.data_start, self.layout.data_end
        ended = False  # met Data End (or Footer)
        while pos < end:
            head = _read_at(self.f, pos, 9)
            op, length = _HEAD.unpack(head) if len(head) == 9 else (-1, 0)
            record_end = pos + 9 + length
            if op <= 0 or record_end > end:
                resume = yield from self.unreadable(pos, op, length)
                if resume is None:
                    ended = True
                    break
                pos = resume
                continue
            if op != Opcode.MESSAGE_INDEX:
                self.settle_pending()
            if op == Opcode.CHUNK:
                yield from self.flush_segment()
                yield from self.chunk(pos, length)
            elif op == Opcode.MESSAGE:
                yield from self.message(pos, length)
            elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
                self.register(op, _read_at(self.f, pos + 9, length), pos)
            elif op == Opcode.METADATA:
                self.metadata(_read_at(self.f, pos + 9, length), pos)
            elif op == Opcode.ATTACHMENT:
                self.attachment(pos, length)
            elif op == Opcode.MESSAGE_INDEX:
                self.index_after_failed_chunk(pos, length)
            elif op in (Opcode.DATA_END, Opcode.FOOTER):
                ended = True
                break
            pos = record_end
        if not ended and not self.layout.has_footer:
            self.damage(TRUNCATED, pos, "the file ends after a complete record, before Data End")
            self.lose_bytes(TRUNCATED, 0)
        yield from self.flush_segment()
        self.settle_pending()
        self.finish()

    def unreadable(
        self, pos: int, op: int, length: int
    ) -> Generator[MessageBatch, None, int | None]:
        """A record that cannot be read at ``pos``: salvage, note, and say where to resume."""
        size, end = self.layout.size, self.layout.data_end
        self.settle_pending()
        if op != 0 and not self.layout.has_footer and pos + 9 + length > size:
            what = "a record header" if op < 0 else f"a {_opcode_name(op)} record"
            self.damage(
                TRUNCATED,
                pos,
                f"the file ends inside {what} at offset {pos} ({size - pos} bytes present)",
            )
            self.lose_bytes(TRUNCATED, size - pos)
            if op == Opcode.CHUNK:
                yield from self.flush_segment()
                yield from self.cut_chunk(pos)
            return None
        what = (
            "reserved opcode 0"
            if op == 0
            else (f"{_opcode_name(op)} record of {length} bytes overruns the data section")
        )
        self.damage(BAD_RECORD, pos, f"unreadable record at offset {pos}: {what}")
        ci = self.layout.chunks.get(pos)
        if ci is not None and self.count_lost(ci, None, BAD_RECORD):
            return pos + ci.chunk_length
        later = [s for s in self.layout.chunk_starts if s > pos]
        resume = later[0] if later else end
        self.lose_bytes(BAD_RECORD, resume - pos)
        return resume if later else None

    # -- messages outside chunks ----------------------------------------------------------

    def message(self, pos: int, length: int) -> Iterator[MessageBatch]:
        if length < _MESSAGE.size:
            self.damage(BAD_RECORD, pos, f"Message record of {length} bytes is too short")
            self.lose_bytes(BAD_RECORD, 9 + length)
            return
        body = _read_at(self.f, pos + 9, length)
        channel_id, _seq, log, pub = _MESSAGE.unpack_from(body)
        if channel_id in self.catalog.raw and not self.wants(channel_id):
            return
        self.segment.add(pos, channel_id, log, pub, body[_MESSAGE.size :])
        if self.segment.nbytes >= SEGMENT_BYTES:
            yield from self.flush_segment()

    def flush_segment(self) -> Iterator[MessageBatch]:
        segment, self.segment = self.segment, _Segment()
        for channel_id, payloads in segment.payloads.items():
            channel = self.catalog.get(channel_id)
            if channel is None:
                self.unknown_channel(channel_id, len(payloads), segment.offset)
            elif self.wants(channel_id):
                yield self.batch(
                    channel,
                    np.array(segment.logs[channel_id], dtype=np.int64),
                    np.array(segment.pubs[channel_id], dtype=np.int64),
                    payloads,
                )

    def unknown_channel(self, channel_id: int, n: int, offset: int) -> None:
        self.damage(
            UNKNOWN_CHANNEL,
            offset,
            f"{n} messages on channel id {channel_id}, which no Channel record defines",
        )
        self.lose(channel_id, UNKNOWN_CHANNEL, n)

    # -- chunks -----------------------------------------------------------------------------

    def chunk(self, pos: int, length: int) -> Iterator[MessageBatch]:
        self.report.chunk_count += 1
        ci = self.layout.chunks.get(pos)
        if ci is not None and ci.chunk_length != 9 + length:
            self.damage(
                BAD_INDEX,
                pos,
                f"the Chunk Index gives {ci.chunk_length} bytes, the "
                f"Chunk record has {9 + length}; parsed without the index",
            )
            ci = None
        if ci is not None:
            self.report.compression.add(ci.compression or "none")
        ids = ci.message_index_offsets if ci is not None else {}
        indexed = bool(ids) and all(self.catalog.get(c) is not None for c in ids)
        if indexed and self.layout.channels_complete and not any(self.wants(c) for c in ids):
            return  # nothing wanted in it, and no channel definition to learn from it
        span = 9 + length
        if ci is not None:
            span = min(ci.chunk_length + ci.message_index_length, self.layout.data_end - pos)
        window = _read_at(self.f, pos, span)
        try:
            compression, usize, crc, data = _chunk_fields(window, 9 + length)
            self.report.compression.add(compression or "none")
            records = _decompress(compression, data, self.zstd)
            intact = crc != 0 and zlib.crc32(records) == crc
            if len(records) != usize:
                if not intact:  # nothing vouches for data whose size the header contradicts
                    raise _MalformedError(
                        CHUNK_DECOMPRESS, f"decompressed to {len(records)} bytes, not {usize}"
                    )
                self.damage(
                    CHUNK_SIZE,
                    pos,
                    f"chunk at offset {pos}: its header says {usize} bytes uncompressed, its "
                    f"data holds {len(records)} and passes the chunk's CRC: read whole",
                )
            elif crc and not intact:
                raise _MalformedError(CHUNK_CRC, f"records fail the chunk's CRC {crc:#010x}")
        except _MalformedError as exc:
            self.damage(exc.reason, pos, f"chunk at offset {pos} skipped: {exc.detail}")
            if ci is None or not self.count_lost(ci, window, exc.reason):
                self.pending, self.pending_counted = (exc.reason, pos, 9 + length), False
            return
        if indexed and ci is not None:
            batches = self.indexed(ci, window, pos, records)
            if batches is not None:
                yield from batches
                return
        yield from self.sequential(records, pos, partial=False)

    def cut_chunk(self, pos: int) -> Iterator[MessageBatch]:
        """The complete Message records at the start of a Chunk cut off by the end of file."""
        self.report.chunk_count += 1
        record = _read_at(self.f, pos, self.layout.size - pos)
        length = _HEAD.unpack_from(record)[1]
        fixed_end = 9 + _CHUNK_FIXED.size
        if len(record) < fixed_end + 8:
            return
        clen = _CHUNK_FIXED.unpack_from(record, 9)[4]
        at = fixed_end + clen
        if at + 8 > len(record):
            return
        compression = record[fixed_end:at].decode("utf-8", errors="replace")
        self.report.compression.add(compression or "none")
        rlen = struct.unpack_from("<Q", record, at)[0]
        data = record[at + 8 : min(at + 8 + rlen, 9 + length)]
        records = _decompress_prefix(compression, data, self.zstd)
        yield from self.sequential(records, pos, partial=True)

    def message_index(
        self, offset: int, window: bytes | None, pos: int
    ) -> tuple[int, np.ndarray] | None:
        """The Message Index record at ``offset`` (from ``window`` when it holds it)."""
        rel = offset - pos
        if window is not None and rel >= 0 and rel + 9 <= len(window):
            head = window[rel : rel + 9]
        else:
            head, window = _read_at(self.f, offset, 9), None
        if len(head) < 9:
            return None
        op, length = _HEAD.unpack(head)
        if op != Opcode.MESSAGE_INDEX or length < 6 or offset + 9 + length > self.layout.size:
            return None
        if window is not None and rel + 9 + length <= len(window):
            body = window[rel + 9 : rel + 9 + length]
        else:
            body = _read_at(self.f, offset + 9, length)
        channel_id, nbytes = struct.unpack_from("<HI", body)
        if nbytes % 16 or 6 + nbytes > length:
            return None
        return channel_id, np.frombuffer(body, dtype=_INDEX_ENTRY, count=nbytes // 16, offset=6)

    def count_lost(self, ci: mr.ChunkIndex, window: bytes | None, reason: str) -> bool:
        """Count a failed chunk's messages from its Message Index records; False if unreadable."""
        counts: dict[int, int] = {}
        for channel_id, offset in ci.message_index_offsets.items():
            found = self.message_index(offset, window, ci.chunk_start_offset)
            if found is None or found[0] != channel_id:
                return False
            counts[channel_id] = len(np.unique(found[1]["offset"]))
        for channel_id, n in counts.items():
            self.lose(channel_id, reason, n)
        return bool(counts)

    def index_after_failed_chunk(self, pos: int, length: int) -> None:
        """A Message Index record in the data section: counts what a failed chunk held."""
        if self.pending is None:
            return
        found = self.message_index(pos, None, pos)
        if found is not None:
            self.lose(found[0], self.pending[0], len(np.unique(found[1]["offset"])))
            self.pending_counted = True

    def indexed(
        self, ci: mr.ChunkIndex, window: bytes, pos: int, records: bytes
    ) -> list[MessageBatch] | None:
        """The fast path: wanted channels' messages located by their Message Index records.
        None (with ``bad_index`` damage) when an index disagrees with the chunk."""
        parts: list[tuple[Channel, np.ndarray, np.ndarray, list[bytes]]] = []
        n = len(records)
        for channel_id in sorted(ci.message_index_offsets):
            if not self.wants(channel_id):
                continue
            channel = self.catalog.get(channel_id)
            found = self.message_index(ci.message_index_offsets[channel_id], window, pos)
            if channel is None or found is None or found[0] != channel_id:
                self.damage(
                    BAD_INDEX,
                    pos,
                    f"chunk at offset {pos}: the Message Index for "
                    f"channel {channel_id} is unreadable; chunk parsed instead",
                )
                return None
            entries = found[1]
            if not len(entries):
                continue
            order = np.argsort(entries["offset"], kind="stable")
            offsets, times = entries["offset"][order], entries["time"][order]
            keep = np.ones(len(offsets), dtype=bool)
            keep[1:] = offsets[1:] != offsets[:-1]  # each message at most once
            offsets, times = offsets[keep], times[keep]
            if int(offsets[-1]) > n - _MESSAGE_HEAD:
                self.damage(
                    BAD_INDEX,
                    pos,
                    f"chunk at offset {pos}: a Message Index offset for "
                    f"channel {channel_id} is past the chunk; chunk parsed instead",
                )
                return None
            at = offsets.astype(np.int64)
            fields = _gather(records, at)
            ok = (
                (fields.opcode == Opcode.MESSAGE)
                & (fields.channel == channel_id)
                & (fields.length >= _MESSAGE.size)
                & (fields.length <= (n - 9 - at).astype(np.uint64))
                & (fields.log == times.view(np.int64))
            )
            if not ok.all():
                self.damage(
                    BAD_INDEX,
                    pos,
                    f"chunk at offset {pos}: the Message Index for "
                    f"channel {channel_id} does not match its messages; chunk parsed",
                )
                return None
            parts.append((channel, fields.log, fields.pub, _payloads(records, at, fields.length)))
        return [self.batch(*part) for part in parts]  # counted once all indexes proved right

    def sequential(self, records: bytes, pos: int, partial: bool) -> Iterator[MessageBatch]:
        """The salvage path: walk a chunk's records one by one, then gather its messages.
        ``partial``: the records were cut off by the end of the file (no damage for the tail)."""
        n = len(records)
        at = 0
        offsets: list[int] = []
        unpack = _HEAD.unpack_from
        message, schema, channel = Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL
        while at + 9 <= n:
            op, length = unpack(records, at)
            end = at + 9 + length
            if end > n:
                break
            if op == message:
                if length >= _MESSAGE.size:
                    offsets.append(at)
                else:
                    self.damage(
                        BAD_RECORD,
                        pos,
                        f"chunk at offset {pos}: Message record of "
                        f"{length} bytes at +{at} is too short",
                    )
                    self.lose_bytes(BAD_RECORD, 9 + length)
            elif op in (schema, channel):
                self.register(op, records[at + 9 : end], pos)
            at = end
        if at < n and not partial:
            self.damage(
                BAD_RECORD, pos, f"chunk at offset {pos}: the record at +{at} overruns the chunk"
            )
            self.lose_bytes(BAD_RECORD, n - at)
        if not offsets:
            return
        starts = np.asarray(offsets, dtype=np.int64)
        fields = _gather(records, starts)
        ids, first = np.unique(fields.channel, return_index=True)
        for channel_id in ids[np.argsort(first)].tolist():
            mask = fields.channel == channel_id
            resolved = self.catalog.get(channel_id)
            if resolved is None:
                self.unknown_channel(channel_id, int(mask.sum()), pos)
            elif self.wants(channel_id):
                sel = np.flatnonzero(mask)
                yield self.batch(
                    resolved,
                    fields.log[sel],
                    fields.pub[sel],
                    _payloads(records, starts[sel], fields.length[sel]),
                )


# --------------------------------------------------------------------------------------------
# The reader
# --------------------------------------------------------------------------------------------


class LogReader:
    """An MCAP log opened for reading; use as a context manager.

    >>> with LogReader(path, topics={"/imu"}) as log:     # doctest: +SKIP
    ...     for batch in log.batches():
    ...         ...
    ...     log.report.lost

    Raises :class:`LogReadError` at construction for a file that is missing, not MCAP or
    without a readable Header. ``topics`` limits :meth:`batches` (not :meth:`channels`).
    """

    def __init__(self, path: str | Path, topics: Collection[str] | None = None) -> None:
        self.path = Path(path)
        self._topics = None if topics is None else frozenset(topics)
        self._file: IO[bytes] | None
        self._file, size = open_mcap(self.path)
        try:
            self._layout = _read_header(self._file, self.path, size)
            _read_summary(self._file, self._layout)
        except BaseException:
            self.close()
            raise
        self._report = self._new_report()
        self._catalog: _Catalog | None = (
            self._layout.summary if self._layout.channels_complete else None
        )

    # -- context manager ---------------------------------------------------------------------

    def __enter__(self) -> LogReader:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (batches() can no longer be iterated)."""
        f, self._file = self._file, None
        if f is not None:
            f.close()

    def _open_file(self) -> IO[bytes]:
        if self._file is None:
            raise ValueError(f"{self.path}: the log reader is closed")
        return self._file

    def _new_report(self) -> ReadReport:
        return ReadReport(used_index=bool(self._layout.chunks), damage=list(self._layout.damage))

    # -- reading -----------------------------------------------------------------------------

    @property
    def profile(self) -> str:
        """The Header record's profile (``ros2`` for ROS 2 logs)."""
        return self._layout.profile

    @property
    def library(self) -> str:
        """The Header record's library string."""
        return self._layout.library

    def channels(self) -> dict[str, Channel]:
        """Topic -> channel for every topic of the log (the lowest channel id when a topic has
        several). From the summary when it holds every channel; otherwise a pre-pass reads the
        Schema and Channel records of the whole file, including those inside chunks."""
        if self._catalog is None:
            walk = _Walk(self._open_file(), self._layout, frozenset(), self._new_report())
            for _ in walk.run():
                pass
            self._catalog = walk.catalog
        out: dict[str, Channel] = {}
        for channel_id in sorted(self._catalog.raw):
            channel = self._catalog.get(channel_id)
            if channel is not None:
                out.setdefault(channel.topic, channel)
        return out

    def batches(self) -> Iterator[MessageBatch]:
        """The wanted topics' messages, one batch per channel per chunk (or per segment of
        messages outside chunks), in file order. Each call reads the file again and starts a
        new :attr:`report`."""
        self._report = self._new_report()
        walk = _Walk(self._open_file(), self._layout, self._topics, self._report)
        yield from walk.run()
        if self._catalog is None:
            self._catalog = walk.catalog

    @property
    def report(self) -> ReadReport:
        """What the last :meth:`batches` pass delivered and lost; complete once it is exhausted."""
        return self._report

    # -- the summary alone ------------------------------------------------------------------

    @property
    def has_summary(self) -> bool:
        """Whether a readable summary section was found (its indexes may still be partial)."""
        return self._layout.summary_read

    @property
    def statistics(self) -> mr.Statistics | None:
        """The summary's Statistics record, if it has one."""
        return self._layout.statistics

    @property
    def summary_metadata_names(self) -> list[str]:
        """Names of the Metadata records the summary's Metadata Index records list."""
        return list(self._layout.metadata_names)

    @property
    def summary_attachment_names(self) -> list[str]:
        """Names of the Attachment records the summary's Attachment Index records list."""
        return list(self._layout.attachment_names)

    def index_times(self) -> dict[int, np.ndarray] | None:
        """Channel id -> log times (int64 ns, file order) from the Message Index records
        alone: no chunk is decompressed, so no CRC is checked.

        None when the index cannot vouch for every message: no Chunk Index, a chunk without
        message indexes, channels defined only inside chunks, an unreadable Message Index,
        or a Statistics message count that the indexes do not reach (messages outside
        chunks). The caller then reads the file with :meth:`batches`.
        """
        layout = self._layout
        if not layout.chunks or not layout.channels_complete:
            return None
        f = self._open_file()
        walk = _Walk(f, layout, frozenset(), self._new_report())
        parts: dict[int, list[np.ndarray]] = {}
        total = 0
        for start in layout.chunk_starts:
            ci = layout.chunks[start]
            if not ci.message_index_offsets:
                return None
            for channel_id, offset in sorted(ci.message_index_offsets.items()):
                found = walk.message_index(offset, None, start)
                if found is None or found[0] != channel_id:
                    return None
                entries = np.sort(found[1], order="offset")  # file order within the chunk
                parts.setdefault(channel_id, []).append(entries["time"].view(np.int64))
                total += len(entries)
        stats = layout.statistics
        if stats is not None and stats.message_count != total:
            return None
        return {
            channel_id: np.concatenate(parts.get(channel_id, [np.zeros(0, np.int64)]))
            for channel_id in sorted(layout.summary.raw)
        }

    def chunk_indexes(self) -> list[mr.ChunkIndex]:
        """The summary's usable Chunk Index records, in file order."""
        return [self._layout.chunks[s] for s in self._layout.chunk_starts]

    def channel_by_id(self) -> dict[int, Channel]:
        """Channel id -> channel, for every channel known (see :meth:`channels`)."""
        self.channels()
        catalog = self._catalog
        if catalog is None:  # pragma: no cover - channels() always sets it
            return {}
        out: dict[int, Channel] = {}
        for channel_id in sorted(catalog.raw):
            channel = catalog.get(channel_id)
            if channel is not None:
                out[channel_id] = channel
        return out


__all__ = [
    "BAD_INDEX",
    "BAD_RECORD",
    "CHUNK_CRC",
    "CHUNK_DECOMPRESS",
    "CHUNK_SIZE",
    "NO_SUMMARY",
    "SEGMENT_BYTES",
    "TRUNCATED",
    "UNKNOWN_CHANNEL",
    "UNSUPPORTED_COMPRESSION",
    "Channel",
    "Damage",
    "LogReader",
    "MessageBatch",
    "ReadReport",
]
