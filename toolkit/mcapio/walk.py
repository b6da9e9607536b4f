"""One pass over an MCAP log's data section: the fast path from the index, and salvage.

Package-internal to :mod:`toolkit.mcapio`: :class:`LogReader` (:mod:`toolkit.mcapio.reader`,
whose docstring tells how the file is read and what each damage reason means) runs a
:class:`Walk` for each pass.
"""

from __future__ import annotations

import struct
import zlib
from array import array
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from typing import IO, cast

import numpy as np
import zstandard
from mcap import records as mr
from mcap.opcode import Opcode

from toolkit.mcapio.chunks import chunk_fields, decompress, decompress_prefix
from toolkit.mcapio.damage import (
    BAD_INDEX,
    BAD_RECORD,
    CHUNK_CRC,
    CHUNK_DECOMPRESS,
    CHUNK_SIZE,
    TRUNCATED,
    UNKNOWN_CHANNEL,
    Damage,
    ReadReport,
)
from toolkit.mcapio.records import (
    CHUNK_FIXED,
    HEAD,
    INDEX_ENTRY,
    MESSAGE,
    MESSAGE_HEAD,
    PARSE_ERRORS,
    Channel,
    MalformedError,
    MessageBatch,
    cut_payloads,
    gather,
    opcode_name,
    parse_record,
    read_at,
)
from toolkit.mcapio.summary import Layout

#: Messages outside chunks are delivered in segments of about this many payload bytes.
SEGMENT_BYTES = 4 * 1024 * 1024


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
        self.nbytes += len(payload) + MESSAGE_HEAD


