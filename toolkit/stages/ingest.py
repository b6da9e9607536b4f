"""Ingest: one MCAP log -> the contract's per-sensor Parquet tables and the log's manifest.

:func:`ingest_log` streams the log chunk by chunk (:class:`~toolkit.mcapio.reader.LogReader`),
decodes each chunk's messages of one topic in one vectorised call
(:func:`~toolkit.mcapio.cdr.decode_batch`), converts them to rows by the topic's role
(:mod:`toolkit.ingestion.roles`) and appends them to one streaming Parquet writer per table.
Memory stays bounded by a chunk plus a small reorder buffer per table, whatever the log's length.

Faithful accounting, per topic: every message the reader delivers is either written or rejected
with one reason, so ``read = written + sum(rejects)``; messages the reader could not salvage
from a damaged file are reported separately, by reason (``lost``). Reject reasons, checked in
this order:

- ``duplicate``: same topic, same log time and the same payload bytes as a message already seen
  (within :data:`DUPLICATE_WINDOW_NS` of log time, which covers a repeated chunk or record);
- ``bad_payload``: the payload does not decode as the channel's message type;
- ``time_outlier``: the row sits at one end of its (time-sorted) table, cut off from the rest
  by more than a minute, in a group of at most 0.1 % of the rows: a stray stamp minutes to
  years away (:mod:`toolkit.ingestion.timecheck`);
- ``bad_time``: the message's time (stamp, or log time when the stamp is zero) is negative
  as int64 nanoseconds: a time beyond 2^63 ns or a corrupt one;
- ``clock_skew``: the corrected header stamp is more than ``time.max_header_skew_ns`` from the
  log time;
- ``non_finite``: NaN/inf where a value must be finite (imu, wheels, heading, laser angles, a GPS
  position that claims a fix, the truth pose).

Kept but counted (``counts`` in the manifest, not rejects): laser no-returns (beams),
``gps_no_fix`` (NO_FIX messages are kept with their status; the pose stage decides),
``stamp_missing`` (zero header stamp: the log time is used) and ``out_of_order`` (a message whose
``t_ns`` is earlier than one before it on the same topic; tables are sorted by ``t_ns`` anyway,
by a reorder buffer and, when rows arrive later than the buffer can hold, an out-of-core re-sort
of the table's partial file).

Outputs (``WS/logs/<log_id>/``): ``imu``, ``gps``, ``heading``, ``wheels`` and ``laser`` tables
(always; empty when an optional role is absent), ``truth_pose.parquet`` and
``truth_features.parquet`` when the log has them (simulated logs), ``tf_static.json`` when it has
static transforms (the sensor mounts, for the projection stage), ``mcap_metadata.json`` when the
log has MCAP metadata records (name -> key -> value; the simulator's ``terrain_sim`` record
holds its ENU origin and truth parameters). Every file is written aside and
renamed into place only once all of them are complete; on any error the partial files are
removed and the stage is left not current in the manifest.

Manifest (``WS/logs/<log_id>/manifest.json``): the stage record ``ingest`` (inputs
``{"log": sha256}``, the hash of the ``topics``, ``time`` and ``pose`` sections, outputs, rows
per table, reject totals by reason, timings, warnings), and two top-level sections: ``source``
(path, sha256, size) and ``ingest`` (per topic: role, type, read, written, rows, rejects, counts
and lost by reason; configured topics missing from the log; the reader's damage list and
unknown lost bytes; tables that needed the out-of-core re-sort; count totals).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.atomic import atomic_write_json
from toolkit.config import PipelineConfig, TimeConfig, TopicsConfig
from toolkit.errors import CdrError, LogReadError, SchemaError, StageError
from toolkit.ingestion.dedup import DuplicateFilter
from toolkit.ingestion.reorder import DEFAULT_REORDER_BUFFER_BYTES, ReorderBuffer
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.ingestion.rows import ConvertContext, Converter, RoleRows
from toolkit.ingestion.timecheck import stream_time_outliers
from toolkit.layout import log_file_name
from toolkit.manifest import StageRecord, file_sha256
from toolkit.mcapio.cdr import decode_batch
from toolkit.mcapio.msgdefs import full_type_name, known_types, parse_schema_text
from toolkit.mcapio.reader import Channel, Damage, LogReader, MessageBatch, ReadReport
from toolkit.progress import progress
from toolkit.sim.record import sim_origin
from toolkit.stages.contract import Call, Made, Recalled, Stage
from toolkit.stages.runner import run_stage
from toolkit.stages.truth import truth_to_pose_frame
from toolkit.tableio import TableWriter
from toolkit.workspace import Workspace, make_log_id

_log = logging.getLogger(__name__)

#: The manifest's name for this stage.
STAGE = "ingest"

#: Configuration sections ingest reads: its identity (a pose tuning change must not make
#: every ingest stale, so ``[pose]`` is not among them).
CONFIG_SECTIONS: tuple[str, ...] = ("topics", "time")

#: Sensor tables always written, empty when their role is absent (role -> table).
SENSOR_TABLES: dict[str, str] = {
    "imu": "imu",
    "gps": "gps",
    "heading": "heading",
    "wheels": "wheels",
    "lasers": "laser",
}

#: Roles written as Parquet tables only when the log has them.
TRUTH_TABLES: dict[str, str] = {"truth_pose": "truth_pose", "truth_features": "truth_features"}

#: Tables with a contract schema in schemas/tables (truth_features has none: written as is).
SCHEMA_TABLES: frozenset[str] = frozenset({*SENSOR_TABLES.values(), "truth_pose"})

#: Output name of the static transforms.
TF_STATIC_OUTPUT = log_file_name("tf_static")

#: Output name of the log's MCAP metadata records (record name -> key -> value).
MCAP_METADATA_OUTPUT = log_file_name("mcap_metadata")

#: A topic rejecting more than this fraction of its messages is a warning on the terminal.
REJECT_WARN_FRACTION = 0.01

#: Reject reasons, in the order they are checked.
REJECT_REASONS: tuple[str, ...] = (
    "duplicate",
    "bad_payload",
    "bad_time",
    "clock_skew",
    "non_finite",
    "time_outlier",
)


# --------------------------------------------------------------------------------------
# Results and accounting
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IngestResult:
    """What :func:`ingest_log` did to one log.

    ``status`` is ``"ingested"`` or ``"up_to_date"`` (nothing rewritten). ``row_counts`` is
    rows per output table; ``rejects`` and ``lost`` are counts by topic, then reason
    (``lost``: messages the reader could not salvage from a damaged file).
    """

    log_path: Path
    log_id: str
    status: str
    row_counts: dict[str, int]
    rejects: dict[str, dict[str, int]]
    lost: dict[str, dict[str, int]]
    warnings: tuple[str, ...]
    seconds: float

    def summary(self) -> str:
        """One line for people."""
        rows = ", ".join(f"{k} {v}" for k, v in sorted(self.row_counts.items()))
        rejected = sum(sum(r.values()) for r in self.rejects.values())
        lost = sum(sum(r.values()) for r in self.lost.values())
        return (
            f"{self.log_path}: {self.status.replace('_', ' ')} as {self.log_id} "
            f"({rows}; {rejected} rejected, {lost} lost) in {self.seconds:.2f} s"
        )


@dataclass
class TopicAccount:
    """Per-topic accounting: ``read == written + sum(rejects)``."""

    topic: str
    role: str
    type_name: str
    table: str
    read: int = 0
    written: int = 0
    rows: int = 0
    rejects: Counter[str] = field(default_factory=lambda: Counter(dict.fromkeys(REJECT_REASONS, 0)))
    counts: Counter[str] = field(
        default_factory=lambda: Counter({"out_of_order": 0, "stamp_missing": 0})
    )
    lost: dict[str, int] = field(default_factory=dict)
    max_t_ns: int | None = None

    def to_json(self) -> dict[str, Any]:
        """JSON-ready (for the manifest)."""
        return {
            "role": self.role,
            "type": self.type_name,
            "table": self.table,
            "read": self.read,
            "written": self.written,
            "rows": self.rows,
            "rejects": dict(sorted(self.rejects.items())),
            "counts": dict(sorted(self.counts.items())),
            "lost": dict(sorted(self.lost.items())),
        }


# --------------------------------------------------------------------------------------
# Topics, roles and decoders
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicPlan:
    """How one topic of the log is ingested: its role, table, decoder and converter."""

    topic: str
    role: str
    table: str
    schema_name: str
    type_name: str
    decode: Callable[[Sequence[bytes]], dict[str, np.ndarray]]
    convert: Converter
    context: ConvertContext


@functools.cache
def _known_types() -> frozenset[str]:
    return frozenset(known_types())


def channel_decoder(
    topic: str, channel: Channel
) -> Callable[[Sequence[bytes]], dict[str, np.ndarray]]:
    """decode_batch bound to the channel's type: by name for a type the toolkit ships,
    else by the schema text the log carries (parsed once)."""
    if channel.message_encoding != "cdr":
        raise StageError(
            f"topic {topic} has message encoding {channel.message_encoding!r}; only ROS 2 "
            "'cdr' messages can be ingested"
        )
    name = full_type_name(channel.schema_name)
    if name in _known_types():
        return functools.partial(decode_batch, name)
    if channel.schema_encoding == "ros2msg" and channel.schema_data:
        try:
            spec = parse_schema_text(name, bytes(channel.schema_data).decode("utf-8"))
        except (SchemaError, UnicodeDecodeError, ValueError) as exc:
            raise StageError(f"topic {topic}: unusable schema {name!r}: {exc}") from exc
        return functools.partial(decode_batch, spec)
    raise StageError(f"topic {topic}: no message definition for {name!r} in the log or toolkit")


def _role_line(role: str, topics: Sequence[str]) -> str:
    accepts = ", ".join(ROLE_SPECS[role].accepted_types)
    return f"{role} ({', '.join(topics)}; accepts {accepts})"


def resolve_topics(
    config: IngestSettings, found: Mapping[str, Channel], log_path: Path
) -> tuple[dict[str, TopicPlan], dict[str, list[str]], list[str]]:
    """Plan every configured topic present in the log.

    Returns (topic -> plan, role -> configured topics missing from the log, warnings). Any
    role may be missing: all missing roles are reported in one warning line, each with its
    configured topics and the message types it accepts (their tables are written empty). A
    log holding none of the configured topics is a StageError naming the topics it does
    hold; a message type a role does not accept is a StageError naming topic, type and the
    accepted types.
    """
    plans: dict[str, TopicPlan] = {}
    missing: dict[str, list[str]] = {}
    warnings: list[str] = []
    wholly_missing: list[str] = []
    by_role = config.topics.by_role()
    for role, topics in by_role.items():
        absent = [t for t in topics if t not in found]
        if absent:
            missing[role] = absent
        if len(absent) == len(topics):
            wholly_missing.append(role)
        elif absent:
            warnings.append(f"role {role}: topic(s) {', '.join(absent)} not in the log")
        for topic in topics:
            if topic in found:
                plans[topic] = plan_topic(topic, role, found[topic], config, log_path)
    if not plans:
        configured = "; ".join(_role_line(r, t) for r, t in by_role.items()) or "none"
        raise StageError(
            f"none of the configured topics is in the log (configured: {configured}; topics "
            f"found: {', '.join(sorted(found)) or 'none'}); give a configuration for this "
            "vehicle with -c",
            path=log_path,
        )
    if wholly_missing:
        warnings.insert(
            0,
            "roles missing from the log, their tables empty: "
            + "; ".join(_role_line(r, by_role[r]) for r in wholly_missing),
        )
    return plans, missing, warnings


def plan_topic(
    topic: str, role: str, channel: Channel, config: IngestSettings, log_path: Path
) -> TopicPlan:
    """The plan of one channel playing ``role``; StageError (naming the log) when the role
    does not accept its type or its messages cannot be decoded."""
    spec = ROLE_SPECS[role]
    try:
        convert = spec.converter_for(topic, channel.schema_name)
        decode = channel_decoder(topic, channel)
    except StageError as exc:
        raise StageError(str(exc), path=log_path) from None
    return TopicPlan(
        topic=topic,
        role=role,
        table=spec.table,
        schema_name=channel.schema_name,
        type_name=full_type_name(channel.schema_name),
        decode=decode,
        convert=convert,
        context=ConvertContext.for_topic(topic, role, channel.schema_name, config.time),
    )


# --------------------------------------------------------------------------------------
# One batch
# --------------------------------------------------------------------------------------


def _decode_tolerant(
    plan: TopicPlan, payloads: Sequence[bytes]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Decode a batch; if some payload is broken, find which (one by one, the rare path)
    and decode the rest. Returns the columns of the good payloads and their mask."""
    ok = np.ones(len(payloads), dtype=bool)
    try:
        return plan.decode(payloads), ok
    except CdrError:
        pass
    for i, payload in enumerate(payloads):
        try:
            plan.decode([payload])
        except CdrError:
            ok[i] = False
    good = [p for p, keep in zip(payloads, ok.tolist(), strict=True) if keep]
    return (plan.decode(good) if good else {}), ok


