"""Manifests: what each stage read, with which configuration, and what it wrote.

A manifest is JSON: ``{"format", "stages": {name: record}, ...header fields}``. A stage's
record (:class:`StageRecord`) holds the sha256 of its inputs, the hash of the configuration
it read, and the size and sha256 of every output as written, so "up to date"
(:func:`check_up_to_date`) means "the same inputs and configuration, and the outputs are
still what that run wrote". Updates are read-modify-write under a lock on the manifest's
directory and land by atomic rename.

Reading one checks its numbers: the toolkit writes strict JSON (no NaN or infinity), so a
non-finite number anywhere, or a count or size that is not a whole number, is a tampered or
corrupt manifest: a WorkspaceError naming the file and the field, as for invalid JSON.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import fcntl
import hashlib
import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toolkit.atomic import atomic_write_json
from toolkit.errors import SchemaError, WorkspaceError
from toolkit.strict_json import non_finite_field
from toolkit.tableio import load_table_schema, read_table_metadata

#: Version of the manifest's JSON layout.
MANIFEST_FORMAT = 1

_HASH_CHUNK_BYTES = 1 << 20


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


# --------------------------------------------------------------------------------------
# Manifest
# --------------------------------------------------------------------------------------


def whole_number(value: Any, field_name: str) -> int:
    """``value`` if it is a whole number of at least 0 (a count, a size in bytes); else a
    ValueError naming ``field_name``. A float, even an integral one, is not: the toolkit
    writes counts as JSON integers."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{field_name} is {value!r}, not a whole number of at least 0")
    return value


def finite_number(value: Any, field_name: str) -> float:
    """``value`` as a float if it is a finite number; else a ValueError naming
    ``field_name``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{field_name} is {value!r}, not a finite number")
    return float(value)


def _counts(obj: Mapping[str, Any], key: str) -> dict[str, int]:
    """A record's ``key`` table of whole numbers (row counts, rejects), checked."""
    return {str(k): whole_number(v, f"{key}.{k}") for k, v in obj.get(key, {}).items()}


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
        return cls(whole_number(obj["bytes"], "bytes"), str(obj["sha256"]))


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
    mean "the outputs are still what this run wrote" (:func:`check_up_to_date`);
    ``code_version`` the version of the code that made them (:mod:`toolkit.code_version`;
    empty in a record written before the toolkit kept it).
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
    code_version: str = ""
    #: The configuration sections (or ``section.key``) ``config_hash`` was taken over, so a
    #: reader can tell a record made with another configuration without the stage's code.
    config_sections: tuple[str, ...] = ()

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
            "code_version": self.code_version,
            "config_sections": list(self.config_sections),
        }

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> StageRecord:
        """Inverse of :meth:`to_json` (raises KeyError/TypeError on a malformed record, and
        ValueError naming the field on a count that is not a whole number or a time that is
        not a finite number)."""
        return cls(
            inputs={str(k): str(v) for k, v in obj["inputs"].items()},
            config_hash=str(obj["config_hash"]),
            outputs=tuple(str(o) for o in obj.get("outputs", ())),
            row_counts=_counts(obj, "row_counts"),
            rejects=_counts(obj, "rejects"),
            timings_s={
                str(k): finite_number(v, f"timings_s.{k}")
                for k, v in obj.get("timings_s", {}).items()
            },
            warnings=tuple(str(w) for w in obj.get("warnings", ())),
            toolkit_version=str(obj.get("toolkit_version", "")),
            finished_utc=str(obj.get("finished_utc", "")),
            output_files={str(k): _digest(k, v) for k, v in obj.get("output_files", {}).items()},
            code_version=str(obj.get("code_version", "")),
            config_sections=tuple(str(c) for c in obj.get("config_sections", ())),
        )


def _digest(name: str, obj: Mapping[str, Any]) -> FileDigest:
    """One entry of a record's ``output_files``, its errors naming the entry."""
    try:
        return FileDigest.from_json(obj)
    except ValueError as exc:
        raise ValueError(f"output_files.{name}.{exc}") from None


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
        bad = non_finite_field(obj)
        if bad is not None:
            raise WorkspaceError(
                f"manifest field {bad} is not a finite number (the toolkit never writes one: "
                "the file was changed or damaged)",
                path=self.path,
            )
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
    code_version: str | None = None,
) -> Freshness:
    """A stage is current when its record has the same inputs (names and hashes), the
    same config hash and (when given) the same ``code_version``, and every output exists and
    is still, in size and sha256, the file that run wrote: a truncated, overwritten or
    half-copied output makes the stage run again, as does an output another version of the
    stage's code made (before a fix that changed results, say)."""
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
    if code_version is not None and record.code_version != code_version:
        return Freshness(False, code_changed(record))
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


def code_changed(record: StageRecord) -> str:
    """Why a record's outputs are stale when another version of its code made them."""
    if not record.code_version:
        return "made by a toolkit that recorded no code version"
    made_by = f" (terrain {record.toolkit_version})" if record.toolkit_version else ""
    return f"made by other code{made_by}: its code has changed since"


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


__all__ = [
    "MANIFEST_FORMAT",
    "FileDigest",
    "Freshness",
    "Manifest",
    "StageRecord",
    "check_up_to_date",
    "digest_files",
    "file_sha256",
    "finite_number",
    "require_finished",
    "whole_number",
]
