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
from toolkit.config import ImuConfig, LidarConfig, TimeConfig, TopicsConfig
from toolkit.geometry.static_transforms import (
    StaticTransformSet,
    TransformRecord,
    select_static_transforms,
)
from toolkit.ingestion.accounts import TopicAccount, count_totals, reject_warnings, usable_roles
from toolkit.ingestion.converters import laser_notices
from toolkit.ingestion.dedup import DuplicateFilter
from toolkit.ingestion.imucheck import IMU_REJECT_REASONS, stream_imu_check
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
        imu: ImuConfig | None = None,
    ) -> None:
        self.plans = plans
        self.buffers = buffers
        self.writers = {name: b.writer for name, b in buffers.items()}
        self.topics = topics
        self.time = time_config
        self.log_path = log_path
        self.lidar = lidar
        self.imu = imu if imu is not None else ImuConfig()
        self.accounts = {t: TopicAccount(t, p.role, p.type_name, p.table) for t, p in plans.items()}
        for account in self.accounts.values():
            if account.table == "imu":  # checked once the table is finished (imucheck)
                account.rejects.update(dict.fromkeys(IMU_REJECT_REASONS, 0))
        self.dedups = {t: DuplicateFilter() for t in plans}
        self.tf_rows: list[pa.Table] = []
        #: The static transforms kept of ``tf_rows`` (:meth:`finish`), None before or without.
        self.tf_static: StaticTransformSet | None = None
        self.mcap_metadata: dict[str, dict[str, str]] = {}
        self.extra_plans: dict[tuple[str, int], TopicPlan] = {}
        #: Lines for the terminal from the channels planned while reading (schema notices;
        #: those of the first channels are said by resolve_topics).
        self.notices: list[str] = []
        self._said = {p.notice for p in plans.values() if p.notice}
        self.timings: defaultdict[str, float] = defaultdict(float)
        self.outputs: list[str] = []
        self.warnings: list[str] = []

    def _plan(self, batch: MessageBatch) -> TopicPlan | None:
        topic = batch.channel.topic
        plan = self.plans.get(topic)
        if plan is None or batch.channel.id == plan.channel_id:
            return plan
        # Another channel on the same topic, with another type or another schema of it: plan
        # it as well (its schema checked as the first channel's was).
        key = (topic, batch.channel.id)
        if key not in self.extra_plans:
            extra = plan_topic(
                topic, plan.role, batch.channel, self.time, self.log_path, self.lidar
            )
            self.extra_plans[key] = extra
            if extra.notice and extra.notice not in self._said:
                self._said.add(extra.notice)
                self.notices.append(extra.notice)
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
        self.warnings = [*self.notices, *usable_roles(self.accounts, self.log_path)]
        self.warnings += reject_warnings(self.accounts)
        check_sweeps(self.accounts)
        self.warnings += laser_notices(self.accounts) + lidar_notices(self.accounts)
        if self.tf_rows:
            self.tf_static = select_static_transforms(
                tf_records(self.tf_rows), self.topics.tf_static or "tf_static"
            )
            self.warnings += self.tf_static.warnings
        t0 = time.perf_counter()
        for buffer in self.buffers.values():
            buffer.flush()
        self.outputs = [name for name, w in self.writers.items() if w.finish()]
        for name in tables_written("always").values():
            if name in self.outputs and self.writers[name].rows:
                self._drop_time_outliers(name)
        if "imu" in self.outputs and self.writers["imu"].rows:
            self.warnings += self._drop_impossible_imu()
        self.timings["finish"] = time.perf_counter() - t0

    def _drop_impossible_imu(self) -> list[str]:
        """Rewrite the finished IMU table without the samples no sensor produces
        (:mod:`toolkit.ingestion.imucheck`), counted per reason; a warning per reason, since
        each one would have moved the pose."""
        old = self.writers["imu"]
        verdict = stream_imu_check(old.finished_path, self.imu)
        if verdict is None:
            return []
        topic = next(t for t, plan in self.plans.items() if plan.table == "imu")
        account = self.accounts[topic]
        masks = dict(zip(IMU_REJECT_REASONS, (verdict.beyond_range, verdict.spike), strict=True))
        why = {
            "imu_beyond_range": (
                f"beyond the sensor's full scale ([imu] gyro_range_radps "
                f"{self.imu.gyro_range_radps:g}, accel_range_mps2 {self.imu.accel_range_mps2:g})"
            ),
            "imu_spike": (
                f"gyro spikes no vehicle makes ([imu] max_angular_accel_radps2 "
                f"{self.imu.max_angular_accel_radps2:g})"
            ),
        }
        lines = []
        for reason, mask in masks.items():
            n = int(np.count_nonzero(mask))
            if n:
                account.rejects[reason] += n
                account.written -= n
                account.rows -= n
                lines.append(f"topic {topic}: {n} IMU samples rejected, {why[reason]}")
        keep = pa.array(~(verdict.beyond_range | verdict.spike))
        self.writers["imu"] = old.rewrite(
            lambda piece, first: piece.filter(keep.slice(first, piece.num_rows))
        )
        return lines

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
        if self.tf_static is not None:
            atomic_write_json(log_dir / TF_STATIC_OUTPUT, tf_json(self.tf_static))
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
        """Rows per output (tf_static: the transforms kept)."""
        counts = {name: self.writers[name].rows for name in self.outputs}
        if self.tf_static is not None:
            counts["tf_static"] = len(self.tf_static.transforms)
        return counts

    def detail(self, report: ReadReport, missing: Mapping[str, list[str]]) -> dict[str, Any]:
        """The manifest's ``ingest`` section: per-topic accounting, reader damage, counts, and
        the static transforms kept and dropped (``tf_static``, when the log has them)."""
        out: dict[str, Any] = {
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
        if self.tf_static is not None:
            out["tf_static"] = self.tf_static.to_json()
        return out


def damage_json(damage: Iterable[Damage]) -> list[dict[str, Any]]:
    """The reader's damage list, JSON-ready."""
    return [dataclasses.asdict(d) for d in damage]


def tf_records(tables: Sequence[pa.Table]) -> list[TransformRecord]:
    """The transforms of the tf_static converter's rows, in the log's order."""
    return [
        TransformRecord(
            r["parent_frame"],
            r["child_frame"],
            int(r["t_ns"]),
            (r["tx"], r["ty"], r["tz"]),
            (r["qx"], r["qy"], r["qz"], r["qw"]),
        )
        for r in pa.concat_tables(tables).to_pylist()
    ]


def tf_json(kept: StaticTransformSet) -> dict[str, Any]:
    """``tf_static.json``: the transforms kept, one per child frame (normalised, finite)."""
    return {"transforms": [t.to_json() for t in kept.transforms]}


__all__ = [
    "MCAP_METADATA_OUTPUT",
    "TF_STATIC_OUTPUT",
    "schema_tables",
    "IngestRun",
    "damage_json",
    "make_buffers",
    "tf_json",
    "tf_records",
]
