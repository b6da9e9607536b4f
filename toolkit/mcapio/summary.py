"""Opening an MCAP log: magic, Header, Footer, and the summary section's indexes.

Package-internal to :mod:`toolkit.mcapio`: :class:`Layout` tells the walk over the data
section (:mod:`toolkit.mcapio.walk`) where things are. Damage found here is noted in the
layout, never raised; only a file without a readable Header is a LogReadError.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, cast

from mcap import records as mr
from mcap.opcode import Opcode

from toolkit.errors import LogReadError
from toolkit.mcapio.damage import BAD_INDEX, NO_SUMMARY, Damage
from toolkit.mcapio.records import (
    CHUNK_FIXED,
    HEAD,
    MAGIC,
    PARSE_ERRORS,
    Catalog,
    MalformedError,
    opcode_name,
    parse_record,
    read_at,
)

_FOOTER_BYTES = 9 + 20  # Footer: summary_start u64, summary_offset_start u64, summary_crc u32


def _open_file(path: Path) -> IO[bytes]:
    """Open the log (a seam for tests that count the bytes read)."""
    return open(path, "rb")  # noqa: SIM115 - closed by LogReader.close


@dataclass
class Layout:
    """Where things are in the file, from its Header, Footer and summary section."""

    size: int
    data_start: int  # first byte after the Header record
    data_end: int  # the linear walk stops here
    has_footer: bool = False
    summary: Catalog = field(default_factory=Catalog)
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


def read_header(f: IO[bytes], path: Path, size: int) -> Layout:
    head = read_at(f, len(MAGIC), 9)
    if len(head) < 9 or head[0] != Opcode.HEADER:
        raise LogReadError("MCAP file without a Header record after the magic bytes", path)
    length = HEAD.unpack(head)[1]
    end = len(MAGIC) + 9 + length
    if end > size:
        raise LogReadError("MCAP file whose Header record is cut off", path)
    try:
        header = cast(mr.Header, parse_record(mr.Header, read_at(f, len(MAGIC) + 9, length)))
    except PARSE_ERRORS as exc:
        raise LogReadError(f"MCAP file with an unreadable Header record ({exc!r})", path) from exc
    return Layout(
        size=size, data_start=end, data_end=size, profile=header.profile, library=header.library
    )


def _read_footer(f: IO[bytes], layout: Layout) -> tuple[int, int, int] | None:
    """The Footer's (summary_start, summary_offset_start, summary_crc), or None without one."""
    at = layout.size - len(MAGIC) - _FOOTER_BYTES
    if at < layout.data_start:
        return None
    tail = read_at(f, at, _FOOTER_BYTES + len(MAGIC))
    if tail[_FOOTER_BYTES:] != MAGIC or HEAD.unpack_from(tail) != (Opcode.FOOTER, 20):
        return None
    layout.has_footer = True
    layout.data_end = at
    start, offset_start, crc = struct.unpack_from("<QQI", tail, 9)
    if crc and start:
        section = read_at(f, start, at - start) if layout.data_start <= start <= at else b""
        if zlib.crc32(tail[:25], zlib.crc32(section)) != crc:
            layout.damage.append(Damage(BAD_INDEX, start, "the summary section fails its CRC"))
            return None
    return start, offset_start, crc


def _summary_records(section: bytes) -> Iterator[mr.McapRecord]:
    pos = 0
    while pos < len(section):
        if pos + 9 > len(section):
            raise MalformedError(BAD_INDEX, "the summary section ends inside a record header")
        op, length = HEAD.unpack_from(section, pos)
        end = pos + 9 + length
        if end > len(section):
            raise MalformedError(BAD_INDEX, f"a summary {opcode_name(op)} record overruns it")
        cls = {
            Opcode.SCHEMA: mr.Schema,
            Opcode.CHANNEL: mr.Channel,
            Opcode.CHUNK_INDEX: mr.ChunkIndex,
            Opcode.STATISTICS: mr.Statistics,
            Opcode.METADATA_INDEX: mr.MetadataIndex,
            Opcode.ATTACHMENT_INDEX: mr.AttachmentIndex,
        }.get(op)
        if cls is not None:
            yield parse_record(cls, section[pos + 9 : end])
        pos = end


def read_summary(f: IO[bytes], layout: Layout) -> None:
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
    catalog = Catalog()
    chunks: list[mr.ChunkIndex] = []
    stats: mr.Statistics | None = None
    metadata_names: list[str] = []
    attachment_names: list[str] = []
    try:
        for record in _summary_records(read_at(f, start, end - start)):
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
    except (MalformedError, *PARSE_ERRORS) as exc:
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


def _chunk_index_fits(ci: mr.ChunkIndex, layout: Layout) -> bool:
    chunk_end = ci.chunk_start_offset + ci.chunk_length
    return (
        layout.data_start <= ci.chunk_start_offset
        and ci.chunk_length >= 9 + CHUNK_FIXED.size + 8
        and chunk_end <= layout.data_end
        and all(chunk_end <= o <= layout.data_end - 15 for o in ci.message_index_offsets.values())
    )