@dataclass
class _BatchRows:
    """The rows one batch contributes to its table, and the table metadata they carry."""

    rows: pa.Table
    metadata: dict[str, str]


def convert_batch(
    plan: TopicPlan,
    log_time_ns: np.ndarray,
    payloads: Sequence[bytes],
    dedup: DuplicateFilter,
    account: TopicAccount,
    max_skew_ns: int,
) -> _BatchRows | None:
    """Dedup, decode, convert and screen one batch of a topic; update its account.

    Returns the rows to write (None when none survive).
    """
    n = len(payloads)
    account.read += n
    log_t = np.asarray(log_time_ns, dtype=np.int64)
    dup = dedup.check(log_t, payloads)
    if dup.any():
        account.rejects["duplicate"] += int(dup.sum())
        idx = np.flatnonzero(~dup)
        payloads = [payloads[i] for i in idx.tolist()]
        log_t = log_t[idx]
    if not payloads:
        return None
    cols, ok = _decode_tolerant(plan, payloads)
    if not ok.all():
        account.rejects["bad_payload"] += int((~ok).sum())
        log_t = log_t[ok]
    if not len(log_t):
        return None
    rows: RoleRows = plan.convert(cols, log_t, plan.context)
    keep = rows.finite.copy()
    if rows.message_of_row is None:
        # A time before 1970 comes only from a log time or stamp beyond int64 (2^63 ns) or a
        # corrupt one: no row may carry it (it would sort first and stretch the log).
        bad_time = rows.t_ns < 0
        account.rejects["bad_time"] += int(bad_time.sum())
        skew = (np.abs(rows.t_ns - log_t) > max_skew_ns) & ~rows.stamp_missing & ~bad_time
        account.rejects["clock_skew"] += int(skew.sum())
        keep &= ~skew & ~bad_time
        account.rejects["non_finite"] += int((~rows.finite & ~skew & ~bad_time).sum())
    else:
        account.rejects["non_finite"] += int((~rows.finite).sum())
    account.counts["stamp_missing"] += int((rows.stamp_missing & keep).sum())
    for key, per_msg in rows.counts.items():
        account.counts[key] += int(per_msg[keep].sum())
    kept = int(keep.sum())
    account.written += kept
    if rows.message_of_row is None:
        table = rows.table if kept == len(keep) else rows.table.filter(pa.array(keep))
    else:
        row_keep = keep[rows.message_of_row]
        table = rows.table if row_keep.all() else rows.table.filter(pa.array(row_keep))
    if rows.message_of_row is None and kept:
        t = table.column("t_ns").to_numpy()
        prior = np.iinfo(np.int64).min if account.max_t_ns is None else account.max_t_ns
        running = np.maximum.accumulate(np.concatenate([[prior], t[:-1]]))
        account.counts["out_of_order"] += int(np.count_nonzero(t < running))
        account.max_t_ns = int(max(prior, int(t.max())))
    account.rows += table.num_rows
    return _BatchRows(table, rows.metadata) if table.num_rows else None


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------


