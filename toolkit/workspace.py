"""The workspace: its state (logs, configuration, lock) and the operations on it.

The paths are :mod:`toolkit.layout`'s, the manifests :mod:`toolkit.manifest`'s, the atomic
write :mod:`toolkit.atomic`'s. The workspace and its manifests are the only state shared
between stages. Files appear only when complete, a manifest is updated by read-modify-write
under a lock on its directory, and one process at a time works on a workspace
(:meth:`Workspace.lock`).

``WS/logs/<log_id>`` is a link to the log's current *generation*: a stage changes a log by
writing a new generation and switching the link in one atomic rename
(:meth:`Workspace.change_log`, :mod:`toolkit.generations`), so a log is always in the state
before a stage or after it, whenever the stage is killed.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from toolkit.atomic import atomic_write_text
from toolkit.config import PipelineConfig, config_hash, dump_toml, load_config
from toolkit.errors import ConfigError, WorkspaceError
from toolkit.generations import Generation, open_generation
from toolkit.layout import WorkspaceLayout
from toolkit.manifest import Freshness, Manifest, check_up_to_date, file_sha256

_LOG_ID_HASH_CHARS = 12
_LOG_ID_STEM_CHARS = 48


# --------------------------------------------------------------------------------------
# Log ids
# --------------------------------------------------------------------------------------


def make_log_id(stem: str, sha256_hex: str) -> str:
    """``<stem>-<first 12 hex of sha256>``, the stem reduced to ``[A-Za-z0-9._-]``."""
    clean = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._-")[:_LOG_ID_STEM_CHARS]
    return f"{clean or 'log'}-{sha256_hex[:_LOG_ID_HASH_CHARS].lower()}"


def log_id_for(path: str | Path) -> str:
    """The stable id of a log file: its name's stem plus a prefix of its content hash.

    The same file gives the same id wherever it lives; a renamed copy keeps its hash
    prefix, and two different files with the same name differ by their hash.
    """
    path = Path(path)
    return make_log_id(path.stem, file_sha256(path))


# --------------------------------------------------------------------------------------
# Where outputs may go
# --------------------------------------------------------------------------------------


def workspace_around(path: str | Path) -> Path | None:
    """The workspace ``path`` lies in or is (a folder holding ``config.toml`` and ``logs/``,
    found among its real path's ancestors), or None. An output of export, viz, sim or
    config init may not go there: it would replace the workspace's own files (its
    configuration, a model, a manifest, a log's table inside its generation) or pass for
    one of its logs."""
    real = Path(os.path.realpath(path))
    for folder in (real, *real.parents):
        if (folder / Workspace.CONFIG_NAME).is_file() and (folder / "logs").is_dir():
            return folder
    return None


def refuse_inside_workspace(path: str | Path) -> None:
    """WorkspaceError when ``path`` lies in a workspace (:func:`workspace_around`)."""
    around = workspace_around(path)
    if around is not None:
        raise WorkspaceError(
            f"lies inside the workspace {around}; write outputs outside a workspace", path=path
        )


def _unlink_unheld_lock(path: Path) -> None:
    """Remove an empty lock file nobody holds (OSError otherwise, the file kept): taken
    exclusively, without waiting, while it is unlinked, so a process that holds it (another
    shard's ingest) keeps its lock and its file."""
    if not path.exists():
        return
    if path.stat().st_size != 0:
        raise OSError(f"{path} is not an empty lock file")
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        path.unlink()
    finally:
        os.close(fd)


def missing_log_problem(target: Path) -> str:
    """What is wrong with a log whose link points to ``target``, which does not exist."""
    return (
        f"the log's folder is missing: its link points to {target}, which does not exist "
        "(its tables and manifest are gone); ingest its log again"
    )


# --------------------------------------------------------------------------------------
# The workspace
# --------------------------------------------------------------------------------------


class WorkspaceLock:
    """A non-blocking flock on ``WS/.lock``: exclusive (a stage over the whole workspace, such
    as pose) or shared (ingests, which may run side by side, each writing its own logs). A
    request that conflicts with a holder is refused with a WorkspaceError saying so.

    The lock belongs to the open file: it is released on :meth:`release`, on exit from the
    ``with`` block, or when the process dies. The file itself stays (deleting lock files
    races with other processes opening them).
    """

    def __init__(self, path: Path, *, shared: bool = False) -> None:
        self.path = path
        self.shared = shared
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock or raise WorkspaceError naming the holder's pid."""
        if self._fd is not None:
            raise WorkspaceError("workspace lock already held by this object", path=self.path)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:  # read-only workspace, no permission, ...
            raise WorkspaceError(
                f"cannot lock the workspace: {exc.strerror or exc}", path=self.path.parent
            ) from exc
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if self.shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
            os.close(fd)
            who = f"pid {holder}" if holder else "ingest"
            raise WorkspaceError(
                f"workspace is in use by another terrain process ({who}); try again when "
                "it has finished",
                path=self.path.parent,
            ) from None
        except BaseException:
            os.close(fd)
            raise
        if not self.shared:  # an exclusive holder names itself for the refusal above
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        self._fd = fd

    def release(self) -> None:
        """Release the lock (idempotent)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            if not self.shared:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
            os.close(fd)

    def __enter__(self) -> WorkspaceLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class Workspace(WorkspaceLayout):
    """A workspace's state and the operations on it; its paths are :class:`WorkspaceLayout`'s."""

    def __repr__(self) -> str:
        return f"Workspace({str(self.root)!r})"

    # -- state -------------------------------------------------------------------------

    def create(self) -> Workspace:
        """Make the root and ``logs/`` if missing; returns self."""
        try:
            self.logs_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise WorkspaceError(
                f"cannot create workspace: {exc.strerror or exc}", self.root
            ) from exc
        return self

    @contextlib.contextmanager
    def created(self) -> Iterator[Workspace]:
        """The workspace, created for a command that fills it with logs (ingest, run).

        If it did not exist before and the command leaves no log in it (every log failed,
        or the command raised), what the command made is taken away again: a failed first
        run leaves no workspace. Only the toolkit's own empty entries are removed (the
        workspace lock, the logs' lock files, the empty ``logs/``), each only if it is
        still empty; anything else found there keeps the folder."""
        fresh = not self.root.exists()
        self.create()
        try:
            yield self
        finally:
            if fresh and not self.log_ids():
                self._remove_unused()

    def _remove_unused(self) -> None:
        """Remove the empty skeleton :meth:`create` and a failed ingest leave (see
        :meth:`created`); stops quietly at the first entry that is not the toolkit's."""
        try:
            for lock in self.logs_dir.glob(".*.lock"):
                _unlink_unheld_lock(lock)
            self.logs_dir.rmdir()
            _unlink_unheld_lock(self.root / self.LOCK_NAME)
            self.root.rmdir()
        except OSError:
            pass  # something else is there, or in use: leave the folder as it is

    def require(self) -> Workspace:
        """Raise WorkspaceError unless this is an existing workspace (has config.toml)."""
        if not self.root.is_dir():
            raise WorkspaceError("no such workspace directory", path=self.root)
        if not self.config_path.is_file():
            raise WorkspaceError(
                f"not a workspace: no {self.CONFIG_NAME} (run 'terrain ingest' first)",
                path=self.root,
            )
        return self

    def log_ids(self) -> list[str]:
        """Ids of the logs in the workspace, sorted."""
        if not self.logs_dir.is_dir():
            return []
        return sorted(
            p.name for p in self.logs_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
        )

    def missing_logs(self) -> dict[str, Path]:
        """The logs whose ``WS/logs/<log_id>`` link points to nothing (its generation removed
        by hand or lost with a disk), id -> the folder it points to, sorted by id. They are not
        among :meth:`log_ids`: nothing of them, not even their manifest, can be read."""
        if not self.logs_dir.is_dir():
            return {}
        return {
            p.name: self.logs_dir / os.readlink(p)
            for p in sorted(self.logs_dir.iterdir())
            if not p.name.startswith(".") and p.is_symlink() and not p.exists()
        }

    def require_log(self, log_id: str) -> Path:
        """The directory of the workspace's log ``log_id``; WorkspaceError naming the logs it
        does have (or saying it has none yet) when it is not one of them, or naming the folder
        its link points to when that is missing."""
        path = self.log_dir(log_id)
        if path.is_dir() and not log_id.startswith("."):
            return path
        gone = self.missing_logs().get(log_id)
        if gone is not None:
            raise WorkspaceError(missing_log_problem(gone), path=path)
        ids = self.log_ids()
        if not ids:
            raise WorkspaceError(
                f"no log {log_id!r}: the workspace has no log yet (run `terrain ingest`)",
                path=self.root,
            )
        shown = ", ".join(ids[:20]) + (f" and {len(ids) - 20} more" if len(ids) > 20 else "")
        raise WorkspaceError(f"no log {log_id!r} in the workspace; its logs: {shown}", self.root)

    def change_log(self, log_id: str) -> contextlib.AbstractContextManager[Generation]:
        """Open a new generation of ``WS/logs/<log_id>`` to change it all or nothing::

            with ws.change_log(log_id) as gen:
                ...read and write under gen.path...
                gen.commit()

        (see :mod:`toolkit.generations`)."""
        self.log_dir(log_id)  # validates the id
        return open_generation(self.logs_dir, log_id)

    def lock(self, *, shared: bool = False) -> WorkspaceLock:
        """The workspace's lock, exclusive or shared; use as ``with ws.lock(): ...``."""
        self.create()
        return WorkspaceLock(self.lock_path, shared=shared)

    def manifest(self, log_id: str | None = None) -> Manifest:
        """A log's manifest, or with no id the workspace-level one."""
        if log_id is None:
            return Manifest(self.manifest_path)
        return Manifest(self.log_manifest_path(log_id))

    def read_config(self) -> PipelineConfig:
        """The configuration in force (``WS/config.toml``)."""
        self.require()
        return load_config(self.config_path)

    def write_config(self, cfg: PipelineConfig) -> None:
        """Record ``cfg`` as the configuration in force."""
        self.create()
        atomic_write_text(self.config_path, dump_toml(cfg))

    def check_config(self, cfg: PipelineConfig, *, overwrite: bool) -> bool:
        """Whether ``cfg`` must be recorded as the configuration in force once a stage has
        succeeded with it (True: the workspace has none, or ``overwrite`` replaces another).

        A workspace holds the results of one configuration: a different one is a ConfigError
        (naming both) unless ``overwrite``. Nothing is written here, so a configuration a
        stage then fails with never becomes the workspace's.
        """
        if not self.config_path.is_file():
            return True
        with contextlib.suppress(OSError, UnicodeDecodeError):
            if self.config_path.read_text(encoding="utf-8") == dump_toml(cfg):
                return False  # the file this configuration writes: equal without parsing it
        current = self.read_config()
        if current == cfg:
            return False
        if not overwrite:
            raise ConfigError(
                f"the workspace was set up with another configuration ({current.name}, "
                f"{config_hash(current)[:12]}) than the one given ({cfg.name}, "
                f"{config_hash(cfg)[:12]}); use a new workspace or --overwrite to replace it",
                path=self.config_path,
            )
        return True

    def use_config(self, cfg: PipelineConfig, *, overwrite: bool) -> None:
        """:meth:`check_config`, then record ``cfg`` at once (for callers that have already
        succeeded with it)."""
        if self.check_config(cfg, overwrite=overwrite):
            self.write_config(cfg)

    def is_up_to_date(
        self,
        stage: str,
        *,
        log_id: str | None,
        inputs: Mapping[str, str],
        config_hash: str,
        outputs: Iterable[str | Path],
    ) -> Freshness:
        """:func:`check_up_to_date` against this workspace's manifest for ``log_id``."""
        record = self.manifest(log_id).stage(stage)
        return check_up_to_date(record, inputs=inputs, config_hash=config_hash, outputs=outputs)
