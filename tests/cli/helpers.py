"""What the command line's tests share: the repository's files, one-line errors, a fake
simulator."""

from __future__ import annotations

import sys
import types
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE_LOG = REPO / "sample_logs" / "sample.mcap"


def assert_one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("terrain: error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


class FakeResult:
    def summary(self) -> str:
        return "wrote 1200 m, 5 lasers"


def fake_sim_module(monkeypatch: pytest.MonkeyPatch, simulate: Any) -> None:
    module = types.ModuleType("toolkit.sim.simulate")
    module.simulate = simulate  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "toolkit.sim.simulate", module)
