"""The one way a file is replaced whole: written aside under a hidden name, fsynced, renamed.

A reader sees the old file or the new one, never a half-written one; a run killed while
writing leaves only a hidden file naming its host and process, which the next run on that
host removes once the process is gone (:func:`remove_dead_temp_files`). Tables go through
:class:`toolkit.tableio.TableWriter` and whole log folders through
:mod:`toolkit.generations`, both built on these.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import re
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from toolkit.errors import WorkspaceError


def host_name() -> str:
    """This host's name as it appears in hidden file names (letters, digits, ``_``)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname()) or "host"


def fsync_dir(directory: Path) -> None:
    """fsync a directory, so renames in it survive a power cut; best effort, since some
    file systems cannot fsync a directory (EINVAL), and a rename there is all there is."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: Hidden files written aside: ``.<name>.<host>-<pid>-<random>.<suffix>``.
_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<host>[^.]+)-(?P<pid>\d+)-[0-9a-f]{12}\.[a-z]+$")


def temp_path_beside(path: Path, suffix: str = "tmp") -> Path:
    """A fresh hidden name beside ``path`` for writing aside, naming the host and process
    that writes it (``.<name>.<host>-<pid>-<random>.<suffix>``), so a later run can tell
    the files of a dead run from those of a live one (:func:`remove_dead_temp_files`)."""
    return path.with_name(
        f".{path.name}.{host_name()}-{os.getpid()}-{uuid.uuid4().hex[:12]}.{suffix}"
    )


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's live process
    return True


def remove_dead_temp_files(directory: Path) -> list[str]:
    """Remove the hidden files that runs on this host left behind when they were killed
    (their process no longer exists); files of live runs, and of other hosts sharing the
    workspace, are left alone. Returns the names removed."""
    removed: list[str] = []
    if not directory.is_dir():
        return removed
    host = host_name()
    for entry in directory.iterdir():
        m = _TEMP_NAME.match(entry.name)
        if m is None or m["host"] != host or _pid_alive(int(m["pid"])):
            continue
        with contextlib.suppress(FileNotFoundError):
            entry.unlink()
            removed.append(entry.name)
    return removed


def fsync_file(path: Path) -> None:
    """Flush a written file's data to the disk, so a rename after it cannot publish a file
    whose bytes a crash would lose."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


#: Linux renameat2(2): paths relative to the working directory; swap the two names.
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap two existing paths in one atomic step, so a reader of either name sees the old
    entry or the new one, never neither (Linux ``renameat2(RENAME_EXCHANGE)``, called
    through ctypes: Python's os module has no exchange). Used to replace a whole directory,
    which ``os.replace`` cannot do unless the target is empty.

    Returns False, changing nothing, where the C library, kernel or file system cannot
    exchange (no ``renameat2``; EINVAL, ENOSYS, EOPNOTSUPP): the caller then falls back to
    two renames. Any other failure is an OSError naming ``b``."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_uint,
    ]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is fsynced and renamed over it.

    On any exception the temporary file is removed and ``path`` is left as it was, so a
    reader never sees a half-written file. Parent directories are created as needed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_beside(path)
    try:
        yield tmp
        if not tmp.exists():
            raise WorkspaceError("nothing was written to the temporary file", path=tmp)
        fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    fsync_dir(path.parent)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (write aside, fsync, rename)."""
    path = Path(path)
    try:
        with atomic_output(path) as tmp, tmp.open("wb") as fh:
            fh.write(data)
    except OSError as exc:
        raise WorkspaceError(f"cannot write: {exc.strerror or exc}", path=path) from exc


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented, key-sorted JSON atomically."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n")


__all__ = [
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "exchange_paths",
    "fsync_dir",
    "fsync_file",
    "host_name",
    "remove_dead_temp_files",
    "temp_path_beside",
]
