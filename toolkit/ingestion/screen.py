"""One batch of one topic: dedup, decode, convert and screen it into rows for its table.

The checks run in the order of :data:`~toolkit.ingestion.accounts.REJECT_REASONS` and each
rejected message is counted once, under the first reason that applies, in the topic's
:class:`~toolkit.ingestion.accounts.TopicAccount` (``docs/ingest.md`` lists the reasons).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from toolkit.arrays import BoolArray, IntArray
from toolkit.errors import CdrError
from toolkit.ingestion.accounts import TopicAccount
from toolkit.ingestion.dedup import DuplicateFilter
from toolkit.ingestion.plans import TopicPlan
from toolkit.ingestion.rows import RoleRows


@dataclass
class BatchRows:
    """The rows one batch contributes to its table, and the table metadata they carry."""

    rows: pa.Table
    metadata: dict[str, str]


def decode_tolerant(
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


def convert_batch(
    plan: TopicPlan,
    log_time_ns: np.ndarray,
    payloads: Sequence[bytes],
    dedup: DuplicateFilter,
    account: TopicAccount,
    max_skew_ns: int,
) -> BatchRows | None:
    """Dedup, decode, convert and screen one batch of a topic; update its account.

    Returns the rows to write (None when none survive).
    """
    account.read += len(payloads)
    log_t, payloads = _drop_duplicates(
        np.asarray(log_time_ns, dtype=np.int64), payloads, dedup, account
    )
    if not payloads:
        return None
    cols, ok = decode_tolerant(plan, payloads)
    if not ok.all():
        account.rejects["bad_payload"] += int((~ok).sum())
        log_t = log_t[ok]
    if not len(log_t):
        return None
    rows: RoleRows = plan.convert(cols, log_t, plan.context)
    keep = _screen(rows, log_t, account, max_skew_ns)
    table = _kept_table(rows, keep)
    if rows.message_of_row is None and int(keep.sum()):
        _count_out_of_order(table, account)
    account.rows += table.num_rows
    return BatchRows(table, rows.metadata) if table.num_rows else None


def _drop_duplicates(
    log_t: IntArray, payloads: Sequence[bytes], dedup: DuplicateFilter, account: TopicAccount
) -> tuple[IntArray, Sequence[bytes]]:
    """The batch without the messages that repeat earlier ones (counted ``duplicate``)."""
    dup = dedup.check(log_t, payloads)
    if not dup.any():
        return log_t, payloads
    account.rejects["duplicate"] += int(dup.sum())
    idx = np.flatnonzero(~dup)
    return log_t[idx], [payloads[i] for i in idx.tolist()]


def _screen(rows: RoleRows, log_t: IntArray, account: TopicAccount, max_skew_ns: int) -> BoolArray:
    """The mask of messages kept; counts the rejected by reason and the kept's counts, and
    adds the kept to ``written``."""
    keep = rows.finite.copy()
    message_t = rows.t_ns if rows.message_of_row is None else rows.message_t_ns
    if message_t is not None:
        # A time before 1970 comes only from a log time or stamp beyond int64 (2^63 ns) or a
        # corrupt one: no row may carry it (it would sort first and stretch the log).
        bad_time = message_t < 0
        account.rejects["bad_time"] += int(bad_time.sum())
        skew = (np.abs(message_t - log_t) > max_skew_ns) & ~rows.stamp_missing & ~bad_time
        account.rejects["clock_skew"] += int(skew.sum())
        keep &= ~skew & ~bad_time
        account.rejects["non_finite"] += int((~rows.finite & ~skew & ~bad_time).sum())
    else:
        account.rejects["non_finite"] += int((~rows.finite).sum())
    account.counts["stamp_missing"] += int((rows.stamp_missing & keep).sum())
    for key, per_msg in rows.counts.items():
        account.counts[key] += int(per_msg[keep].sum())
    if rows.span_ns is not None and rows.message_t_ns is not None:
        account.sweeps.append((rows.message_t_ns[keep], rows.span_ns[keep]))
    account.written += int(keep.sum())
    return keep


def _kept_table(rows: RoleRows, keep: BoolArray) -> pa.Table:
    """The rows of the kept messages (every element row of a kept list message)."""
    if rows.message_of_row is None:
        return rows.table if int(keep.sum()) == len(keep) else rows.table.filter(pa.array(keep))
    row_keep = keep[rows.message_of_row]
    return rows.table if row_keep.all() else rows.table.filter(pa.array(row_keep))


def _count_out_of_order(table: pa.Table, account: TopicAccount) -> None:
    """Count rows earlier than one before them on the topic (``out_of_order``)."""
    t = table.column("t_ns").to_numpy()
    prior = np.iinfo(np.int64).min if account.max_t_ns is None else account.max_t_ns
    running = np.maximum.accumulate(np.concatenate([[prior], t[:-1]]))
    account.counts["out_of_order"] += int(np.count_nonzero(t < running))
    account.max_t_ns = int(max(prior, int(t.max())))


__all__ = ["BatchRows", "convert_batch", "decode_tolerant"]
