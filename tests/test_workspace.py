"""Tests of toolkit.workspace: log ids, the configuration in force, the lock, its logs."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.test_manifest import _record
from toolkit.atomic import atomic_write_bytes
from toolkit.config import default_config
from toolkit.errors import ConfigError, WorkspaceError
from toolkit.manifest import digest_files
from toolkit.workspace import Workspace, log_id_for, make_log_id

# -- hashing and log ids ------------------------------------------------------------------


def test_log_id_is_stable_and_content_derived(tmp_path: Path) -> None:
    a = tmp_path / "race day.mcap"
    a.write_bytes(b"one")
    sha = hashlib.sha256(b"one").hexdigest()
    assert log_id_for(a) == f"race_day-{sha[:12]}"
    assert log_id_for(a) == log_id_for(a)
    copy = tmp_path / "sub" / "race day.mcap"
    copy.parent.mkdir()
    copy.write_bytes(b"one")
    assert log_id_for(copy) == log_id_for(a)  # where it lives does not matter
    b = tmp_path / "other" / "race day.mcap"
    b.parent.mkdir()
    b.write_bytes(b"two")
    assert log_id_for(b) != log_id_for(a)  # same name, different content


def test_make_log_id_sanitises_stem() -> None:
    sha = "ABCDEF0123456789" * 4
    assert make_log_id("../../etc/passwd", sha) == "etc_passwd-abcdef012345"
    assert make_log_id("///", sha) == "log-abcdef012345"
    assert "/" not in make_log_id("a/b", sha)


# -- atomic writes ------------------------------------------------------------------------


# -- manifest -----------------------------------------------------------------------------


def test_workspace_is_up_to_date_uses_log_manifest(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    out = ws.log_table("L1", "imu")
    kwargs = {"inputs": {"log": "aa" * 32}, "config_hash": "cc" * 32, "outputs": [out]}
    assert not ws.is_up_to_date("ingest", log_id="L1", **kwargs)  # type: ignore[arg-type]
    atomic_write_bytes(out, b"parquet")
    ws.manifest("L1").record_stage(
        "ingest", _record(output_files=digest_files(out.parent, ["imu.parquet"]))
    )
    assert ws.is_up_to_date("ingest", log_id="L1", **kwargs)  # type: ignore[arg-type]
    assert not ws.is_up_to_date("ingest", log_id=None, **kwargs)  # type: ignore[arg-type]


# -- workspace paths, config, lock ------------------------------------------------------


def test_workspace_config_round_trip_and_require(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    with pytest.raises(WorkspaceError, match="no such workspace"):
        ws.require()
    ws.create()
    with pytest.raises(WorkspaceError, match="not a workspace"):
        ws.read_config()
    ws.write_config(default_config())
    assert ws.read_config() == default_config()
    ws.config_path.write_text("[label]\nfir_tap = 3\n")
    with pytest.raises(ConfigError, match="label.fir_tap"):
        ws.read_config()


def test_log_ids_lists_directories(tmp_path: Path) -> None:
    ws = Workspace(tmp_path).create()
    assert ws.log_ids() == []
    (ws.logs_dir / "b-1").mkdir()
    (ws.logs_dir / "a-2").mkdir()
    (ws.logs_dir / "stray.txt").write_text("")
    assert ws.log_ids() == ["a-2", "b-1"]


def test_lock_is_exclusive_within_a_process(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    with ws.lock(), pytest.raises(WorkspaceError, match=rf"in use .*pid {os.getpid()}"):
        ws.lock().acquire()
    with ws.lock():  # released: can be taken again
        pass


def test_lock_held_by_another_process(tmp_path: Path) -> None:
    ws = Workspace(tmp_path)
    holder = textwrap.dedent(
        f"""
        import sys, time
        from toolkit.workspace import Workspace
        with Workspace({str(tmp_path)!r}).lock():
            print("locked", flush=True)
            sys.stdin.readline()
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", holder], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        with pytest.raises(WorkspaceError, match=f"pid {proc.pid}") as info:
            ws.lock().acquire()
        assert info.value.path == tmp_path
    finally:
        assert proc.stdin is not None
        proc.stdin.write("\n")
        proc.stdin.close()
        proc.wait(30)
    with ws.lock():
        pass


