"""LogReader: the same messages as mcap's own reader, and every loss accounted for on damage."""

from __future__ import annotations

import io
import json
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import CompressionType

from toolkit.errors import LogReadError
from toolkit.mcapio import summary as summary_module
from toolkit.mcapio.msgdefs import load_msgdef
from toolkit.mcapio.reader import LogReader

from . import damage
from .logs import TOPICS, counts, make_log, make_plain_log, read_all


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

    monkeypatch.setattr(summary_module, "_open_file", lambda p: Counting(p, "rb"))
    with LogReader(path) as log:
        batches = log.batches()
        first = next(batches)
        assert first.payloads
        assert read["bytes"] < size / 10  # summary + first chunk, not the whole file
        rest = sum(len(b.payloads) for b in batches)
    assert read["bytes"] < 1.5 * size  # one pass, not several
    assert len(first.payloads) + rest == sum(counts(damage.reference(path)).values())


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
