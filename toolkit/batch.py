"""Batches: one task per log on an executor (:mod:`toolkit.executors`), past any failure.

Batch work (ingesting a thousand logs, running every stage over them) goes through a
:class:`concurrent.futures.Executor`, so the same code runs on one laptop or a cluster:

- :func:`~toolkit.executors.make_executor` opens the executor: ``"local"`` is a process pool
  on this machine, ``"dask"`` a ``distributed`` client's executor
  (``pip install 'terrain[distributed]'``).
- :func:`shard` picks this job's share of the logs, for job arrays (``--shard-index I
  --num-shards K``): every job sees the same list and takes a disjoint part of it.
- :func:`run_batch` submits one task per item and collects the outcomes. One failing item
  never stops the others: its error becomes a one-line reason in the :class:`BatchSummary`.
- :func:`run_ingest_batch` is ``terrain ingest``: the config loaded once, the logs sharded
  and ingested by :func:`~toolkit.stages.ingest.ingest_log` in parallel.

Tasks cross process (and machine) boundaries, so a task is a module-level function (or a
``functools.partial`` of one) whose arguments are plain data: paths and TOML text, not live
objects. On Dask, every worker must see the logs and the workspace at the same paths (a
shared filesystem); relative paths are made absolute against the submitting process's cwd.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import logging.handlers
import os
import time
import traceback
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, Literal, TypeVar

from toolkit.config import PipelineConfig, default_config, load_config
from toolkit.errors import ConfigError, ToolkitError
from toolkit.executors import make_executor
from toolkit.progress import note, progress
from toolkit.stages import registry
from toolkit.stages.runner import run_stage
from toolkit.workspace import Workspace

_log = logging.getLogger(__name__)

_P = TypeVar("_P", bound="str | os.PathLike[str]")

ItemStatus = Literal["done", "up_to_date", "failed"]
_STATUS_ORDER: dict[str, int] = {"done": 0, "up_to_date": 1, "failed": 2}


# --------------------------------------------------------------------------------------
# Shards
# --------------------------------------------------------------------------------------


def _shard_key(item: str | os.PathLike[str]) -> tuple[str, str]:
    path = PurePath(item)
    return (path.name, str(path))


def shard(items: Iterable[_P], shard_index: int, num_shards: int) -> list[_P]:
    """This job's share of ``items`` (log paths): every ``num_shards``-th of the sorted list.

    The items are sorted by file name, then by the whole path, and shard ``i`` takes
    positions ``i, i + K, i + 2K, ...`` (round-robin). Sorting by name first keeps the split
    the same on machines that mount the logs under different directories; round-robin keeps
    the shards within one item of each other in size. Every job of an array must be given the
    same list: the shards are then disjoint and together hold every item once (repeated
    items are kept once). A log added between jobs may move others to another shard; a
    re-run picks up whatever was missed, since finished logs are skipped as up to date.

    Raises ConfigError when ``num_shards < 1`` or ``shard_index`` is not in
    ``0..num_shards-1``, naming both values.
    """
    for name, value in (("shard_index", shard_index), ("num_shards", num_shards)):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name}: expected an integer (got {value!r})")
    if num_shards < 1:
        raise ConfigError(f"num_shards: expected 1 or more (got {num_shards})")
    if not 0 <= shard_index < num_shards:
        raise ConfigError(
            f"shard_index: expected 0..{num_shards - 1} for num_shards={num_shards} "
            f"(got shard_index={shard_index})"
        )
    unique: dict[str, _P] = {}
    for item in items:
        unique.setdefault(str(item), item)
    ordered = sorted(unique.values(), key=_shard_key)
    return ordered[shard_index::num_shards]


# --------------------------------------------------------------------------------------
# Running a batch
# --------------------------------------------------------------------------------------


def _item_name(item: Any) -> str:
    """How a progress line names an item: a log's id when known, else its file's name."""
    if isinstance(item, tuple) and item:
        return str(item[1]) if len(item) > 1 and item[1] else Path(str(item[0])).name
    return Path(str(item)).name if isinstance(item, (str, Path)) else str(item)


@dataclass(frozen=True)
class ItemOutcome:
    """What became of one item: its status, the task's result or the failure's reason."""

    item: Any
    status: ItemStatus
    result: Any = None
    reason: str = ""
    detail: str = ""  # the traceback of an unexpected (non-Toolkit) error, for --debug

    @property
    def label(self) -> str:
        """The word shown in the summary: the result's own ``status`` when it has one."""
        if self.status == "failed":
            return "failed"
        if self.status == "up_to_date":
            return "up to date"
        own = getattr(self.result, "status", None)
        return own.replace("_", " ") if isinstance(own, str) and own else "done"


