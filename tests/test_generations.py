"""Generations of a log's directory: all or nothing, hard links, recovery, one writer."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from toolkit.generations import current_generation, open_generation


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_nothing_is_visible_until_commit_and_a_discard_leaves_no_trace(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    with open_generation(logs, "a") as gen:
        (gen.path / "x.parquet").write_bytes(b"1")
        assert not (logs / "a").exists()
    assert not (logs / "a").exists()
    assert [p.name for p in logs.iterdir()] == [".a.lock"]
    with open_generation(logs, "a") as gen:
        (gen.path / "x.parquet").write_bytes(b"1")
        gen.commit()
    assert (logs / "a").is_symlink() and _files(logs / "a") == {"x.parquet": b"1"}


def test_a_new_generation_links_the_old_files_and_replacing_one_spares_the_old(
    tmp_path: Path,
) -> None:
    logs = tmp_path / "logs"
    with open_generation(logs, "a") as gen:
        (gen.path / "x.parquet").write_bytes(b"old")
        (gen.path / "y.parquet").write_bytes(b"kept")
        gen.commit()
    old_dir = current_generation(logs, "a")
    assert old_dir is not None
    with open_generation(logs, "a") as gen:
        assert os.stat(gen.path / "y.parquet").st_ino == os.stat(old_dir / "y.parquet").st_ino
        tmp = gen.path / ".x.tmp"
        tmp.write_bytes(b"new")
        os.replace(tmp, gen.path / "x.parquet")  # how every writer of the toolkit replaces
        assert _files(logs / "a") == {"x.parquet": b"old", "y.parquet": b"kept"}
        gen.commit()
    assert _files(logs / "a") == {"x.parquet": b"new", "y.parquet": b"kept"}
    assert not old_dir.exists()  # the replaced generation is gone


def test_a_plain_directory_from_before_generations_is_taken_over(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    (logs / "a").mkdir(parents=True)
    (logs / "a" / "x.parquet").write_bytes(b"old")
    with open_generation(logs, "a") as gen:
        (gen.path / "z.parquet").write_bytes(b"z")
        gen.commit()
    assert (logs / "a").is_symlink()
    assert _files(logs / "a") == {"x.parquet": b"old", "z.parquet": b"z"}
    assert sorted(p.name for p in logs.iterdir() if not p.name.endswith((".gen", ".lock"))) == ["a"]


def test_a_commit_killed_between_its_two_renames_recovers_the_old_state(tmp_path: Path) -> None:
    """The one non-atomic step (a plain directory moved aside, the link not yet in place)
    is undone by the next change: the old directory goes back."""
    logs = tmp_path / "logs"
    (logs / "a").mkdir(parents=True)
    (logs / "a" / "x.parquet").write_bytes(b"old")
    dead = _dead_pid()
    aside = logs / f".a.{_host()}-{dead}-0123456789ab.old"
    os.rename(logs / "a", aside)  # what the killed commit had done
    orphan = logs / f".a.{_host()}-{dead}-0123456789ac.gen"
    orphan.mkdir()  # and the generation it was publishing
    foreign = logs / ".a.otherhost-1-0123456789ad.gen"
    foreign.mkdir()  # another host's, maybe alive (network file system): left alone
    with open_generation(logs, "a") as gen:
        assert _files(logs / "a") == {"x.parquet": b"old"}
        assert _files(gen.path) == {"x.parquet": b"old"}
    assert not aside.exists() and not orphan.exists() and foreign.exists()


def _host() -> str:
    import re
    import socket

    return re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname())


def _dead_pid() -> int:
    import subprocess
    import sys

    child = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    return int(child.stdout)


def test_interrupted_just_after_the_switch_the_log_is_the_new_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import toolkit.generations as generations

    logs = tmp_path / "logs"
    with open_generation(logs, "a") as gen:
        (gen.path / "x").write_bytes(b"old")
        gen.commit()

    def interrupted(directory: Path) -> None:
        if directory == logs:
            raise KeyboardInterrupt

    monkeypatch.setattr(generations, "fsync_dir", interrupted)
    with pytest.raises(KeyboardInterrupt), open_generation(logs, "a") as gen:
        (gen.path / "x").unlink()
        (gen.path / "x").write_bytes(b"new")
        gen.commit()
    monkeypatch.undo()
    assert _files(logs / "a") == {"x": b"new"}
    with open_generation(logs, "a"):
        pass
    assert _files(logs / "a") == {"x": b"new"}


def test_a_log_whose_id_extends_another_is_left_alone(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    for log_id in ("a", "a.b"):
        with open_generation(logs, log_id) as gen:
            (gen.path / "x").write_bytes(log_id.encode())
            gen.commit()
    for _ in range(2):
        with open_generation(logs, "a"):
            pass
    assert _files(logs / "a.b") == {"x": b"a.b"} and _files(logs / "a") == {"x": b"a"}


def test_a_link_to_nothing_is_pointed_at_the_newest_generation(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    with open_generation(logs, "a") as gen:
        (gen.path / "x").write_bytes(b"1")
        gen.commit()
    target = (logs / "a").resolve()
    kept = logs / f".a.{_host()}-{_dead_pid()}-0123456789ab.gen"
    os.rename(target, kept)  # the link now points at nothing
    with open_generation(logs, "a"):
        pass
    assert _files(logs / "a") == {"x": b"1"}


def test_two_changes_of_one_log_take_turns(tmp_path: Path) -> None:
    """The second waits for the first to commit and starts from its result: nothing lost."""
    logs = tmp_path / "logs"
    order: list[str] = []
    first_open = threading.Event()

    def first() -> None:
        with open_generation(logs, "a") as gen:
            first_open.set()
            time.sleep(0.3)
            (gen.path / "one").write_bytes(b"1")
            gen.commit()
            order.append("first")

    t = threading.Thread(target=first)
    t.start()
    first_open.wait()
    with open_generation(logs, "a") as gen:
        order.append("second")
        (gen.path / "two").write_bytes(b"2")
        gen.commit()
    t.join()
    assert order == ["first", "second"]
    assert _files(logs / "a") == {"one": b"1", "two": b"2"}


def test_an_unwritable_workspace_is_one_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A read-only file system (simulated: tests run as root, whom permissions do not stop)
    is a WorkspaceError naming the directory, not an internal error."""
    import errno

    from toolkit.errors import WorkspaceError

    logs = tmp_path / "logs"
    logs.mkdir()

    def read_only(self: Path, *args: object, **kwargs: object) -> None:
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    with (
        pytest.raises(WorkspaceError, match="Read-only file system") as err,
        open_generation(logs, "a"),
    ):
        pass
    assert str(logs) in str(err.value)
