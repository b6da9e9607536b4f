"""The workspace: its paths, per-log manifests, atomic writes, the lock, up-to-date checks.

Layout (see the contract)::

    WS/config.toml                   the configuration in force
    WS/manifest.json                 stages that span logs (tables, learn, evaluate, ...)
    WS/logs/<log_id>/manifest.json   per-log stages (ingest, pose, project, label, ...)
    WS/logs/<log_id>/<table>.parquet
    WS/tables/events.parquet, WS/tables/event_points.parquet
    WS/model.json
    WS/report/...

The workspace and its manifests are the only state shared between stages. Files appear
only when complete (:func:`atomic_write_bytes`, :func:`atomic_output`), a manifest is
updated by read-modify-write under a lock on its directory, and one process at a time
works on a workspace (:meth:`Workspace.lock`).

``WS/logs/<log_id>`` is a link to the log's current *generation*: a stage changes a log by
writing a new generation and switching the link in one atomic rename
(:meth:`Workspace.change_log`, :mod:`toolkit.generations`), so a log is always in the state
before a stage or after it, whenever the stage is killed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import fcntl
import hashlib
import json
import os
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toolkit.atomic import atomic_write_json, atomic_write_text
from toolkit.config import PipelineConfig, config_hash, dump_toml, load_config
from toolkit.errors import ConfigError, SchemaError, WorkspaceError
from toolkit.generations import Generation, open_generation
from toolkit.tableio import load_table_schema, read_table_metadata

#: Version of the manifest's JSON layout.
MANIFEST_FORMAT = 1

_HASH_CHUNK_BYTES = 1 << 20
_LOG_ID_HASH_CHARS = 12
_LOG_ID_STEM_CHARS = 48


# --------------------------------------------------------------------------------------
# Hashing and log ids
# --------------------------------------------------------------------------------------


def file_sha256(path: str | Path) -> str:
    """sha256 (hex) of a file's content, read in 1 MiB chunks (logs may be many GB)."""
    path = Path(path)
    digest = hashlib.sha256()
    try:
        with path.open("rb") as fh:
            while chunk := fh.read(_HASH_CHUNK_BYTES):
                digest.update(chunk)
    except OSError as exc:
        raise WorkspaceError(f"cannot read: {exc.strerror or exc}", path=path) from exc
    return digest.hexdigest()


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
# Atomic writes
# --------------------------------------------------------------------------------------


def workspace_around(path: str | Path) -> Path | None:
    """The workspace ``path`` lies in or is (a folder holding ``config.toml`` and ``logs/``,
    found among its real path's ancestors), or None. An output of export, viz or sim may not
    go there: it would replace the workspace's own files (a model, a manifest, a log's
    table inside its generation) or pass for one of its logs."""
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


# --------------------------------------------------------------------------------------
# Manifest
# --------------------------------------------------------------------------------------


def _now_utc() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


@dataclass(frozen=True)
class FileDigest:
    """A file's size and sha256, as a stage wrote it."""

    size_bytes: int
    sha256: str

    @classmethod
    def of(cls, path: Path) -> FileDigest:
        """The digest of the file at ``path`` now."""
        return cls(path.stat().st_size, file_sha256(path))

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return {"bytes": self.size_bytes, "sha256": self.sha256}

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> FileDigest:
        """Inverse of :meth:`to_json`."""
        return cls(int(obj["bytes"]), str(obj["sha256"]))


def digest_files(directory: Path, names: Iterable[str]) -> dict[str, FileDigest]:
    """name -> digest of each named file in ``directory`` (a stage's outputs, once written)."""
    return {name: FileDigest.of(directory / name) for name in names}