@dataclass(frozen=True)
class BatchSummary:
    """The outcome of a batch, item by item in input order.

    ``done`` and ``up_to_date`` list the items that succeeded (work done, or nothing to do);
    ``failed`` maps each failed item to a one-line reason. ``render`` gives the text summary.
    """

    desc: str
    outcomes: tuple[ItemOutcome, ...]
    seconds: float
    unit: str = "item"
    notes: tuple[str, ...] = field(default=())

    @property
    def done(self) -> list[Any]:
        """Items whose task did its work."""
        return [o.item for o in self.outcomes if o.status == "done"]

    @property
    def up_to_date(self) -> list[Any]:
        """Items that had nothing to do (already current)."""
        return [o.item for o in self.outcomes if o.status == "up_to_date"]

    @property
    def failed(self) -> dict[Any, str]:
        """Failed item -> one-line reason, in input order."""
        return {o.item: o.reason for o in self.outcomes if o.status == "failed"}

    @property
    def results(self) -> dict[Any, Any]:
        """Item -> the task's result, for the items that succeeded."""
        return {o.item: o.result for o in self.outcomes if o.status != "failed"}

    @property
    def ok(self) -> bool:
        """True when no item failed."""
        return all(o.status != "failed" for o in self.outcomes)

    def render(self, *, with_reasons: bool = True) -> str:
        """One line per item, then the counts: ``ingest: 3 logs: 1 ingested, 1 up to date, ...``.

        ``with_reasons=False`` leaves the failure reasons out (the command line prints them
        on stderr instead, so a terminal does not show them twice).
        """
        width = max((len(o.label) for o in self.outcomes), default=0)
        lines = []
        for o in self.outcomes:
            line = f"  {o.label:<{width}}  {o.item}"
            log_id = getattr(o.result, "log_id", None)
            if isinstance(log_id, str) and log_id:
                line += f"  [{log_id}]"
            warnings = getattr(o.result, "warnings", None)
            if isinstance(warnings, Sequence) and not isinstance(warnings, str) and warnings:
                line += f"  ({len(warnings)} warning{'s' if len(warnings) != 1 else ''})"
            if o.status == "failed" and with_reasons:
                line += f": {o.reason}"
            lines.append(line)
        counts: dict[str, int] = {}
        for o in sorted(self.outcomes, key=lambda o: _STATUS_ORDER[o.status]):
            counts[o.label] = counts.get(o.label, 0) + 1
        counts.setdefault("failed", 0)
        n = len(self.outcomes)
        noun = self.unit if n == 1 else f"{self.unit}s"
        text = ", ".join(f"{count} {label}" for label, count in counts.items())
        lines.append(f"{self.desc}: {n} {noun}: {text} in {self.seconds:.1f} s")
        lines.extend(self.notes)
        return "\n".join(lines)


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _reason(exc: BaseException, item: Any) -> str:
    """One line saying why an item failed.

    A ToolkitError gives its message, without the path prefix when it names the item itself
    (the summary already shows the item); any other exception is prefixed with its type.
    """
    if isinstance(exc, ToolkitError):
        message = str(exc)
        if exc.path is not None:
            prefix = f"{exc.path}: "
            same = str(exc.path) == str(item)
            with contextlib.suppress(OSError, TypeError, ValueError):
                same = same or Path(exc.path).resolve() == Path(item).resolve()
            if same and message.startswith(prefix):
                message = message[len(prefix) :]
        return _one_line(message) or type(exc).__name__
    text = _one_line(str(exc))
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _call_guarded(task: Callable[[Any], Any], item: Any) -> ItemOutcome:
    """Run ``task(item)`` where the task runs, turning any error into a failed outcome.

    Catching on the worker side means an exception never has to survive pickling (a
    ToolkitError subclass with extra constructor arguments might not), and the reason is
    computed while the exception's attributes (e.g. its path) are still at hand.
    """
    try:
        result = task(item)
    except ToolkitError as exc:
        return ItemOutcome(item, "failed", reason=_reason(exc, item))
    except Exception as exc:  # a bug in one task must not stop the batch: record it
        return ItemOutcome(item, "failed", reason=_reason(exc, item), detail=traceback.format_exc())
    own = getattr(result, "status", result)
    status: ItemStatus = "up_to_date" if isinstance(own, str) and own == "up_to_date" else "done"
    return ItemOutcome(item, status, result=result)


