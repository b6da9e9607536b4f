"""Damaged copies of MCAP logs, and facts about intact ones, for the reader's tests.

Everything here reads the intact file through ``mcap``'s own reader (never through the code under
test) or edits raw bytes at offsets taken from its summary: the Chunk Index gives where a Chunk
record starts, and the Chunk record's layout (MCAP spec: opcode, length, message_start_time,
message_end_time, uncompressed_size, uncompressed_crc, compression, records) where its fields are.
"""

from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Chunk, ChunkIndex, Message
from mcap.stream_reader import StreamReader, breakup_chunk

#: (log_time, publish_time, payload) per topic, in file order.
Messages = dict[str, list[tuple[int, int, bytes]]]


def reference(path: Path) -> Messages:
    """Every message of an intact file, read with mcap's StreamReader (file order)."""
    out: Messages = {}
    topics: dict[int, str] = {}
    with open(path, "rb") as f:
        for record in StreamReader(f).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                out.setdefault(topics[record.channel_id], []).append(
                    (record.log_time, record.publish_time, record.data)
                )
    return out


def chunk_indexes(path: Path) -> list[ChunkIndex]:
    """The summary's Chunk Index records, in file order."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def chunk_topics(path: Path, index: ChunkIndex) -> Counter[str]:
    """Messages per topic inside one chunk of an intact file."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        f.seek(index.chunk_start_offset)
        chunk = next(iter(StreamReader(f, skip_magic=True, emit_chunks=True).records))
    assert isinstance(chunk, Chunk)
    return Counter(
        summary.channels[r.channel_id].topic for r in breakup_chunk(chunk) if isinstance(r, Message)
    )


def compressed_start(index: ChunkIndex) -> int:
    """File offset of a chunk's (compressed) records."""
    return index.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len(index.compression.encode()) + 8


def crc_field(index: ChunkIndex) -> int:
    """File offset of a chunk's uncompressed_crc field."""
    return index.chunk_start_offset + 9 + 8 + 8 + 8


def data_end(path: Path) -> int:
    """The offset where the summary section starts (the Footer's summary_start)."""
    data = path.read_bytes()
    start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    assert start > 0
    return int(start)


def flip(src: Path, dst: Path, offset: int, mask: int = 0xFF) -> Path:
    """A copy of ``src`` with the byte at ``offset`` XORed with ``mask``."""
    data = bytearray(src.read_bytes())
    data[offset] ^= mask
    dst.write_bytes(bytes(data))
    return dst


def truncate(src: Path, dst: Path, size: int) -> Path:
    """The first ``size`` bytes of ``src``."""
    dst.write_bytes(src.read_bytes()[:size])
    return dst


def cut_summary(src: Path, dst: Path) -> Path:
    """``src`` without its summary, summary offsets, Footer and closing magic (ends at Data End)."""
    return truncate(src, dst, data_end(src))


def message_spans(path: Path) -> list[tuple[str, int, int, int]]:
    """(topic, log_time, first byte, byte after) in the file of every Message record, for an
    intact file whose chunks are uncompressed (found by walking its records with mcap's
    StreamReader positions and the chunk layout)."""
    spans: list[tuple[str, int, int, int]] = []
    data = path.read_bytes()
    topics: dict[int, str] = {}

    def walk(start: int, end: int) -> None:
        pos = start
        while pos < end:
            op, length = struct.unpack_from("<BQ", data, pos)
            body = pos + 9
            if op == 0x04:  # Channel: id u16, schema_id u16, topic string
                channel_id = struct.unpack_from("<H", data, body)[0]
                n = struct.unpack_from("<I", data, body + 4)[0]
                topics[channel_id] = data[body + 8 : body + 8 + n].decode()
            elif op == 0x05:  # Message
                channel_id, _seq, log_time = struct.unpack_from("<HIQ", data, body)
                spans.append((topics[channel_id], log_time, pos, body + length))
            elif op == 0x06:  # Chunk
                clen = struct.unpack_from("<I", data, body + 28)[0]
                assert data[body + 32 : body + 32 + clen] == b"", "compressed chunk"
                rlen = struct.unpack_from("<Q", data, body + 32 + clen)[0]
                records = body + 32 + clen + 8
                walk(records, records + rlen)
            elif op == 0x0F:  # Data End
                return
            pos = body + length

    walk(8, len(data))
    return spans


def top_level(path: Path) -> list[tuple[int, int, int]]:
    """(offset, opcode, content length) of every record from the Header to Data End."""
    data = path.read_bytes()
    out: list[tuple[int, int, int]] = []
    pos = 8
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, length))
        if op == 0x0F:
            break
        pos += 9 + length
    return out


def messages_in_chunk_at(path: Path, offset: int) -> int:
    """How many Message records the (intact) Chunk record at ``offset`` holds."""
    with open(path, "rb") as f:
        f.seek(offset)
        chunk = next(iter(StreamReader(f, skip_magic=True, emit_chunks=True).records))
    assert isinstance(chunk, Chunk)
    return sum(isinstance(r, Message) for r in breakup_chunk(chunk))


def channel_ids(path: Path) -> dict[str, int]:
    """Topic -> channel id, from the summary of an intact file."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic: c.id for c in summary.channels.values()}
