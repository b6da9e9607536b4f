"""Progress: bars on a terminal, a heartbeat and log lines off it, nothing when quiet."""

from __future__ import annotations

import time

import pytest

from toolkit import progress as progress_mod
from toolkit.progress import Heartbeat, note, progress, set_quiet


@pytest.fixture(autouse=True)
def _off_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(progress_mod, "progress_enabled", lambda: False)
    monkeypatch.setenv("TERRAIN_HEARTBEAT_S", "0.05")
    set_quiet(False)


def test_off_a_terminal_a_long_loop_beats_with_what_and_how_far(
    capsys: pytest.CaptureFixture[str],
) -> None:
    bar = progress(total=4, desc="learn", unit="rotation")
    assert isinstance(bar, Heartbeat)
    with bar:
        bar.update(1)
        bar.set_postfix_str("training the oracle")
        time.sleep(0.3)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) >= 2, lines
    assert lines[-1].startswith("terrain: learn: 1/4 rotation (25 %), training the oracle, after ")
    time.sleep(0.2)  # closed: silent from now on
    assert capsys.readouterr().err == ""


def test_an_iterated_heartbeat_counts_its_items_and_stops_at_the_end(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for _ in progress(range(3), desc="ingest x.mcap", unit="batch"):
        time.sleep(0.08)
    err = capsys.readouterr().err
    assert "terrain: ingest x.mcap: " in err and " batch, after " in err
    time.sleep(0.2)
    assert capsys.readouterr().err == ""


def test_notes_and_heartbeats_are_silent_when_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    note("tables done")
    assert capsys.readouterr().err == "terrain: tables done\n"
    set_quiet(True)
    try:
        with progress(total=2, desc="sim") as bar:
            assert not isinstance(bar, Heartbeat)
            time.sleep(0.15)
        note("tables done")
    finally:
        set_quiet(False)
    assert capsys.readouterr().err == ""
