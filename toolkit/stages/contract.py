"""The stage contract: what every stage declares, what it is handed, what it gives back.

A stage is a :class:`Stage`: its name, its scope (once per log, or once over the workspace),
the files it needs and makes by layout name (:mod:`toolkit.layout`), the configuration
sections it reads, and a compute function over named inputs. The runner
(:mod:`toolkit.stages.runner`) does the rest, once for every stage: the freshness check, the
manifest record, the log's generation, the summary; the registry
(:mod:`toolkit.stages.registry`) lists the stages in the order they run. Modelled on
Kedro's node (a pure function over named inputs and outputs) and rosbags' name-to-class map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal, Protocol, TypeVar, cast

from toolkit.code_version import code_version
from toolkit.config import SECTIONS, PipelineConfig, config_hash
from toolkit.layout import LogFiles
from toolkit.manifest import Manifest, StageRecord
from toolkit.workspace import Workspace

#: Where a stage runs: once per log (in parallel over logs), or once over the workspace.
Scope = Literal["log", "workspace"]


class Outcome(Protocol):
    """What a stage returns: at least whether it computed anything (:attr:`Stage.describe`
    says the rest)."""

    @property
    def status(self) -> str: ...  # "up_to_date" when it found nothing to do


#: A stage's outcome type (its ``...Result``): what its compute makes and its recall gives.
OutcomeT = TypeVar("OutcomeT", bound=Outcome)
#: A stage's settings type (``LabelSettings``...): what its compute and recall are handed.
SettingsT = TypeVar("SettingsT")


def _summary(outcome: Any) -> str:
    """An outcome's own summary line(s)."""
    return str(outcome.summary())


@dataclass(frozen=True)
class Need:
    """A file a stage reads, by layout name, and the stage that makes it: the runner
    refuses it unless that stage's last finished run wrote it as it is now. An optional
    need (``tf_static``: not every log has one) is read when present."""

    name: str
    made_by: str
    optional: bool = False


@dataclass(frozen=True)
class Call(Generic[SettingsT]):
    """What the runner hands a stage's compute function.

    ``settings`` is the stage's own frozen configuration (its :attr:`Stage.settings`
    built from the sections it reads); ``inputs`` the sha256 of every need present, by
    layout name; ``files`` the directory it writes into (a per-log stage: the log's new
    generation); ``manifest`` that directory's manifest, for the header fields of the
    stages before it; ``config_hash`` the hash the runner records (and the stage stamps on
    its tables); ``start`` when the stage began (``time.perf_counter()``); ``step`` a
    progress hook (a word on what it is doing); ``found`` what the stage's
    :attr:`Stage.gather` found besides the inputs' hashes (None without one)."""

    workspace: Workspace
    log_id: str
    settings: SettingsT
    files: LogFiles
    manifest: Manifest
    inputs: Mapping[str, str]
    config_hash: str
    start: float
    step: Callable[[str], None]
    found: Any = None


