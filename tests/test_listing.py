"""``terrain logs``: a workspace's logs and stages, from the manifests."""

from __future__ import annotations

import json
from pathlib import Path

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
        assert doc["stage"] == verb and doc["status"] == "up_to_date"
        assert doc["record"]["row_counts"] and doc["summary"]
    source = json.loads(runner.invoke(main, ["logs", "-w", ws, "--json"]).stdout)["logs"][0]
    result = runner.invoke(main, ["ingest", source["source"], "-w", ws, "--json"])
    assert result.exit_code == 0, result.output
    (outcome,) = json.loads(result.stdout)["logs"]
    assert outcome == {
        "log": source["source"], "status": "up to date", "log_id": log_id, "error": None,
    }  # fmt: skip
