"""Chunks (toolkit.mcapio.chunks): one failing its CRC or decompression is skipped, its
messages counted from the index."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import CompressionType

from . import damage
from .logs import check_one_bad_chunk, make_log, read_all


def test_bad_crc_field_skips_the_chunk_and_counts_its_messages(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[2]
    bad = damage.flip(path, tmp_path / "crc.mcap", damage.crc_field(ci), 0x01)
    got, report = read_all(bad)
    assert check_one_bad_chunk(report, got, path, 2, {"chunk_crc"}) == "chunk_crc"
    assert report.used_index


def test_broken_compression_frame_skips_the_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[1]
    bad = damage.flip(path, tmp_path / "magic.mcap", damage.compressed_start(ci))  # zstd magic
    got, report = read_all(bad)
    assert check_one_bad_chunk(report, got, path, 1, {"chunk_decompress"}) == "chunk_decompress"


def test_unknown_compression_skips_the_chunk(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    ci = damage.chunk_indexes(path)[4]
    at = damage.compressed_start(ci) - 8 - 1  # last letter of "zstd"
    got, report = read_all(damage.flip(path, tmp_path / "zstx.mcap", at, ord("d") ^ ord("x")))
    check_one_bad_chunk(report, got, path, 4, {"unsupported_compression"})


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
    check_one_bad_chunk(report, got, path, 3, {"chunk_crc", "chunk_decompress"})