@dataclass(frozen=True)
class Made(Generic[OutcomeT]):
    """What a stage's compute function gives back: its outcome, and what the runner records
    (the files it wrote, relative to its directory; rows per table; rejects by reason;
    seconds per step; warnings; and the manifest's header fields it sets)."""

    outcome: OutcomeT
    outputs: tuple[str, ...]
    row_counts: Mapping[str, int] = field(default_factory=dict)
    rejects: Mapping[str, int] = field(default_factory=dict)
    timings_s: Mapping[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    header: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Recalled(Generic[SettingsT]):
    """An up-to-date stage's last run, for its :attr:`Stage.recall`: its record, the
    manifest's header, the log, the settings, the seconds the check took, the workspace,
    and what the stage's gather or locate found."""

    log_id: str
    record: StageRecord
    header: Mapping[str, Any]
    settings: SettingsT
    seconds: float
    workspace: Workspace
    found: Any = None


@dataclass(frozen=True)
class Stage(Generic[SettingsT, OutcomeT]):
    """One stage's declaration.

    - ``name``, ``scope``: as listed in the registry.
    - ``compute`` makes its outputs from a :class:`Call`; ``recall`` gives its outcome from
      its record when it is up to date.
    - ``needs``, ``makes``: what it reads and writes, by layout name (:mod:`toolkit.layout`).
    - ``settings``: the frozen dataclass it receives, whose fields are named after the
      configuration's sections (fields with defaults that are no section stay as they are).
    - ``sections``: the configuration whose hash is its configuration's part of the
      up-to-date key: by default (None) the sections its ``settings`` hold; declared when it
      hashes fewer (one key, ``"model.wheel_window_radius_m"``, or leaves out a section whose
      changes already reach it through its inputs); ``hashed`` overrides them when what it
      reads depends on the configuration (project reads the tyres' radius only when it cuts
      by one). Declared sections its settings do not hold are refused when it is declared.
    - ``check`` refuses, before anything is hashed, a log the stage cannot work on (a role
      it needs missing).
    - ``gather`` replaces the hashing of ``needs`` for a stage whose inputs are no fixed
      list of files (tables reads every log's): the inputs' hashes, checked against their
      makers, and what it found on the way (``call.found``). ``locate`` is the gather of the
      stage that starts a log from its file (ingest): from the file's path, the log's id,
      the inputs' hashes and what it found.
    - ``rows``: the row counts its summary line shows (None: all, summed); ``unit`` what its
      progress counts and ``progress_total`` how many; ``describe`` its outcome in words.
    """

    name: str
    scope: Scope
    compute: Callable[[Call[SettingsT]], Made[OutcomeT]]
    recall: Callable[[Recalled[SettingsT]], OutcomeT]
    settings: type[SettingsT]
    needs: tuple[Need, ...] = ()
    makes: tuple[str, ...] = ()
    sections: tuple[str, ...] | None = None
    hashed: Callable[[PipelineConfig], tuple[str, ...]] | None = None
    check: Callable[[LogFiles, SettingsT], None] | None = None
    gather: Callable[[Workspace, PipelineConfig], tuple[dict[str, str], Any]] | None = None
    locate: Callable[[Path], tuple[str, dict[str, str], Any]] | None = None
    rows: tuple[str, ...] | None = None
    unit: str = "step"
    progress_total: Callable[[PipelineConfig], int | None] | None = None
    describe: Callable[[OutcomeT], str] = _summary

    def __post_init__(self) -> None:
        """Refuse a declaration the runner could not honour: settings that are no dataclass,
        a settings field that is neither a configuration section nor has a default, or a
        declared section its settings do not hold (TypeError, naming the stage)."""
        if not (isinstance(self.settings, type) and dataclasses.is_dataclass(self.settings)):
            raise TypeError(f"stage {self.name!r}: settings must be a dataclass class")
        for f in dataclasses.fields(self.settings):
            no_default = f.default is dataclasses.MISSING and (
                f.default_factory is dataclasses.MISSING
            )
            if f.name not in SECTIONS and no_default:
                raise TypeError(
                    f"stage {self.name!r}: settings field {f.name!r} is no configuration "
                    "section and has no default"
                )
        held = self._setting_sections()
        for name in self.sections or ():
            if name.partition(".")[0] not in held:
                raise TypeError(
                    f"stage {self.name!r}: it hashes {name!r}, which its settings do not hold"
                )

    @property
    def starts_log(self) -> bool:
        """Whether it starts a log from its file (ingest): run with ``source``, the file."""
        return self.locate is not None

    @property
    def after(self) -> tuple[str, ...]:
        """The stages whose outputs this one reads, in the order first needed."""
        return tuple(dict.fromkeys(n.made_by for n in self.needs if n.made_by != self.name))

    def hashed_sections(self, config: PipelineConfig) -> tuple[str, ...]:
        """The configuration whose hash keys this stage's up-to-date check."""
        if self.hashed is not None:
            return self.hashed(config)
        if self.sections is not None:
            return self.sections
        return self._setting_sections()

    def config_hash(self, config: PipelineConfig) -> str:
        """The hash of the configuration this stage reads (:meth:`hashed_sections`): its part
        of the up-to-date key, stamped on its tables."""
        return config_hash(config, self.hashed_sections(config))

    @property
    def code_version(self) -> str:
        """The version of the code of this stage's functions: their modules and all they
        import (:mod:`toolkit.code_version`). A registered stage is keyed by its registry
        module's instead (:func:`toolkit.stages.runner.code_version_for`), the same code
        found without importing it."""
        functions = (self.compute, self.recall, self.check, self.gather, self.locate)
        return code_version(f.__module__ for f in functions if f is not None)

    def settings_from(self, config: PipelineConfig) -> SettingsT:
        """The stage's own frozen configuration: its ``settings`` class, each field the
        configuration's section of that name."""
        return self.settings(**{name: getattr(config, name) for name in self._setting_sections()})

    def _setting_sections(self) -> tuple[str, ...]:
        """The fields of its ``settings`` that are configuration sections, in order."""
        fields = dataclasses.fields(cast(Any, self.settings))
        return tuple(f.name for f in fields if f.name in SECTIONS)


__all__ = [
    "Call",
    "Made",
    "Need",
    "Outcome",
    "Recalled",
    "OutcomeT",
    "Scope",
    "SettingsT",
    "Stage",
]
