"""Fixtures of the export's tests: the workspace is the pipeline run ``test_learn.py`` builds
(label, tables, learn, evaluate on the projected sample, once per session, see
:func:`tests.stages.test_learn.build_pipeline`), exported once per test module."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pytest

from tests.publish.exported import expected_rows
from tests.stages.test_learn import Pipeline
from toolkit.config import PipelineConfig
from toolkit.publish.export import ExportResult, run_export


@pytest.fixture(scope="module")
def config(pipeline: Pipeline) -> PipelineConfig:
    return pipeline.ws.read_config()


@pytest.fixture(scope="module")
def exported(
    pipeline: Pipeline, config: PipelineConfig, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, ExportResult]:
    """The export of the shared pipeline's workspace (into a folder that does not exist)."""
    out = tmp_path_factory.mktemp("export") / "dataset"
    return out, run_export(pipeline.ws, out, config)


@pytest.fixture(scope="module")
def expected(pipeline: Pipeline) -> dict[str, dict[str, pa.Table]]:
    """The rows the export of the shared pipeline's workspace must hold
    (:func:`expected_rows`)."""
    return expected_rows(pipeline.ws)


@pytest.fixture()
def hf_offline(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Path]:
    """``datasets`` kept off the network and out of the home directory; yields its cache."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))
    yield tmp_path / "hf_cache"
