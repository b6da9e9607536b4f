"""The walk over the data section (toolkit.mcapio.walk): segments, truncation, chunks
without a usable index, undefined channels."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer

from toolkit.errors import LogReadError
from toolkit.mcapio import walk as walk_module
from toolkit.mcapio.reader import LogReader

from . import damage
from .logs import TOPICS, accounted, check_one_bad_chunk, counts, make_log, make_plain_log, read_all


def test_unchunked_log_with_summary_and_small_segments(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = make_plain_log(tmp_path / "flat.mcap", chunked=False, summary=True)
    monkeypatch.setattr(walk_module, "SEGMENT_BYTES", 2000)
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
        assert counts(got) == {t: n for t, n in expected.items() if n}, cut
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
        assert sum(counts(got).values()) > sum(before.values())  # some of the cut chunk
        assert {"truncated", "no_summary"} == report.reasons()
        assert report.unknown_lost_bytes["truncated"] == cut - ci.chunk_start_offset


def test_bad_chunk_without_summary_counts_from_following_message_indexes(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "bad.mcap", damage.crc_field(ci), 0x01)
    got, report = read_all(damage.cut_summary(bad, tmp_path / "cut.mcap"))
    assert not report.used_index and "no_summary" in report.reasons()
    check_one_bad_chunk(report, got, path, 2, {"chunk_crc"})


def test_bad_chunk_without_any_index_counts_its_bytes(tmp_path: Path) -> None:
    path = make_plain_log(tmp_path / "plain.mcap", summary=False, indexes=False)
    reference = damage.reference(path)
    start, _, length = [r for r in damage.top_level(path) if r[1] == 0x06][2]  # third chunk
    bad = damage.flip(path, tmp_path / "bad.mcap", start + 9 + 24, 0x01)  # its CRC field
    got, report = read_all(bad)
    assert [d.reason for d in report.damage] == ["no_summary", "chunk_crc"]
    assert report.lost == {}
    assert report.unknown_lost_bytes == {"chunk_crc": 9 + length}
    missing = sum(counts(reference).values()) - sum(counts(got).values())
    assert missing == damage.messages_in_chunk_at(path, start) > 0


def test_unreadable_chunk_record_resumes_at_the_next_indexed_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "len.mcap", ci.chunk_start_offset + 8, 0x40)  # length
    got, report = read_all(bad)
    assert [d.reason for d in report.damage] == ["bad_record"]
    assert report.lost == {t: {"bad_record": n} for t, n in damage.chunk_topics(path, ci).items()}
    accounted(report, damage.reference(path))


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
