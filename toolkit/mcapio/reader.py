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

from collections.abc import Collection, Iterator
from pathlib import Path
from typing import IO

import numpy as np
from mcap import records as mr

from toolkit.mcapio.closing import Closing
from toolkit.mcapio.damage import (
    BAD_INDEX,
    BAD_RECORD,
    CHUNK_CRC,
    CHUNK_DECOMPRESS,
    CHUNK_SIZE,
    NO_SUMMARY,
    TRUNCATED,
    UNKNOWN_CHANNEL,
    UNSUPPORTED_COMPRESSION,
    Damage,
    ReadReport,
)
from toolkit.mcapio.records import Catalog, Channel, MessageBatch
from toolkit.mcapio.summary import open_mcap, read_header, read_summary
from toolkit.mcapio.walk import SEGMENT_BYTES, Walk


class LogReader(Closing):
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
            self._layout = read_header(self._file, self.path, size)
            read_summary(self._file, self._layout)
        except BaseException:
            self.close()
            raise
        self._report = self._new_report()
        self._catalog: Catalog | None = (
            self._layout.summary if self._layout.channels_complete else None
        )

    # -- closing -----------------------------------------------------------------------------

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
            walk = Walk(self._open_file(), self._layout, frozenset(), self._new_report())
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
        walk = Walk(self._open_file(), self._layout, self._topics, self._report)
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
        walk = Walk(f, layout, frozenset(), self._new_report())
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