def _result_from_record(
    log_path: Path, log_id: str, record: StageRecord, detail: Mapping[str, Any], seconds: float
) -> IngestResult:
    topics = detail.get("topics", {}) if isinstance(detail, Mapping) else {}
    return IngestResult(
        log_path=log_path,
        log_id=log_id,
        status="up_to_date",
        row_counts=dict(record.row_counts),
        rejects=_nonzero(topics, "rejects"),
        lost=_nonzero(topics, "lost"),
        warnings=(),
        seconds=seconds,
    )


def _nonzero(topics: Mapping[str, Any], key: str) -> dict[str, dict[str, int]]:
    """topic -> reason -> count from the manifest's per-topic detail, zeros left out."""
    out: dict[str, dict[str, int]] = {}
    for topic, acc in topics.items():
        counts = {str(k): int(v) for k, v in dict(acc.get(key, {})).items() if v}
        if counts:
            out[topic] = counts
    return out


def _damage_json(damage: Iterable[Damage]) -> list[dict[str, Any]]:
    return [dataclasses.asdict(d) for d in damage]


class _Run:
    """The state of one ingest pass: a plan, account and duplicate filter per topic, a
    writer behind a reorder buffer per table. :meth:`consume` takes the reader's batches;
    :meth:`finish` completes the tables aside; :meth:`commit` publishes them all;
    :meth:`discard` removes everything."""

    def __init__(
        self,
        plans: dict[str, TopicPlan],
        buffers: dict[str, ReorderBuffer],
        config: IngestSettings,
        log_path: Path,
        *,
        source_sha256: str,
        cfg_hash: str,
    ) -> None:
        self.plans = plans
        self.buffers = buffers
        self.source_sha256 = source_sha256
        self.config_hash = cfg_hash
        self.writers = {name: b.writer for name, b in buffers.items()}
        self.config = config
        self.log_path = log_path
        self.accounts = {t: TopicAccount(t, p.role, p.type_name, p.table) for t, p in plans.items()}
        self.dedups = {t: DuplicateFilter() for t in plans}
        self.tf_rows: list[pa.Table] = []
        self.mcap_metadata: dict[str, dict[str, str]] = {}
        self.extra_plans: dict[tuple[str, str], TopicPlan] = {}
        self.timings: defaultdict[str, float] = defaultdict(float)
        self.outputs: list[str] = []
        self.warnings: list[str] = []

    def _plan(self, batch: MessageBatch) -> TopicPlan | None:
        topic = batch.channel.topic
        plan = self.plans.get(topic)
        if plan is None or batch.channel.schema_name == plan.schema_name:
            return plan
        # Another channel on the same topic with another type: plan it as well.
        key = (topic, batch.channel.schema_name)
        if key not in self.extra_plans:
            self.extra_plans[key] = plan_topic(
                topic, plan.role, batch.channel, self.config, self.log_path
            )
        return self.extra_plans[key]

    def consume(self, batch: MessageBatch) -> None:
        """Convert one batch and hand its rows to its table."""
        plan = self._plan(batch)
        if plan is None:
            return  # a topic the configuration does not use
        t0 = time.perf_counter()
        out = convert_batch(
            plan,
            batch.log_time_ns,
            batch.payloads,
            self.dedups[plan.topic],
            self.accounts[plan.topic],
            self.config.time.max_header_skew_ns,
        )
        t1 = time.perf_counter()
        if out is not None:
            if plan.role == "tf_static":
                self.tf_rows.append(out.rows)
            else:
                self.buffers[plan.table].add(out.rows, plan.topic, out.metadata)
        self.timings["decode_convert"] += t1 - t0
        self.timings["write"] += time.perf_counter() - t1

    def finish(self, report: ReadReport) -> None:
        """Count the reader's losses, check something usable came, complete every table."""
        for topic, by_reason in report.lost.items():
            if topic in self.accounts:
                self.accounts[topic].lost = {k: int(v) for k, v in by_reason.items() if v}
        self.warnings = _usable_roles(self.accounts, self.log_path)
        self.warnings += _reject_warnings(self.accounts)
        t0 = time.perf_counter()
        for buffer in self.buffers.values():
            buffer.flush()
        self.outputs = [name for name, w in self.writers.items() if w.finish()]
        for name in SENSOR_TABLES.values():
            if name in self.outputs and self.writers[name].rows:
                self._drop_time_outliers(name)
        if "truth_pose" in self.outputs:
            self._truth_to_pose_frame()
        self.timings["finish"] = time.perf_counter() - t0

    def _drop_time_outliers(self, name: str) -> None:
        """Rewrite a finished table without the rows :mod:`toolkit.ingestion.timecheck` finds
        stamped far outside the log's span, counting them per topic as ``time_outlier``."""
        old = self.writers[name]
        drop = stream_time_outliers(old.finished_path)
        if drop is None:
            return
        topics = (
            pq.read_table(old.finished_path, columns=["laser"]).column("laser").to_pylist()
            if name == "laser"
            else None
        )
        sources = [topic for topic, plan in self.plans.items() if plan.table == name]
        for i in np.flatnonzero(drop).tolist():
            account = self.accounts[topics[i] if topics is not None else sources[0]]
            account.rejects["time_outlier"] += 1
            account.written -= 1
            account.rows -= 1
        keep = pa.array(~drop)
        self.writers[name] = old.rewrite(
            lambda piece, first: piece.filter(keep.slice(first, piece.num_rows))
        )

    def _truth_to_pose_frame(self) -> None:
        """Rewrite the finished truth table in the pose's frame (see stages/truth.py)."""
        sim = sim_origin(self.mcap_metadata)
        if sim is None:
            self.warnings.append("truth_pose left in the simulator's frame: no terrain_sim origin")
            return
        moved = truth_to_pose_frame(
            self.writers["truth_pose"], self.writers["gps"].finished_path, sim
        )
        if isinstance(moved, str):
            self.warnings.append(moved)
        else:
            self.writers["truth_pose"] = moved

    def commit(self, log_dir: Path) -> list[str]:
        """Publish the finished tables, then write the JSON outputs; the file names."""
        files = [self.writers[name].publish().name for name in self.outputs]
        if self.tf_rows:
            atomic_write_json(log_dir / TF_STATIC_OUTPUT, _tf_json(self.tf_rows))
            files.append(TF_STATIC_OUTPUT)
        if self.mcap_metadata:
            atomic_write_json(log_dir / MCAP_METADATA_OUTPUT, self.mcap_metadata)
            files.append(MCAP_METADATA_OUTPUT)
        return files

    def discard(self) -> None:
        """Remove every partial file (after an error)."""
        for writer in self.writers.values():
            writer.abort()

    def row_counts(self) -> dict[str, int]:
        """Rows per output (tf_static: transforms)."""
        counts = {name: self.writers[name].rows for name in self.outputs}
        if self.tf_rows:
            counts["tf_static"] = sum(t.num_rows for t in self.tf_rows)
        return counts

    def rejects_by_topic(self) -> dict[str, dict[str, int]]:
        """topic -> reason -> count, zeros left out."""
        out: dict[str, dict[str, int]] = {}
        for topic, acc in self.accounts.items():
            nonzero = {k: v for k, v in acc.rejects.items() if v}
            if nonzero:
                out[topic] = nonzero
        return out

    def detail(self, report: ReadReport, missing: Mapping[str, list[str]]) -> dict[str, Any]:
        """The manifest's ``ingest`` section: per-topic accounting, reader damage, counts."""
        return {
            "topics": {t: a.to_json() for t, a in sorted(self.accounts.items())},
            "missing_topics": dict(missing),
            "missing_roles": sorted(
                role
                for role, topics in missing.items()
                if len(topics) == len(self.config.topics.by_role()[role])
            ),
            "absent_roles": list(self.config.topics.absent_roles()),
            "used_index": report.used_index,
            "damage": _damage_json(report.damage),
            "unknown_lost_bytes": dict(report.unknown_lost_bytes),
            "resorted_tables": sorted(n for n, w in self.writers.items() if w.resorted),
            "counts": _count_totals(self.accounts),
        }


