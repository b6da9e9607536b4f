"""All-or-nothing changes to a log's directory: generations and one atomic switch.

``WS/logs/<log_id>`` is a symbolic link to a hidden *generation* directory beside it,
``WS/logs/.<log_id>.<host>-<pid>-<random>.gen``. A stage that changes a log never writes
into the current generation. It opens a new one (:func:`open_generation`) holding hard links
to every file of the current one, writes and replaces files there, and commits
(:meth:`Generation.commit`) by pointing the link at the new generation with a single
``rename(2)``, which POSIX makes atomic; the old generation is removed after. Whenever the
writer is killed, a reader of ``WS/logs/<log_id>`` therefore sees the old directory or the
new one, never a mixture of the two; what a killed writer leaves is a hidden generation that
the next change of that log removes.

Why hard links: opening a generation costs one directory entry per file instead of a copy
of gigabytes of tables, and since every writer of the toolkit replaces a file by renaming a
new one over it (:class:`toolkit.tableio.TableWriter`, :func:`toolkit.atomic.atomic_output`)
and never writes into an existing file, a file shared by two generations is never changed
under the other.

One change of a log at a time: :func:`open_generation` holds an exclusive ``flock`` on
``WS/logs/.<log_id>.lock`` until the generation is committed or discarded, so two processes
changing the same log wait for each other instead of losing each other's work (the last
switch would otherwise win).

What is all or nothing is the change: a reader that opens several files of a log by their
public paths while a stage commits may get some from each generation, and a path already
resolved through the link (or a shell whose working directory is inside it) points into a
generation that the commit removes. Stages therefore read and write only inside a generation
they opened, under the log's lock. A run that finds nothing to do still opens (and discards)
a generation: a few milliseconds and one hard link per file.

A directory left from before generations existed (a plain ``WS/logs/<log_id>/``) is taken
as the current generation; the first commit moves it aside (``.old``), puts the link in its
place and removes it. A kill between those two renames leaves no ``WS/logs/<log_id>`` and one
``.old`` directory, which the next :func:`open_generation` renames back: the old state.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import shutil
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

from toolkit.atomic import fsync_dir, host_name
from toolkit.errors import ToolkitError, WorkspaceError

_log = logging.getLogger(__name__)

#: Suffix of a generation directory, of a link being put in place, of a pre-generation
#: directory moved aside.
GENERATION_SUFFIX = ".gen"
_LINK_SUFFIX = ".link"
_OLD_SUFFIX = ".old"


#: Age after which another host's unfinished generation counts as abandoned, s.
FOREIGN_AGE_S = 24 * 3600.0


def _hidden_name(log_id: str, suffix: str) -> str:
    """``.<log_id>.<host>-<pid>-<random><suffix>``: hidden, and naming who made it."""
    return f".{log_id}.{host_name()}-{os.getpid()}-{uuid.uuid4().hex[:12]}{suffix}"


def _siblings(logs_dir: Path, log_id: str, suffix: str) -> list[Path]:
    """The hidden entries of ``log_id`` in ``logs_dir`` that end in ``suffix``."""
    # The host part has no dot (see _hidden_name), so log "a" never matches log "a.b"'s.
    pattern = re.compile(
        rf"^\.{re.escape(log_id)}\.(?P<host>[A-Za-z0-9_]+)-(?P<pid>\d+)-[0-9a-f]{{12}}"
        rf"{re.escape(suffix)}$"
    )
    return sorted(p for p in logs_dir.iterdir() if pattern.match(p.name))


def _abandoned(path: Path) -> bool:
    """Whether a hidden entry (not the current generation) was left by a run that is gone,
    asked under the log's lock. One of this host: always, since a live run of this host
    changing the log would hold that lock (its pid is no help: a killed process can linger as
    a zombie where nothing reaps it, and pids are reused). One of another host, which may
    share the workspace over a network file system where locks cannot be relied on: only
    once untouched for :data:`FOREIGN_AGE_S`."""
    m = re.search(r"\.(?P<host>[A-Za-z0-9_]+)-(?P<pid>\d+)-[0-9a-f]{12}\.[a-z]+$", path.name)
    if m is None:
        return False
    if m["host"] == host_name():
        return True
    try:
        return time.time() - path.lstat().st_mtime > FOREIGN_AGE_S
    except OSError:
        return False


def _fsync_tree(directory: Path) -> None:
    """fsync every directory of a generation: the renames in it must be on the disk before
    the switch that publishes it (the files themselves were fsynced by their writers)."""
    for root, _dirs, _files in os.walk(directory):
        fsync_dir(Path(root))


class Generation:
    """A new generation of one log's directory, open for writing (see the module docstring).

    ``path`` is where the stage reads its inputs and writes its outputs; nothing written
    there is visible at ``WS/logs/<log_id>`` until :meth:`commit`. Leaving the
    :func:`open_generation` block without committing discards it.
    """

    def __init__(self, logs_dir: Path, log_id: str, path: Path, current: Path | None) -> None:
        self.logs_dir = logs_dir
        self.log_id = log_id
        self.path = path
        self._current = current  # the generation (or plain directory) it was opened from
        self.committed = False

    @property
    def link(self) -> Path:
        """``WS/logs/<log_id>``: the name readers use."""
        return self.logs_dir / self.log_id

    def commit(self) -> None:
        """Publish this generation at ``WS/logs/<log_id>`` in one atomic rename, then remove
        the generation it replaces."""
        if self.committed:
            raise WorkspaceError("generation already committed", path=self.path)
        _fsync_tree(self.path)
        tmp_link = self.logs_dir / _hidden_name(self.log_id, _LINK_SUFFIX)
        try:
            os.symlink(self.path.name, tmp_link)  # relative: a copied workspace still works
        except OSError as exc:
            raise WorkspaceError(
                f"cannot make a symbolic link ({exc.strerror or exc}); the workspace needs a "
                "file system that has them (not FAT or exFAT)",
                path=self.logs_dir,
            ) from exc
        try:
            if self.link.is_symlink() or not self.link.exists():
                os.replace(tmp_link, self.link)
            else:  # a plain directory from before generations: move it aside first
                aside = self.logs_dir / _hidden_name(self.log_id, _OLD_SUFFIX)
                os.rename(self.link, aside)
                try:
                    os.replace(tmp_link, self.link)
                except BaseException:
                    os.rename(aside, self.link)  # put it back: the old state
                    raise
                self._current = aside
        except BaseException:
            with contextlib.suppress(OSError):
                tmp_link.unlink()
            raise
        # From here the new generation is the log: nothing below may discard it.
        self.committed = True
        fsync_dir(self.logs_dir)
        if self._current is not None:
            shutil.rmtree(self._current, ignore_errors=True)

    def discard(self) -> None:
        """Remove this generation (idempotent; nothing of it was ever visible)."""
        if not self.committed:
            shutil.rmtree(self.path, ignore_errors=True)


def current_generation(logs_dir: Path, log_id: str) -> Path | None:
    """The directory ``WS/logs/<log_id>`` stands for now, or None if the log has none."""
    link = logs_dir / log_id
    if link.is_symlink():
        target = logs_dir / os.readlink(link)
        return target if target.is_dir() else None
    return link if link.is_dir() else None


def _recover(logs_dir: Path, log_id: str) -> None:
    """Undo what a killed commit or change left (under the log's lock): a pre-generation
    directory moved aside but not replaced goes back; generations that are not current
    are removed (said on the terminal, so a user who wonders where disk space went hears
    it)."""
    link = logs_dir / log_id
    aside = _siblings(logs_dir, log_id, _OLD_SUFFIX)
    if not link.exists() and not link.is_symlink() and aside:
        os.rename(aside[-1], link)
        aside = aside[:-1]
    if link.is_symlink() and not link.exists():
        # A link to nothing (its generation removed by hand, or by a run of an older
        # version): never guess by deleting; point it at the newest generation there is.
        gens = sorted(
            _siblings(logs_dir, log_id, GENERATION_SUFFIX), key=lambda p: p.stat().st_mtime
        )
        if gens:
            tmp_link = logs_dir / _hidden_name(log_id, _LINK_SUFFIX)
            os.symlink(gens[-1].name, tmp_link)
            os.replace(tmp_link, link)
            _log.warning("%s: pointed at its newest version %s", link, gens[-1].name)
    current = current_generation(logs_dir, log_id)
    stale = [
        p
        for p in _siblings(logs_dir, log_id, GENERATION_SUFFIX) + aside
        if (current is None or p.resolve() != current.resolve()) and _abandoned(p)
    ]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    for p in _siblings(logs_dir, log_id, _LINK_SUFFIX):
        with contextlib.suppress(OSError):
            p.unlink()
    if stale:
        _log.warning(
            "%s: removed %d unfinished change(s) of this log left by killed runs",
            logs_dir / log_id,
            len(stale),
        )


def _link_or_copy(src: str, dst: str) -> None:
    """A hard link, or a copy on a file system without them (slower, the same result)."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


@contextlib.contextmanager
def _log_lock(logs_dir: Path, log_id: str) -> Iterator[None]:
    """Exclusive flock on ``WS/logs/.<log_id>.lock``, waited for (said once if it has to)."""
    path = logs_dir / f".{log_id}.lock"
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise WorkspaceError(f"cannot lock the log: {exc.strerror or exc}", path=path) from exc
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _log.warning("%s: another terrain process is changing this log; waiting", path)
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:  # a file system without flock
            raise WorkspaceError(
                f"cannot lock the log ({exc.strerror or exc}); the workspace needs a file "
                "system with flock",
                path=path,
            ) from exc
        yield
    finally:
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def open_generation(
    logs_dir: Path, log_id: str, *, carry_files: bool = True
) -> Iterator[Generation]:
    """Open a new generation of ``WS/logs/<log_id>`` holding (hard links to) the current
    files, or nothing with ``carry_files=False`` (an output made whole each time, as the
    report is); yield it; discard it unless it was committed. Raises WorkspaceError when the
    workspace cannot be written (read-only, full, no permission)."""
    try:
        logs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WorkspaceError(
            f"cannot create the logs directory: {exc.strerror or exc}", path=logs_dir
        ) from exc
    with _log_lock(logs_dir, log_id):
        _recover(logs_dir, log_id)
        current = current_generation(logs_dir, log_id)
        path = logs_dir / _hidden_name(log_id, GENERATION_SUFFIX)
        try:
            if current is None or not carry_files:
                path.mkdir()
            else:
                shutil.copytree(
                    current,
                    path,
                    symlinks=True,
                    copy_function=_link_or_copy,
                    ignore=lambda _d, names: [n for n in names if n.startswith(".")],
                )
        except (OSError, shutil.Error) as exc:
            shutil.rmtree(path, ignore_errors=True)
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc)
            raise WorkspaceError(
                f"cannot open a new version of the log: {reason}", path=logs_dir / log_id
            ) from None
        gen = Generation(logs_dir, log_id, path, current)
        try:
            yield gen
        except ToolkitError as exc:
            exc.moved(path, gen.link)  # errors name the log's public directory
            raise
        finally:
            gen.discard()


__all__ = [
    "GENERATION_SUFFIX",
    "Generation",
    "current_generation",
    "open_generation",
]
