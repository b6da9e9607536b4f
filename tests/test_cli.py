"""Tests of the command line's plumbing: help, exit codes, error lines, logging, progress.

The sim and info verbs' implementations belong to other modules; here they are replaced by
fakes so only argument handling and error mapping are tested.
"""

from __future__ import annotations

import io
import logging
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
from toolkit.errors import LogReadError, SimulationError
from toolkit.workspace import Workspace

VERBS = ["sim", "info", "ingest", "pose", "project", "label", "tables"]


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture(autouse=True)
def _restore_logging_and_quiet() -> Any:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
    progress_mod.set_quiet(False)


def assert_one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("terrain: error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


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


# -- info -------------------------------------------------------------------------------


class FakeInfo:
    def to_dict(self) -> dict[str, Any]:
        return {"topics": [{"topic": "/imu/data", "count": 3}], "problems": []}


def fake_sim_module(monkeypatch: pytest.MonkeyPatch, simulate: Any) -> None:
    module = types.ModuleType("toolkit.sim.simulate")
    module.simulate = simulate  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "toolkit.sim.simulate", module)


def fake_info_module(scan: Any) -> types.ModuleType:
    module = types.ModuleType("toolkit.mcapio.info")
    module.scan_log = scan  # type: ignore[attr-defined]
    module.render_table = lambda info: "TOPIC /imu/data 3"  # type: ignore[attr-defined]
    return module


def test_info_missing_file_exits_1_with_one_line(runner: CliRunner, tmp_path: Path) -> None:
    missing = tmp_path / "absent.mcap"
    result = runner.invoke(main, ["info", str(missing)])
    assert result.exit_code == 1
    line = assert_one_error_line(result.stderr)
    assert str(missing) in line and "no such file" in line


