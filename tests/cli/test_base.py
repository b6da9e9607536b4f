"""The command line's plumbing (toolkit/cli/base.py, group.py): help, usage errors, exit
codes, error lines, the entry point, global flags, logging and progress."""

from __future__ import annotations

import io
import logging
import re
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

import toolkit
from toolkit import progress as progress_mod
from toolkit.cli import main

from .helpers import FakeResult, assert_one_error_line, fake_sim_module

VERBS = ["sim", "info", "ingest", "pose", "project", "label", "tables"]


# -- help and usage -----------------------------------------------------------------------


def test_main_help_lists_verbs(runner: CliRunner) -> None:
    result = runner.invoke(main, ["--help"])
    assert result.exit_code == 0
    for verb in VERBS:
        assert verb in result.output
    for option in ("--verbose", "--quiet", "--debug", "--version"):
        assert option in result.output


@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_has_help(runner: CliRunner, verb: str) -> None:
    result = runner.invoke(main, [verb, "--help"])
    assert result.exit_code == 0, result.output
    assert f"Usage: terrain {verb}" in result.output or f"{verb} [OPTIONS]" in result.output


def test_version(runner: CliRunner) -> None:
    result = runner.invoke(main, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"terrain {toolkit.__version__}"


@pytest.mark.parametrize(
    "args",
    [
        ["frobnicate"],
        ["sim"],
        ["sim", "out.mcap", "--profile", "desert"],
        ["sim", "out.mcap", "--distance-m", "-5"],
        ["sim", "out.mcap", "--distance-m", "50"],  # the least route is 100 m, said in --help
        ["run", "sample.mcap", "-w", "ws", "--from", "learn", "--to", "tables"],
        ["sim", "out.mcap", "--seed", "many"],
        ["info"],
        ["info", "a.mcap", "--bogus"],
        ["--no-such-global"],
    ],
)
def test_usage_errors_exit_2(runner: CliRunner, args: list[str]) -> None:
    result = runner.invoke(main, args)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output


def test_unexpected_exception_exits_1_with_hint(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def simulate(out_path: Path, **kwargs: Any) -> FakeResult:
        raise ZeroDivisionError("division by zero")

    fake_sim_module(monkeypatch, simulate)
    result = runner.invoke(main, ["sim", str(tmp_path / "x.mcap")])
    assert result.exit_code == 1
    line = assert_one_error_line(result.stderr)
    assert "ZeroDivisionError" in line and "--debug" in line
    debug = runner.invoke(main, ["--debug", "sim", str(tmp_path / "x.mcap")])
    assert debug.exit_code == 1
    assert "Traceback" in debug.stderr


def test_python_dash_m_entry_point(tmp_path: Path) -> None:
    """The real process: exit code and a single stderr line, no traceback."""
    proc = subprocess.run(
        [sys.executable, "-m", "toolkit", "info", str(tmp_path / "absent.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1
    assert_one_error_line(proc.stderr)
    usage = subprocess.run(
        [sys.executable, "-m", "toolkit", "sim"], capture_output=True, text=True, timeout=120
    )
    assert usage.returncode == 2


# -- logging and progress -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("flags", "level"),
    [
        ([], logging.WARNING),
        (["-v"], logging.INFO),
        (["-vv"], logging.DEBUG),
        (["-q"], logging.ERROR),
    ],
)
def test_verbosity_sets_log_level(
    runner: CliRunner, tmp_path: Path, flags: list[str], level: int
) -> None:
    result = runner.invoke(main, [*flags, "info", str(tmp_path / "absent.mcap")])
    assert result.exit_code == 1
    assert logging.getLogger().level == level


def test_log_records_are_one_line_on_stderr(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def simulate(out_path: Path, **kwargs: Any) -> FakeResult:
        logging.getLogger("toolkit.sim").warning("gps dropout\nfor 2 s")
        logging.getLogger("toolkit.sim").info("details")
        return FakeResult()

    fake_sim_module(monkeypatch, simulate)
    result = runner.invoke(main, ["sim", str(tmp_path / "x.mcap")])
    assert result.exit_code == 0
    assert result.stderr.splitlines() == ["terrain: warning: [toolkit.sim] gps dropout for 2 s"]
    assert "gps dropout" not in result.stdout
    verbose = runner.invoke(main, ["-v", "sim", str(tmp_path / "x.mcap")])
    assert "terrain: info: [toolkit.sim] details" in verbose.stderr.splitlines()


def test_progress_disabled_off_terminal_in_ci_and_quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    class Tty:
        def isatty(self) -> bool:
            return True

        def write(self, text: str) -> int:
            return len(text)

        def flush(self) -> None:
            pass

    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setattr(sys, "stderr", Tty())
    assert progress_mod.progress_enabled()
    for value in ("true", "1"):
        monkeypatch.setenv("CI", value)
        assert not progress_mod.progress_enabled()
    monkeypatch.setenv("CI", "false")
    assert progress_mod.progress_enabled()
    progress_mod.set_quiet(True)
    assert not progress_mod.progress_enabled()
    progress_mod.set_quiet(False)
    monkeypatch.setattr(sys, "stderr", types.SimpleNamespace(isatty=lambda: False))
    assert not progress_mod.progress_enabled()


def test_progress_under_ci_is_a_heartbeat_and_passes_items_through(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A CI log is not a terminal, even when stderr claims to be: no bar, a heartbeat
    (silent for work shorter than its interval)."""
    monkeypatch.setenv("CI", "true")
    terminal = io.StringIO()
    terminal.isatty = lambda: True  # type: ignore[method-assign]
    monkeypatch.setattr(sys, "stderr", terminal)
    progress_mod.set_quiet(False)
    bar = progress_mod.progress(range(5), desc="x")
    assert isinstance(bar, progress_mod.Heartbeat)
    assert list(bar) == [0, 1, 2, 3, 4]
    with progress_mod.progress(total=10, unit="B") as manual:
        manual.update(4)
    assert isinstance(manual, progress_mod.Heartbeat) and terminal.getvalue() == ""


def test_progress_draws_on_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    terminal = io.StringIO()
    terminal.isatty = lambda: True  # type: ignore[method-assign]
    monkeypatch.setattr(sys, "stderr", terminal)
    progress_mod.set_quiet(False)
    assert list(progress_mod.progress(range(3), desc="ingest")) == [0, 1, 2]
    with progress_mod.progress(total=10, unit="B", desc="bytes") as manual:
        manual.update(4)
        assert not manual.disable and manual.n == 4
    drawn = terminal.getvalue()
    assert "ingest:" in drawn and "bytes:" in drawn and "0/10" in drawn


def test_quiet_flag_disables_progress(runner: CliRunner, tmp_path: Path) -> None:
    runner.invoke(main, ["-q", "info", str(tmp_path / "absent.mcap")])
    assert progress_mod._quiet is True


def test_global_flags_work_after_the_verb(runner: CliRunner, tmp_path: Path) -> None:
    result = runner.invoke(main, ["info", str(tmp_path / "absent.mcap"), "-q"])
    assert result.exit_code == 1
    assert progress_mod._quiet is True
    result = runner.invoke(main, ["info", "--debug", str(tmp_path / "absent.mcap")])
    assert result.exit_code == 1
    assert "Traceback" in result.stderr and "LogReadError" in result.stderr
    result = runner.invoke(main, ["info", str(tmp_path / "absent.mcap")])
    assert "Traceback" not in result.stderr  # without the flag: one line
    assert_one_error_line(result.stderr)


def test_off_a_terminal_long_work_logs_progress_lines(tmp_path: Path) -> None:
    """In a pipe: the simulator beats while it works (here every 0.2 s), and each log of
    a batch gets a line as it finishes; stdout keeps the results alone."""
    env = {**__import__("os").environ, "TERRAIN_HEARTBEAT_S": "0.2"}
    env.pop("CI", None)
    out = tmp_path / "hb.mcap"
    args = ["sim", str(out), "--profile", "race", "--distance-m", "300", "--no-lasers"]
    proc = subprocess.run(
        [sys.executable, "-m", "toolkit", *args], capture_output=True, text=True, env=env
    )
    assert proc.returncode == 0, proc.stderr
    beats = [line for line in proc.stderr.splitlines() if line.startswith("terrain: sim: ")]
    # Metres of route driven out of the route's length, never past it.
    done = [re.fullmatch(r"terrain: sim: (\d+)/(\d+) m \((\d+) %\), after \d+ s", b) for b in beats]
    assert beats and all(done), proc.stderr
    assert all(int(m[1]) <= int(m[2]) and int(m[3]) <= 100 for m in done if m), proc.stderr
    assert "terrain: sim" not in proc.stdout
    proc = subprocess.run(
        [sys.executable, "-m", "toolkit", "ingest", str(out), "-w", str(tmp_path / "ws")],
        capture_output=True,
        text=True,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert "terrain: ingest: hb.mcap ingested (1/1)" in proc.stderr.splitlines()
