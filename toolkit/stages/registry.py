"""Every stage, in the order they run: name -> where it is declared, its scope, its help.

The command line (one command per stage), ``terrain run`` (``--from``/``--to``, the order,
which stages run per log), the executors and ``terrain logs`` all read this one list. A
line names the module that declares the stage (its ``SPEC``, a
:class:`~toolkit.stages.contract.Stage`), its scope and its command's one-line help, so
``terrain --help`` needs no stage imported; a stage's module is imported the first time its
declaration is asked for. Adding a stage is one new module with a ``SPEC`` and one line here.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from toolkit.stages.contract import Stage


class Listed(NamedTuple):
    """A stage's line: the module declaring its ``SPEC``, its scope, its command's help."""

    module: str
    scope: Literal["log", "workspace"]
    help: str


#: Stage name -> its line, in dependency order.
REGISTRY: dict[str, Listed] = {
    "ingest": Listed("toolkit.stages.ingest", "log", "MCAP logs -> per-sensor Parquet tables."),
    "pose": Listed(
        "toolkit.stages.pose", "log", "UKF pose fusion: WS/logs/<id>/pose.parquet at 100 Hz."
    ),
    "project": Listed(
        "toolkit.stages.project",
        "log",
        "Laser scans + pose -> WS/logs/<id>/points.parquet, the 3-D point cloud (sect. 3).",
    ),
    "label": Listed(
        "toolkit.stages.label",
        "log",
        "IMU shock -> WS/logs/<id>/events.parquet with ruggedness labels (sect. 5).",
    ),
    "tables": Listed(
        "toolkit.stages.tables",
        "workspace",
        "Events and the points under each rear tyre, split train/test: WS/tables/ (sect. 7).",
    ),
    "learn": Listed(
        "toolkit.stages.learn",
        "workspace",
        "Coordinate ascent on the training tables -> WS/model.json, the 14 parameters (sect. 6).",
    ),
    "online": Listed(
        "toolkit.stages.online",
        "workspace",
        "Learning while driving: test-then-train replay of the tables -> WS/online/ (sect. 8).",
    ),
    "evaluate": Listed(
        "toolkit.stages.evaluate",
        "workspace",
        "ROC against the race's method, speed control, report -> WS/report/ (sect. 7).",
    ),
}


def names() -> tuple[str, ...]:
    """Every stage's name, in the order they run."""
    return tuple(REGISTRY)


def listed(name: str) -> Listed:
    """Stage ``name``'s line (ToolkitError when there is none)."""
    line = REGISTRY.get(name)
    if line is None:
        raise ToolkitError(f"no stage named {name!r} (stages: {', '.join(REGISTRY)})")
    return line


def code_version_of(name: str) -> str:
    """The code version of registered stage ``name`` (:mod:`toolkit.code_version`): of the
    module that declares it and all it imports, found without importing any of them, so
    ``terrain logs`` tells stale outputs in milliseconds."""
    from toolkit.code_version import code_version

    return code_version([listed(name).module])


def stage(name: str) -> Stage[Any, Any]:
    """The declaration of stage ``name`` (ToolkitError when there is none, or it does not
    match its line)."""
    from toolkit.stages.contract import Stage

    line = listed(name)
    spec = getattr(importlib.import_module(line.module), "SPEC", None)
    if not isinstance(spec, Stage) or spec.name != name or spec.scope != line.scope:
        raise ToolkitError(f"{line.module} declares no SPEC = Stage({name!r}, {line.scope!r}, ...)")
    return spec


def stages() -> tuple[Stage[Any, Any], ...]:
    """Every stage's declaration, in order; each reads only stages listed before it."""
    out = tuple(stage(n) for n in REGISTRY)
    seen: set[str] = set()
    for s in out:
        later = [a for a in s.after if a not in seen]
        if later:
            raise ToolkitError(f"stage {s.name!r} needs {later[0]!r}, listed after it")
        seen.add(s.name)
    return out


def per_log() -> tuple[str, ...]:
    """The stages that run once per log, in order."""
    return tuple(n for n, line in REGISTRY.items() if line.scope == "log")


def over_workspace() -> tuple[str, ...]:
    """The stages that run once over the workspace, in order."""
    return tuple(n for n, line in REGISTRY.items() if line.scope == "workspace")


__all__ = [
    "code_version_of",
    "REGISTRY",
    "Listed",
    "listed",
    "names",
    "over_workspace",
    "per_log",
    "stage",
    "stages",
]