def test_info_prints_table_or_json(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "a.mcap"
    log.write_bytes(b"")
    seen: list[Path] = []

    def scan(path: Path, **kwargs: Any) -> FakeInfo:
        seen.append(path)
        assert kwargs == {"full": path.name == "full.mcap"}
        return FakeInfo()

    monkeypatch.setitem(sys.modules, "toolkit.mcapio.info", fake_info_module(scan))
    result = runner.invoke(main, ["info", str(log)])
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == "TOPIC /imu/data 3"
    assert seen == [log]
    result = runner.invoke(main, ["info", str(log), "--json"])
    assert result.exit_code == 0
    assert '"topic": "/imu/data"' in result.stdout
    full = tmp_path / "full.mcap"
    full.write_bytes(b"")
    assert runner.invoke(main, ["info", str(full), "--full"]).exit_code == 0


def test_info_log_read_error_exits_1(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "broken.mcap"
    log.write_bytes(b"garbage")

    def scan(path: Path, **kwargs: Any) -> FakeInfo:
        raise LogReadError("no MCAP magic\nat offset 0", path=path)

    monkeypatch.setitem(sys.modules, "toolkit.mcapio.info", fake_info_module(scan))
    result = runner.invoke(main, ["info", str(log)])
    assert result.exit_code == 1
    line = assert_one_error_line(result.stderr)
    assert line == f"terrain: error: {log}: no MCAP magic at offset 0"
    assert result.stdout == ""

    debug = runner.invoke(main, ["--debug", "info", str(log)])
    assert debug.exit_code == 1
    assert "Traceback" in debug.stderr and "LogReadError" in debug.stderr
    assert debug.stderr.rstrip().splitlines()[-1].startswith("terrain: error: ")


# -- sim --------------------------------------------------------------------------------


class FakeResult:
    def summary(self) -> str:
        return "wrote 1200 m, 5 lasers"


def test_sim_passes_arguments_and_prints_summary(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[Path, dict[str, Any]]] = []

    def simulate(out_path: Path, **kwargs: Any) -> FakeResult:
        calls.append((out_path, kwargs))
        return FakeResult()

    fake_sim_module(monkeypatch, simulate)
    out = tmp_path / "race.mcap"
    args = ["sim", str(out), "--profile", "race", "--distance-m", "1200", "--seed", "7"]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == "wrote 1200 m, 5 lasers"
    assert calls == [
        (
            out,
            {
                "profile": "race",
                "distance_m": 1200.0,
                "seed": 7,
                "show_progress": True,
                "workers": None,
                "lasers": True,
            },
        )
    ]
    result = runner.invoke(main, ["sim", str(out), "--workers", "0"])
    assert calls[-1][1] == {
        "profile": "sample",
        "distance_m": None,
        "seed": 0,
        "show_progress": True,
        "workers": 0,
        "lasers": True,
    }
    result = runner.invoke(main, ["sim", str(out), "--no-lasers"])
    assert result.exit_code == 0, result.output
    assert calls[-1][1]["lasers"] is False


def test_sim_toolkit_error_exits_1(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def simulate(out_path: Path, **kwargs: Any) -> FakeResult:
        raise SimulationError("distance_m 3 is shorter than one scan")

    fake_sim_module(monkeypatch, simulate)
    result = runner.invoke(main, ["sim", str(tmp_path / "x.mcap")])
    assert result.exit_code == 1
    assert assert_one_error_line(result.stderr).endswith("shorter than one scan")


def test_sim_missing_output_directory_exits_1(runner: CliRunner, tmp_path: Path) -> None:
    result = runner.invoke(main, ["sim", str(tmp_path / "nope" / "x.mcap")])
    assert result.exit_code == 1
    assert "output directory does not exist" in assert_one_error_line(result.stderr)


def test_sim_onto_an_existing_file_refuses_without_overwrite(
    runner: CliRunner, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Like export and viz: a log already there is replaced only with --overwrite."""
    calls: list[Path] = []

    def simulate(out_path: Path, **kwargs: Any) -> FakeResult:
        calls.append(out_path)
        return FakeResult()

    fake_sim_module(monkeypatch, simulate)
    out = tmp_path / "x.mcap"
    out.write_bytes(b"a recorded log")
    result = runner.invoke(main, ["sim", str(out)])
    assert result.exit_code == 1
    assert "already exists; pass --overwrite" in assert_one_error_line(result.stderr)
    assert out.read_bytes() == b"a recorded log" and not calls
    assert runner.invoke(main, ["sim", str(tmp_path)]).exit_code == 2  # a directory: usage
    result = runner.invoke(main, ["sim", str(out), "--overwrite"])
    assert result.exit_code == 0 and calls == [out]


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


# -- global flags after the verb, and multi-log verbs -----------------------------------------

SAMPLE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"


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


def test_pose_carries_on_past_a_failing_log_and_exits_1(runner: CliRunner, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    copy = tmp_path / "other.mcap"
    copy.write_bytes(SAMPLE_LOG.read_bytes()[:-1] + b"\x00")  # another log (another hash)
    assert runner.invoke(main, ["ingest", str(SAMPLE_LOG), str(copy), "-w", str(ws)]).exit_code == 0
    logs = [ws / "logs" / i for i in Workspace(ws).log_ids()]
    assert len(logs) == 2
    (logs[0] / "imu.parquet").unlink()  # the first log (in the order pose takes) fails
    result = runner.invoke(main, ["pose", "-w", str(ws)])
    assert result.exit_code == 1
    assert f"{logs[0].name}: " in result.stderr and "imu.parquet" in result.stderr
    assert (logs[1] / "pose.parquet").is_file()  # the other log was still posed
    assert "pose: 2 logs: 1 estimated, 1 failed" in result.stdout


# -- the point stages on a vehicle without lasers -----------------------------------------


def test_point_stages_on_a_log_without_lasers_say_why_in_one_line(
    runner: CliRunner, tmp_path: Path
) -> None:
    """The Husky has no lasers: project names the missing role, label the missing pose,
    tables what it needs; each exits 1 with one line, never a traceback."""
    data = Path(__file__).resolve().parent / "data" / "real-logs" / "husky-gps-imu-odom.mcap"
    config = Path(__file__).resolve().parents[1] / "pipelines" / "husky.toml"
    ws = str(tmp_path / "ws")
    assert runner.invoke(main, ["ingest", str(data), "-w", ws, "-c", str(config)]).exit_code == 0
    project = runner.invoke(main, ["project", "-w", ws])
    assert project.exit_code == 1
    assert "projection needs the lasers role" in assert_one_error_line(project.stderr)
    label = runner.invoke(main, ["label", "-w", ws])
    assert label.exit_code == 1
    assert "run `terrain pose` first" in assert_one_error_line(label.stderr)
    tables = runner.invoke(main, ["tables", "-w", ws])
    assert tables.exit_code == 1
    assert "run `terrain label`" in assert_one_error_line(tables.stderr)


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
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"
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


def test_summaries_say_what_they_count(runner: CliRunner, tmp_path: Path) -> None:
    """One log is "1 log"; a workspace stage's failure names the stage once."""
    default = Path(toolkit.__file__).parent / "default_config.toml"
    ws = tmp_path / "ws"
    (ws / "logs" / "fake-1").mkdir(parents=True)
    (ws / "config.toml").write_text(default.read_text())
    result = runner.invoke(main, ["pose", "-w", str(ws)])
    assert result.exit_code == 1
    assert "pose: 1 log: 1 failed" in result.output
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"
    result = runner.invoke(main, ["run", str(sample), "-w", str(ws), "--from", "learn"])
    assert result.exit_code == 1
    errors = [line for line in result.stderr.splitlines() if line.startswith("terrain: error:")]
    assert len(errors) == 1
    assert errors[0].startswith("terrain: error: learn: ") and "learn: learn:" not in errors[0]


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
    assert beats and all(" block (" in b and ", after " in b for b in beats), proc.stderr
    assert "terrain: sim" not in proc.stdout
    proc = subprocess.run(
        [sys.executable, "-m", "toolkit", "ingest", str(out), "-w", str(tmp_path / "ws")],
        capture_output=True,
        text=True,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert "terrain: ingest: hb.mcap ingested (1/1)" in proc.stderr.splitlines()


def test_sim_writes_no_log_inside_a_workspace(runner: CliRunner, tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")
    result = runner.invoke(main, ["sim", str(ws.logs_dir / "x.mcap")])
    assert result.exit_code == 1
    assert "lies inside the workspace" in assert_one_error_line(result.stderr)
    assert not (ws.logs_dir / "x.mcap").exists()


def test_label_with_the_longest_valid_filter_refuses_in_one_line(
    sample_projected: tuple[Path, str], tmp_path: Path
) -> None:
    """``fir_taps = 1000``, the largest the configuration accepts: its design does not
    converge at the sample's IMU rate; the label stage says so in one line naming the key,
    at once, and writes nothing."""
    import shutil

    root, log_id = sample_projected
    ws_root = tmp_path / "ws"
    shutil.copytree(root, ws_root, symlinks=True)
    config = ws_root / "config.toml"
    config.write_text(config.read_text().replace("fir_taps = 40", "fir_taps = 1000", 1))
    result = CliRunner().invoke(main, ["label", "-w", str(ws_root)])
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("terrain: error:")]
    assert result.exit_code == 1
    assert len(errors) == 1 and "label.fir_taps = 1000" in errors[0]
    assert "does not converge" in errors[0] and "Traceback" not in result.stderr
    assert not (ws_root / "logs" / log_id / "events.parquet").exists()