def ingest_log(
    log_path: Path,
    workspace: Workspace,
    config: PipelineConfig,
    *,
    overwrite: bool = False,
    reorder_buffer_bytes: int = DEFAULT_REORDER_BUFFER_BYTES,
) -> IngestResult:
    """Ingest one MCAP log into ``WS/logs/<log_id>/`` (see the module docstring).

    Idempotent: when the manifest records an ingest of the same log content (sha256) under
    the same configuration and its outputs exist, nothing is rewritten and the status is
    ``"up_to_date"``; ``overwrite=True`` redoes it. Refuses (ConfigError) a configuration other
    than the workspace's unless ``overwrite``, and records it as ``WS/config.toml`` only once
    it has succeeded (a failed first ingest leaves no configuration behind).
    Raises StageError when none of the configured topics is in the log or nothing usable is,
    LogReadError when the file cannot be read at all. ``reorder_buffer_bytes`` bounds the
    rows each table holds back for sorting.
    """
    settings = IngestSettings(config.topics, config.time, reorder_buffer_bytes)
    result = run_stage(
        SPEC, workspace, config, overwrite=overwrite, settings=settings, source=Path(log_path)
    )
    return cast(IngestResult, result)


@dataclass(frozen=True)
class IngestSettings:
    """What ingest reads of the configuration: the topics of each role and the clocks; and
    how many bytes each table holds back for sorting (not a configuration key)."""

    topics: TopicsConfig
    time: TimeConfig
    buffer_bytes: int = DEFAULT_REORDER_BUFFER_BYTES


