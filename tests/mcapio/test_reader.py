"""LogReader: the same messages as mcap's own reader, and every loss accounted for on damage."""

from __future__ import annotations

import io
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.writer import CompressionType, IndexType, Writer

from toolkit.errors import LogReadError
from toolkit.mcapio import reader as reader_module
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


def _counts(messages: damage.Messages) -> dict[str, int]:
    return {topic: len(m) for topic, m in messages.items()}


def _accounted(report: ReadReport, reference: damage.Messages) -> None:
    """Per topic: messages read + messages known lost = messages in the intact file."""
    for topic, messages in reference.items():
        lost = sum(report.lost.get(topic, {}).values())
        assert report.messages_read.get(topic, 0) + lost == len(messages), topic


# --------------------------------------------------------------------------------------------
# Intact files
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
def test_fast_path_gives_what_mcap_gives(tmp_path: Path, compression: CompressionType) -> None:
    path = make_log(tmp_path / "log.mcap", compression=compression)
    assert len(damage.chunk_indexes(path)) >= 5
    got, report = read_all(path)
    assert got == damage.reference(path)
    assert report.used_index and report.damage == [] and report.lost == {}
    assert report.unknown_lost_bytes == {}
    assert report.messages_read["/silent"] == 0
    with LogReader(path) as log:
        channels = log.channels()
        assert log.profile == "ros2"
    assert list(channels) == [*TOPICS, "/silent"]
    imu = channels["/imu"]
    assert (imu.message_encoding, imu.schema_name, imu.schema_encoding) == (
        "cdr",
        "sensor_msgs/msg/Imu",
        "ros2msg",
    )
    assert imu.schema_data == load_msgdef("sensor_msgs/msg/Imu").encode()


@pytest.mark.parametrize("chunked", [True, False])
@pytest.mark.parametrize("indexes", [True, False])
def test_logs_without_summary_or_repeated_channels(
    tmp_path: Path, chunked: bool, indexes: bool
) -> None:
    """Without indexes mcap's Writer writes no summary at all; with them, a summary of chunk
    indexes only (channels then come from the records inside the chunks)."""
    path = make_plain_log(tmp_path / "plain.mcap", chunked=chunked, summary=False, indexes=indexes)
    got, report = read_all(path)
    assert got == damage.reference(path)
    fast = chunked and indexes
    assert report.used_index == fast
    assert report.reasons() == (set() if fast else {"no_summary"})
    assert report.lost == {} and report.unknown_lost_bytes == {}
    with LogReader(path) as log:
        channels = log.channels()  # a pre-pass: Channel records sit in the data or the chunks
    assert set(channels) == set(TOPICS)
    assert channels["/wheels"].schema_name == "terrain_msgs/msg/WheelSpeeds"


