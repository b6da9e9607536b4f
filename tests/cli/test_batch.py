"""The verbs that start from MCAP files (toolkit/cli/batch.py): a failed first run
leaves no workspace, and no folder it did not make is touched."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from toolkit.cli import main

from .helpers import SAMPLE_LOG


@pytest.mark.parametrize("verb", ["run", "ingest"])
def test_a_failed_first_run_leaves_no_workspace(
    runner: CliRunner, tmp_path: Path, verb: str
) -> None:
    """A missing log, a log that is not MCAP, or a configuration with an unknown key: exit
    1 and no workspace folder left behind."""
    garbage = tmp_path / "g.mcap"
    garbage.write_bytes(b"not an mcap")
    bad_config = tmp_path / "bad.toml"
    bad_config.write_text("[bogus]\nx = 1\n")
    sample = SAMPLE_LOG
    cases = {
        "missing": [str(tmp_path / "nope.mcap")],
        "garbage": [str(garbage)],
        "config": [str(sample), "-c", str(bad_config)],
    }
    for name, args in cases.items():
        ws = tmp_path / f"ws-{name}"
        result = runner.invoke(main, [verb, *args, "-w", str(ws)])
        assert result.exit_code == 1, (name, result.output)
        assert not ws.exists(), name


def test_a_failed_run_keeps_a_folder_it_did_not_make(runner: CliRunner, tmp_path: Path) -> None:
    """An existing folder, and everything in it, is left as it was by a failed run."""
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / "notes.txt").write_text("mine")
    result = runner.invoke(main, ["ingest", str(tmp_path / "nope.mcap"), "-w", str(ws)])
    assert result.exit_code == 1
    assert (ws / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("verb", ["run", "ingest"])
def test_a_log_argument_that_is_no_file_is_one_line_before_any_work(
    runner: CliRunner, tmp_path: Path, verb: str
) -> None:
    """A mistyped log or a folder given as a log: one line naming it and the problem, exit
    1, nothing run (no stage table, no empty log name), whatever else was given."""
    ws = tmp_path / "ws"
    cases = {
        "no such log file": [str(tmp_path / "nosuch.mcap")],
        "is a directory, not an MCAP log": [str(tmp_path)],
        "no such log file (1 more": [str(SAMPLE_LOG), "a.mcap", "b.mcap"],
    }
    for problem, logs in cases.items():
        result = runner.invoke(main, [verb, *logs, "-w", str(ws)])
        assert result.exit_code == 1, result.output
        assert result.stdout == ""
        (line,) = result.stderr.splitlines()
        assert problem in line, line
        assert not ws.exists()