@dataclass(frozen=True)
class _Source:
    """The log file being ingested: its path, sha256 and identity when hashed."""

    path: Path
    sha256: str
    identity: tuple[int, int, int, int]


def _locate(log_path: Path) -> tuple[str, dict[str, str], _Source]:
    """The log's id and its file's hash (ingest's one input); LogReadError when it is no
    regular file."""
    if not log_path.exists():
        raise LogReadError("no such log file", path=log_path)
    if not log_path.is_file():  # a directory, a FIFO, a device: never opened, never hashed
        raise LogReadError("not a regular file (a log is an MCAP file)", path=log_path)
    before = _identity(log_path)
    sha256 = file_sha256(log_path)
    return make_log_id(log_path.stem, sha256), {"log": sha256}, _Source(log_path, sha256, before)


def _recall(last: Recalled) -> IngestResult:
    """The outcome of an up-to-date ingest, from its record."""
    source: _Source = last.found
    _log.info("%s: up to date (%s)", source.path, last.log_id)
    return _result_from_record(
        source.path, last.log_id, last.record, last.header.get(STAGE, {}), last.seconds
    )


def _compute(call: Call) -> Made:
    """Read the log into its tables (the module docstring); the runner records them."""
    config: IngestSettings = call.settings
    source: _Source = call.found
    log_path, sha256, before = source.path, source.sha256, source.identity
    log_dir, log_id, cfg_hash, start = call.files.dir, call.log_id, call.config_hash, call.start
    reorder_buffer_bytes = config.buffer_bytes
    record = call.manifest.stage(STAGE)
    run: _Run | None = None
    try:
        with LogReader(log_path, topics=_configured_topics(config)) as reader:
            plans, missing, warnings = resolve_topics(config, reader.channels(), log_path)
            buffers = _make_buffers(
                plans,
                log_dir,
                source_sha256=sha256,
                config_hash=cfg_hash,
                buffer_bytes=reorder_buffer_bytes,
            )
            run = _Run(plans, buffers, config, log_path, source_sha256=sha256, cfg_hash=cfg_hash)
            t_read = time.perf_counter()
            batches = reader.batches()
            for batch in progress(batches, desc=f"ingest {log_path.name}", unit="batch"):
                run.consume(batch)
            spent = run.timings["decode_convert"] + run.timings["write"]
            run.timings["read"] = time.perf_counter() - t_read - spent
            report = reader.report
        if _identity(log_path) != before:  # the hash must describe the bytes read
            raise LogReadError(
                "the log changed while it was read (size or modification time); ingest "
                "it again once it is complete",
                path=log_path,
            )
        run.mcap_metadata = report.metadata
        run.finish(report)
        warnings += run.warnings
        damage_warning = report.summary_line()  # the same line `terrain info` prints
        if damage_warning:
            warnings.append(damage_warning)
        for w in warnings:
            _log.warning("%s: %s", log_path, w)
        out_files = run.commit(log_dir)
    except BaseException:
        if run is not None:
            run.discard()
        raise
    _remove_stale_outputs(log_dir, record, out_files)
    run.timings["total"] = time.perf_counter() - start
    rejects_total: Counter[str] = Counter()
    for by_reason in run.rejects_by_topic().values():
        rejects_total.update(by_reason)
    source_header = {
        "path": str(log_path.resolve()),
        "sha256": sha256,
        "log_id": log_id,
        "size_bytes": log_path.stat().st_size,
    }
    result = IngestResult(
        log_path=log_path,
        log_id=log_id,
        status="ingested",
        row_counts=run.row_counts(),
        rejects=run.rejects_by_topic(),
        lost={t: dict(a.lost) for t, a in run.accounts.items() if a.lost},
        warnings=tuple(warnings),
        seconds=time.perf_counter() - start,
    )
    _log.info("%s", result.summary())
    return Made(
        result,
        tuple(out_files),
        row_counts=run.row_counts(),
        rejects=dict(sorted(rejects_total.items())),
        timings_s=run.timings,
        warnings=tuple(warnings),
        header={"source": source_header, "ingest": run.detail(report, missing)},
    )


