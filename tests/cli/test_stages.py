"""The stages' commands (toolkit/cli/stages.py): a failing log does not stop the others,
a stage that cannot run says why in one line, summaries count what they say."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

import toolkit
from toolkit.cli import main
from toolkit.workspace import Workspace

from .helpers import REPO, SAMPLE_LOG, assert_one_error_line


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


def test_point_stages_on_a_log_without_lasers_say_why_in_one_line(
    runner: CliRunner, tmp_path: Path
) -> None:
    """The Husky has no lasers and a 30 Hz IMU: project names the missing role, label the
    IMU too slow for the shock band (before asking for a pose it could not use), tables
    why this log cannot feed it, never advising a stage that cannot run; each exits 1 with
    one line, never a traceback."""
    data = REPO / "tests" / "data" / "real-logs" / "husky-gps-imu-odom.mcap"
    config = REPO / "pipelines" / "husky.toml"
    ws = str(tmp_path / "ws")
    assert runner.invoke(main, ["ingest", str(data), "-w", ws, "-c", str(config)]).exit_code == 0
    project = runner.invoke(main, ["project", "-w", ws])
    assert project.exit_code == 1
    assert "projection needs a scanner, and this log has none" in assert_one_error_line(
        project.stderr
    )
    label = runner.invoke(main, ["label", "-w", ws])
    assert label.exit_code == 1
    assert "cannot carry the shock band" in assert_one_error_line(label.stderr)
    tables = runner.invoke(main, ["tables", "-w", ws])
    assert tables.exit_code == 1
    line = assert_one_error_line(tables.stderr)
    assert "this log cannot feed label: IMU rate" in line and "run `terrain" not in line


def test_summaries_say_what_they_count(runner: CliRunner, tmp_path: Path) -> None:
    """One log is "1 log"; a workspace stage's failure names the stage once."""
    default = Path(toolkit.__file__).parent / "default_config.toml"
    ws = tmp_path / "ws"
    (ws / "logs" / "fake-1").mkdir(parents=True)
    (ws / "config.toml").write_text(default.read_text())
    result = runner.invoke(main, ["pose", "-w", str(ws)])
    assert result.exit_code == 1
    assert "pose: 1 log: 1 failed" in result.output
    sample = SAMPLE_LOG
    result = runner.invoke(main, ["run", str(sample), "-w", str(ws), "--from", "learn"])
    assert result.exit_code == 1
    errors = [line for line in result.stderr.splitlines() if line.startswith("terrain: error:")]
    assert len(errors) == 1
    assert errors[0].startswith("terrain: error: learn: ") and "learn: learn:" not in errors[0]


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
