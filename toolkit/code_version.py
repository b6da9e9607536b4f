"""The version of the code that makes a stage's outputs, derived from the code itself.

A stage's up-to-date key holds its inputs and its configuration; without its code, an
output made before a fix that changed results looks as current as one made after it. The
key therefore also holds a *code version*: the sha256 of the source of every module of this
package the stage's own modules import, directly or through others (imports inside
functions included), each module's path and bytes in the order of their names.

Derived, not declared. Dagster's ``code_version`` is declared by hand and bumped when
results change; a forgotten bump is exactly the stale result this guards against, and
nothing would say so. The datasets library hashes its builder's source instead, as here: a
change to any module a stage runs makes it run again, a change elsewhere (another stage's
module, the command line, the simulator) does not. The price is a rerun after an edit that
changes no result (a comment, a refactor): safe, and for a user it happens only on an
upgrade of the toolkit, which is when outputs must be checked anyway.

The import graph is read from the source with a regular expression (``import toolkit.x``,
``from toolkit.x import y``, ``y`` counted when it is a module), which takes milliseconds
where parsing the package's syntax trees took seconds; every package on a module's path
counts too (its ``__init__`` runs first); imports for type checking only do not. A module
imported by a name built at run time (``importlib``) is not seen: only the registry does so,
to find a stage's module, from which that stage's version starts anyway.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from functools import cache
from pathlib import Path

#: The package's root: ``toolkit/``, wherever it is installed.
PACKAGE_DIR = Path(__file__).resolve().parent
PACKAGE = PACKAGE_DIR.name

_FROM = re.compile(
    rf"^[ \t]*from[ \t]+({PACKAGE}(?:\.\w+)*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]+)", re.MULTILINE
)
_IMPORT = re.compile(r"^[ \t]*import[ \t]+([^\n]+)", re.MULTILINE)
_NAME = re.compile(r"\w+")


def module_file(name: str) -> Path | None:
    """The source file of module ``name`` of this package (``toolkit.a.b``), or None when
    there is none (a name imported from a module rather than a module)."""
    parts = name.split(".")
    if parts[0] != PACKAGE:
        return None
    base = PACKAGE_DIR.joinpath(*parts[1:])
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _run_time_source(source: str) -> str:
    """``source`` less its ``if TYPE_CHECKING:`` blocks, whose imports never run."""
    kept: list[str] = []
    block_indent: int | None = None
    for line in source.splitlines():
        indent = len(line) - len(line.lstrip())
        if block_indent is not None:
            if not line.strip() or indent > block_indent:
                continue
            block_indent = None
        if line.strip() == "if TYPE_CHECKING:":
            block_indent = indent
            continue
        kept.append(line)
    return "\n".join(kept)


def _imported(source: str) -> set[str]:
    """The modules of this package ``source`` imports when it runs, by name."""
    source = _run_time_source(source)
    found: set[str] = set()
    for module, names in _FROM.findall(source):
        found.add(module)
        for name in _NAME.findall(names.split("#")[0].replace(" as ", " , ")):
            found.add(f"{module}.{name}")
    for names in _IMPORT.findall(source):
        for item in names.split("#")[0].split(","):
            word = item.split(" as ")[0].strip()
            if word == PACKAGE or word.startswith(f"{PACKAGE}."):
                found.add(word)
    return {m for m in found if module_file(m) is not None}


@cache
def _closure(roots: frozenset[str]) -> tuple[str, ...]:
    """Every module of the package ``roots`` import, directly or not, with their packages,
    sorted by name."""
    seen: set[str] = set()
    todo = [r for r in roots if module_file(r) is not None]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        todo.extend(".".join(parts[:k]) for k in range(1, len(parts)))  # its packages
        path = module_file(name)
        if path is not None:
            todo.extend(_imported(path.read_text(encoding="utf-8")) - seen)
    return tuple(sorted(seen))


def modules_of(roots: Iterable[str]) -> tuple[str, ...]:
    """The modules a code version covers: ``roots`` and all they import of the package."""
    return _closure(frozenset(roots))


@cache
def _version(roots: frozenset[str]) -> str:
    digest = hashlib.sha256()
    for name in _closure(roots):
        path = module_file(name)
        if path is None:
            continue
        digest.update(name.encode() + b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


def code_version(roots: Iterable[str]) -> str:
    """The sha256 (hex) of the source of ``roots`` (module names of this package) and of
    every module of the package they import (module docstring). Computed once a process."""
    return _version(frozenset(roots))


__all__ = ["PACKAGE_DIR", "code_version", "module_file", "modules_of"]
