"""Opening a log (toolkit.mcapio.summary): not MCAP, Header only, summary cut or failing
its CRC."""

from __future__ import annotations

from pathlib import Path

import pytest

from toolkit.errors import LogReadError
from toolkit.mcapio import records as records_module
from toolkit.mcapio.reader import LogReader

from . import damage
from .logs import make_log, read_all


def test_cut_summary_loses_nothing(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    cut = damage.cut_summary(path, tmp_path / "cut.mcap")
    got, report = read_all(cut)
    assert got == damage.reference(path)
    assert report.reasons() == {"no_summary"} and not report.used_index


def test_summary_failing_its_crc_is_ignored(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    bad = damage.flip(path, tmp_path / "summary.mcap", damage.data_end(path) + 20)
    got, report = read_all(bad)
    assert got == damage.reference(path)
    assert report.reasons() == {"bad_index"} and not report.used_index


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
    magic.write_bytes(records_module.MAGIC)
    with pytest.raises(LogReadError, match="magic.mcap: MCAP file without a Header"):
        LogReader(magic)


def test_header_only_file_reads_as_empty_and_truncated(tmp_path: Path) -> None:
    path = make_log(tmp_path / "log.mcap")
    header_end = 8 + 9 + int.from_bytes(path.read_bytes()[9:17], "little")
    got, report = read_all(damage.truncate(path, tmp_path / "header.mcap", header_end))
    assert got == {}
    assert report.reasons() == {"no_summary", "truncated"}
    assert report.messages_read == {}
