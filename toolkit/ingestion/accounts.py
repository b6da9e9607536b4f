"""Faithful accounting, per topic: every message read is written or rejected for one reason.

``read = written + sum(rejects)``; messages the reader could not salvage from a damaged file
are counted apart, by reason (``lost``). The reasons and the order they are checked in are
:data:`REJECT_REASONS` (``docs/ingest.md`` says what each means); ``counts`` are things kept
but worth reporting (``out_of_order``, ``stamp_missing``, laser no-returns, GPS without a fix).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from toolkit.errors import StageError

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
    #: The kept messages' (stamp, span of their rows' times) in ns, for the topics whose
    #: messages are sweeps (a lidar's clouds): checked against the period once all are read.
    sweeps: list[tuple[Any, Any]] = field(default_factory=list)
    #: Their period (ns, the median step between stamps) once checked; 0 before.
    period_ns: float = 0.0

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


def usable_roles(accounts: Mapping[str, TopicAccount], log_path: Path) -> list[str]:
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


def reject_warnings(accounts: Mapping[str, TopicAccount]) -> list[str]:
    """One warning per topic that rejected more than :data:`REJECT_WARN_FRACTION` of what it
    read (with the count by reason): many rejects usually mean a wrong clock or config."""
    lines = []
    for topic, acc in sorted(accounts.items()):
        rejected = sum(acc.rejects.values())
        if acc.read and rejected > REJECT_WARN_FRACTION * acc.read:
            reasons = ", ".join(f"{k} {v}" for k, v in sorted(acc.rejects.items()) if v)
            lines.append(f"topic {topic}: {rejected} of {acc.read} messages rejected ({reasons})")
    return lines


def count_totals(accounts: Mapping[str, TopicAccount]) -> dict[str, int]:
    """The kept-but-counted totals over every topic, by name."""
    total: Counter[str] = Counter()
    for acc in accounts.values():
        total.update(acc.counts)
    return dict(sorted((k, v) for k, v in total.items()))


def rejects_by_topic(accounts: Mapping[str, TopicAccount]) -> dict[str, dict[str, int]]:
    """topic -> reason -> count, zeros left out."""
    out: dict[str, dict[str, int]] = {}
    for topic, acc in accounts.items():
        nonzero = {k: v for k, v in acc.rejects.items() if v}
        if nonzero:
            out[topic] = nonzero
    return out


def reject_totals(accounts: Mapping[str, TopicAccount]) -> dict[str, int]:
    """reason -> count over every topic, zeros left out, sorted by reason."""
    total: Counter[str] = Counter()
    for by_reason in rejects_by_topic(accounts).values():
        total.update(by_reason)
    return dict(sorted(total.items()))


def lost_by_topic(accounts: Mapping[str, TopicAccount]) -> dict[str, dict[str, int]]:
    """topic -> reason -> messages the reader could not salvage, topics without loss left out."""
    return {t: dict(a.lost) for t, a in accounts.items() if a.lost}


__all__ = [
    "REJECT_REASONS",
    "REJECT_WARN_FRACTION",
    "TopicAccount",
    "count_totals",
    "lost_by_topic",
    "reject_totals",
    "reject_warnings",
    "rejects_by_topic",
    "usable_roles",
]
