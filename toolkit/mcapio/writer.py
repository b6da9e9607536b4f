"""Writing ROS 2 MCAP logs: complete or not at all, and byte-for-byte reproducible.

:class:`LogWriter` wraps ``mcap.writer.Writer`` with the settings every toolkit log uses: profile
``ros2``, ``ros2msg`` schemas from :func:`~toolkit.mcapio.msgdefs.load_msgdef`, CDR messages,
zstd chunks of about 1 MiB, every index, summary and data CRCs. It writes ``<path>.partial`` and
renames it to ``<path>`` only when closed without error; on error the partial file is deleted,
so a half-written log never exists under its final name.

Nothing written depends on the wall clock or the environment beyond the installed versions of
the toolkit, ``mcap`` and ``zstandard``: ``mcap``'s writer records no times of its own, channel
and schema ids follow registration order, message sequence numbers count per channel from 0, and
attachments take explicit times (default 0). Identical input gives identical bytes.

Readers expect chunks roughly in log-time order, so batches of several topics should be merged
before writing: :func:`merge_by_time` does that, and :meth:`LogWriter.write_interleaved` writes
its output.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import CompressionType, IndexType, Writer

import toolkit
from toolkit.errors import SchemaError
from toolkit.mcapio.closing import Closing
from toolkit.mcapio.msgdefs import full_type_name, load_msgdef

#: Target uncompressed size of a chunk.
CHUNK_SIZE = 1024 * 1024

#: The ``library`` string of the MCAP header.
LIBRARY = f"terrain-toolkit/{toolkit.__version__}"


class Record(NamedTuple):
    """One message to write: topic, log time and publish time (ns) and its CDR payload."""

    topic: str
    log_time_ns: int
    payload: bytes
    publish_time_ns: int


class Batch(NamedTuple):
    """Messages of one topic: log times (ns), payloads and optional publish times (ns)."""

    topic: str
    log_time_ns: np.ndarray
    payloads: Sequence[bytes]
    publish_time_ns: np.ndarray | None = None


def _times(name: str, values: np.ndarray | Sequence[int], count: int) -> np.ndarray:
    """Validate a vector of nanosecond times: integers, non-negative, ``count`` of them."""
    arr = np.asarray(values)
    if arr.ndim != 1 or arr.shape[0] != count:
        raise ValueError(f"{name} must hold one time per payload ({count}), got shape {arr.shape}")
    if arr.size and arr.dtype.kind not in "iu":
        raise ValueError(f"{name} must hold integer nanoseconds, got {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() > np.iinfo(np.int64).max):
        raise ValueError(f"{name} must be non-negative int64 nanoseconds")
    return arr.astype(np.int64, copy=False)


def merge_by_time(batches: Iterable[Batch | tuple[object, ...]]) -> Iterator[Record]:
    """Merge per-topic batches into one stream in global log-time order.

    Each batch is ``(topic, log_time_ns, payloads[, publish_time_ns])``; publish times default
    to log times. The merge is stable: equal log times keep batch order, then order within the
    batch. Batches need not be sorted themselves.
    """
    topics: list[str] = []
    payloads: list[Sequence[bytes]] = []
    logs: list[np.ndarray] = []
    pubs: list[np.ndarray] = []
    for raw in batches:
        batch = Batch(*raw)
        count = len(batch.payloads)
        log = _times(f"{batch.topic}: log_time_ns", batch.log_time_ns, count)
        pub = (
            log
            if batch.publish_time_ns is None
            else _times(f"{batch.topic}: publish_time_ns", batch.publish_time_ns, count)
        )
        topics.append(batch.topic)
        payloads.append(batch.payloads)
        logs.append(log)
        pubs.append(pub)
    if not topics:
        return
    all_log = np.concatenate(logs)
    all_pub = np.concatenate(pubs)
    which = np.repeat(np.arange(len(topics)), [len(x) for x in logs])
    starts = np.cumsum([0] + [len(x) for x in logs])
    order = np.argsort(all_log, kind="stable")
    for k in order.tolist():
        b = int(which[k])
        yield Record(topics[b], int(all_log[k]), payloads[b][k - int(starts[b])], int(all_pub[k]))


class LogWriter(Closing):
    """An MCAP log being written; use as a context manager.

    >>> with LogWriter(path) as log:                      # doctest: +SKIP
    ...     log.register("/imu", "sensor_msgs/msg/Imu")
    ...     log.write_batch("/imu", times, payloads)

    The file appears at ``path`` only when the ``with`` block (or :meth:`close`) finishes
    without error; :meth:`abort` or any exception removes the partial file.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = CHUNK_SIZE,
        compression: CompressionType = CompressionType.ZSTD,
        library: str = LIBRARY,
    ) -> None:
        self.path = Path(path)
        self.partial_path = self.path.with_name(self.path.name + ".partial")
        self._stream: IO[bytes] | None = open(self.partial_path, "wb")  # noqa: SIM115
        try:
            self._writer = Writer(
                self._stream,
                chunk_size=chunk_size,
                compression=compression,
                index_types=IndexType.ALL,
                repeat_channels=True,
                repeat_schemas=True,
                use_chunking=True,
                use_statistics=True,
                use_summary_offsets=True,
                enable_crcs=True,
                enable_data_crcs=True,
            )
            self._writer.start(profile=Profile.ROS2, library=library)
        except BaseException:
            self.abort()
            raise
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._sequence: dict[int, int] = {}
        self._closed = False

    # -- registration -----------------------------------------------------------------------

    def register(self, topic: str, type_name: str) -> None:
        """Declare a topic and its ROS 2 message type (e.g. ``sensor_msgs/msg/Imu``).

        Registering a topic again with the same type does nothing; with another type it is a
        :class:`SchemaError`.
        """
        self._check_open()
        name = full_type_name(type_name)
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != name:
                raise SchemaError(f"topic {topic} is already registered as {known[1]}, not {name}")
            return
        schema_id = self._schemas.get(name)
        if schema_id is None:
            text = load_msgdef(name)
            schema_id = self._writer.register_schema(
                name=name, encoding=SchemaEncoding.ROS2, data=text.encode("utf-8")
            )
            self._schemas[name] = schema_id
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MessageEncoding.CDR, schema_id=schema_id, metadata={}
        )
        self._channels[topic] = (channel_id, name)
        self._sequence[channel_id] = 0

    # -- messages ---------------------------------------------------------------------------

    def _channel(self, topic: str) -> int:
        known = self._channels.get(topic)
        if known is None:
            raise SchemaError(f"topic {topic} is not registered (call register() first)")
        return known[0]

    def write(
        self, topic: str, log_time_ns: int, payload: bytes, publish_time_ns: int | None = None
    ) -> None:
        """Write one message."""
        self._check_open()
        channel_id = self._channel(topic)
        if log_time_ns < 0 or (publish_time_ns is not None and publish_time_ns < 0):
            raise ValueError(f"{topic}: times must be non-negative nanoseconds")
        seq = self._sequence[channel_id]
        self._writer.add_message(
            channel_id=channel_id,
            log_time=int(log_time_ns),
            data=payload,
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=seq,
        )
        self._sequence[channel_id] = seq + 1

    def write_batch(
        self,
        topic: str,
        log_time_ns: np.ndarray | Sequence[int],
        payloads: Sequence[bytes],
        publish_time_ns: np.ndarray | Sequence[int] | None = None,
    ) -> None:
        """Write a topic's messages in the order given (publish times default to log times).

        Messages of several topics should be merged by log time first (:func:`merge_by_time`
        and :meth:`write_interleaved`) so that chunks stay time-ordered.
        """
        self._check_open()
        channel_id = self._channel(topic)
        count = len(payloads)
        log = _times(f"{topic}: log_time_ns", np.asarray(log_time_ns), count)
        pub = (
            log
            if publish_time_ns is None
            else _times(f"{topic}: publish_time_ns", np.asarray(publish_time_ns), count)
        )
        seq = self._sequence[channel_id]
        add = self._writer.add_message
        for i, (t_log, t_pub) in enumerate(zip(log.tolist(), pub.tolist(), strict=True)):
            add(
                channel_id=channel_id,
                log_time=t_log,
                data=payloads[i],
                publish_time=t_pub,
                sequence=seq + i,
            )
        self._sequence[channel_id] = seq + count

    def write_interleaved(self, records: Iterable[Record | tuple[str, int, bytes, int]]) -> None:
        """Write records ``(topic, log_time_ns, payload, publish_time_ns)`` in the order given,
        typically the output of :func:`merge_by_time`."""
        self._check_open()
        for topic, log_time, payload, publish_time in records:
            self.write(topic, log_time, payload, publish_time)

    # -- metadata and attachments -----------------------------------------------------------

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Add a named metadata record (string keys and values only)."""
        self._check_open()
        bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise ValueError(f"metadata {name!r}: keys and values must be str (bad keys: {bad})")
        self._writer.add_metadata(name=name, data=dict(data))

    def add_attachment(
        self,
        name: str,
        data: bytes,
        media_type: str = "application/octet-stream",
        *,
        log_time_ns: int = 0,
        create_time_ns: int = 0,
    ) -> None:
        """Add a file attachment; its times are explicit so the output stays reproducible."""
        self._check_open()
        self._writer.add_attachment(
            create_time=int(create_time_ns),
            log_time=int(log_time_ns),
            name=name,
            media_type=media_type,
            data=bytes(data),
        )

    # -- finishing --------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed or self._stream is None:
            raise ValueError(f"{self.path}: the log writer is already closed")

    def close(self) -> None:
        """Finish the file (summary, indexes, footer) and move it to its final name."""
        if self._closed:
            return
        stream = self._stream
        if stream is None:
            return
        try:
            self._writer.finish()
            stream.flush()
            os.fsync(stream.fileno())
            stream.close()
            os.replace(self.partial_path, self.path)
        except BaseException:
            self.abort()
            raise
        self._stream = None
        self._closed = True

    def abort(self) -> None:
        """Give up: close and delete the partial file; nothing appears at ``path``."""
        stream, self._stream = self._stream, None
        self._closed = True
        if stream is not None:
            with contextlib.suppress(OSError):
                stream.close()
        with contextlib.suppress(FileNotFoundError):
            self.partial_path.unlink()


__all__ = ["CHUNK_SIZE", "LIBRARY", "Batch", "LogWriter", "Record", "merge_by_time"]
