"""Where an export goes: the checks that keep it from replacing anything but an earlier
export, and the publishing of the finished hidden directory in one step, so a reader never
finds half an export. See ``docs/export.md``."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
from pathlib import Path

from toolkit.atomic import exchange_paths, fsync_dir, host_name, temp_path_beside
from toolkit.errors import StageError, WorkspaceError
from toolkit.workspace import Workspace, refuse_inside_workspace

_log = logging.getLogger(__name__)

#: The hidden directory an export is written in: ``.<OUT name>.<host>-<pid>-<random>.export``.
_TEMP_DIR = re.compile(r"^\.(?P<name>.+)\.(?P<host>[^.]+)-(?P<pid>\d+)-[0-9a-f]{12}\.export$")


def check_destination(workspace: Workspace, out_dir: Path, overwrite: bool) -> None:
    """Refuse a destination the export may not take (before anything is read or written)."""
    if out_dir.is_symlink():
        raise StageError("is a symbolic link; give the directory itself", path=out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise StageError("exists and is not a directory", path=out_dir)
    root = Path(os.path.realpath(workspace.root))
    real = Path(os.path.realpath(out_dir))
    if real == root or real in root.parents:
        # Replacing it would delete the workspace the export is made from.
        raise StageError(f"holds the workspace {workspace.root}; export elsewhere", path=out_dir)
    refuse_inside_workspace(out_dir)
    if not _nonempty(out_dir):
        return
    if not overwrite:
        raise StageError(
            "exists and is not empty; choose a new directory or use --overwrite to replace "
            "the export there",
            path=out_dir,
        )
    # --overwrite replaces an earlier export, never an arbitrary folder of someone's files:
    # every file there must be one the export wrote (its card, its Croissant metadata and
    # the data files that metadata lists).
    foreign = _not_written_by_export(out_dir)
    if foreign is not None:
        raise StageError(
            f"holds {foreign}, which no export wrote; refusing to replace it, choose a new "
            "or empty directory",
            path=out_dir,
        )


def _not_written_by_export(out_dir: Path) -> str | None:
    """The first file or folder in ``out_dir`` (relative) that an export did not write, or
    None when the folder is an earlier export and nothing else: ``README.md``,
    ``croissant.json`` and the files its distribution lists (``contentUrl``)."""
    if not (out_dir / "croissant.json").is_file() or not (out_dir / "README.md").is_file():
        return "no croissant.json and README.md (not an earlier export)"
    try:
        doc = json.loads((out_dir / "croissant.json").read_text(encoding="utf-8"))
        listed = {
            str(d["contentUrl"])
            for d in doc.get("distribution", [])
            if isinstance(d, dict) and d.get("@type") == "cr:FileObject"
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "croissant.json that cannot be read (not an earlier export)"
    ours = {"README.md", "croissant.json", *listed}
    folders = {str(p) for f in listed for p in Path(f).parents if str(p) != "."}
    for entry in sorted(out_dir.rglob("*")):
        rel = str(entry.relative_to(out_dir))
        if entry.is_dir() and not entry.is_symlink():
            if rel not in folders:
                return rel
        elif rel not in ours:
            return rel
    return None


def _nonempty(directory: Path) -> bool:
    try:
        return any(directory.iterdir())
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise WorkspaceError(f"cannot read: {exc.strerror or exc}", path=directory) from exc


def remove_dead_temp_dirs(out_dir: Path) -> None:
    """Remove the hidden directories that exports to ``out_dir`` on this host left when they
    were killed (their process is gone); those of live runs are left alone."""
    parent = out_dir.parent
    if not parent.is_dir():
        return
    host = host_name()
    for entry in parent.iterdir():
        m = _TEMP_DIR.match(entry.name)
        if m is None or m["name"] != out_dir.name or m["host"] != host:
            continue
        try:
            os.kill(int(m["pid"]), 0)
            continue  # a live run's
        except ProcessLookupError:
            pass
        except PermissionError:
            continue  # someone else's live process
        _log.warning("removing %s, left by an interrupted export", entry)
        shutil.rmtree(entry, ignore_errors=True)


def publish(tmp: Path, out_dir: Path) -> None:
    """Put the finished export ``tmp`` at ``out_dir`` (absent, empty, or an earlier export
    checked by :func:`check_destination`)."""
    try:
        if not _nonempty(out_dir):
            # rename(2) replaces an empty directory in one step.
            os.rename(tmp, out_dir)
        elif exchange_paths(tmp, out_dir):
            # ``tmp`` is now the earlier export. The new one is published whatever happens
            # here: what cannot be removed now, the next export removes (its process gone).
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            old = temp_path_beside(out_dir, "export")
            os.rename(out_dir, old)
            try:
                os.rename(tmp, out_dir)
            except BaseException:
                os.rename(old, out_dir)
                raise
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        raise WorkspaceError(f"cannot publish the export: {exc.strerror or exc}", out_dir) from exc
    fsync_dir(out_dir.parent)


__all__ = ["check_destination", "publish", "remove_dead_temp_dirs"]
