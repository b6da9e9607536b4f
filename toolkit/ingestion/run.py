"""One ingest pass over a log: a plan, account and duplicate filter per topic, a table writer
behind a reorder buffer per table, and the files they become.

:meth:`IngestRun.consume` takes the reader's batches; :meth:`IngestRun.finish` completes the
tables aside (sorted, stray stamps dropped: :mod:`toolkit.ingestion.timecheck`);
:meth:`IngestRun.commit` publishes them all with the JSON outputs; :meth:`IngestRun.discard`
removes every partial file. Nothing is published until every table is complete.
"""

from __future__ import annotations

import dataclasses
import time
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.atomic import atomic_write_json
from toolkit.config import LidarConfig, TimeConfig, TopicsConfig
from toolkit.ingestion.accounts import TopicAccount, count_totals, reject_warnings, usable_roles
from toolkit.ingestion.converters import laser_notices
from toolkit.ingestion.dedup import DuplicateFilter
from toolkit.ingestion.lidar import check_sweeps, lidar_notices
from toolkit.ingestion.plans import TopicPlan, plan_topic
from toolkit.ingestion.reorder import ReorderBuffer
from toolkit.ingestion.roles import ROLE_SPECS, tables_written
from toolkit.ingestion.screen import convert_batch
from toolkit.ingestion.timecheck import stream_time_outliers
from toolkit.layout import log_file_name
from toolkit.mcapio.reader import Damage, MessageBatch, ReadReport
from toolkit.tableio import TableWriter, table_schema_names


def schema_tables() -> frozenset[str]:
    """Tables with a contract schema in schemas/tables; any other (truth_features) is
    written as its converter builds it."""
    return frozenset(table_schema_names())


#: Output name of the static transforms.
TF_STATIC_OUTPUT = log_file_name("tf_static")

#: Output name of the log's MCAP metadata records (record name -> key -> value).
MCAP_METADATA_OUTPUT = log_file_name("mcap_metadata")


def make_buffers(
    plans: Mapping[str, TopicPlan],
    log_dir: Path,
    *,
    source_sha256: str,
    config_hash: str,
    buffer_bytes: int,
) -> dict[str, ReorderBuffer]:
    """A writer behind a reorder buffer per table a role always writes (the sensors',
    empty when absent) and per table of a role written when present that the log has
    (:func:`~toolkit.ingestion.roles.tables_written`, read now: a role added since import
    counts)."""
    sources: dict[str, list[str]] = {}
    for topic, plan in plans.items():
        sources.setdefault(plan.table, []).append(topic)
    present = tables_written("present")
    tables = list(tables_written("always").values()) + [
        present[r] for r in present if any(p.role == r for p in plans.values())
    ]
    with_schema = schema_tables()
    bulk = {spec.table for spec in ROLE_SPECS.values() if spec.bulk}
    return {
        name: ReorderBuffer(
            TableWriter(
                log_dir / log_file_name(name),
                name if name in with_schema else None,
                table_name=name,
                source_sha256=source_sha256,
                config_hash=config_hash,
                sort_by="t_ns",
                bulk=name in bulk,
            ),
            sources.get(name, []),
            buffer_bytes=buffer_bytes,
        )
        for name in tables
    }


class IngestRun:
    """The state of one ingest pass (the module docstring)."""

    def __init__(
        self,
        plans: dict[str, TopicPlan],
        buffers: dict[str, ReorderBuffer],
        topics: TopicsConfig,
        time_config: TimeConfig,
        log_path: Path,
        lidar: LidarConfig | None = None,
    ) -> None:
        self.plans = plans
        self.buffers = buffers
        self.writers = {name: b.writer for name, b in buffers.items()}
        self.topics = topics
        self.time = time_config
        self.log_path = log_path
        self.lidar = lidar
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
                topic, plan.role, batch.channel, self.time, self.log_path, self.lidar
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
            self.time.max_header_skew_ns,
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
        self.warnings = usable_roles(self.accounts, self.log_path)
        self.warnings += reject_warnings(self.accounts)
        check_sweeps(self.accounts)
        self.warnings += laser_notices(self.accounts) + lidar_notices(self.accounts)
        t0 = time.perf_counter()
        for buffer in self.buffers.values():
            buffer.flush()
        self.outputs = [name for name, w in self.writers.items() if w.finish()]
        for name in tables_written("always").values():
            if name in self.outputs and self.writers[name].rows:
                self._drop_time_outliers(name)
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

    def commit(self, log_dir: Path) -> list[str]:
        """Publish the finished tables, then write the JSON outputs; the file names."""
        files = [self.writers[name].publish().name for name in self.outputs]
        if self.tf_rows:
            atomic_write_json(log_dir / TF_STATIC_OUTPUT, tf_json(self.tf_rows))
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

    def detail(self, report: ReadReport, missing: Mapping[str, list[str]]) -> dict[str, Any]:
        """The manifest's ``ingest`` section: per-topic accounting, reader damage, counts."""
        return {
            "topics": {t: a.to_json() for t, a in sorted(self.accounts.items())},
            "missing_topics": dict(missing),
            "missing_roles": sorted(
                role
                for role, topics in missing.items()
                if len(topics) == len(self.topics.by_role()[role])
            ),
            "absent_roles": list(self.topics.absent_roles()),
            "used_index": report.used_index,
            "damage": damage_json(report.damage),
            "unknown_lost_bytes": dict(report.unknown_lost_bytes),
            "resorted_tables": sorted(n for n, w in self.writers.items() if w.resorted),
            "counts": count_totals(self.accounts),
        }


def damage_json(damage: Iterable[Damage]) -> list[dict[str, Any]]:
    """The reader's damage list, JSON-ready."""
    return [dataclasses.asdict(d) for d in damage]


def tf_json(tables: Sequence[pa.Table]) -> dict[str, Any]:
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


__all__ = [
    "MCAP_METADATA_OUTPUT",
    "TF_STATIC_OUTPUT",
    "schema_tables",
    "IngestRun",
    "damage_json",
    "make_buffers",
    "tf_json",
]