class Walk:
    """One pass over the data section, yielding batches and filling a :class:`ReadReport`."""

    def __init__(
        self, f: IO[bytes], layout: Layout, topics: frozenset[str] | None, report: ReadReport
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
            self.catalog.add(parse_record(mr.Schema if op == Opcode.SCHEMA else mr.Channel, body))
        except PARSE_ERRORS as exc:
            self.damage(BAD_RECORD, offset, f"unreadable {opcode_name(op)} record: {exc!r}")

    def metadata(self, body: bytes, offset: int) -> None:
        """A Metadata record: merged into the report by name (later keys win)."""
        try:
            record = cast(mr.Metadata, parse_record(mr.Metadata, body))
        except PARSE_ERRORS as exc:
            self.damage(BAD_RECORD, offset, f"unreadable Metadata record: {exc!r}")
            return
        merged = self.report.metadata.setdefault(record.name, {})
        merged.update({str(k): str(v) for k, v in record.metadata.items()})

    def attachment(self, pos: int, length: int) -> None:
        """An Attachment record: only its name is kept (log_time u64, create_time u64, then
        the name as a u32-length string), so its data is never read."""
        head = read_at(self.f, pos + 9, min(length, 20))
        if len(head) < 20:
            self.damage(BAD_RECORD, pos, "Attachment record too short for its fixed fields")
            return
        n = struct.unpack_from("<I", head, 16)[0]
        if 20 + n > length:
            self.damage(BAD_RECORD, pos, "Attachment name overruns its record")
            return
        name = read_at(self.f, pos + 29, n).decode("utf-8", errors="replace")
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
            head = read_at(self.f, pos, 9)
            op, length = HEAD.unpack(head) if len(head) == 9 else (-1, 0)
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
                self.register(op, read_at(self.f, pos + 9, length), pos)
            elif op == Opcode.METADATA:
                self.metadata(read_at(self.f, pos + 9, length), pos)
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
            what = "a record header" if op < 0 else f"a {opcode_name(op)} record"
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
            else (f"{opcode_name(op)} record of {length} bytes overruns the data section")
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
        if length < MESSAGE.size:
            self.damage(BAD_RECORD, pos, f"Message record of {length} bytes is too short")
            self.lose_bytes(BAD_RECORD, 9 + length)
            return
        body = read_at(self.f, pos + 9, length)
        channel_id, _seq, log, pub = MESSAGE.unpack_from(body)
        if channel_id in self.catalog.raw and not self.wants(channel_id):
            return
        self.segment.add(pos, channel_id, log, pub, body[MESSAGE.size :])
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
        window = read_at(self.f, pos, span)
        try:
            compression, usize, crc, data = chunk_fields(window, 9 + length)
            self.report.compression.add(compression or "none")
            records = decompress(compression, data, self.zstd)
            intact = crc != 0 and zlib.crc32(records) == crc
            if len(records) != usize:
                if not intact:  # nothing vouches for data whose size the header contradicts
                    raise MalformedError(
                        CHUNK_DECOMPRESS, f"decompressed to {len(records)} bytes, not {usize}"
                    )
                self.damage(
                    CHUNK_SIZE,
                    pos,
                    f"chunk at offset {pos}: its header says {usize} bytes uncompressed, its "
                    f"data holds {len(records)} and passes the chunk's CRC: read whole",
                )
            elif crc and not intact:
                raise MalformedError(CHUNK_CRC, f"records fail the chunk's CRC {crc:#010x}")
        except MalformedError as exc:
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
        record = read_at(self.f, pos, self.layout.size - pos)
        length = HEAD.unpack_from(record)[1]
        fixed_end = 9 + CHUNK_FIXED.size
        if len(record) < fixed_end + 8:
            return
        clen = CHUNK_FIXED.unpack_from(record, 9)[4]
        at = fixed_end + clen
        if at + 8 > len(record):
            return
        compression = record[fixed_end:at].decode("utf-8", errors="replace")
        self.report.compression.add(compression or "none")
        rlen = struct.unpack_from("<Q", record, at)[0]
        data = record[at + 8 : min(at + 8 + rlen, 9 + length)]
        records = decompress_prefix(compression, data, self.zstd)
        yield from self.sequential(records, pos, partial=True)

    def message_index(
        self, offset: int, window: bytes | None, pos: int
    ) -> tuple[int, np.ndarray] | None:
        """The Message Index record at ``offset`` (from ``window`` when it holds it)."""
        rel = offset - pos
        if window is not None and rel >= 0 and rel + 9 <= len(window):
            head = window[rel : rel + 9]
        else:
            head, window = read_at(self.f, offset, 9), None
        if len(head) < 9:
            return None
        op, length = HEAD.unpack(head)
        if op != Opcode.MESSAGE_INDEX or length < 6 or offset + 9 + length > self.layout.size:
            return None
        if window is not None and rel + 9 + length <= len(window):
            body = window[rel + 9 : rel + 9 + length]
        else:
            body = read_at(self.f, offset + 9, length)
        channel_id, nbytes = struct.unpack_from("<HI", body)
        if nbytes % 16 or 6 + nbytes > length:
            return None
        return channel_id, np.frombuffer(body, dtype=INDEX_ENTRY, count=nbytes // 16, offset=6)

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
            if int(offsets[-1]) > n - MESSAGE_HEAD:
                self.damage(
                    BAD_INDEX,
                    pos,
                    f"chunk at offset {pos}: a Message Index offset for "
                    f"channel {channel_id} is past the chunk; chunk parsed instead",
                )
                return None
            at = offsets.astype(np.int64)
            fields = gather(records, at)
            ok = (
                (fields.opcode == Opcode.MESSAGE)
                & (fields.channel == channel_id)
                & (fields.length >= MESSAGE.size)
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
            parts.append(
                (channel, fields.log, fields.pub, cut_payloads(records, at, fields.length))
            )
        return [self.batch(*part) for part in parts]  # counted once all indexes proved right

    def sequential(self, records: bytes, pos: int, partial: bool) -> Iterator[MessageBatch]:
        """The salvage path: walk a chunk's records one by one, then gather its messages.
        ``partial``: the records were cut off by the end of the file (no damage for the tail)."""
        n = len(records)
        at = 0
        offsets: list[int] = []
        unpack = HEAD.unpack_from
        message, schema, channel = Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL
        while at + 9 <= n:
            op, length = unpack(records, at)
            end = at + 9 + length
            if end > n:
                break
            if op == message:
                if length >= MESSAGE.size:
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
        fields = gather(records, starts)
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
                    cut_payloads(records, starts[sel], fields.length[sel]),
                )