def _identity(path: Path) -> tuple[int, int, int, int]:
    """(device, inode, size, mtime ns): what changes when a file is rewritten or appended."""
    st = path.stat()
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _configured_topics(config: IngestSettings) -> list[str]:
    return [t for topics in config.topics.by_role().values() for t in topics]


def _make_buffers(
    plans: Mapping[str, TopicPlan],
    log_dir: Path,
    *,
    source_sha256: str,
    config_hash: str,
    buffer_bytes: int,
) -> dict[str, ReorderBuffer]:
    """A writer behind a reorder buffer per sensor table (always) and per truth table the
    log has."""
    sources: dict[str, list[str]] = {}
    for topic, plan in plans.items():
        sources.setdefault(plan.table, []).append(topic)
    tables = list(SENSOR_TABLES.values()) + [
        TRUTH_TABLES[r] for r in TRUTH_TABLES if any(p.role == r for p in plans.values())
    ]
    return {
        name: ReorderBuffer(
            TableWriter(
                log_dir / f"{name}.parquet",
                name if name in SCHEMA_TABLES else None,
                table_name=name,
                source_sha256=source_sha256,
                config_hash=config_hash,
                sort_by="t_ns",
            ),
            sources.get(name, []),
            buffer_bytes=buffer_bytes,
        )
        for name in tables
    }