def run_batch(
    task: Callable[[Any], Any],
    items: Sequence[Hashable],
    executor: Executor,
    *,
    desc: str,
    unit: str = "item",
    bar: Any = None,
) -> BatchSummary:
    """Run ``task(item)`` for every item on ``executor``; never stop at a failure.

    ``task`` must pickle (a module-level function or a ``functools.partial`` of one). An item
    whose task raises is recorded as failed with a one-line reason (a ToolkitError's
    message; any other exception with its type) and the others go on; so are items the
    executor itself could not run (a worker process that died, a lost Dask worker). A result
    counts as up to date when it (or its ``status`` attribute) is ``"up_to_date"``, as done
    otherwise. Outcomes are reported in input order; repeated items run once. A progress bar
    over the items shows on a terminal; ``bar``, an open progress bar (``terrain run``'s
    one display for the whole run), is advanced instead.
    """
    unique = list(dict.fromkeys(items))
    start = time.perf_counter()
    outcomes: dict[int, ItemOutcome] = {}
    own = progress(total=len(unique), desc=desc, unit=unit) if bar is None else None
    with own if own is not None else contextlib.nullcontext(bar) as bar:
        futures: dict[Future[ItemOutcome], int] = {}
        for index, item in enumerate(unique):
            try:
                futures[executor.submit(_call_guarded, task, item)] = index
            except Exception as exc:  # e.g. a broken pool or a task that does not pickle
                outcomes[index] = ItemOutcome(item, "failed", reason=_reason(exc, item))
                bar.update(1)
        for future in as_completed(futures):
            index = futures[future]
            item = unique[index]
            try:
                outcome = future.result()
            except Exception as exc:  # the executor could not run the task at all
                outcome = ItemOutcome(item, "failed", reason=_reason(exc, item))
            outcomes[index] = outcome
            if outcome.detail:
                _log.debug("%s: %s", item, outcome.detail)
            bar.update(1)
            # Off a terminal, a line per item as it finishes (the bar says it on one).
            note(f"{desc}: {_item_name(item)} {outcome.label} ({len(outcomes)}/{len(unique)})")
    ordered = tuple(outcomes[i] for i in range(len(unique)))
    return BatchSummary(desc, ordered, time.perf_counter() - start, unit=unit)


# --------------------------------------------------------------------------------------
# terrain ingest
# --------------------------------------------------------------------------------------


def stage_task(
    item: str | tuple[str, str],
    *,
    stage: str,
    workspace_root: str,
    config: PipelineConfig,
    overwrite: bool,
    cwd: str,
) -> Any:
    """One per-log stage on one log, where the task runs (a pool process or a Dask worker).

    ``item`` is the log's path as given, or (that path, its log id) once it is ingested;
    relative paths are taken against ``cwd``, the submitting process's working directory.
    Plain data in (the frozen configuration is pickled: a worker needs no access to the
    user's config file), the stage's outcome out."""
    path, log_id = item if isinstance(item, tuple) else (item, "")
    spec = registry.stage(stage)
    source = Path(cwd, path) if spec.starts_log else None
    ws = Workspace(workspace_root)
    return run_stage(spec, ws, config, log_id=log_id, overwrite=overwrite, source=source)


def this_shard(
    logs: Sequence[Path], shard_index: int, num_shards: int
) -> tuple[dict[str, Path], list[Path]]:
    """The logs once each ("a.mcap" and "./a.mcap" are one log: never run twice at once),
    by absolute path, and this shard's share of them (:func:`shard`) in the user's order."""
    unique: dict[str, Path] = {}
    for log in logs:
        unique.setdefault(os.path.abspath(log), log)
    picked = set(shard(list(unique.values()), shard_index, num_shards))
    return unique, [log for log in unique.values() if log in picked]


def _config_in_force(workspace: Workspace, config_path: Path | None) -> PipelineConfig:
    """``-c CONFIG`` if given, else the workspace's recorded configuration, else the default.

    Loaded (and so validated) once, before anything is submitted: a bad configuration fails
    the command once, not once per log.
    """
    if config_path is not None:
        return load_config(config_path)
    if workspace.config_path.is_file():
        return load_config(workspace.config_path)
    return default_config()


