"""``terrain logs``: a workspace's logs and stages, from the manifests."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from tests.stages.test_learn import Pipeline
from toolkit.cli import main
from toolkit.workspace import Workspace


def test_logs_lists_each_log_its_source_stages_and_rows(pipeline: Pipeline) -> None:
    runner = CliRunner()
    result = runner.invoke(main, ["logs", "-w", str(pipeline.ws.root), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    (entry,) = doc["logs"]
    assert entry["log_id"] == pipeline.ws.log_ids()[0]
    assert entry["source"].endswith(".mcap") and entry["size_bytes"] > 0
    assert entry["stages"] == ["ingest", "pose", "project", "label"]
    assert entry["rows"]["events"] > 0 and entry["rows"]["points"] > 0
    assert set(doc["workspace_stages"]) >= {"tables", "learn"}
    text = runner.invoke(main, ["logs", "-w", str(pipeline.ws.root)]).stdout
    assert entry["log_id"] in text and "ingest pose project label" in text


def test_an_empty_workspace_says_so_and_no_workspace_is_one_line(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")
    runner = CliRunner()
    result = runner.invoke(main, ["logs", "-w", str(ws.root)])
    assert result.exit_code == 0 and "no log yet" in result.stdout
    result = runner.invoke(main, ["logs", "-w", str(tmp_path / "nope")])
    assert result.exit_code == 1 and "no such workspace directory" in result.stderr


def test_every_stage_verb_prints_json_a_script_reads(pipeline: Pipeline) -> None:
    """``--json`` on ingest, the per-log stages and the workspace stages: one JSON document
    on stdout with each log's (or the stage's) status and manifest record."""
    runner = CliRunner()
    ws = str(pipeline.ws.root)
    log_id = pipeline.ws.log_ids()[0]
    for verb in ("pose", "project", "label"):
        result = runner.invoke(main, [verb, "-w", ws, "--json"])
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        (entry,) = doc["logs"]
        assert doc["stage"] == verb and entry["log_id"] == log_id
        assert entry["status"] == "up_to_date" and entry["record"]["row_counts"]
    for verb in ("tables", "learn", "evaluate"):
        result = runner.invoke(main, [verb, "-w", ws, "--json"])
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        assert doc["stage"] == verb and doc["status"] == "up_to_date" and doc["ok"] is True
        assert doc["record"]["row_counts"] and doc["summary"]
    # The verbs that write outside the workspace: their result, its summary, ok first.
    out = pipeline.ws.root.parent / "json-out"
    out.mkdir(exist_ok=True)
    for args in (
        ["export", "-w", ws, "--out", str(out / "dataset"), "--overwrite"],
        ["viz", "-w", ws, "--log", log_id, "--out", str(out / "view.mcap"), "--overwrite"],
    ):
        result = runner.invoke(main, [*args, "--json"])
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        assert list(doc)[0] == "ok" and doc["ok"] is True and doc["summary"]
        assert Path(doc.get("out_dir") or doc["out_path"]).exists()
    source = json.loads(runner.invoke(main, ["logs", "-w", ws, "--json"]).stdout)["logs"][0]
    result = runner.invoke(main, ["ingest", source["source"], "-w", ws, "--json"])
    assert result.exit_code == 0, result.output
    (outcome,) = json.loads(result.stdout)["logs"]
    assert outcome == {
        "log": source["source"], "status": "up_to_date", "log_id": log_id, "error": None,
    }  # fmt: skip


def _current(
    ws: Workspace, stage: str, inputs: dict[str, str], rows: dict[str, int] | None = None
) -> Any:
    """The record a run of ``stage`` by this code with ``ws``'s configuration leaves."""
    from toolkit.manifest import StageRecord
    from toolkit.stages.registry import stage as registered
    from toolkit.stages.runner import code_version_for

    spec = registered(stage)
    config = ws.read_config()
    return StageRecord(
        inputs,
        spec.config_hash(config),
        row_counts=rows or {},
        code_version=code_version_for(spec),
        config_sections=spec.hashed_sections(config),
    )


def _tiny_workspace(tmp_path: Path) -> tuple[Workspace, Path]:
    """A workspace of one log whose manifest records an ingest and a pose (no table: the
    listing reads manifests only); the workspace and that manifest's path."""
    from toolkit.manifest import Manifest

    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")
    ws.log_dir("tiny-0123456789ab").mkdir()
    manifest = Manifest(ws.log_manifest_path("tiny-0123456789ab"))
    manifest.set_header(source={"path": str(tmp_path / "tiny.mcap"), "size_bytes": 1234})
    for stage, rows in (("ingest", {"imu": 10}), ("pose", {"pose": 7})):
        manifest.record_stage(stage, _current(ws, stage, {"log": "aa" * 32}, rows))
    return ws, manifest.path


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ('"size_bytes": 1234', '"size_bytes": NaN', "source.size_bytes"),
        ('"size_bytes": 1234', '"size_bytes": Infinity', "source.size_bytes"),
        ('"pose": 7', '"pose": Infinity', "stages.pose.row_counts.pose"),
        ('"size_bytes": 1234', '"size_bytes": "big"', "source.size_bytes"),
    ],
)
def test_a_tampered_number_in_a_manifest_is_one_line_naming_the_file_and_field(
    tmp_path: Path, old: str, new: str, field: str
) -> None:
    """``terrain logs``, as a table or as JSON: exit 1 and one line naming the manifest and
    the field, as for a manifest that is not JSON; never an internal error, never a NaN
    token in the JSON."""
    ws, manifest = _tiny_workspace(tmp_path)
    runner = CliRunner()
    good = runner.invoke(main, ["logs", "-w", str(ws.root), "--json"])
    assert good.exit_code == 0 and json.loads(good.stdout)["logs"][0]["size_bytes"] == 1234
    manifest.write_text(manifest.read_text().replace(old, new))
    for extra in ([], ["--json"]):
        result = runner.invoke(main, ["logs", "-w", str(ws.root), *extra])
        assert result.exit_code == 1, result.output
        if extra:  # the failure's one document (docs/json.md)
            doc = json.loads(result.stdout)
            assert doc["ok"] is False and field in doc["error"]["message"]
        else:
            assert result.stdout == ""
        (line,) = result.stderr.splitlines()
        assert str(manifest) in line and field in line and "internal error" not in line


