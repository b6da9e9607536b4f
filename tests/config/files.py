"""Paths and a writer of user configuration files, shared by the config tests."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PIPELINE = REPO / "pipelines" / "stanley2005.toml"
PACKAGED = REPO / "toolkit" / "default_config.toml"


def write(tmp_path: Path, text: str, name: str = "user.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path
