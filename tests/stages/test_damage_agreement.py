"""One account of damage: the reader, ``terrain info`` and ingest's manifest agree.

Parametrised over the damage kinds the reader names (as the mcap project parametrises its
tests over readers): for each, a damaged copy of a small ingestible log is read three ways,
and the damage list, the messages lost per topic and the one-line summary must be the same.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import ChunkIndex

from toolkit.mcapio.info import scan_log
from toolkit.mcapio.reader import LogReader, ReadReport
from toolkit.stages.ingest import ingest_log
from toolkit.workspace import Workspace

from .test_ingest import basic_topics, detail, make_config, write_log

#: Damage reasons of the reader (info's problem kinds for damage).
DAMAGE_REASONS = {
    "no_summary",
    "bad_index",
    "truncated",
    "chunk_crc",
    "chunk_decompress",
    "unsupported_compression",
    "bad_record",
    "unknown_channel",
    "chunk_size",
}


def _chunks(path: Path) -> list[ChunkIndex]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _summary_start(data: bytes) -> int:
    return int(struct.unpack_from("<Q", data, len(data) - 8 - 20)[0])


def _compressed_start(ci: ChunkIndex) -> int:
    return ci.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len(ci.compression.encode()) + 8


def _flip(data: bytes, at: int, mask: int) -> bytes:
    out = bytearray(data)
    out[at] ^= mask
    return bytes(out)


Damager = Callable[[bytes, list[ChunkIndex]], bytes]

#: Damage kind -> (how to damage the intact bytes, the reason the reader must give).
DAMAGES: dict[str, tuple[Damager, str]] = {
    "truncated": (lambda d, c: d[: int(len(d) * 0.6)], "truncated"),
    "no_summary": (lambda d, c: d[: _summary_start(d)], "no_summary"),
    "summary_crc": (lambda d, c: _flip(d, _summary_start(d) + 20, 0xFF), "bad_index"),
    "chunk_crc": (lambda d, c: _flip(d, c[2].chunk_start_offset + 9 + 24, 0x01), "chunk_crc"),
    "zstd_frame": (lambda d, c: _flip(d, _compressed_start(c[1]), 0xFF), "chunk_decompress"),
    "compression_name": (
        lambda d, c: _flip(d, _compressed_start(c[3]) - 9, ord("d") ^ ord("x")),
        "unsupported_compression",
    ),
    "chunk_length": (lambda d, c: _flip(d, c[2].chunk_start_offset + 8, 0x40), "bad_record"),
    # The header's uncompressed_size (u64 after the message times) off by 64 bytes: the data
    # decompresses and passes its CRC, so the chunk is read whole.
    "chunk_size_field": (
        lambda d, c: _flip(d, c[2].chunk_start_offset + 9 + 16, 0x40),
        "chunk_size",
    ),
}


def _read(path: Path) -> ReadReport:
    with LogReader(path) as reader:
        for _ in reader.batches():
            pass
        return reader.report


@pytest.mark.parametrize("kind", sorted(DAMAGES))
def test_reader_info_and_ingest_report_the_same_damage(tmp_path: Path, kind: str) -> None:
    intact = write_log(tmp_path / "intact.mcap", basic_topics(), chunk_size=4 * 1024)
    chunks = _chunks(intact)
    assert len(chunks) >= 5
    damager, reason = DAMAGES[kind]
    path = tmp_path / f"{kind}.mcap"
    path.write_bytes(damager(intact.read_bytes(), chunks))

    report = _read(path)
    assert reason in report.reasons()
    damage = [(d.reason, d.offset, d.detail) for d in report.damage]

    info = scan_log(path, full=True)
    info_damage = [(p.kind, p.message) for p in info.problems if p.kind in DAMAGE_REASONS]
    assert info_damage == [(r, m) for r, _, m in damage]
    assert {t.topic: t.messages_lost for t in info.topics if t.messages_lost} == {
        topic: sum(by_reason.values()) for topic, by_reason in report.lost.items()
    }
    assert info.damage_summary == report.summary_line()

    ws = Workspace(tmp_path / "ws")
    result = ingest_log(path, ws, make_config())
    manifest = detail(ws, result)
    assert [(d["reason"], d["offset"], d["detail"]) for d in manifest["damage"]] == damage
    assert {t: a["lost"] for t, a in manifest["topics"].items() if a["lost"]} == report.lost
    if report.summary_line() is None:
        assert not any("damaged log" in w for w in result.warnings)
    else:
        assert report.summary_line() in result.warnings
        assert info.damage_summary in result.warnings


def test_misstated_chunk_size_loses_nothing(tmp_path: Path) -> None:
    intact = write_log(tmp_path / "intact.mcap", basic_topics(), chunk_size=4 * 1024)
    chunks = _chunks(intact)
    damaged, _ = DAMAGES["chunk_size_field"]
    path = tmp_path / "size.mcap"
    path.write_bytes(damaged(intact.read_bytes(), chunks))
    report = _read(path)
    assert report.reasons() == {"chunk_size"} and report.lost == {}
    assert report.messages_read == _read(intact).messages_read
    assert "chunk_size" in scan_log(path, full=True).problem_kinds()


def test_decompression_bomb_costs_bounded_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A chunk whose zstd frame inflates past the chunk limit is refused, not inflated: here
    a 64 MiB run of zeros against a limit lowered to 1 MiB, with no size in the frame."""
    import zstandard

    from toolkit.mcapio import chunks

    monkeypatch.setattr(chunks, "MAX_CHUNK_BYTES", 1024 * 1024)
    intact = write_log(tmp_path / "intact.mcap", basic_topics(), chunk_size=4 * 1024)
    ci = _chunks(intact)[2]
    bomb = zstandard.ZstdCompressor(write_content_size=False).compress(bytes(64 * 1024 * 1024))
    data = intact.read_bytes()
    start = _compressed_start(ci)
    end = ci.chunk_start_offset + ci.chunk_length
    # Keep the chunk's length consistent: the bomb replaces the compressed records.
    head = bytearray(data[ci.chunk_start_offset : start])
    head[1:9] = struct.pack("<Q", ci.chunk_length - 9 - (end - start) + len(bomb))
    head[start - ci.chunk_start_offset - 8 : start - ci.chunk_start_offset] = struct.pack(
        "<Q", len(bomb)
    )
    path = tmp_path / "bomb.mcap"
    path.write_bytes(data[: ci.chunk_start_offset] + bytes(head) + bomb + data[end:])
    report = _read(path)
    bad = [d for d in report.damage if d.reason == "chunk_decompress"]
    assert len(bad) == 1 and "chunk limit" in bad[0].detail
    assert sum(report.messages_read.values()) > 0  # the other chunks were read
