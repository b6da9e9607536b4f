"""MCAP records at the byte level: layouts, parsing helpers, and the channels learnt.

Package-internal to :mod:`toolkit.mcapio`: the reader's modules share these. The public
:class:`Channel` and :class:`MessageBatch` are re-exported by :mod:`toolkit.mcapio.reader`.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np
from mcap import records as mr
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode

from toolkit.mcapio.damage import BAD_RECORD

MAGIC = b"\x89MCAP0\r\n"

HEAD = struct.Struct("<BQ")  # every record: opcode u8, content length u64
CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed_size, uncompressed_crc, len
MESSAGE = struct.Struct("<HIqq")  # Message: channel_id, sequence, log_time, publish_time
MESSAGE_HEAD = 9 + MESSAGE.size  # a Message record up to its data
INDEX_ENTRY = np.dtype([("time", "<u8"), ("offset", "<u8")])  # Message Index (timestamp, offset)
_COLUMNS = np.arange(MESSAGE_HEAD, dtype=np.int64)
PARSE_ERRORS = (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError)


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


# --------------------------------------------------------------------------------------------
# Small parsing helpers
# --------------------------------------------------------------------------------------------


class MalformedError(Exception):
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


def parse_record(cls: Any, body: bytes) -> mr.McapRecord:
    """Parse one record body with mcap's record class ``cls`` (padding after it is ignored).

    ``cls`` is typed Any because mcap's record classes declare their ``read`` untyped; the
    result is checked to be a ``cls``."""
    record: object = cls.read(_Strict(io.BytesIO(body)))
    if isinstance(record, cls) and isinstance(record, mr.McapRecord):
        return record
    raise MalformedError(BAD_RECORD, f"not a {cls.__name__} record")  # pragma: no cover


def opcode_name(op: int) -> str:
    try:
        return Opcode(op).name.title().replace("_", "")
    except ValueError:
        return f"opcode 0x{op:02x}"


def read_at(f: IO[bytes], pos: int, n: int) -> bytes:
    f.seek(pos)
    return f.read(n)


@dataclass
class _Fields:
    """Fixed fields of Message records gathered at known offsets of a chunk buffer."""

    opcode: np.ndarray
    length: np.ndarray  # uint64 record content length
    channel: np.ndarray
    log: np.ndarray  # int64
    pub: np.ndarray  # int64


def gather(buf: bytes, offsets: np.ndarray) -> _Fields:
    """Read the fixed part of the Message records starting at ``offsets`` (int64, each at least
    31 bytes before the end of ``buf``) with one numpy gather, no per-message Python."""
    rows = np.frombuffer(buf, dtype=np.uint8)[offsets[:, None] + _COLUMNS]

    def col(a: int, b: int, dtype: str) -> np.ndarray:
        return np.ascontiguousarray(rows[:, a:b]).view(dtype).reshape(-1)

    return _Fields(
        rows[:, 0], col(1, 9, "<u8"), col(9, 11, "<u2"), col(15, 23, "<i8"), col(23, 31, "<i8")
    )


def cut_payloads(buf: bytes, offsets: np.ndarray, length: np.ndarray) -> list[bytes]:
    ends = (offsets + 9 + length.astype(np.int64)).tolist()
    return [buf[s:e] for s, e in zip((offsets + MESSAGE_HEAD).tolist(), ends, strict=True)]


# --------------------------------------------------------------------------------------------
# Schemas and channels
# --------------------------------------------------------------------------------------------


@dataclass
class Catalog:
    """Schema and Channel records learnt so far (the first definition of an id wins)."""

    schemas: dict[int, mr.Schema] = field(default_factory=dict)
    raw: dict[int, mr.Channel] = field(default_factory=dict)
    resolved: dict[int, Channel] = field(default_factory=dict)

    def copy(self) -> Catalog:
        return Catalog(dict(self.schemas), dict(self.raw), dict(self.resolved))

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