def _usable_roles(accounts: Mapping[str, TopicAccount], log_path: Path) -> list[str]:
    """Warnings for roles whose topics are in the log but gave no usable message; a
    StageError when no role gave any (nothing usable in the log at all)."""
    warnings: list[str] = []
    roles = sorted({a.role for a in accounts.values()})
    empty: list[str] = []
    for role in roles:
        accs = [a for a in accounts.values() if a.role == role]
        if sum(a.written for a in accs) > 0:
            continue
        read = sum(a.read for a in accs)
        rejected: Counter[str] = Counter()
        lost: Counter[str] = Counter()
        for a in accs:
            rejected.update(a.rejects)
            lost.update(a.lost)
        parts = [f"{read} read"]
        parts += [f"{v} rejected ({k})" for k, v in sorted(rejected.items()) if v]
        parts += [f"{v} lost ({k})" for k, v in sorted(lost.items()) if v]
        empty.append(f"{role} ({', '.join(a.topic for a in accs)}: {', '.join(parts)})")
    if empty and len(empty) == len(roles):
        raise StageError(
            f"nothing usable: no message of any role ({'; '.join(empty)})", path=log_path
        )
    if empty:
        warnings.append(f"no usable message, tables empty: {'; '.join(empty)}")
    return warnings


def _reject_warnings(accounts: Mapping[str, TopicAccount]) -> list[str]:
    """One warning per topic that rejected more than :data:`REJECT_WARN_FRACTION` of what it
    read (with the count by reason): many rejects usually mean a wrong clock or config."""
    lines = []
    for topic, acc in sorted(accounts.items()):
        rejected = sum(acc.rejects.values())
        if acc.read and rejected > REJECT_WARN_FRACTION * acc.read:
            reasons = ", ".join(f"{k} {v}" for k, v in sorted(acc.rejects.items()) if v)
            lines.append(f"topic {topic}: {rejected} of {acc.read} messages rejected ({reasons})")
    return lines


