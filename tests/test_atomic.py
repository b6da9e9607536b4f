"""Tests of toolkit.atomic: files replaced whole, and what killed runs leave behind."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from toolkit.atomic import (
    atomic_output,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    exchange_paths,
    remove_dead_temp_files,
    temp_path_beside,
)
from toolkit.errors import WorkspaceError


def test_atomic_write_creates_and_replaces(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "dir" / "file.txt"
    atomic_write_text(path, "first")
    atomic_write_bytes(path, b"second")
    assert path.read_bytes() == b"second"
    assert sorted(p.name for p in path.parent.iterdir()) == ["file.txt"]


def test_atomic_write_json(tmp_path: Path) -> None:
    atomic_write_json(tmp_path / "x.json", {"b": 1, "a": [1.5]})
    assert json.loads((tmp_path / "x.json").read_text()) == {"a": [1.5], "b": 1}


def test_atomic_output_failure_leaves_old_file_and_no_temp(tmp_path: Path) -> None:
    path = tmp_path / "table.parquet"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_output(path) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("writer died")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.parquet"]


def test_atomic_output_failure_leaves_nothing_when_new(tmp_path: Path) -> None:
    path = tmp_path / "new.bin"
    with pytest.raises(KeyboardInterrupt), atomic_output(path) as tmp:
        tmp.write_bytes(b"half")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_atomic_output_requires_a_written_file(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="nothing was written"), atomic_output(tmp_path / "x"):
        pass
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_maps_os_errors(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a dir")
    with pytest.raises(WorkspaceError, match="cannot write"):
        atomic_write_bytes(blocker / "inside.txt", b"x")


def test_temp_files_of_dead_runs_are_removed_not_those_of_live_ones(tmp_path: Path) -> None:
    target = tmp_path / "imu.parquet"
    mine = temp_path_beside(target, "partial")  # this (live) process's
    mine.write_bytes(b"live")
    child = subprocess.run(  # a process that has exited since: its file is an orphan
        [
            sys.executable,
            "-c",
            "import sys; from pathlib import Path; from toolkit.atomic import "
            "temp_path_beside; p = temp_path_beside(Path(sys.argv[1]), 'partial'); "
            "p.write_bytes(b'dead'); print(p.name)",
            str(target),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    dead = tmp_path / child.stdout.strip()
    other_host = tmp_path / ".imu.parquet.otherhost-1-0123456789ab.partial"
    other_host.write_bytes(b"?")
    (tmp_path / "imu.parquet").write_bytes(b"real")
    assert dead.exists()
    assert remove_dead_temp_files(tmp_path) == [dead.name]
    assert mine.exists() and other_host.exists() and not dead.exists()
    assert (tmp_path / "imu.parquet").read_bytes() == b"real"


def test_exchange_paths_swaps_two_directories_or_changes_nothing(tmp_path: Path) -> None:
    """Two full directories trade names in one step; where the system cannot exchange, it
    says so (False) and both are as they were. A missing path is an OSError naming it."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "from_a").write_text("a")
    (b / "from_b").write_text("b")
    if exchange_paths(a, b):
        assert [p.name for p in a.iterdir()] == ["from_b"]
        assert [p.name for p in b.iterdir()] == ["from_a"]
        with pytest.raises(OSError, match="missing"):
            exchange_paths(a, tmp_path / "missing")
    else:
        assert [p.name for p in a.iterdir()] == ["from_a"]
        assert [p.name for p in b.iterdir()] == ["from_b"]
