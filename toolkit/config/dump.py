"""A configuration hashed (:func:`config_hash`) and written back as TOML (:func:`dump_toml`).

Part of :mod:`toolkit.config`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from collections.abc import Iterable
from typing import Any

from toolkit.config.loading import dotted_key
from toolkit.config.sections import CONFIG_FORMAT, PipelineConfig


def to_dict(cfg: PipelineConfig) -> dict[str, Any]:
    """Plain JSON-ready dict (tuples become lists, absent topics stay None)."""
    return typing.cast(dict[str, Any], json.loads(json.dumps(dataclasses.asdict(cfg))))


def config_hash(cfg: PipelineConfig, sections: Iterable[str] | None = None) -> str:
    """sha256 (hex) of the canonical JSON of ``cfg``, or only of the named sections
    (``"tables"``) and single keys (``"model.wheel_window_radius_m"``).

    Hashing only what a stage reads lets an up-to-date check ignore changes to settings the
    stage does not use. The format number is part of every hash.
    """
    full = to_dict(cfg)
    if sections is None:
        body: dict[str, Any] = full
    else:
        wanted = sorted(set(sections))
        body = {}
        for name in wanted:
            section, _, key = name.partition(".")
            if section not in full or (key and key not in full[section]):
                raise ValueError(f"unknown config section or key: {name!r}")
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
    _dump_table(cfg, "", lines)
    return "\n".join(lines).rstrip("\n") + "\n"


def _dump_table(obj: Any, prefix: str, lines: list[str]) -> None:
    nested = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            nested.append((f.name, value))
        else:
            lines.append(f"{f.name} = {toml_value(value)}")
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


def _toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = ['"']
    for ch in text:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)
