"""A configuration hashed (:func:`config_hash`) and written back as TOML (:func:`dump_toml`).

Part of :mod:`toolkit.config`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
import unicodedata
from collections.abc import Iterable
from typing import Any

from toolkit.config.loading import dotted_key
from toolkit.config.sections import CONFIG_FORMAT, PipelineConfig


def to_dict(cfg: PipelineConfig) -> dict[str, Any]:
    """Plain JSON-ready dict (tuples become lists, absent topics stay None)."""
    return typing.cast(dict[str, Any], json.loads(json.dumps(dataclasses.asdict(cfg))))


def keyed_dict(cfg: PipelineConfig) -> dict[str, Any]:
    """:func:`to_dict` without the settings marked ``UNHASHED_AT_DEFAULT`` that hold their
    default (and without a section left empty by that): what keys an output. (A written
    configuration holds every key, these too: it never depends on a default to be complete.)"""
    return typing.cast(dict[str, Any], _prune(cfg))


def _prune(obj: Any) -> Any:
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        return json.loads(json.dumps(obj))
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if f.metadata.get("unhashed_at_default") and value == _default_of(f):
            continue
        pruned = _prune(value)
        if dataclasses.is_dataclass(value) and not pruned:
            continue
        out[f.name] = pruned
    return out


def _default_of(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def config_hash(cfg: PipelineConfig, sections: Iterable[str] | None = None) -> str:
    """sha256 (hex) of the canonical JSON of ``cfg``, or only of the named sections
    (``"tables"``) and single keys (``"model.wheel_window_radius_m"``).

    Hashing only what a stage reads lets an up-to-date check ignore changes to settings the
    stage does not use. The format number is part of every hash.
    """
    full = keyed_dict(cfg)
    known = to_dict(cfg)
    if sections is None:
        body: dict[str, Any] = full
    else:
        wanted = sorted(set(sections))
        body = {}
        for name in wanted:
            section, _, key = name.partition(".")
            if section not in known or (key and key not in known[section]):
                raise ValueError(f"unknown config section or key: {name!r}")
            if section not in full or (key and key not in full[section]):
                continue  # a setting at a default that keys nothing
            if not key:
                body[section] = full[section]
            elif section not in wanted:  # a whole section asked for holds the key already
                body.setdefault(section, {})[key] = full[section][key]
    canonical = json.dumps(
        {"config_format": CONFIG_FORMAT, "config": body},
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=True,
        allow_nan=False,
    )
    return hashlib.sha256(canonical.encode("ascii")).hexdigest()


def dump_toml(cfg: PipelineConfig) -> str:
    """TOML text that :func:`parse_config` reads back to an object equal to ``cfg``."""
    from toolkit import __version__

    lines = [
        f"# Configuration in force, written by terrain {__version__}.",
        f"# config_hash = {config_hash(cfg)}",
        "",
    ]
    _dump_table(to_dict(cfg), "", lines)
    return "\n".join(lines).rstrip("\n") + "\n"


def _dump_table(table: dict[str, Any], prefix: str, lines: list[str]) -> None:
    nested = []
    for name, value in table.items():
        if isinstance(value, dict):
            nested.append((name, value))
        else:
            lines.append(f"{name} = {toml_value(value)}")
    for name, value in nested:
        dotted = dotted_key(prefix, name)
        lines.extend(["", f"[{dotted}]"])
        _dump_table(value, dotted, lines)


def toml_value(value: Any) -> str:
    """A configuration value as TOML text (None as ``""``, tuples as arrays)."""
    if value is None:
        return '""'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def escape_controls(text: str) -> str:
    """``text`` with every control character (C0 with tab and newline, DEL, C1) and Unicode
    line or paragraph separator as its ``\\uXXXX`` escape: what a TOML string or comment may
    not hold raw, or what a reader takes for a line break. A name from a log (a topic, a
    frame) so written is shown, never obeyed."""
    return "".join(
        f"\\u{ord(ch):04x}" if unicodedata.category(ch) in ("Cc", "Zl", "Zp") else ch for ch in text
    )


def _toml_string(text: str) -> str:
    """A TOML basic string: backslashes and quotes escaped, then :func:`escape_controls`."""
    return '"' + escape_controls(text.replace("\\", "\\\\").replace('"', '\\"')) + '"'
