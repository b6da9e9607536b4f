"""One JSON contract for every verb (docs/json.md): with --json, one document on stdout in
success and in failure, ``ok`` first, errors as ``{"kind", "message", "path"}``, statuses
spelled one way, no NaN token."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from toolkit.cli import main

from .helpers import SAMPLE_LOG

VERBS_ON_A_WORKSPACE = ["pose", "project", "label", "tables", "learn", "evaluate", "logs"]


def _document(stdout: str) -> dict[str, object]:
    """The one document on stdout: strict JSON (a NaN token would not parse)."""

    def refuse(token: str) -> None:
        raise ValueError(f"non-strict JSON token {token}")

    doc = json.loads(stdout, parse_constant=refuse)
    assert isinstance(doc, dict) and next(iter(doc)) == "ok"
    return doc


@pytest.mark.parametrize(
    "args",
    [
        *([verb, "-w", "{tmp}/nope"] for verb in VERBS_ON_A_WORKSPACE),
        ["export", "-w", "{tmp}/nope", "--out", "{tmp}/out"],
        ["viz", "-w", "{tmp}/nope", "--log", "x", "--out", "{tmp}/v.mcap"],
        ["ingest", "{tmp}/nope.mcap", "-w", "{tmp}/ws"],
        ["run", "{tmp}/nope.mcap", "-w", "{tmp}/ws"],
        ["info", "{tmp}/nope.mcap"],
        ["config", "init", "{tmp}/nope.mcap"],
    ],
    ids=lambda a: a[0] if a[0] != "config" else "config-init",
)
def test_a_failure_is_one_document_naming_the_error(
    runner: CliRunner, tmp_path: Path, args: list[str]
) -> None:
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args] + ["--json"]
    result = runner.invoke(main, argv)
    assert result.exit_code == 1, result.output
    doc = _document(result.stdout)
    assert doc["ok"] is False and doc["exit_code"] == 1
    error = doc["error"]
    assert isinstance(error, dict) and error["kind"] == "input"
    assert "nope" in str(error["message"]) and "nope" in str(error["path"])
    assert result.stderr.startswith("terrain: error: ")  # said to a person too


@pytest.mark.parametrize(
    "args",
    [
        ["sim", "x.mcap", "--distance-m", "5"],
        ["run", "x.mcap", "-w", "ws", "--from", "learn", "--to", "tables"],
    ],
    ids=["sim", "run"],
)
def test_a_usage_error_is_a_document_too(runner: CliRunner, args: list[str]) -> None:
    result = runner.invoke(main, [*args, "--json"])
    assert result.exit_code == 2
    doc = _document(result.stdout)
    assert doc["ok"] is False and doc["exit_code"] == 2
    assert doc["error"]["kind"] == "usage"  # type: ignore[index]


def test_successes_are_documents_with_ok_first(runner: CliRunner, tmp_path: Path) -> None:
    """info, config init and logs (the verbs that need no finished run; the others' are
    checked on the shared pipeline in tests/test_listing.py)."""
    info = _document(runner.invoke(main, ["info", str(SAMPLE_LOG), "--json"]).stdout)
    assert info["ok"] is True and info["topics"]
    out = tmp_path / "robot.toml"
    result = runner.invoke(main, ["config", "init", str(SAMPLE_LOG), "--out", str(out), "--json"])
    init = _document(result.stdout)
    assert init["ok"] is True and init["out"] == str(out)
    assert init["toml"] == out.read_text()
    ingest = runner.invoke(main, ["ingest", str(SAMPLE_LOG), "-w", str(tmp_path / "ws"), "--json"])
    assert _document(ingest.stdout)["logs"][0]["status"] == "ingested"  # type: ignore[index]
    again = runner.invoke(main, ["ingest", str(SAMPLE_LOG), "-w", str(tmp_path / "ws"), "--json"])
    # One spelling of a status in every verb's document.
    assert _document(again.stdout)["logs"][0]["status"] == "up_to_date"  # type: ignore[index]
    listing = _document(runner.invoke(main, ["logs", "-w", str(tmp_path / "ws"), "--json"]).stdout)
    assert listing["ok"] is True and len(listing["logs"]) == 1  # type: ignore[arg-type]
