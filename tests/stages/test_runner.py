"""The runner: freshness, refusals and records, once for every stage.

Two toy stages stand in for real ones: ``seed`` starts a log from a text file (as ingest
does from an MCAP) and writes ``seed.parquet``; ``double`` needs it and the ``[label]``
section, and writes ``double.parquet``. Nothing here reads a real log, so every rule of the
runner is checked in milliseconds.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from toolkit.config import LabelConfig, PipelineConfig, VehicleConfig, config_hash, default_config
from toolkit.errors import StageError, WorkspaceError
from toolkit.manifest import Manifest, file_sha256
from toolkit.stages.contract import Call, Made, Need, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace, make_log_id


@dataclasses.dataclass(frozen=True)
class Outcome:
    status: str
    value: int
    warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        return f"{self.status} {self.value}"


def _locate(source: Path) -> tuple[str, dict[str, str], Path]:
    sha = file_sha256(source)
    return make_log_id(source.stem, sha), {"log": sha}, source


@dataclasses.dataclass(frozen=True)
class NoSettings:
    """Seed reads no configuration."""


def _seed(call: Call[NoSettings]) -> Made[Outcome]:
    value = int(Path(call.found).read_text())
    pq.write_table(pa.table({"v": [value]}), call.files.path("seed"))
    return Made(Outcome("seeded", value), ("seed.parquet",), row_counts={"seed": 1})


def _double(call: Call[DoubleSettings]) -> Made[Outcome]:
    assert isinstance(call.settings, DoubleSettings)  # its own section, not the config
    value = pq.read_table(call.files.path("seed")).column("v")[0].as_py() * 2
    pq.write_table(pa.table({"v": [value]}), call.files.path("double"))
    warnings = ("an odd seed",) if value % 4 else ()
    return Made(Outcome("doubled", value, warnings), ("double.parquet",), warnings=warnings)


def _never(call: Call[Any]) -> Made[Outcome]:
    raise AssertionError("only declared, never run")


def _recall(last: Recalled[Any]) -> Outcome:
    return Outcome("up_to_date", -1)


@dataclasses.dataclass(frozen=True)
class DoubleSettings:
    label: LabelConfig


SEED = Stage("seed", "log", _seed, _recall, NoSettings, makes=("seed",), locate=_locate)
DOUBLE = Stage(
    "double",
    "log",
    _double,
    _recall,
    needs=(Need("seed", "seed"),),
    makes=("double",),
    settings=DoubleSettings,  # its up-to-date key: the sections it holds, [label]
)


@pytest.fixture
def seeded(tmp_path: Path) -> tuple[Workspace, str, Path]:
    source = tmp_path / "three.txt"
    source.write_text("3")
    ws = Workspace(tmp_path / "ws")
    outcome = run_stage(SEED, ws, default_config(), source=source)
    assert outcome.status == "seeded"
    (log_id,) = ws.log_ids()
    return ws, log_id, source


def test_a_stage_runs_once_then_is_up_to_date_until_its_input_changes(
    seeded: tuple[Workspace, str, Path],
) -> None:
    ws, log_id, source = seeded
    config = default_config()
    assert run_stage(SEED, ws, config, source=source).status == "up_to_date"
    assert run_stage(DOUBLE, ws, config, log_id=log_id).status == "doubled"
    assert run_stage(DOUBLE, ws, config, log_id=log_id).status == "up_to_date"
    assert run_stage(DOUBLE, ws, config, log_id=log_id, overwrite=True).status == "doubled"
    record = Manifest(ws.log(log_id).manifest).stage("double")
    assert record is not None
    assert dict(record.inputs) == {"seed": file_sha256(ws.log(log_id).path("seed"))}
    assert record.config_hash == DOUBLE.config_hash(config)
    assert set(record.output_files) == {"double.parquet"}


def test_only_the_sections_a_stage_reads_rerun_it(seeded: tuple[Workspace, str, Path]) -> None:
    ws, log_id, _ = seeded
    config = default_config()
    run_stage(DOUBLE, ws, config, log_id=log_id)
    other_pose = dataclasses.replace(
        config, pose=dataclasses.replace(config.pose, gps_noise_m=config.pose.gps_noise_m * 2)
    )
    assert run_stage(DOUBLE, ws, other_pose, log_id=log_id).status == "up_to_date"
    other_label = _with_threshold(config, config.label.rough_threshold_g_per_mph * 2)
    assert run_stage(DOUBLE, ws, other_label, log_id=log_id).status == "doubled"


def test_a_stage_is_keyed_by_its_settings_sections_unless_it_declares_fewer() -> None:
    @dataclasses.dataclass(frozen=True)
    class LabelAndVehicle:
        label: LabelConfig
        vehicle: VehicleConfig

    config = default_config()
    wider = dataclasses.replace(
        config, vehicle=dataclasses.replace(config.vehicle, track_m=config.vehicle.track_m + 0.1)
    )
    by_settings = Stage("both", "log", _never, _recall, settings=LabelAndVehicle)
    declared = Stage("both", "log", _never, _recall, settings=LabelAndVehicle, sections=("label",))
    assert by_settings.hashed_sections(config) == ("label", "vehicle")
    assert by_settings.config_hash(config) == config_hash(config, ("label", "vehicle"))
    assert by_settings.config_hash(wider) != by_settings.config_hash(config)
    assert declared.config_hash(wider) == declared.config_hash(config)


def test_a_missing_need_names_the_stage_that_makes_it(tmp_path: Path) -> None:
    source = tmp_path / "three.txt"
    source.write_text("3")
    ws = Workspace(tmp_path / "ws")
    run_stage(SEED, ws, default_config(), source=source)
    (log_id,) = ws.log_ids()
    with ws.change_log(log_id) as gen:  # a log whose seed output is gone
        (gen.path / "seed.parquet").unlink()
        gen.commit()
    with pytest.raises(StageError, match=r"run `terrain seed` first"):
        run_stage(DOUBLE, ws, default_config(), log_id=log_id)


def test_an_input_its_maker_did_not_write_is_refused(
    seeded: tuple[Workspace, str, Path],
) -> None:
    ws, log_id, _ = seeded
    with ws.change_log(log_id) as gen:  # edited by hand after seed finished
        pq.write_table(pa.table({"v": [5]}), gen.path / "seed.parquet")
        gen.commit()
    with pytest.raises(WorkspaceError, match="not the file the last finished seed wrote"):
        run_stage(DOUBLE, ws, default_config(), log_id=log_id)
    assert "double" not in Manifest(ws.log(log_id).manifest).stages()


def test_a_stage_s_warnings_are_said_on_the_terminal(
    seeded: tuple[Workspace, str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    ws, log_id, _ = seeded
    with caplog.at_level(logging.WARNING):
        outcome = run_stage(DOUBLE, ws, default_config(), log_id=log_id)
    assert outcome.warnings == ("an odd seed",)
    assert [r.getMessage() for r in caplog.records] == [f"{log_id}: an odd seed"]


def test_a_stage_is_run_with_what_its_scope_needs(
    seeded: tuple[Workspace, str, Path], tmp_path: Path
) -> None:
    ws, log_id, source = seeded
    config = default_config()
    with pytest.raises(TypeError, match="'seed' starts a log: pass source="):
        run_stage(SEED, Workspace(tmp_path / "none"), config)
    with pytest.raises(TypeError, match="'seed' starts a log: pass source="):
        run_stage(SEED, ws, config, log_id=log_id, source=source)
    with pytest.raises(TypeError, match="'double' runs on one log: pass log_id="):
        run_stage(DOUBLE, ws, config)
    over_all = Stage("over_all", "workspace", _never, _recall, NoSettings)
    with pytest.raises(TypeError, match="'over_all' runs over the workspace: pass no log_id"):
        run_stage(over_all, ws, config, log_id=log_id)
    assert not (tmp_path / "none").exists()  # refused before anything is made


def test_a_declaration_the_runner_could_not_honour_is_refused() -> None:
    @dataclasses.dataclass(frozen=True)
    class Loose:
        label: LabelConfig
        threshold: float  # no section, no default: the runner could not fill it

    with pytest.raises(TypeError, match="'loose': settings field 'threshold'"):
        Stage("loose", "log", _never, _recall, Loose)
    with pytest.raises(TypeError, match="'typo': it hashes 'lable', which its settings"):
        Stage("typo", "log", _never, _recall, DoubleSettings, sections=("lable",))
    with pytest.raises(TypeError, match="'plain': settings must be a dataclass"):
        Stage("plain", "log", _never, _recall, dict)
    narrowed = Stage("narrowed", "log", _never, _recall, DoubleSettings, sections=())
    assert narrowed.hashed_sections(default_config()) == ()  # it may hash nothing


def _with_threshold(config: PipelineConfig, threshold: float) -> PipelineConfig:
    label = dataclasses.replace(config.label, rough_threshold_g_per_mph=threshold)
    return dataclasses.replace(config, label=label)


@pytest.mark.parametrize("recorded", ["an older code's version", ""])
def test_outputs_other_code_made_are_made_again(
    seeded: tuple[Workspace, str, Path], monkeypatch: pytest.MonkeyPatch, recorded: str
) -> None:
    """The code version is part of the key: outputs recorded with another one (or with
    none, by a toolkit before it kept them) are made again, and recorded with this one."""
    ws, log_id, _ = seeded
    config = default_config()
    run_stage(DOUBLE, ws, config, log_id=log_id)
    manifest = Manifest(ws.log(log_id).manifest)
    record = manifest.stage("double")
    assert record is not None and record.code_version == DOUBLE.code_version
    manifest.record_stage("double", dataclasses.replace(record, code_version=recorded))
    assert run_stage(DOUBLE, ws, config, log_id=log_id).status == "doubled"
    assert run_stage(DOUBLE, ws, config, log_id=log_id).status == "up_to_date"
    monkeypatch.setattr(Stage, "code_version", property(lambda self: "f" * 64))
    assert run_stage(DOUBLE, ws, config, log_id=log_id).status == "doubled"
    again = Manifest(ws.log(log_id).manifest).stage("double")
    assert again is not None and again.code_version == "f" * 64


def test_a_stage_refuses_inputs_its_maker_made_with_another_configuration_or_code(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``ingest --overwrite`` with a new configuration leaves the workspace's other logs
    ingested with the old one: a stage run alone on them would mix the two, so it refuses
    in one line naming the log, the maker and what differs; the maker made again, it runs.
    Likewise for outputs another version of the maker's code made."""
    from tests.conftest import SAMPLE_LOG
    from toolkit.stages.ingest import SPEC as INGEST
    from toolkit.stages.ingest import ingest_log
    from toolkit.stages.pose import SPEC as POSE

    ws = Workspace(tmp_path / "ws")
    config = default_config()
    log_id = ingest_log(SAMPLE_LOG, ws, config).log_id
    # A wider gyro range: an ingest setting, not one of pose's own.
    wider = dataclasses.replace(config.imu, gyro_range_radps=config.imu.gyro_range_radps * 2)
    other = dataclasses.replace(config, imu=wider)
    assert INGEST.config_hash(other) != INGEST.config_hash(config)
    with pytest.raises(WorkspaceError, match="ingest outputs are stale .*another configuration"):
        run_stage(POSE, ws, other, log_id=log_id)
    ingest_log(SAMPLE_LOG, ws, other, overwrite=True)
    assert run_stage(POSE, ws, other, log_id=log_id).status != "up_to_date"
    from toolkit.stages import registry

    real = registry.code_version_of
    monkeypatch.setattr(
        registry, "code_version_of", lambda name: "e" * 64 if name == "ingest" else real(name)
    )
    with pytest.raises(WorkspaceError, match="ingest outputs are stale .*made by other code"):
        run_stage(POSE, ws, other, log_id=log_id, overwrite=True)