def test_shared_locks_coexist_and_exclude_an_exclusive_one(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    with (
        ws.lock(shared=True),  # two ingests side by side...
        ws.lock(shared=True),
        pytest.raises(WorkspaceError, match="in use by another terrain process"),
    ):
        ws.lock().acquire()  # ...and a pose is refused while they run
    with ws.lock(), pytest.raises(WorkspaceError, match=rf"pid {os.getpid()}"):
        ws.lock(shared=True).acquire()  # an ingest is refused while a pose runs


def test_ingest_honours_the_lock_a_pose_holds(tmp_path: Path) -> None:
    from toolkit.batch import Executors, run_ingest_batch

    ws = Workspace(tmp_path / "ws")
    sample = Path(__file__).resolve().parents[1] / "sample_logs" / "sample.mcap"
    with ws.lock(), pytest.raises(WorkspaceError, match="in use"):
        run_ingest_batch([sample], ws.root, None, overwrite=False, executors=Executors(workers=1))
    assert not ws.log_ids()


def test_created_takes_away_only_an_unused_fresh_workspace(tmp_path: Path) -> None:
    """Fresh and left without a log: removed. Fresh but holding a file the toolkit did not
    write, or a lock another process holds: kept."""
    import fcntl
    import os

    ws = Workspace(tmp_path / "a")
    with ws.created():
        (ws.logs_dir / ".x-1.lock").touch()  # a failed ingest's log lock
    assert not ws.root.exists()

    ws = Workspace(tmp_path / "b")
    with ws.created():
        (ws.root / "theirs.txt").write_text("x")
    assert (ws.root / "theirs.txt").is_file()

    ws = Workspace(tmp_path / "c")
    with ws.created():
        held = ws.logs_dir / ".y-2.lock"
        held.touch()
        fd = os.open(held, os.O_RDONLY)
        fcntl.flock(fd, fcntl.LOCK_EX)  # another shard's ingest is still at work
    try:
        assert held.is_file()
    finally:
        os.close(fd)


def test_an_unknown_log_is_refused_naming_the_logs_there(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    with pytest.raises(WorkspaceError, match="has no log yet"):
        ws.require_log("a-1")
    for name in ("b-2", "a-1"):
        (ws.logs_dir / name).mkdir()
    assert ws.require_log("a-1") == ws.log_dir("a-1")
    with pytest.raises(WorkspaceError, match="no log 'c-3' in the workspace; its logs: a-1, b-2"):
        ws.require_log("c-3")


def _dangling(ws: Workspace, log_id: str) -> Path:
    """A log committed as a stage commits one, then its generation removed by hand: the
    link ``WS/logs/<log_id>`` points to nothing. The folder it points to."""
    with ws.change_log(log_id) as gen:
        (gen.path / "manifest.json").write_text('{"format": 1, "stages": {}}')
        gen.commit()
    target = ws.logs_dir / os.readlink(ws.log_dir(log_id))
    for entry in target.iterdir():
        entry.unlink()
    target.rmdir()
    return target


def test_a_log_whose_link_points_to_nothing_is_missing_and_said_so(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws").create()
    (ws.logs_dir / "a-1").mkdir()
    target = _dangling(ws, "b-2")
    assert ws.log_ids() == ["a-1"]
    assert ws.missing_logs() == {"b-2": target}
    with pytest.raises(WorkspaceError, match="the log's folder is missing") as err:
        ws.require_log("b-2")
    assert str(target) in str(err.value) and str(ws.log_dir("b-2")) in str(err.value)
