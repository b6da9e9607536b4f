"""One JSON contract for every verb's ``--json`` (``docs/json.md``).

With ``--json`` a verb prints exactly one document on stdout, in success and in failure:

- a JSON object whose first key is ``"ok"`` (true when the verb exits 0);
- strict JSON (:mod:`toolkit.strict_json`: a value that is not a finite number is ``null``,
  never a ``NaN`` token);
- statuses spelled one way everywhere: ``done``-like words of each verb (``ingested``,
  ``projected``...), ``up_to_date``, ``failed``;
- on failure, ``"error"``: ``{"kind", "message", "path"}`` (``kind``: ``usage`` for exit 2,
  ``input`` for a file or value the toolkit refuses, ``stopped`` for Ctrl-C or SIGTERM,
  ``internal`` for a bug), and ``"exit_code"``.

The error lines stay on stderr as without ``--json``, so a person watching sees them too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import click

from toolkit import strict_json

JSON_FLAG = "--json"


def status_word(status: str) -> str:
    """A status as the JSON documents spell it: ``up to date`` -> ``up_to_date``."""
    return status.strip().replace(" ", "_")


def emit(doc: Mapping[str, Any], *, ok: bool = True) -> None:
    """Print the verb's one document: ``ok`` first, then ``doc``'s keys."""
    click.echo(strict_json.dumps({"ok": ok, **{k: v for k, v in doc.items() if k != "ok"}}))


def emit_failure(kind: str, message: str, path: Path | None, exit_code: int) -> None:
    """Print the document of a verb that failed before it could print its own."""
    emit(
        {
            "error": {
                "kind": kind,
                "message": " ".join(str(message).split()),
                "path": None if path is None else str(path),
            },
            "exit_code": exit_code,
        },
        ok=False,
    )


def result_doc(result: Any) -> dict[str, Any]:
    """A verb's result (a dataclass with a ``summary()``) as a document's fields: its
    fields (paths as text) and its summary line."""
    doc = {k: _plain(v) for k, v in dataclasses.asdict(result).items()}
    doc["summary"] = result.summary()
    return doc


def _plain(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def json_asked(args: list[str]) -> bool:
    """Whether a verb's arguments (a group context's ``args``, before the verb parses
    them) ask for ``--json``."""
    return JSON_FLAG in args


__all__ = ["JSON_FLAG", "emit", "emit_failure", "json_asked", "result_doc", "status_word"]