@dataclass(frozen=True)
class StageRecord:
    """What one stage run used and produced, as kept in a manifest.

    ``inputs`` maps an input's name (a table name, or ``"log"``) to its sha256;
    ``outputs`` lists output paths relative to the manifest's directory (or the workspace
    root for workspace-level stages); ``row_counts`` is rows per output table;
    ``rejects`` counts dropped records by reason; ``timings_s`` seconds per step;
    ``output_files`` the size and sha256 of every output as written, so "up to date" can
    mean "the outputs are still what this run wrote" (:func:`check_up_to_date`).
    """

    inputs: Mapping[str, str]
    config_hash: str
    outputs: tuple[str, ...] = ()
    row_counts: Mapping[str, int] = field(default_factory=dict)
    rejects: Mapping[str, int] = field(default_factory=dict)
    timings_s: Mapping[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    toolkit_version: str = ""
    finished_utc: str = ""
    output_files: Mapping[str, FileDigest] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return {
            "inputs": dict(self.inputs),
            "config_hash": self.config_hash,
            "outputs": list(self.outputs),
            "row_counts": dict(self.row_counts),
            "rejects": dict(self.rejects),
            "timings_s": dict(self.timings_s),
            "warnings": list(self.warnings),
            "toolkit_version": self.toolkit_version,
            "finished_utc": self.finished_utc,
            "output_files": {k: v.to_json() for k, v in self.output_files.items()},
        }

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> StageRecord:
        """Inverse of :meth:`to_json` (raises KeyError/TypeError on a malformed record)."""
        return cls(
            inputs={str(k): str(v) for k, v in obj["inputs"].items()},
            config_hash=str(obj["config_hash"]),
            outputs=tuple(str(o) for o in obj.get("outputs", ())),
            row_counts={str(k): int(v) for k, v in obj.get("row_counts", {}).items()},
            rejects={str(k): int(v) for k, v in obj.get("rejects", {}).items()},
            timings_s={str(k): float(v) for k, v in obj.get("timings_s", {}).items()},
            warnings=tuple(str(w) for w in obj.get("warnings", ())),
            toolkit_version=str(obj.get("toolkit_version", "")),
            finished_utc=str(obj.get("finished_utc", "")),
            output_files={
                str(k): FileDigest.from_json(v) for k, v in obj.get("output_files", {}).items()
            },
        )


@contextlib.contextmanager
def _dir_lock(directory: Path) -> Iterator[None]:
    """An exclusive flock on a directory (no lock file left behind), blocking."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


class Manifest:
    """A manifest file: stage name -> :class:`StageRecord`, plus free-form header fields.

    Reads tolerate a missing file (no stages yet). Updates are read-modify-write under an
    exclusive lock on the manifest's directory and land with an atomic rename. A log's
    manifest is written by stages only inside :meth:`Workspace.change_log` (the manifest of
    the new generation, under the log's lock, so two stages of one log take turns); an update
    through ``Workspace.manifest(log_id)`` outside one writes the current generation and is
    lost if a stage running at that moment commits after it.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def _load(self) -> dict[str, Any]:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {"format": MANIFEST_FORMAT, "stages": {}}
        except OSError as exc:
            raise WorkspaceError(f"cannot read manifest: {exc.strerror or exc}", self.path) from exc
        except UnicodeDecodeError as exc:
            raise WorkspaceError(
                f"manifest is not UTF-8 text (byte {exc.start}): {exc.reason}", path=self.path
            ) from exc
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise WorkspaceError(f"manifest is not valid JSON: {exc}", path=self.path) from exc
        if not isinstance(obj, dict) or not isinstance(obj.get("stages"), dict):
            raise WorkspaceError("manifest has no 'stages' table", path=self.path)
        if obj.get("format") != MANIFEST_FORMAT:
            raise WorkspaceError(
                f"manifest format {obj.get('format')!r} is not {MANIFEST_FORMAT}", path=self.path
            )
        return obj

    def read(self) -> dict[str, Any]:
        """The whole manifest as JSON (``{"format", "stages", ...header fields}``)."""
        return self._load()

    def stages(self) -> dict[str, StageRecord]:
        """Every recorded stage."""
        raw = self._load()["stages"]
        return {name: self._record(name, rec) for name, rec in raw.items()}

    def stage(self, name: str) -> StageRecord | None:
        """The record of one stage, or None if it never completed."""
        rec = self._load()["stages"].get(name)
        return None if rec is None else self._record(name, rec)

    def _record(self, name: str, rec: Any) -> StageRecord:
        try:
            return StageRecord.from_json(rec)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise WorkspaceError(f"malformed record for stage {name!r}: {exc}", self.path) from exc

    def record_stage(self, name: str, record: StageRecord) -> None:
        """Store (replace) one stage's record, stamping the time and toolkit version."""
        from toolkit import __version__

        stamped = dataclasses.replace(
            record,
            toolkit_version=record.toolkit_version or __version__,
            finished_utc=record.finished_utc or _now_utc(),
        )
        self.update(lambda m: m["stages"].__setitem__(name, stamped.to_json()))

    def remove_stage(self, name: str) -> None:
        """Forget a stage (e.g. before re-running it, so a failure leaves it not current)."""
        self.update(lambda m: m["stages"].pop(name, None))

    def set_header(self, **fields: Any) -> None:
        """Set free-form top-level fields (e.g. ``source={"path": ..., "sha256": ...}``)."""
        reserved = {"format", "stages"} & fields.keys()
        if reserved:
            raise ValueError(f"reserved manifest fields: {sorted(reserved)}")
        self.update(lambda m: m.update(fields))

    def update(self, change: Callable[[dict[str, Any]], object]) -> None:
        """Apply ``change(manifest_dict)`` under the directory lock and write atomically."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with _dir_lock(self.path.parent):
            obj = self._load()
            change(obj)
            atomic_write_json(self.path, obj)


# --------------------------------------------------------------------------------------
# Up-to-date checks
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Freshness:
    """Whether a stage's outputs are current; ``reason`` says why not (for -v logs)."""

    current: bool
    reason: str

    def __bool__(self) -> bool:
        return self.current


def check_up_to_date(
    record: StageRecord | None,
    *,
    inputs: Mapping[str, str],
    config_hash: str,
    outputs: Iterable[str | Path],
) -> Freshness:
    """A stage is current when its record has the same inputs (names and hashes) and the
    same config hash, and every output exists and is still, in size and sha256, the file that
    run wrote: a truncated, overwritten or half-copied output makes the stage run again."""
    if record is None:
        return Freshness(False, "never ran")
    paths = [Path(p) for p in outputs]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        return Freshness(False, f"output missing: {missing[0]}")
    old, new = dict(record.inputs), dict(inputs)
    if old != new:
        changed = sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
        return Freshness(False, f"inputs changed: {', '.join(changed)}")
    if record.config_hash != config_hash:
        return Freshness(False, "configuration changed")
    for path in paths:
        written = record.output_files.get(path.name)
        if written is None:
            return Freshness(False, f"no record of what was written to {path.name}")
        if path.stat().st_size != written.size_bytes or file_sha256(path) != written.sha256:
            return Freshness(False, f"output changed since it was written: {path.name}")
        stale = _older_table_schema(path)
        if stale:
            return Freshness(False, stale)
    return Freshness(True, "up to date")


def _older_table_schema(path: Path) -> str:
    """Why a Parquet output is out of date for this toolkit (written for an older version of
    its table schema, which every reader refuses), or "" when it is not."""
    if path.suffix != ".parquet":
        return ""
    try:
        meta = read_table_metadata(path)
        name, version = meta.get("schema_name"), meta.get("schema_version")
        if not name or version is None:
            return ""
        current = load_table_schema(name).version
    except (SchemaError, WorkspaceError, OSError, ValueError):
        return ""  # not one of ours: its hash is what counts
    if str(version) != str(current):
        return (
            f"{path.name} was written for schema {name} v{version}, this toolkit writes v{current}"
        )
    return ""


def require_finished(
    record: StageRecord | None, stage: str, files: Mapping[str, str], directory: Path
) -> None:
    """Refuse inputs a finished ``stage`` did not write: ``files`` maps each input's name
    (as in the producer's outputs) to its sha256 now. WorkspaceError, naming the file, when
    the producer never finished, or the file is not the one it recorded (changed since,
    partial, or left by an interrupted run)."""
    if record is None:
        raise WorkspaceError(
            f"no finished {stage} recorded here; run `terrain {stage}` first", path=directory
        )
    for name, sha in files.items():
        written = record.output_files.get(name)
        if written is None or written.sha256 != sha:
            raise WorkspaceError(
                f"not the file the last finished {stage} wrote (changed, partial or left by "
                f"an interrupted run); run `terrain {stage}` again",
                path=directory / name,
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


class Workspace:
    """Paths of a workspace and the operations on its shared state."""

    CONFIG_NAME = "config.toml"
    MANIFEST_NAME = "manifest.json"
    LOCK_NAME = ".lock"

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def __repr__(self) -> str:
        return f"Workspace({str(self.root)!r})"

    # -- paths -------------------------------------------------------------------------

    @property
    def config_path(self) -> Path:
        """``WS/config.toml``: the configuration in force."""
        return self.root / self.CONFIG_NAME

    @property
    def manifest_path(self) -> Path:
        """``WS/manifest.json``: records of the stages that span logs."""
        return self.root / self.MANIFEST_NAME

    @property
    def lock_path(self) -> Path:
        """``WS/.lock``."""
        return self.root / self.LOCK_NAME

    @property
    def logs_dir(self) -> Path:
        """``WS/logs``."""
        return self.root / "logs"

    def log_dir(self, log_id: str) -> Path:
        """``WS/logs/<log_id>``. A log id never starts with a dot: those names are the
        generations' hidden directories and locks (:mod:`toolkit.generations`), which a
        stage must never take for a log."""
        if not log_id or "/" in log_id or "\\" in log_id or log_id.startswith("."):
            raise WorkspaceError(f"invalid log id {log_id!r}", path=self.root)
        return self.logs_dir / log_id

    def log_table(self, log_id: str, table: str) -> Path:
        """``WS/logs/<log_id>/<table>.parquet`` (imu, gps, pose, points, events, ...)."""
        return self.log_dir(log_id) / f"{table}.parquet"

    def log_manifest_path(self, log_id: str) -> Path:
        """``WS/logs/<log_id>/manifest.json``."""
        return self.log_dir(log_id) / self.MANIFEST_NAME

    @property
    def tables_dir(self) -> Path:
        """``WS/tables``."""
        return self.root / "tables"

    @property
    def events_table(self) -> Path:
        """``WS/tables/events.parquet`` (schema ``tables_events``)."""
        return self.tables_dir / "events.parquet"

    @property
    def event_points_table(self) -> Path:
        """``WS/tables/event_points.parquet``."""
        return self.tables_dir / "event_points.parquet"

    @property
    def model_path(self) -> Path:
        """``WS/model.json``."""
        return self.root / "model.json"

    @property
    def report_dir(self) -> Path:
        """``WS/report``."""
        return self.root / "report"

    @property
    def scores_table(self) -> Path:
        """``WS/report/scores.parquet``."""
        return self.report_dir / "scores.parquet"

    @property
    def summary_path(self) -> Path:
        """``WS/report/summary.json``."""
        return self.report_dir / "summary.json"

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

    def require_log(self, log_id: str) -> Path:
        """The directory of the workspace's log ``log_id``; WorkspaceError naming the logs it
        does have (or saying it has none yet) when it is not one of them."""
        path = self.log_dir(log_id)
        if path.is_dir() and not log_id.startswith("."):
            return path
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