def test_a_log_whose_folder_is_gone_is_listed_missing_not_no_log_yet(tmp_path: Path) -> None:
    """``WS/logs/<id>`` pointing to a generation removed by hand: the listing names that
    folder as missing (on the terminal too), shows none of the log's stages done (its
    manifest went with it) and the workspace's stages as recorded; never "no log yet"."""
    from tests.test_workspace import _dangling

    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")
    target = _dangling(ws, "gone-0123456789ab")

    ws.manifest().record_stage(
        "tables",
        _current(ws, "tables", {"gone-0123456789ab/events": "aa"}),
    )
    runner = CliRunner()
    result = runner.invoke(main, ["logs", "-w", str(ws.root)])
    assert result.exit_code == 0, result.output
    assert "no log yet" not in result.stdout
    (row,) = [line for line in result.stdout.splitlines() if line.startswith("gone-")]
    assert f"MISSING: {target}" in row and "ingest" not in row
    assert "workspace: tables 20" in result.stdout
    assert "the log's folder is missing" in result.stderr and str(target) in result.stderr
    doc = json.loads(runner.invoke(main, ["logs", "-w", str(ws.root), "--json"]).stdout)
    (entry,) = doc["logs"]
    assert entry["missing"] == str(target) and entry["stages"] == []
    assert list(doc["workspace_stages"]) == ["tables"]


def test_no_log_left_but_workspace_stages_recorded_says_both(tmp_path: Path) -> None:

    ws = Workspace(tmp_path / "ws").create()
    ws.config_path.write_text("")

    ws.manifest().record_stage("learn", _current(ws, "learn", {}))
    result = CliRunner().invoke(main, ["logs", "-w", str(ws.root)])
    assert result.exit_code == 0 and "no log yet" not in result.stdout
    assert "no log in logs/" in result.stdout and "learn 20" in result.stdout


def test_a_stage_whose_output_is_gone_or_whose_code_changed_is_listed_stale(
    tmp_path: Path,
) -> None:
    """``terrain logs`` marks a recorded stage stale, saying why, when an output it wrote
    is gone or another version of its code made it (a record without a code version
    included); a stage with its outputs there, made by this code, is not."""
    import dataclasses

    from toolkit.manifest import Manifest
    from toolkit.stages.registry import stage
    from toolkit.stages.runner import code_version_for

    ws, path = _tiny_workspace(tmp_path)
    manifest = Manifest(path)
    log_dir = path.parent
    (log_dir / "pose.parquet").write_bytes(b"x")
    for name in ("ingest", "pose"):
        record = manifest.stage(name)
        assert record is not None
        outputs = ("pose.parquet",) if name == "pose" else ("imu.parquet",)
        manifest.record_stage(
            name,
            dataclasses.replace(
                record, outputs=outputs, code_version=code_version_for(stage(name))
            ),
        )
    ws.manifest().record_stage(
        "learn", dataclasses.replace(record, outputs=(), inputs={}, code_version="")
    )
    runner = CliRunner()
    doc = json.loads(runner.invoke(main, ["logs", "-w", str(ws.root), "--json"]).stdout)
    (entry,) = doc["logs"]
    assert entry["stale"] == {"ingest": "output missing: imu.parquet"}
    assert doc["workspace_stale"] == {"learn": "made by a toolkit that recorded no code version"}
    text = runner.invoke(main, ["logs", "-w", str(ws.root)]).stdout
    assert "ingest* pose" in text and "learn* " in text
    assert "tiny-0123456789ab ingest: output missing: imu.parquet" in text
    # Made by another code: a pose recorded with another version.
    pose = manifest.stage("pose")
    assert pose is not None
    manifest.record_stage("pose", dataclasses.replace(pose, code_version="0" * 64))
    doc = json.loads(runner.invoke(main, ["logs", "-w", str(ws.root), "--json"]).stdout)
    assert doc["logs"][0]["stale"]["pose"].startswith("made by other code")
    # Made with another configuration: the workspace's is now another ([pose] changed, as
    # `ingest --overwrite -c new.toml` leaves the other logs).
    manifest.record_stage(
        "pose", dataclasses.replace(pose, code_version=code_version_for(stage("pose")))
    )
    cfg = ws.read_config()
    noisier = dataclasses.replace(cfg.pose, gps_noise_m=cfg.pose.gps_noise_m * 2)
    ws.write_config(dataclasses.replace(cfg, pose=noisier))
    doc = json.loads(runner.invoke(main, ["logs", "-w", str(ws.root), "--json"]).stdout)
    assert doc["logs"][0]["stale"]["pose"] == (
        "made with another configuration than the workspace's"
    )
