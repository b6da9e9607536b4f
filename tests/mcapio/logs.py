"""MCAP logs the reader tests write, read back, and check the account of."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, IndexType, Writer

from toolkit.mcapio.cdr_encode import encode_batch
from toolkit.mcapio.msgdefs import load_msgdef
from toolkit.mcapio.reader import LogReader, ReadReport
from toolkit.mcapio.writer import LogWriter, merge_by_time

from . import damage

T0 = 1_700_000_000_000_000_000
TOPICS = ("/imu", "/wheels", "/heading")


def _stamp(t: np.ndarray) -> dict[str, np.ndarray]:
    return {"header.stamp.sec": t // 10**9, "header.stamp.nanosec": t % 10**9}


def _columns(n: int, seed: int) -> dict[str, tuple[np.ndarray, list[bytes]]]:
    rng = np.random.default_rng(seed)
    t_imu = T0 + np.arange(n, dtype=np.int64) * 5_000_000
    t_wheels = T0 + np.arange(n // 4, dtype=np.int64) * 20_000_000 + 1
    t_heading = T0 + np.arange(n // 10, dtype=np.int64) * 50_000_000 + 2
    frames = np.array(["imu", "imu_link_long_name", ""])[rng.integers(0, 3, n)]
    return {
        "/imu": (
            t_imu,
            encode_batch(
                "sensor_msgs/msg/Imu",
                {
                    **_stamp(t_imu),
                    "header.frame_id": frames,
                    "linear_acceleration.z": rng.normal(9.8, 1.0, n),
                },
            ),
        ),
        "/wheels": (
            t_wheels,
            encode_batch("terrain_msgs/msg/WheelSpeeds", {"front_left": rng.random(len(t_wheels))}),
        ),
        "/heading": (
            t_heading,
            encode_batch(
                "terrain_msgs/msg/GpsHeading",
                {**_stamp(t_heading), "yaw": rng.random(len(t_heading))},
            ),
        ),
    }


def make_log(
    path: Path,
    *,
    compression: CompressionType = CompressionType.ZSTD,
    n: int = 400,
    chunk_size: int = 16 * 1024,
    seed: int = 1,
) -> Path:
    """About ``1.35 n`` messages on three topics (one silent topic registered), several chunks;
    publish times differ from log times."""
    cols = _columns(n, seed)
    with LogWriter(path, compression=compression, chunk_size=chunk_size) as log:
        log.register("/imu", "sensor_msgs/msg/Imu")
        log.register("/wheels", "terrain_msgs/msg/WheelSpeeds")
        log.register("/heading", "terrain_msgs/msg/GpsHeading")
        log.register("/silent", "terrain_msgs/msg/GpsHeading")
        log.add_attachment("notes.txt", b"x" * 5000)
        log.write_interleaved(
            merge_by_time((topic, t, payloads, t - 7) for topic, (t, payloads) in cols.items())
        )
    return path


def make_plain_log(
    path: Path, *, chunked: bool = True, summary: bool = True, indexes: bool = True, n: int = 300
) -> Path:
    """The same kind of log written with mcap's Writer, optionally without chunking, summary
    or indexes (then channel and schema records sit only in the data section, or in chunks)."""
    cols = _columns(n, 2)
    types = {
        "/imu": "sensor_msgs/msg/Imu",
        "/wheels": "terrain_msgs/msg/WheelSpeeds",
        "/heading": "terrain_msgs/msg/GpsHeading",
    }
    with open(path, "wb") as f:
        w = Writer(
            f,
            chunk_size=8 * 1024,
            compression=CompressionType.ZSTD,
            index_types=IndexType.ALL if indexes else IndexType.NONE,
            repeat_channels=summary,
            repeat_schemas=summary,
            use_chunking=chunked,
            use_statistics=summary,
            use_summary_offsets=summary,
        )
        w.start(profile="ros2", library="test")
        ids = {}
        for topic, type_name in types.items():
            sid = w.register_schema(type_name, "ros2msg", load_msgdef(type_name).encode())
            ids[topic] = w.register_channel(topic, "cdr", sid)
        for topic, t, payload, pub in merge_by_time(
            (topic, t, payloads, t + 3) for topic, (t, payloads) in cols.items()
        ):
            w.add_message(ids[topic], log_time=t, data=payload, publish_time=pub)
        w.finish()
    return path


def read_all(path: Path, topics: set[str] | None = None) -> tuple[damage.Messages, ReadReport]:
    got: damage.Messages = {}
    with LogReader(path, topics) as log:
        for batch in log.batches():
            n = len(batch.payloads)
            assert n > 0
            assert batch.log_time_ns.dtype == np.int64 and batch.log_time_ns.shape == (n,)
            assert batch.publish_time_ns.dtype == np.int64 and batch.publish_time_ns.shape == (n,)
            assert all(type(p) is bytes for p in batch.payloads)
            got.setdefault(batch.channel.topic, []).extend(
                zip(
                    batch.log_time_ns.tolist(),
                    batch.publish_time_ns.tolist(),
                    batch.payloads,
                    strict=True,
                )
            )
        report = log.report
    for topic, messages in got.items():
        assert report.messages_read[topic] == len(messages)
    return got, report


def counts(messages: damage.Messages) -> dict[str, int]:
    return {topic: len(m) for topic, m in messages.items()}


def accounted(report: ReadReport, reference: damage.Messages) -> None:
    """Per topic: messages read + messages known lost = messages in the intact file."""
    for topic, messages in reference.items():
        lost = sum(report.lost.get(topic, {}).values())
        assert report.messages_read.get(topic, 0) + lost == len(messages), topic


def check_one_bad_chunk(
    report: ReadReport, got: damage.Messages, path: Path, k: int, reasons: set[str]
) -> str:
    """Chunk ``k`` lost, counted from the index, every other message delivered intact."""
    reference = damage.reference(path)
    chunks = damage.chunk_indexes(path)
    lost_here = damage.chunk_topics(path, chunks[k])
    bad = [
        d
        for d in report.damage
        if d.reason in {"chunk_crc", "chunk_decompress", "unsupported_compression"}
    ]
    assert len(bad) == 1 and bad[0].reason in reasons
    assert bad[0].offset == chunks[k].chunk_start_offset
    reason = bad[0].reason
    assert report.lost == {t: {reason: n} for t, n in lost_here.items()}
    assert report.unknown_lost_bytes == {}
    accounted(report, reference)
    for topic in TOPICS:  # what was delivered is the reference minus that chunk's messages
        kept = Counter(got.get(topic, []))
        assert not kept - Counter(reference[topic])
    assert sum(counts(got).values()) == sum(counts(reference).values()) - sum(lost_here.values())
    return reason
