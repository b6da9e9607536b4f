"""The verbs around the stages (toolkit/cli/tools.py): info, sim and config init. Their
implementations belong to other modules; here they are replaced by fakes (or never reached)
so only argument handling and error mapping are tested."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from toolkit.cli import main
from toolkit.errors import LogReadError, SimulationError
from toolkit.workspace import Workspace

from .helpers import SAMPLE_LOG, FakeResult, assert_one_error_line, fake_sim_module

# -- info -------------------------------------------------------------------------------


class FakeInfo:
    topics = (
        types.SimpleNamespace(topic="/imu/data", message_type="sensor_msgs/Imu", layout=None),
    )

    def to_dict(self) -> dict[str, Any]:
        return {"topics": [{"topic": "/imu/data", "count": 3}], "problems": []}


def fake_info_module(scan: Any) -> types.ModuleType:
    module = types.ModuleType("toolkit.mcapio.info")
    module.scan_log = scan  # type: ignore[attr-defined]
    module.render_table = (  # type: ignore[attr-defined]
        lambda info, roles: f"TOPIC /imu/data 3 {' '.join(roles['/imu/data'])}"
    )
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
    assert result.stdout.strip() == "TOPIC /imu/data 3 imu"  # the role its type can play
    assert seen == [log]
    result = runner.invoke(main, ["info", str(log), "--json"])
    assert result.exit_code == 0
    assert json.loads(result.stdout)["topics"] == [
        {"topic": "/imu/data", "count": 3, "roles": ["imu"]}
    ]
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
                "lidar": False,
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
        "lidar": False,
    }
    result = runner.invoke(main, ["sim", str(out), "--no-lasers"])
    assert result.exit_code == 0, result.output
    assert calls[-1][1]["lasers"] is False
    result = runner.invoke(main, ["sim", str(out), "--lidar"])
    assert result.exit_code == 0, result.output
    assert calls[-1][1]["lidar"] is True


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


@pytest.mark.parametrize("verb", ["viz", "export"])
def test_every_verb_writing_outside_a_workspace_refuses_a_missing_folder(
    runner: CliRunner, tmp_path: Path, verb: str
) -> None:
    """viz and export, as sim: the folder the output goes into must exist (a mistyped
    path is one line, exit 1, and no folder is made), checked before the workspace."""
    out = tmp_path / "nope" / "deeper" / "out"
    args = [verb, "-w", str(tmp_path / "ws"), "--out", str(out)]
    result = runner.invoke(main, args + (["--log", "x"] if verb == "viz" else []))
    assert result.exit_code == 1, result.output
    line = assert_one_error_line(result.stderr)
    assert "output directory does not exist" in line and str(out.parent) in line
    assert not (tmp_path / "nope").exists()


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


def test_sim_writes_no_log_inside_a_workspace(runner: CliRunner, tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")
    result = runner.invoke(main, ["sim", str(ws.logs_dir / "x.mcap")])
    assert result.exit_code == 1
    assert "lies inside the workspace" in assert_one_error_line(result.stderr)
    assert not (ws.logs_dir / "x.mcap").exists()


# -- config init ----------------------------------------------------------------------------


def test_config_init_writes_nothing_inside_a_workspace(runner: CliRunner, tmp_path: Path) -> None:
    """``--out WS/config.toml --overwrite`` replaced the workspace's configuration (and a
    manifest the same way): refused as viz and sim refuse, one line, exit 1, nothing
    touched, whatever the flags."""
    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("# the workspace's own\n")
    manifest = ws.logs_dir / "log-1" / "manifest.json"
    manifest.parent.mkdir()
    manifest.write_text("{}")
    for out in (ws.config_path, manifest, ws.root / "mine.toml"):
        for flags in ([], ["--overwrite"]):
            args = ["config", "init", str(SAMPLE_LOG), "--out", str(out), *flags]
            result = runner.invoke(main, args)
            assert result.exit_code == 1, result.output
            line = assert_one_error_line(result.stderr)
            assert f"{out}: lies inside the workspace " in line
    assert ws.config_path.read_text() == "# the workspace's own\n"
    assert manifest.read_text() == "{}" and not (ws.root / "mine.toml").exists()
