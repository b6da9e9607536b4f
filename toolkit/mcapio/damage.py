"""What a read of an MCAP log found wrong: the damage reasons, and the report of a pass.

The reasons are described in :mod:`toolkit.mcapio.reader`; :class:`ReadReport` is the one
account of a log's damage that ``terrain info`` and ``terrain ingest`` both print.
"""

from __future__ import annotations

from dataclasses import dataclass, field

NO_SUMMARY = "no_summary"
BAD_INDEX = "bad_index"
TRUNCATED = "truncated"
CHUNK_CRC = "chunk_crc"
CHUNK_DECOMPRESS = "chunk_decompress"
UNSUPPORTED_COMPRESSION = "unsupported_compression"
BAD_RECORD = "bad_record"
UNKNOWN_CHANNEL = "unknown_channel"
CHUNK_SIZE = "chunk_size"


@dataclass(frozen=True)
class Damage:
    """Something wrong found at byte ``offset`` of the file (``reason``: see module docstring)."""

    reason: str
    offset: int
    detail: str


@dataclass
class ReadReport:
    """What a pass of :meth:`LogReader.batches` delivered, and what it could not.

    Besides messages: the Metadata records met (name -> key -> value, records of one name
    merged, later keys winning), the Attachment records' names, and the Chunk records met with
    their compression (``"none"`` for uncompressed). This report is the one account of a
    log's damage: ``terrain info`` and ``terrain ingest`` both print it (:meth:`summary_line`).
    """

    used_index: bool
    messages_read: dict[str, int] = field(default_factory=dict)
    lost: dict[str, dict[str, int]] = field(default_factory=dict)
    damage: list[Damage] = field(default_factory=list)
    unknown_lost_bytes: dict[str, int] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachment_names: list[str] = field(default_factory=list)
    chunk_count: int = 0
    compression: set[str] = field(default_factory=set)

    def reasons(self) -> set[str]:
        """The reasons of every damage found."""
        return {d.reason for d in self.damage}

    def lost_total(self) -> dict[str, int]:
        """Messages lost, by reason, over every topic."""
        total: dict[str, int] = {}
        for by_reason in self.lost.values():
            for reason, n in by_reason.items():
                total[reason] = total.get(reason, 0) + n
        return {k: v for k, v in sorted(total.items()) if v}

    def summary_line(self) -> str | None:
        """One line on what is wrong with the file and what that cost, or None if intact.

        ``no_summary`` alone loses nothing: a log written without an index is not damaged,
        so it gets no line either."""
        reasons: dict[str, int] = {}
        for d in self.damage:
            reasons[d.reason] = reasons.get(d.reason, 0) + 1
        lost = self.lost_total()
        unknown = sum(self.unknown_lost_bytes.values())
        if set(reasons) <= {NO_SUMMARY} and not lost and not unknown:
            return None
        what = ", ".join(f"{k} x{v}" if v > 1 else k for k, v in sorted(reasons.items()))
        line = f"damaged log ({what or 'damage'}): read {sum(self.messages_read.values())} messages"
        if lost:
            detail = ", ".join(f"{v} {k}" for k, v in lost.items())
            line += f", lost {sum(lost.values())} messages ({detail})"
        if unknown:
            line += f", {unknown} bytes of unknown content lost"
        return line
