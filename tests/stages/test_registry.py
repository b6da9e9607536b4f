"""The stage registry: adding a stage is one new module and one registry line.

The toy stage below is written as a module of its own (in ``tmp_path``) and registered by
inserting one line into :data:`toolkit.stages.registry.REGISTRY`; the command line (its own
command, ``--help``), ``terrain run`` (``--to``, the order, the per-log executor), the
up-to-date check and ``terrain logs`` all pick it up with nothing else changed.
"""

from __future__ import annotations

import dataclasses
import json
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from toolkit.cli import main
from toolkit.config import config_hash, default_config
from toolkit.errors import ToolkitError
from toolkit.stages import registry
from toolkit.stages.registry import Listed
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"

TOY_MODULE = '''
"""A toy stage: counts a log's IMU rows into toy.parquet."""

from dataclasses import dataclass

import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.config import LabelConfig
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage


@dataclass(frozen=True)
class ToySettings:
    label: LabelConfig


@dataclass(frozen=True)
class Counted:
    status: str
    rows: int
    warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        return f"toy {self.status}: {self.rows} IMU rows"


def compute(call: Call[ToySettings]) -> Made[Counted]:
    assert isinstance(call.settings, ToySettings)  # its own section, not the whole config
    rows = pq.read_metadata(call.files.imu).num_rows
    pq.write_table(pa.table({"imu_rows": [rows]}), call.files.path("toy"))
    return Made(Counted("counted", rows), ("toy.parquet",), row_counts={"toy": rows})


def recall(last: Recalled[ToySettings]) -> Counted:
    return Counted("up_to_date", int(last.record.row_counts["toy"]))


SPEC = Stage(
    "toy",
    "log",
    needs=(Need("imu", "ingest"),),
    makes=("toy",),
    settings=ToySettings,
    compute=compute,
    recall=recall,
    rows=("toy",),
)
'''


@pytest.fixture
def toy_registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The toy module on the path and its one line in the registry, after ingest."""
    (tmp_path / "toy_stage.py").write_text(textwrap.dedent(TOY_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    lines = list(registry.REGISTRY.items())
    lines.insert(1, ("toy", Listed("toy_stage", "log", "Count each log's IMU rows.")))
    monkeypatch.setattr(registry, "REGISTRY", dict(lines))


def _terrain(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, ["-q", *args])
    return result.exit_code, result.output


def test_a_toy_stage_is_picked_up_by_run_the_cli_and_the_up_to_date_check(
    toy_registered: None, tmp_path: Path
) -> None:
    ws = str(tmp_path / "ws")
    code, out = _terrain("--help")
    assert code == 0 and "Count each log's IMU rows." in out

    # `run` takes it in the registry's order, through the per-log executor.
    code, out = _terrain("run", str(SAMPLE_LOG), "-w", ws, "--to", "toy", "--workers", "0")
    assert code == 0, out
    assert [ln.split()[0] for ln in out.splitlines()[:2]] == ["ingest", "toy"]
    toy_line = out.splitlines()[1]
    assert "1 done" in toy_line and "rows: toy " in toy_line
    (log_id,) = Workspace(ws).log_ids()
    written = Workspace(ws).log(log_id).path("toy")
    assert written.is_file()

    # Its own command, and the up-to-date check: nothing changed, nothing done.
    code, out = _terrain("toy", "-w", ws, "--json")
    assert code == 0, out
    (entry,) = json.loads(out)["logs"]
    assert entry["status"] == "up_to_date"
    assert entry["record"]["inputs"].keys() == {"imu"}
    code, out = _terrain("run", str(SAMPLE_LOG), "-w", ws, "--to", "toy", "--workers", "0")
    assert code == 0 and "toy" in out and "1 up to date" in out.splitlines()[1]

    # An output changed since it was written makes it run again.
    written.write_bytes(written.read_bytes() + b"\0")
    code, out = _terrain("toy", "-w", ws)
    assert code == 0 and out.startswith("toy counted: ")

    # `terrain logs` lists it among the per-log stages done.
    code, out = _terrain("logs", "-w", ws)
    assert code == 0 and "ingest toy" in out.splitlines()[1]


def test_a_stage_listed_before_a_stage_it_needs_is_refused(
    toy_registered: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    lines = [(n, line) for n, line in registry.REGISTRY.items() if n != "ingest"]
    lines.append(("ingest", registry.REGISTRY["ingest"]))
    monkeypatch.setattr(registry, "REGISTRY", dict(lines))
    with pytest.raises(ToolkitError, match="stage 'toy' needs 'ingest', listed after it"):
        registry.stages()


def test_every_registered_stage_declares_itself_as_listed() -> None:
    for spec in registry.stages():
        assert spec.scope == registry.REGISTRY[spec.name].scope
        assert set(spec.after) <= set(registry.names())


#: What each stage's up-to-date key hashes (default configuration): a change here makes every
#: workspace's stage stale, so it is pinned. Pose leaves out the topics its settings hold
#: (their changes reach it through ingest's tables); tables hashes one key of [model];
#: project keeping every point hashes only which points it keeps of its section.
HASHED = {
    # [lidar] keys nothing at its defaults (toolkit.config.UNHASHED_AT_DEFAULT), so the key
    # of a laser vehicle's ingest is what it was before the 3-D lidar: checked below.
    "ingest": ("topics", "time", "lidar", "imu"),
    "pose": ("pose", "time", "vehicle"),
    "project": ("vehicle", "project.keep"),
    "label": ("label", "vehicle"),
    "tables": ("tables", "vehicle", "model.wheel_window_radius_m"),
    "learn": ("model", "learn"),
    "online": ("model", "label", "learn", "online"),
    "evaluate": ("model", "learn", "evaluate"),
}


def test_every_stage_hashes_the_configuration_it_always_has() -> None:
    config = default_config()
    assert {s.name: s.hashed_sections(config) for s in registry.stages()} == HASHED
    ingest = registry.stage("ingest")
    assert ingest.config_hash(config) == config_hash(config, ["topics", "time"])
    near_path = dataclasses.replace(config.project, keep="near_path")
    keeping_near_path = dataclasses.replace(config, project=near_path)
    hashed = registry.stage("project").hashed_sections(keeping_near_path)
    assert hashed == ("vehicle", "project", "model.wheel_window_radius_m", "vehicle.track_m")