def _count_totals(accounts: Mapping[str, TopicAccount]) -> dict[str, int]:
    total: Counter[str] = Counter()
    for acc in accounts.values():
        total.update(acc.counts)
    return dict(sorted((k, v) for k, v in total.items()))


def _tf_json(tables: Sequence[pa.Table]) -> dict[str, Any]:
    """Static transforms, the latest per (parent, child) pair."""
    merged = pa.concat_tables(tables).to_pylist()
    latest: dict[tuple[str, str], dict[str, Any]] = {}
    for row in merged:
        latest[(row["parent_frame"], row["child_frame"])] = row
    transforms = [
        {
            "parent_frame": r["parent_frame"],
            "child_frame": r["child_frame"],
            "t_ns": int(r["t_ns"]),
            "translation_m": [r["tx"], r["ty"], r["tz"]],
            "rotation_xyzw": [r["qx"], r["qy"], r["qz"], r["qw"]],
        }
        for r in latest.values()
    ]
    return {"transforms": transforms}


def _remove_stale_outputs(log_dir: Path, old: StageRecord | None, current: Sequence[str]) -> None:
    """Remove outputs a previous ingest wrote that this one did not (e.g. a role dropped)."""
    if old is None:
        return
    for name in set(old.outputs) - set(current):
        if "/" in name or name.startswith("."):
            continue
        with contextlib.suppress(FileNotFoundError):
            (log_dir / name).unlink()


SPEC = Stage(
    STAGE,
    "log",
    makes=("imu", "gps", "heading", "wheels", "laser", "tf_static", "mcap_metadata"),
    sections=CONFIG_SECTIONS,
    settings=IngestSettings,
    locate=_locate,
    compute=_compute,
    recall=_recall,
    rows=None,
    unit="log",
)

#: The hash of the configuration this stage reads (its up-to-date key).
stage_config_hash = SPEC.config_hash


__all__ = [
    "SPEC",
    "CONFIG_SECTIONS",
    "STAGE",
    "IngestResult",
    "MCAP_METADATA_OUTPUT",
    "TopicAccount",
    "TopicPlan",
    "convert_batch",
    "ingest_log",
    "plan_topic",
    "resolve_topics",
    "stage_config_hash",
]