@dataclass(frozen=True)
class Executors:
    """Where a batch's logs run: a local pool (``workers`` processes, 0 in this process) or
    a Dask cluster (``scheduler``), and which share of the logs is this job's
    (``shard_index`` of ``num_shards``, for job arrays)."""

    executor_kind: str = "local"
    scheduler: str | None = None
    workers: int | None = None
    shard_index: int = 0
    num_shards: int = 1

    def open(self) -> contextlib.AbstractContextManager[Executor]:
        """The executor (:func:`~toolkit.executors.make_executor`); closing the ``with``
        shuts it down."""
        return make_executor(self.executor_kind, workers=self.workers, scheduler=self.scheduler)

    def mine(self, logs: Sequence[Path]) -> tuple[dict[str, Path], list[Path]]:
        """The logs once each, and this shard's share (:func:`this_shard`)."""
        return this_shard(logs, self.shard_index, self.num_shards)


#: Every log, on a local pool of one process per CPU.
LOCAL = Executors()


@dataclass(frozen=True)
class BatchStart:
    """What a batch command settles before any log runs (:func:`begin_batch`)."""

    workspace: Workspace
    config: PipelineConfig
    adopt_config: bool  # record ``config`` as the workspace's once it has worked
    unique: dict[str, Path]  # the logs once each
    mine: list[Path]  # this shard's share


@contextlib.contextmanager
def begin_batch(
    logs: Sequence[Path],
    workspace_root: Path,
    config_path: Path | None,
    *,
    overwrite: bool,
    executors: Executors,
) -> Iterator[BatchStart]:
    """How ``terrain ingest`` and ``terrain run`` both begin: this shard's logs
    (:meth:`Executors.mine`), the configuration in force (:func:`_config_in_force`), and
    the workspace, created for the ``with`` (:meth:`Workspace.created`), with that
    configuration checked against its own once (:meth:`Workspace.check_config`).

    The configuration is validated before anything is made: a bad one leaves no workspace.
    A first run that ingests no log leaves no workspace either. ingest_log's own rule
    (refuse another configuration unless ``overwrite``) is checked once here, so a mismatch
    fails the command once, not once per log.
    """
    unique, mine = executors.mine(logs)
    workspace = Workspace(workspace_root)
    config = _config_in_force(workspace, config_path)
    with workspace.created():
        adopt_config = workspace.check_config(config, overwrite=overwrite)
        yield BatchStart(workspace, config, adopt_config, unique, mine)


def run_ingest_batch(
    logs: Sequence[Path],
    workspace_root: Path,
    config_path: Path | None,
    *,
    overwrite: bool,
    executors: Executors = LOCAL,
    executor: Executor | None = None,
) -> BatchSummary:
    """``terrain ingest``: ingest this shard's logs in parallel; return the summary.

    The configuration is read once (``config_path``, else the workspace's recorded
    ``WS/config.toml``, else the built-in default), recorded as the configuration in force
    (one that differs from the workspace's is refused unless ``overwrite``, as ingest_log
    does) and sent to every task. Logs are sharded (:func:`shard`) and each runs
    through the ingest stage (:func:`stage_task`) on ``executor`` if given, else on
    one opened by :func:`~toolkit.executors.make_executor` (and closed before
    returning). A log that cannot be ingested is listed as failed with its reason; the
    others complete. Re-running finishes only what is missing: ingest_log reports unchanged
    logs as up to date.

    The workspace lock is taken shared: the jobs of an array share one workspace (each log's
    files and manifest are its own), while a stage holding it exclusively refuses them.
    """
    shard_index, num_shards = executors.shard_index, executors.num_shards
    # Each ingest_log records the config only when it succeeds with it.
    with begin_batch(
        logs, workspace_root, config_path, overwrite=overwrite, executors=executors
    ) as begun:
        workspace, config, mine = begun.workspace, begun.config, begun.mine
        task = functools.partial(
            stage_task,
            stage="ingest",
            workspace_root=os.path.abspath(workspace_root),
            config=config,
            overwrite=overwrite,
            cwd=os.getcwd(),
        )
        # Shared: ingests (a job array's shards) run side by side, but not while a stage holds the
        # workspace exclusively (pose), and such a stage waits for no ingest: it is refused.
        with workspace.lock(shared=True):
            if executor is not None:
                summary = run_batch(task, mine, executor, desc="ingest", unit="log")
            else:
                with executors.open() as opened:
                    summary = run_batch(task, mine, opened, desc="ingest", unit="log")
        if begun.adopt_config and (summary.done or summary.up_to_date):
            workspace.write_config(config)  # a config becomes the workspace's once it has worked
        if num_shards > 1:
            note = f"shard {shard_index} of {num_shards}: {len(mine)} of {len(begun.unique)} logs"
            summary = dataclasses.replace(summary, notes=(note,))
    return summary