def test_unchunked_log_with_summary_and_small_segments(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = make_plain_log(tmp_path / "flat.mcap", chunked=False, summary=True)
    monkeypatch.setattr(reader_module, "SEGMENT_BYTES", 2000)
    with LogReader(path) as log:
        batches = list(log.batches())
        report = log.report
    assert len(batches) > 10  # delivered in bounded segments, not in one piece
    assert report.reasons() == set() and not report.used_index
    got: damage.Messages = {}
    for b in batches:
        got.setdefault(b.channel.topic, []).extend(
            zip(b.log_time_ns.tolist(), b.publish_time_ns.tolist(), b.payloads, strict=True)
        )
    assert got == damage.reference(path)


def test_cut_summary_loses_nothing(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    cut = damage.cut_summary(path, tmp_path / "cut.mcap")
    got, report = read_all(cut)
    assert got == damage.reference(path)
    assert report.reasons() == {"no_summary"} and not report.used_index


def test_topics_filter(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    reference = damage.reference(path)
    for source in (path, damage.cut_summary(path, tmp_path / "cut.mcap")):
        got, report = read_all(source, {"/wheels", "/heading", "/nowhere"})
        assert got == {t: reference[t] for t in ("/wheels", "/heading")}
        assert set(report.messages_read) == {"/wheels", "/heading"}
        with LogReader(source, {"/wheels"}) as log:
            assert set(log.channels()) == {*TOPICS, "/silent"}  # channels() ignores the filter


def test_batches_stream_one_chunk_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = make_log(tmp_path / "log.mcap", n=10000)
    size = path.stat().st_size
    read = Counter[str]()

    class Counting(io.FileIO):
        def read(self, n: int = -1, /) -> bytes:
            data = super().read(n)
            read["bytes"] += len(data)
            return data

    monkeypatch.setattr(reader_module, "_open_file", lambda p: Counting(p, "rb"))
    with LogReader(path) as log:
        batches = log.batches()
        first = next(batches)
        assert first.payloads
        assert read["bytes"] < size / 10  # summary + first chunk, not the whole file
        rest = sum(len(b.payloads) for b in batches)
    assert read["bytes"] < 1.5 * size  # one pass, not several
    assert len(first.payloads) + rest == sum(_counts(damage.reference(path)).values())


# --------------------------------------------------------------------------------------------
# Truncation
# --------------------------------------------------------------------------------------------


def test_truncated_uncompressed_log_keeps_every_message_before_the_cut(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap", compression=CompressionType.NONE)
    spans = damage.message_spans(path)
    chunks = damage.chunk_indexes(path)
    end = damage.data_end(path)
    header_end = damage.top_level(path)[0][2] + 8 + 9
    cuts = [
        30,  # inside the Header
        chunks[0].chunk_start_offset + 4,  # inside a record header
        chunks[0].chunk_start_offset + 30,  # inside a chunk's fixed fields
        (chunks[1].chunk_start_offset + chunks[2].chunk_start_offset) // 2,  # inside a chunk
        chunks[2].chunk_start_offset + chunks[2].chunk_length + 10,  # inside a message index
        chunks[3].chunk_start_offset,  # at a record boundary
        end - 3,  # inside Data End
    ]
    for cut in cuts:
        short = damage.truncate(path, tmp_path / f"cut{cut}.mcap", cut)
        if cut < header_end:
            with pytest.raises(LogReadError, match=f"cut{cut}.mcap"):
                LogReader(short)
            continue
        got, report = read_all(short)
        expected: Counter[str] = Counter(t for t, _, _, stop in spans if stop <= cut)
        assert _counts(got) == {t: n for t, n in expected.items() if n}, cut
        for topic, messages in got.items():  # a prefix of each topic, intact
            assert messages == damage.reference(path)[topic][: len(messages)]
        assert "truncated" in report.reasons(), cut
        assert report.reasons() <= {"truncated", "no_summary"}
        at = next(d.offset for d in report.damage if d.reason == "truncated")
        assert report.unknown_lost_bytes["truncated"] == cut - at


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4])
def test_truncated_compressed_log(tmp_path: Path, compression: CompressionType) -> None:
    """Chunks before the cut are whole; the cut chunk gives the messages of its complete
    compression blocks (zstd: 128 KiB, lz4: 64 KiB of records), an intact prefix."""
    path = make_log(tmp_path / "log.mcap", compression=compression, n=5000, chunk_size=256 * 1024)
    reference = damage.reference(path)
    chunks = damage.chunk_indexes(path)
    assert len(chunks) >= 4
    for k in (1, 3):
        ci = chunks[k]
        cut = ci.chunk_start_offset + ci.chunk_length * 3 // 4
        got, report = read_all(damage.truncate(path, tmp_path / f"cut{k}.mcap", cut))
        before = Counter[str]()
        for previous in chunks[:k]:
            before.update(damage.chunk_topics(path, previous))
        inside = damage.chunk_topics(path, ci)
        for topic in TOPICS:
            n = len(got.get(topic, []))
            assert before[topic] <= n <= before[topic] + inside[topic], (k, topic)
            assert got.get(topic, []) == reference[topic][:n]
        assert sum(_counts(got).values()) > sum(before.values())  # some of the cut chunk
        assert {"truncated", "no_summary"} == report.reasons()
        assert report.unknown_lost_bytes["truncated"] == cut - ci.chunk_start_offset


# --------------------------------------------------------------------------------------------
# Damaged chunks
# --------------------------------------------------------------------------------------------


def _check_one_bad_chunk(
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
    _accounted(report, reference)
    for topic in TOPICS:  # what was delivered is the reference minus that chunk's messages
        kept = Counter(got.get(topic, []))
        assert not kept - Counter(reference[topic])
    assert sum(_counts(got).values()) == sum(_counts(reference).values()) - sum(lost_here.values())
    return reason


def test_bad_crc_field_skips_the_chunk_and_counts_its_messages(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "crc.mcap", damage.crc_field(ci), 0x01)
    got, report = read_all(bad)
    assert _check_one_bad_chunk(report, got, path, 2, {"chunk_crc"}) == "chunk_crc"
    assert report.used_index


def test_broken_compression_frame_skips_the_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[1]
    bad = damage.flip(path, tmp_path / "magic.mcap", damage.compressed_start(ci))  # zstd magic
    got, report = read_all(bad)
    assert _check_one_bad_chunk(report, got, path, 1, {"chunk_decompress"}) == "chunk_decompress"


def test_unknown_compression_skips_the_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[4]
    at = damage.compressed_start(ci) - 8 - 1  # last letter of "zstd"
    got, report = read_all(damage.flip(path, tmp_path / "zstx.mcap", at, ord("d") ^ ord("x")))
    _check_one_bad_chunk(report, got, path, 4, {"unsupported_compression"})


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
@pytest.mark.parametrize("where", [0.3, 0.6, 0.9])
def test_flipped_byte_in_compressed_data(
    tmp_path: Path, compression: CompressionType, where: float
) -> None:
    path = make_log(tmp_path / "log.mcap", compression=compression)
    ci = damage.chunk_indexes(path)[3]
    at = damage.compressed_start(ci) + int(ci.compressed_size * where)
    got, report = read_all(damage.flip(path, tmp_path / "flip.mcap", at, 0x10))
    _check_one_bad_chunk(report, got, path, 3, {"chunk_crc", "chunk_decompress"})


def test_bad_chunk_without_summary_counts_from_following_message_indexes(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "bad.mcap", damage.crc_field(ci), 0x01)
    got, report = read_all(damage.cut_summary(bad, tmp_path / "cut.mcap"))
    assert not report.used_index and "no_summary" in report.reasons()
    _check_one_bad_chunk(report, got, path, 2, {"chunk_crc"})


def test_bad_chunk_without_any_index_counts_its_bytes(tmp_path: Path) -> None:
    path = make_plain_log(tmp_path / "plain.mcap", summary=False, indexes=False)
    reference = damage.reference(path)
    start, _, length = [r for r in damage.top_level(path) if r[1] == 0x06][2]  # third chunk
    bad = damage.flip(path, tmp_path / "bad.mcap", start + 9 + 24, 0x01)  # its CRC field
    got, report = read_all(bad)
    assert [d.reason for d in report.damage] == ["no_summary", "chunk_crc"]
    assert report.lost == {}
    assert report.unknown_lost_bytes == {"chunk_crc": 9 + length}
    missing = sum(_counts(reference).values()) - sum(_counts(got).values())
    assert missing == damage.messages_in_chunk_at(path, start) > 0


def test_unreadable_chunk_record_resumes_at_the_next_indexed_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "len.mcap", ci.chunk_start_offset + 8, 0x40)  # length
    got, report = read_all(bad)
    assert [d.reason for d in report.damage] == ["bad_record"]
    assert report.lost == {t: {"bad_record": n} for t, n in damage.chunk_topics(path, ci).items()}
    _accounted(report, damage.reference(path))


def test_wrong_message_index_falls_back_to_parsing_the_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[1]
    ids = damage.channel_ids(path)
    assert ids["/heading"] == max(ids[t] for t in TOPICS)  # indexes of the others pass first
    index_at = ci.message_index_offsets[ids["/heading"]]
    entry = index_at + 9 + 2 + 4  # the first (log_time, offset) pair of /heading's index
    bad = damage.flip(path, tmp_path / "index.mcap", entry + 8, 0x02)  # its offset
    got, report = read_all(bad)
    assert got == damage.reference(path)
    assert report.reasons() == {"bad_index"} and report.lost == {}


def test_summary_failing_its_crc_is_ignored(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    bad = damage.flip(path, tmp_path / "summary.mcap", damage.data_end(path) + 20)
    got, report = read_all(bad)
    assert got == damage.reference(path)
    assert report.reasons() == {"bad_index"} and not report.used_index


def test_messages_on_an_undefined_channel_are_counted(tmp_path: Path) -> None:
    path = tmp_path / "orphan.mcap"
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start(profile="ros2", library="test")
        known = w.register_channel("/known", "cdr", 0)
        for i in range(3):
            w.add_message(known, log_time=i, data=b"k", publish_time=i)
            w.add_message(99, log_time=i, data=b"?", publish_time=i)
        w.finish()
    got, report = read_all(path)
    assert got == {"/known": [(0, 0, b"k"), (1, 1, b"k"), (2, 2, b"k")]}
    assert report.lost == {"<channel 99>": {"unknown_channel": 3}}
    assert "unknown_channel" in report.reasons()


# --------------------------------------------------------------------------------------------
# Not a log
# --------------------------------------------------------------------------------------------


def test_files_that_are_not_mcap_raise_log_read_error(tmp_path: Path) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("hello, not a log\n")
    with pytest.raises(LogReadError, match="notes.mcap: not an MCAP file"):
        LogReader(text)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(LogReadError, match="empty.mcap: not an MCAP file"):
        LogReader(empty)
    with pytest.raises(LogReadError, match="missing.mcap: no such file"):
        LogReader(tmp_path / "missing.mcap")
    with pytest.raises(LogReadError, match="not a regular file"):
        LogReader(tmp_path)
    magic = tmp_path / "magic.mcap"
    magic.write_bytes(reader_module.MAGIC)
    with pytest.raises(LogReadError, match="magic.mcap: MCAP file without a Header"):
        LogReader(magic)


def test_header_only_file_reads_as_empty_and_truncated(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    header_end = 8 + 9 + int.from_bytes(path.read_bytes()[9:17], "little")
    got, report = read_all(damage.truncate(path, tmp_path / "header.mcap", header_end))
    assert got == {}
    assert report.reasons() == {"no_summary", "truncated"}
    assert report.messages_read == {}


# --------------------------------------------------------------------------------------------
# Conformance corpus
# --------------------------------------------------------------------------------------------


def _corpus_messages(path: Path) -> list[tuple[int, int, bytes]]:
    records = json.loads(path.with_suffix(".json").read_text())["records"]
    fields: list[dict[str, Any]] = [dict(r["fields"]) for r in records if r["type"] == "Message"]
    return sorted(
        (int(f["log_time"]), int(f["publish_time"]), bytes(int(b) for b in f["data"]))
        for f in fields
    )


def test_conformance_corpus(conformance_files: list[Path]) -> None:
    outcomes: Counter[str] = Counter()
    for path in conformance_files:
        try:
            with LogReader(path) as log:
                channels = log.channels()
                got = sorted(
                    message
                    for b in log.batches()
                    for message in zip(
                        b.log_time_ns.tolist(), b.publish_time_ns.tolist(), b.payloads, strict=True
                    )
                )
                report = log.report
        except LogReadError:
            outcomes["refused"] += 1
            continue
        outcomes["read"] += 1
        assert got == _corpus_messages(path), path.name
        assert sum(report.messages_read.values()) == len(got), path.name
        assert report.lost == {} and report.unknown_lost_bytes == {}, path.name
        records = json.loads(path.with_suffix(".json").read_text())["records"]
        topics = {dict(r["fields"])["topic"] for r in records if r["type"] == "Channel"}
        assert set(channels) == topics, path.name
    assert outcomes["read"] == len(conformance_files), outcomes
